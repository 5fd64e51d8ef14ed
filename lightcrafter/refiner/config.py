"""Refiner configuration: pydantic models (:class:`RefinerSettings`), two presets (``tiny`` and ``paper``).

The models are the only definition of the refiner's keys, types, ranges, defaults and docs (the
workflow's ``refiner`` section is this model; config/README.md is generated from it). A run's config
is ``resolve_config(overrides)``: the model's defaults, the preset named by ``overrides["preset"]``
(default ``tiny`` here; the workflow's default is ``paper``) and the overrides, deep-merged and
validated; the result is a plain dict. Unknown keys at any depth are an error, so a typo never falls
back to a default.
"""

from __future__ import annotations

import copy
from typing import Literal, Optional, Union

from pydantic import (BaseModel, ConfigDict, Field, NonNegativeFloat, NonNegativeInt, PositiveFloat, PositiveInt,
                      model_validator)

# CogVideoX-5B(-I2V) scheduler_config.json, as published with the checkpoint. The diffusers class
# defaults differ (epsilon, leading, snr_shift 3.0), so the parameterisation is always set from here
# (or from the local checkpoint's own file when a model path is configured).
COGVIDEOX_5B_SCHEDULER: dict = {
    "num_train_timesteps": 1000,
    "beta_start": 0.00085,
    "beta_end": 0.012,
    "beta_schedule": "scaled_linear",
    "clip_sample": False,
    "clip_sample_range": 1.0,
    "sample_max_value": 1.0,
    "set_alpha_to_one": True,
    "steps_offset": 0,
    "prediction_type": "v_prediction",
    "rescale_betas_zero_snr": True,
    "snr_shift_scale": 1.0,
    "timestep_spacing": "trailing",
    "trained_betas": None,
}

TINY_TRANSFORMER: dict = {
    # modelled on diffusers' own CPU test config (tests/models/transformers/
    # test_models_transformer_cogvideox.py), a little wider so it can learn something.
    # inner dim 4 * 64 = 256 >= the 2x2-patch output size 4 * 64 latent channels, so the network
    # can represent "copy the proxy" (a narrower one bottlenecks every token).
    "num_attention_heads": 4,
    "attention_head_dim": 64,
    "time_embed_dim": 64,
    "text_embed_dim": 16,
    "num_layers": 2,
    "sample_width": 12,  # latent width the sincos embedding is precomputed for (recomputed if different)
    "sample_height": 8,
    "sample_frames": 9,  # pixel frames
    "patch_size": 2,
    "temporal_compression_ratio": 4,
    "max_text_seq_length": 8,
    "use_rotary_positional_embeddings": False,
    "use_learned_positional_embeddings": False,
}

