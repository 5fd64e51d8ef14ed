"""Refiner configuration: one plain dict, two presets (``tiny`` and ``paper``).

Every key is documented in :data:`KEY_DOCS`. A run's config is ``resolve_config(overrides)``:
the preset named by ``overrides["preset"]`` (default ``tiny``) deep-merged with the overrides.
Unknown top-level keys are an error so that typos do not silently fall back to defaults.
"""

from __future__ import annotations

import copy

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

_BASE: dict = {
    "preset": "tiny",
    "seed": 0,
    # --- model
    "model": {
        "kind": "tiny",  # tiny: random-init transformer + DCT patch autoencoder; paper: local CogVideoX-5B-I2V
        "model_path": None,  # local diffusers folder of CogVideoX-5B-I2V (paper)
        "dtype": "float32",  # float32 | bfloat16
        "gradient_checkpointing": False,
        "vae_slicing": False,
        "vae_tiling": False,
        "transformer": copy.deepcopy(TINY_TRANSFORMER),
        "ae_coeffs": [40, 12, 12],  # tiny autoencoder: DCT coefficients kept per 4x8x8 block for
        # (luma, chroma1, chroma2); latent channels = their sum
        "ae_normalisation": "channel",  # tiny autoencoder: channel (unit variance per channel) | global
        "empty_prompt_cache": None,  # path of the cached empty-prompt embedding (.pt); paper only
        "proxy_anchor": "none",  # none (paper: the network outputs v) | x0 | v: identity at initialisation
        "anchor_affine": False,  # anchor = learned per-latent-channel affine map of the proxy (identity at init)
    },
    # --- diffusion parameterisation (see COGVIDEOX_5B_SCHEDULER)
    "scheduler": copy.deepcopy(COGVIDEOX_5B_SCHEDULER),
    # --- training
    "train": {
        "lr": 1e-3,  # tiny default (trains from scratch); the paper fine-tunes with 1e-5 (preset "paper")
        "weight_decay": 1e-2,
        "adam_betas": [0.9, 0.999],
        "batch_size": 1,
        "grad_accum": 4,
        "max_steps": 400,  # optimizer steps
        "warmup_steps": 20,
        "max_grad_norm": 1.0,
        "proxy_dropout": 0.1,  # probability of zeroing the proxy latent (enables CFG on the proxy)
        "cond_noise_log_sigma_mean": -3.0,  # log sigma ~ N(mean, std) on proxy pixels in [-1, 1]
        "cond_noise_log_sigma_std": 0.5,
        "latent_window": 3,  # latent frames per training crop (paper: 13 = 49 pixel frames)
        "timesteps": "all",  # all (paper: uniform over the 1000 training steps) | sampler_range
        "hflip": False,  # mirror training samples left-right with probability 1/2
        "anchor_lr": None,  # learning rate of the anchor's affine map (null = train.lr)
        "checkpoint_every": 50,  # optimizer steps
        "log_every": 1,
    },
    # --- inference
    "infer": {
        "num_steps": 50,
        "strength": 1.0,  # SDEdit: 1 = start from pure noise (paper); s < 1 starts from the noised proxy
        "guidance_scale": 6.0,
        # weight of the transformer's correction F on top of the proxy anchor (model.proxy_anchor != none):
        # 1 = the trained model; 0 = the anchor alone (the learned latent map of the proxy, no transformer
        # call). Chosen on validation through select.residual_scales; ignored without an anchor.
        "residual_scale": 1.0,
        "num_samples": 1,  # refined = mean of this many samples (different noise); 1 = one sample (paper)
        "sampler": "ddim",  # ddim | dpm (CogVideoXDPMScheduler: stochastic, carries previous x0)
        "window": 3,  # latent frames per tile (paper: 13)
        "overlap": 1,  # latent frames shared by neighbouring tiles (paper: 3)
        "min_tent_weight": 0.1,  # tent weight at a tile's outermost frame (> 0)
        "pad_frames": "error",  # error | repeat_last: what to do when the frame count is not 4k+1
    },
    "data": {
        "exposure_ev": 0.0,  # display transform exposure (io.linear_to_display)
        "max_train_pairs": None,
        "cache_pixels": True,  # keep decoded proxy/target frames in memory (exact; off at paper scale)
    },
    # --- model selection on validation scenes carved out of the train split (never test)
    "select": {
        "val_scenes": 0,  # 0 = no selection (paper: infer.* as configured); n >= 1 scenes, or a fraction < 1
        "max_val_pairs": 4,  # validation clips evaluated per candidate (cost)
        "checkpoints": [],  # optimizer steps whose weights are candidates (the last step always is)
        "strengths": [1.0],
        "guidance_scales": [6.0],
        "residual_scales": [1.0],  # candidate infer.residual_scale values (only with a proxy anchor)
        "metric": "psnr_db",  # psnr_db | ssim: mean over validation clips, higher is better
    },
    # --- baselines trained and evaluated beside the refiner (same data, same network)
    "baselines": {
        "regressor_steps": 0,  # optimizer steps of the one-step regressor (same network, L2 on x0); 0 = off
        "affine_colour": False,  # per-channel affine colour fit of proxy to target on the training pairs
    },
}

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
    "tiny": copy.deepcopy(TINY_SMALL_SCALE),
    "paper": {
        "model": {
            "kind": "paper",
            "dtype": "bfloat16",
            "gradient_checkpointing": True,
            "vae_slicing": True,
            "vae_tiling": True,
            "transformer": None,  # read from the checkpoint
        },
        "train": {"lr": 1e-5, "warmup_steps": 0, "latent_window": 13, "max_steps": 10000, "checkpoint_every": 500},
        "infer": {"window": 13, "overlap": 3, "sampler": "dpm"},  # paper: "full DPM solver", 50 steps
        "data": {"cache_pixels": False},
    },
}

KEY_DOCS: dict[str, str] = {
    "preset": "tiny | paper: base values the rest of the dict overrides",
    "seed": "integer seed of every random draw in training and inference",
    "model.kind": "tiny (random-init transformer, DCT patch autoencoder, CPU) | paper (CogVideoX-5B-I2V from model_path)",
    "model.model_path": "local diffusers folder of CogVideoX-5B-I2V; required for kind=paper, never downloaded",
    "model.dtype": "float32 | bfloat16 (paper)",
    "model.gradient_checkpointing": "recompute transformer activations in backward (paper: true)",
    "model.vae_slicing": "VAE encodes/decodes the batch one sample at a time (paper)",
    "model.vae_tiling": "VAE works in spatial tiles (paper)",
    "model.transformer": "CogVideoXTransformer3DModel kwargs for kind=tiny (in/out channels are derived)",
    "model.ae_coeffs": "tiny autoencoder: DCT coefficients per 4x8x8 block for [luma, chroma1, chroma2] "
    "(latent channels = sum; [256, 256, 256] = lossless); the paper VAE has 16 latent channels",
    "model.anchor_affine": "with a proxy anchor: the anchor is a learned per-latent-channel affine map of the proxy "
    "latent (gain and bias per channel, zero-initialised: still the identity at initialisation), trained with "
    "the network by the same loss; for the DCT autoencoder a per-frequency linear filter of the proxy",
    "model.ae_normalisation": "tiny autoencoder latent scaling: channel (each channel to unit variance) | global "
    "(one scale, like the CogVideoX VAE's scaling factor: latent L2 = pixel L2 up to a constant)",
    "model.empty_prompt_cache": "file caching the T5 embedding of the empty prompt (paper)",
    "model.proxy_anchor": "none (paper: the network's output is v) | x0: x0_hat = proxy latent + F, i.e. "
    "v = v_anchor - F / sqrt(1 - abar_t) | v: v = v_anchor + F; v_anchor is the v whose x0 estimate is the "
    "proxy latent, F's output projection is zero-initialised, so an untrained model returns the proxy. "
    "The anchor uses the proxy in both CFG branches (guidance acts on F's proxy input)",
    "scheduler": "diffusers CogVideoX scheduler kwargs (defaults: CogVideoX-5B's scheduler_config.json)",
    "train.lr": "AdamW learning rate (paper 1e-5; tiny default 1e-3 because it trains from scratch)",
    "train.weight_decay": "AdamW weight decay",
    "train.adam_betas": "AdamW betas",
    "train.batch_size": "pairs per micro-batch (1)",
    "train.grad_accum": "micro-batches per optimizer step (4)",
    "train.max_steps": "optimizer steps to train",
    "train.warmup_steps": "linear LR warm-up, optimizer steps",
    "train.max_grad_norm": "gradient clipping norm",
    "train.proxy_dropout": "probability of zeroing the proxy latent in a training sample",
    "train.cond_noise_log_sigma_mean": "mean of log sigma of pixel-space proxy noise (images in [-1, 1])",
    "train.cond_noise_log_sigma_std": "std of log sigma of pixel-space proxy noise",
    "train.latent_window": "latent frames per training crop (cropped from the globally encoded clip)",
    "train.anchor_lr": "AdamW learning rate of the anchor's affine map (no weight decay); null = train.lr",
    "train.hflip": "augmentation: mirror each training sample (proxy and target) left-right with probability 1/2",
    "train.timesteps": "all (uniform over the scheduler's training steps, paper) | sampler_range: uniform over "
    "[last timestep the sampler visits at infer.num_steps, first timestep at the largest strength in "
    "select.strengths and infer.strength]",
    "train.checkpoint_every": "optimizer steps between checkpoints",
    "train.log_every": "optimizer steps between log lines",
    "infer.num_steps": "denoising steps (50)",
    "infer.strength": "SDEdit strength in [0, 1]: keep int(num_steps * strength) steps and start from the proxy "
    "latent noised to the first kept timestep; 1 = pure noise (paper); 0 = the proxy through the autoencoder. "
    "Chosen on validation when select.val_scenes > 0",
    "infer.guidance_scale": "classifier-free guidance on the proxy latent (6.0); 1 disables the unconditional pass. "
    "Chosen on validation when select.val_scenes > 0",
    "infer.num_samples": "the refined video is the pixel-wise mean of this many samples drawn with successive "
    "noise from the run's generator: an estimate of the posterior mean, which PSNR/SSIM reward; 1 = a single "
    "sample (paper). Costs num_samples x the sampling time",
    "infer.sampler": "ddim (CogVideoXDDIMScheduler, deterministic) | dpm (CogVideoXDPMScheduler, stochastic)",
    "infer.window": "latent frames per temporal tile (paper 13 = 49 pixel frames)",
    "infer.overlap": "latent frames shared by neighbouring tiles (paper 3 = 12 pixel frames)",
    "infer.min_tent_weight": "tent weight at a tile's edge frame, > 0 so every frame is defined",
    "infer.pad_frames": "error | repeat_last: frame counts that are not 4k+1 raise, or are padded then cropped",
    "data.exposure_ev": "exposure (EV) of the display transform applied to proxy and target alike",
    "data.max_train_pairs": "use at most this many training pairs (null = all)",
    "data.cache_pixels": "keep decoded frames of training pairs in memory (exact); false at paper scale",
    "select.val_scenes": "validation scenes carved out of the train split by whole scene (scene_id, else clip_id), "
    "deterministic in seed: an integer count, or a fraction < 1 of the train-split scenes (at least 1); "
    "0 = no selection. Needs at least 2 train-split scenes, else selection is skipped and logged",
    "select.max_val_pairs": "validation clips evaluated per candidate setting (the first n in pair-id order)",
    "select.checkpoints": "optimizer steps whose weights are candidate models besides the last step",
    "select.strengths": "candidate infer.strength values",
    "select.guidance_scales": "candidate infer.guidance_scale values",
    "select.residual_scales": "candidate infer.residual_scale values (0 = the learned anchor alone)",
    "infer.residual_scale": "weight in [0, 1] of the transformer's correction on top of the proxy anchor "
    "(0 = anchor alone, no transformer call)",
    "select.metric": "psnr_db | ssim: the validation score (mean over clips) that picks checkpoint, strength, guidance",
    "baselines.regressor_steps": "optimizer steps of the one-step deterministic regressor (same network and "
    "anchor, proxy latent in both inputs, fixed timestep, L2 on the x0 latent); 0 = not trained",
    "baselines.affine_colour": "fit a per-channel affine map proxy -> target (display values, least squares over "
    "the fit pairs) and evaluate it as a baseline",
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


def resolve_config(overrides: dict | None = None) -> dict:
    """Defaults <- preset <- overrides (deep merge). Raises KeyError on unknown top-level keys."""
    overrides = dict(overrides or {})
    preset = overrides.get("preset", "tiny")
    if preset not in PRESETS:
        raise KeyError(f"unknown refiner preset {preset!r}; choose one of {sorted(PRESETS)}")
    cfg = _merge(_BASE, PRESETS[preset])
    cfg = _merge(cfg, overrides)
    inf = cfg["infer"]
    if not (0 <= inf["overlap"] < inf["window"]):
        raise ValueError(f"infer.overlap={inf['overlap']} must be in [0, window={inf['window']})")
    if not inf["min_tent_weight"] > 0:
        raise ValueError("infer.min_tent_weight must be > 0 (zero edge weights leave frames undefined)")
    if inf["pad_frames"] not in ("error", "repeat_last"):
        raise ValueError(f"infer.pad_frames={inf['pad_frames']!r}: use 'error' or 'repeat_last'")
    sel = cfg["select"]
    for s in [inf["strength"], *sel["strengths"]]:
        if not 0.0 <= float(s) <= 1.0:
            raise ValueError(f"strength {s}: must be in [0, 1] (infer.strength, select.strengths)")
    if int(inf["num_samples"]) < 1:
        raise ValueError(f"infer.num_samples={inf['num_samples']}: must be >= 1")
    if cfg["model"]["ae_normalisation"] not in ("channel", "global"):
        raise ValueError(f"model.ae_normalisation={cfg['model']['ae_normalisation']!r}: use 'channel' or 'global'")
    if cfg["model"]["proxy_anchor"] not in ("none", "x0", "v"):
        raise ValueError(f"model.proxy_anchor={cfg['model']['proxy_anchor']!r}: use 'none', 'x0' or 'v'")
    if cfg["train"]["timesteps"] not in ("all", "sampler_range"):
        raise ValueError(f"train.timesteps={cfg['train']['timesteps']!r}: use 'all' or 'sampler_range'")
    if sel["metric"] not in ("psnr_db", "ssim"):
        raise ValueError(f"select.metric={sel['metric']!r}: use 'psnr_db' or 'ssim'")
    if float(sel["val_scenes"]) < 0 or (float(sel["val_scenes"]) >= 1 and float(sel["val_scenes"]) % 1):
        raise ValueError(f"select.val_scenes={sel['val_scenes']}: an integer count >= 0 or a fraction in (0, 1)")
    if not sel["strengths"] or not sel["guidance_scales"] or not sel["residual_scales"]:
        raise ValueError("select.strengths, select.guidance_scales and select.residual_scales need at least one "
                         "value each")
    for r in [inf["residual_scale"], *sel["residual_scales"]]:
        if not 0.0 <= float(r) <= 1.0:
            raise ValueError(f"residual scale {r}: must be in [0, 1] (infer.residual_scale, select.residual_scales)")
    if cfg["model"]["proxy_anchor"] == "none":
        # without an anchor the transformer's output is the whole prediction: nothing to weigh
        inf["residual_scale"], sel["residual_scales"] = 1.0, [1.0]
    return cfg