class _Section(BaseModel):
    """A refiner config section: unknown keys are an error, values are checked on assignment too."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class RefinerModelSettings(_Section):
    kind: Literal["tiny", "paper"] = Field(
        "tiny", description="tiny (random-init transformer, DCT patch autoencoder, CPU) | paper (CogVideoX-5B-I2V "
        "from model_path)")
    model_path: Optional[str] = Field(
        None, description="local diffusers folder of CogVideoX-5B-I2V (subfolders transformer/ vae/ text_encoder/ "
        "tokenizer/ scheduler/); required for kind=paper, never downloaded")
    dtype: Literal["float32", "bfloat16"] = Field("float32", description="float32 | bfloat16 (paper)")
    gradient_checkpointing: bool = Field(False, description="recompute transformer activations in backward (paper: true)")
    vae_slicing: bool = Field(False, description="VAE encodes/decodes the batch one sample at a time (paper)")
    vae_tiling: bool = Field(False, description="VAE works in spatial tiles (paper)")
    transformer: Optional[dict] = Field(
        default_factory=lambda: copy.deepcopy(TINY_TRANSFORMER),
        description="CogVideoXTransformer3DModel kwargs for kind=tiny (in/out channels are derived); null for "
        "kind=paper (read from the checkpoint)")
    ae_coeffs: list[PositiveInt] = Field(
        [40, 12, 12], min_length=3, max_length=3,
        description="tiny autoencoder: DCT coefficients per 4x8x8 block for [luma, chroma1, chroma2] (latent "
        "channels = sum; [256, 256, 256] = lossless); the paper VAE has 16 latent channels")
    ae_normalisation: Literal["channel", "global"] = Field(
        "channel", description="tiny autoencoder latent scaling: channel (each channel to unit variance) | global "
        "(one scale, like the CogVideoX VAE's scaling factor: latent L2 = pixel L2 up to a constant)")
    min_ae_round_trip_db: Optional[float] = Field(
        25.0, description="floor (dB, display PSNR) of the autoencoder's round trip decode(encode(x)) on the first 2 "
        "training targets, checked before training: below it training stops with a one-line error, since the "
        "refined clips are decoded by it and can be no closer to their targets (the default's DCT autoencoder "
        "38.6 dB; a VAE with the wrong or random weights, about 15 dB). null = no check")
    empty_prompt_cache: Optional[str] = Field(
        None, description="file caching the T5 embedding of the empty prompt (.pt; paper)")
    proxy_anchor: Literal["none", "x0", "v"] = Field(
        "none", description="none (paper: the network's output is v) | x0: x0_hat = proxy latent + F, i.e. "
        "v = v_anchor - F / sqrt(1 - abar_t) | v: v = v_anchor + F; v_anchor is the v whose x0 estimate is the "
        "proxy latent, F's output projection is zero-initialised, so an untrained model returns the proxy. "
        "The anchor uses the proxy in both CFG branches (guidance acts on F's proxy input)")
    anchor_space: Literal["latent", "pixel"] = Field(
        "latent", description="with anchor_affine: latent = a per-latent-channel gain and bias (for the tiny DCT "
        "autoencoder a per-DCT-frequency filter, which varies across each 8x8-pixel and 4-frame block: it leaves a "
        "block grid in the output) | pixel (tiny DCT autoencoder only) = the decoded proxy through a colour affine "
        "map (3x3 + bias) and a (2r+1)^2 kernel per colour channel (r = anchor_kernel_px), both the identity at "
        "initialisation, re-encoded: the same at every pixel, so no block grid")
    anchor_kernel_px: NonNegativeInt = Field(0, le=8, description="radius r of the pixel anchor's kernel (0 = the "
                                             "colour map alone)")
    anchor_affine: bool = Field(
        False, description="with a proxy anchor: the anchor is a learned per-latent-channel affine map of the proxy "
        "latent (gain and bias per channel, zero-initialised: still the identity at initialisation), trained with "
        "the network by the same loss; for the DCT autoencoder a per-frequency linear filter of the proxy")
    anchor_init: Literal["identity", "affine_colour"] = Field(
        "identity", description="start of the pixel anchor's colour map: identity | affine_colour = the affine "
        "colour fit of the training pairs (baselines.affine_colour's least squares, per channel, display values), "
        "so that before any step the refiner at residual scale 0 is that baseline and the transformer learns what "
        "a colour map cannot (anchor_space: pixel; like it, no effect without an anchor)")

    @model_validator(mode="after")
    def _pixel_anchor_needs_the_dct_autoencoder(self):
        anchored = self.anchor_affine and self.proxy_anchor != "none"
        if self.anchor_space == "pixel" and anchored and self.kind != "tiny":
            raise ValueError("anchor_space=pixel filters the decoded proxy at every step, which only the tiny DCT "
                             "autoencoder makes cheap; use anchor_space: latent for kind=paper")
        if self.anchor_init != "identity" and anchored and self.anchor_space != "pixel":
            raise ValueError(f"anchor_init={self.anchor_init} starts the pixel anchor's colour map; set anchor_space: "
                             "pixel, or anchor_init: identity")
        return self


class RefinerTrainSettings(_Section):
    lr: PositiveFloat = Field(1e-3, description="AdamW learning rate (paper 1e-5; tiny 3e-4 because it trains "
                              "from scratch)")
    weight_decay: NonNegativeFloat = Field(1e-2, description="AdamW weight decay")
    adam_betas: list[float] = Field([0.9, 0.999], min_length=2, max_length=2, description="AdamW betas")
    batch_size: PositiveInt = Field(1, description="pairs per micro-batch (paper: 1)")
    grad_accum: PositiveInt = Field(4, description="micro-batches per optimizer step (paper: 4)")
    max_steps: PositiveInt = Field(400, description="optimizer steps to train")
    warmup_steps: NonNegativeInt = Field(20, description="linear LR warm-up, optimizer steps")
    max_grad_norm: PositiveFloat = Field(1.0, description="gradient clipping norm")
    proxy_dropout: float = Field(0.1, ge=0, le=1, description="probability of zeroing the proxy latent in a "
                                 "training sample (enables CFG on the proxy)")
    cond_noise_log_sigma_mean: float = Field(-3.0, description="mean of log sigma of pixel-space proxy noise "
                                             "(images in [-1, 1]; paper: -3)")
    cond_noise_log_sigma_std: NonNegativeFloat = Field(0.5, description="std of log sigma of pixel-space proxy "
                                                       "noise (paper: 0.5)")
    latent_window: PositiveInt = Field(3, description="latent frames per training crop, cropped from the globally "
                                       "encoded clip (paper: 13 = 49 pixel frames)")
    timesteps: Literal["all", "sampler_range"] = Field(
        "all", description="all (uniform over the scheduler's training steps, paper) | sampler_range: uniform over "
        "[last timestep the sampler visits at infer.num_steps, first timestep at the largest strength in "
        "select.strengths and infer.strength]")
    num_workers: NonNegativeInt = Field(
        0, description="data-loading worker processes: 0 = pairs are read in the training process, the pair index "
        "drawn from the run's generator (tiny); N > 0 = a DataLoader reads them in N processes ahead of the GPU, "
        "the pair indices from their own seeded stream (resumable by count). paper: 4")
    hflip: bool = Field(False, description="augmentation: mirror each training sample (proxy and target) left-right "
                        "with probability 1/2")
    anchor_lr: Optional[PositiveFloat] = Field(None, description="AdamW learning rate of the anchor's affine map "
                                               "(no weight decay); null = train.lr")
    anchor_loss_weight: NonNegativeFloat = Field(
        0.0, description="weight of a second loss on the learned anchor alone: the mean squared error of the "
        "anchor's map of the proxy latent against the target latent (latent units, beside the v loss). Trained "
        "only through the sum anchor + correction, the anchor drifts off as the transformer learns, while "
        "selection offers it alone (select.residual_scales 0); 0 = off (the paper has no learned anchor)")
    checkpoint_every: PositiveInt = Field(50, description="optimizer steps between checkpoints")
    log_every: PositiveInt = Field(1, description="optimizer steps between log lines")


class RefinerInferSettings(_Section):
    num_steps: PositiveInt = Field(50, description="denoising steps, trailing spacing (paper: 50)")
    strength: float = Field(
        1.0, ge=0, le=1, description="SDEdit strength in [0, 1]: keep int(num_steps * strength) steps and start "
        "from the proxy latent noised to the first kept timestep; 1 = pure noise (paper); 0 = the proxy through the "
        "autoencoder. Chosen on validation when select.val_scenes > 0")
    guidance_scale: NonNegativeFloat = Field(
        6.0, description="classifier-free guidance on the proxy latent (paper: 6.0); 1 disables the unconditional "
        "pass. Chosen on validation when select.val_scenes > 0")
    residual_scale: float = Field(
        1.0, ge=0, le=1, description="weight in [0, 1] of the transformer's correction on top of the proxy anchor "
        "(0 = anchor alone, no transformer call); ignored without an anchor")
    correction_blur_px: NonNegativeFloat = Field(
        0.0, description="sigma in pixels of a Gaussian applied, frame by frame in display space, to the refined "
        "clip's difference from the learned anchor's output (the transformer's correction; "
        "lightcrafter.refiner.sampler.blur_correction): the correction keeps its shading and colour and loses the "
        "tiny preset's 16-pixel token grid. 0 = off; ignored without an anchor. Chosen on validation when "
        "select.val_scenes > 0 (select.correction_blurs_px)")
    correction_blur_frames: NonNegativeFloat = Field(
        0.0, description="sigma in frames of a Gaussian applied along the clip to the same correction (after "
        "correction_blur_px): the tiny preset's correction changes once per 4-frame latent frame, and steps at "
        "those boundaries; 0 = off; ignored without an anchor. Chosen on validation when select.val_scenes > 0 "
        "(select.correction_blurs_frames)")
    num_samples: PositiveInt = Field(
        1, description="the refined video is the pixel-wise mean of this many samples drawn with successive noise "
        "from the run's generator (a posterior-mean estimate, which PSNR/SSIM reward); 1 = a single sample (paper)")
    sampler: Literal["ddim", "dpm"] = Field(
        "ddim", description="ddim (CogVideoXDDIMScheduler, deterministic) | dpm (CogVideoXDPMScheduler, stochastic; "
        "the paper's 'full DPM solver')")
    window: PositiveInt = Field(3, description="latent frames per temporal tile (paper 13 = 49 pixel frames)")
    overlap: NonNegativeInt = Field(1, description="latent frames shared by neighbouring tiles (paper 3 = 12 pixel "
                                    "frames)")
    min_tent_weight: PositiveFloat = Field(0.1, description="tent weight at a tile's edge frame, > 0 so every frame "
                                           "is defined")
    pad_frames: Literal["error", "repeat_last"] = Field(
        "error", description="error | repeat_last: frame counts that are not 4k+1 raise, or are padded then cropped")

    @model_validator(mode="after")
    def _overlap_below_window(self):
        if not self.overlap < self.window:
            raise ValueError(f"infer.overlap={self.overlap} must be in [0, window={self.window})")
        return self


class RefinerDataSettings(_Section):
    exposure_ev: float = Field(0.0, description="exposure (EV) of the display transform applied to proxy and "
                               "target alike")
    max_train_pairs: Optional[PositiveInt] = Field(None, description="use at most this many training pairs "
                                                   "(null = all)")
    cache_pixels: bool = Field(True, description="keep decoded frames of training pairs in memory (exact); false "
                               "at paper scale")


class RefinerSelectSettings(_Section):
    val_scenes: Union[NonNegativeInt, NonNegativeFloat] = Field(
        0, description="validation scenes carved out of the train split by whole scene (scene_id; real clips by "
        "their source video), per kind (synthetic, real; lightcrafter.refiner.validation), deterministic in seed: an "
        "integer count, or a fraction < 1 of a kind's train-split scenes (at least 1); a kind with one scene keeps "
        "it for fitting. 0 = no selection (paper). Needs at least 2 train-split scenes, else selection is skipped "
        "and logged")
    max_val_pairs: PositiveInt = Field(4, description="validation clips evaluated per candidate setting (the first "
                                       "n in pair-id order)")
    checkpoints: list[PositiveInt] = Field([], description="optimizer steps whose weights are candidate models "
                                           "besides the last step")
    strengths: list[float] = Field([1.0], min_length=1, description="candidate infer.strength values")
    guidance_scales: list[NonNegativeFloat] = Field([6.0], min_length=1, description="candidate "
                                                    "infer.guidance_scale values")
    residual_scales: list[float] = Field([1.0], min_length=1, description="candidate infer.residual_scale values "
                                         "(0 = the learned anchor alone; only with a proxy anchor)")
    correction_blurs_px: list[NonNegativeFloat] = Field(
        [0.0], min_length=1, description="candidate infer.correction_blur_px values (0 = the correction as the "
        "transformer made it; only with a proxy anchor and a residual scale above 0)")
    correction_blurs_frames: list[NonNegativeFloat] = Field(
        [0.0], min_length=1, description="candidate infer.correction_blur_frames values, each with every "
        "correction_blurs_px value (a clip is sampled once per candidate and every blur scored on it)")
    max_block_ratio: Optional[PositiveFloat] = Field(
        None, description="candidates whose validation clips have more block-grid texture than this times the "
        "proxy's (lightcrafter.refiner.fit.block_ratio: 8- and 16-px blockiness, refined over proxy) are not chosen, "
        "whatever their score (the refiner's goal: within 10 % of the target's); null = no limit")
    max_jump_ratio: Optional[PositiveFloat] = Field(
        None, description="candidates whose validation clips step at the autoencoder's 4-frame blocks more than "
        "this times their targets do (lightcrafter.refiner.fit.jump_ratio: the 4-frame jump, refined over target) "
        "are not chosen, whatever their score (the refiner's goal: within 10 % of the target's); null = no limit")
    min_warp_ssim_ratio: Optional[PositiveFloat] = Field(
        None, description="candidates whose validation clips are less consistent over time than this times the "
        "proxy's (lightcrafter.refiner.fit.warp_ssim_ratio: Warp-SSIM with the target's optical flow, refined over "
        "proxy) are not chosen, whatever their score (the refiner's goal: Warp-SSIM at least the proxy's); null = "
        "no limit")
    metric: Literal["psnr_db", "ssim"] = Field("psnr_db", description="psnr_db | ssim: the validation score (mean "
                                               "over clips) that picks checkpoint, strength, guidance")

    @model_validator(mode="after")
    def _ranges(self):
        v = float(self.val_scenes)
        if v >= 1 and v % 1:
            raise ValueError(f"select.val_scenes={self.val_scenes}: an integer count >= 0 or a fraction in (0, 1)")
        for s in self.strengths:
            if not 0.0 <= s <= 1.0:
                raise ValueError(f"select.strengths: {s} must be in [0, 1]")
        for r in self.residual_scales:
            if not 0.0 <= r <= 1.0:
                raise ValueError(f"select.residual_scales: {r} must be in [0, 1]")
        return self


class RefinerBaselineSettings(_Section):
    regressor_steps: NonNegativeInt = Field(
        0, description="optimizer steps of the one-step deterministic regressor (same network and anchor, proxy "
        "latent in both inputs, fixed timestep, L2 on the x0 latent); 0 = not trained. The workflow trains the "
        "baselines with the first of datasets.variants only (they are Table 1 methods)")
    affine_colour: bool = Field(
        False, description="fit a per-channel affine map proxy -> target (display values, least squares over the fit "
        "pairs) and evaluate it as a baseline")


class RefinerSettings(_Section):
    """The refiner's config: the preset named by ``preset`` supplies the base values (PRESETS), the rest
    of the dict overrides them. ``resolve_config`` returns it as a plain dict."""

    preset: Literal["tiny", "paper"] = Field(
        "tiny", description="tiny: random-init CogVideoX transformer + DCT patch autoencoder on the CPU, with what a "
        "small model trained from scratch needs (SDEdit start, proxy anchor, validation selection, baselines); "
        "paper: CogVideoX-5B-I2V from model.model_path (bf16, gradient checkpointing, VAE slicing/tiling), "
        "pure-noise sampling, no anchor, no selection, no baselines. Base values the rest of the section overrides")
    seed: NonNegativeInt = Field(0, description="integer seed of every random draw in training and inference")
    device: Literal["auto", "cpu", "cuda"] = Field(
        "auto", description="where training, inference and the baselines run (lightcrafter/devices.py): cpu | cuda "
        "(a one-line error when torch sees no GPU: never a silent CPU fallback) | auto (CUDA when present; an error "
        "when the job was given a GPU torch cannot see). tiny: cpu; paper: cuda")
    model: RefinerModelSettings = Field(default_factory=RefinerModelSettings)
    scheduler: dict = Field(default_factory=lambda: copy.deepcopy(COGVIDEOX_5B_SCHEDULER),
                            description="diffusers CogVideoX scheduler kwargs (defaults: CogVideoX-5B's "
                            "scheduler_config.json)")
    train: RefinerTrainSettings = Field(default_factory=RefinerTrainSettings)
    infer: RefinerInferSettings = Field(default_factory=RefinerInferSettings)
    data: RefinerDataSettings = Field(default_factory=RefinerDataSettings)
    select: RefinerSelectSettings = Field(default_factory=RefinerSelectSettings)
    baselines: RefinerBaselineSettings = Field(default_factory=RefinerBaselineSettings)


def _base() -> dict:
    """Every key of the refiner config with the model's default (before a preset is applied)."""
    return RefinerSettings().model_dump()


# What a small model trained from scratch on a few clips needs (lightcrafter/refiner/__init__.py,
# "Small scale"): start from the noised proxy (SDEdit), predict a correction of the proxy (identity
# at initialisation), train on the timesteps sampling visits, pick checkpoint, strength and guidance
# on validation scenes, and train the baselines it must beat.
TINY_SMALL_SCALE: dict = {
    "model": {"proxy_anchor": "x0", "anchor_affine": True, "ae_normalisation": "global"},
    "train": {"lr": 3e-4, "timesteps": "sampler_range", "hflip": True, "anchor_lr": 1e-2},
    "infer": {"strength": 0.1, "guidance_scale": 1.0},
    "select": {"val_scenes": 0.25, "max_val_pairs": 4, "checkpoints": [], "strengths": [0.1, 0.3],
               "guidance_scales": [1.0, 2.0], "residual_scales": [0.0, 1.0]},
    "baselines": {"regressor_steps": 150, "affine_colour": True},
}

PRESETS: dict[str, dict] = {
    "tiny": {"device": "cpu", **copy.deepcopy(TINY_SMALL_SCALE)},
    "paper": {
        "device": "cuda",
        "model": {
            "kind": "paper",
            "dtype": "bfloat16",
            "gradient_checkpointing": True,
            "vae_slicing": True,
            "vae_tiling": True,
            "transformer": None,  # read from the checkpoint
        },
        # 48 h of training (the paper) as optimizer steps: 7,500 at the 23.1 s per step measured on one H200,
        # the smallest single GPU the full fine-tune fits (derivation in docs/paper_numbers.md; scale by the
        # GPU count under data parallelism)
        "train": {"lr": 1e-5, "warmup_steps": 0, "latent_window": 13, "max_steps": 7500, "checkpoint_every": 200,
                  "num_workers": 4},
        "infer": {"window": 13, "overlap": 3, "sampler": "dpm"},  # paper: "full DPM solver", 50 steps
        "data": {"cache_pixels": False},
    },
}

def _merge(base: dict, over: dict, path: str = "") -> dict:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if k not in base:
            raise KeyError(f"unknown refiner config key {path + k!r}; known: {sorted(base)}")
        if isinstance(v, dict) and isinstance(out.get(k), dict) and k not in ("transformer", "scheduler"):
            out[k] = _merge(out[k], v, path + k + ".")
        elif isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = {**out[k], **copy.deepcopy(v)}
        else:
            out[k] = copy.deepcopy(v)
    return out


def apply_preset(section: dict | None, default_preset: str = "tiny", strict: bool = True) -> dict:
    """The model's defaults, then the values of the preset the section names (``default_preset`` when it
    names none), then the section's own keys (deep merge; ``transformer`` and ``scheduler`` key by key).
    Without a proxy anchor the transformer's output is the whole prediction, so the residual scale is 1.
    ``strict``: an unknown key raises KeyError naming it (else it is kept, for pydantic to name)."""
    section = dict(section or {})
    preset = section.get("preset", default_preset)
    if preset not in PRESETS:
        raise KeyError(f"unknown refiner preset {preset!r}; choose one of {sorted(PRESETS)}")
    base = _base()
    base["preset"] = preset
    if strict:
        cfg = _merge(_merge(base, PRESETS[preset]), section)
    else:
        from lightcrafter.config import deep_merge

        cfg = deep_merge(deep_merge(base, PRESETS[preset]), section)
    if isinstance(cfg.get("model"), dict) and cfg["model"].get("proxy_anchor") == "none":
        cfg["infer"]["residual_scale"], cfg["select"]["residual_scales"] = 1.0, [1.0]
        cfg["infer"]["correction_blur_px"], cfg["select"]["correction_blurs_px"] = 0.0, [0.0]
        cfg["infer"]["correction_blur_frames"], cfg["select"]["correction_blurs_frames"] = 0.0, [0.0]
    return cfg


def resolve_config(overrides: dict | None = None) -> dict:
    """:func:`apply_preset` (default preset ``tiny``), validated by :class:`RefinerSettings`.

    Returns a plain dict of every key. Raises KeyError naming an unknown key at any depth and
    ValueError naming a key whose value has the wrong type or is out of range."""
    from lightcrafter.config import validate_section

    return validate_section(RefinerSettings, apply_preset(overrides, "tiny"), "refiner").model_dump()


def key_docs(model: type[BaseModel] = RefinerSettings, prefix: str = "") -> dict[str, str]:
    """{dotted key: description} of every documented key of ``model`` (sub-models flattened)."""
    out: dict[str, str] = {}
    for name, f in model.model_fields.items():
        ann = f.annotation
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            out.update(key_docs(ann, f"{prefix}{name}."))
        elif f.description:
            out[prefix + name] = f.description
    return out


KEY_DOCS: dict[str, str] = key_docs()
