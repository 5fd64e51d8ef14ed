"""The refiner network: CogVideoX transformer over [noisy latent || proxy latent] (channel concat).

``in_channels = 2 * latent_channels`` (no zero-padding in time: proxy and target are length-aligned),
``out_channels = latent_channels``. The text branch is disabled by one fixed empty-prompt embedding
of shape (1, max_text_seq_length, text_embed_dim), computed once and kept as a buffer:

* ``tiny``: zeros (there is no text encoder; any fixed tensor is equivalent to an empty prompt);
* ``paper``: the T5 encoding of "" padded to 226 tokens (the model's text length), read from
  ``model.empty_prompt_cache`` or computed once from ``{model_path}/text_encoder`` and cached there.

The model output is the scheduler's ``v`` (v-prediction); the paper calls it the noise prediction.

Proxy anchor (``model.proxy_anchor``; ``none`` in the paper preset). With the CogVideoX
parameterisation z_t = sqrt(abar) x0 + sqrt(1 - abar) eps, v = sqrt(abar) eps - sqrt(1 - abar) x0 and
x0_hat = sqrt(abar) z_t - sqrt(1 - abar) v, the *anchor* velocity

    v_anchor(z_t, a, t) = (sqrt(abar_t) z_t - a) / sqrt(1 - abar_t)

is the v whose x0 estimate is exactly the proxy latent ``a``. The transformer's output F is added to it:

* ``x0``: v = v_anchor - F / sqrt(1 - abar_t), i.e. x0_hat = a + F: F is a correction of the proxy in
  latent units, whose target x0 - a has the same scale at every t. The v-MSE loss becomes
  |F - (x0 - a)|^2 / (1 - abar_t): the paper's loss and minimiser, reweighted towards small t.
* ``v``: v = v_anchor + F (F's target (a - x0) / sqrt(1 - abar_t) grows as t -> 0).

With ``model.anchor_affine`` and ``model.anchor_space: pixel`` the anchor is instead a learned colour map and
kernel on the decoded proxy's pixels (:class:`PixelAnchor`), which has no block grid. Without the kernel,
the anchor is a learned per-latent-channel affine map of the proxy,
``a' = a * (1 + gain) + bias`` (:class:`LatentAffine`, zero-initialised, so still the identity at
initialisation): a per-frequency linear filter of the proxy (for the DCT autoencoder, one gain per
kept DCT coefficient and colour channel), shared by every position and timestep, that the
transformer's bottleneck (inner dim 256 < the 4 * C outputs of a 2x2 patch) cannot represent.

The transformer's output projection is zero-initialised, so an untrained model predicts x0 = proxy at
every step: sampling returns the proxy latent. The anchor is a fixed skip connection, not a network
input: CFG's unconditional branch zeroes the network's proxy input but keeps the anchor, so guidance
scales F's dependence on the proxy and an untrained model returns the proxy at every guidance scale.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

from .autoencoder import CogVideoXVAE, DCTPatchAutoencoder


class MissingWeightsError(FileNotFoundError):
    """The paper model's local weights are not configured or absent."""


def _dtype(name: str) -> torch.dtype:
    return {"float32": torch.float32, "bfloat16": torch.bfloat16, "float16": torch.float16}[name]


def require_model_path(cfg: dict) -> Path:
    path = cfg["model"].get("model_path")
    if not path or not (Path(path) / "transformer").is_dir():
        raise MissingWeightsError(
            f"refiner model.kind=paper needs a local CogVideoX-5B-I2V diffusers folder in model.model_path "
            f"(got {path!r}); nothing is downloaded. Use preset 'tiny' on machines without the weights."
        )
    return Path(path)


def empty_prompt_embedding(cfg: dict, max_len: int, dim: int) -> torch.Tensor:
    """(1, max_len, dim) fixed text embedding of the empty prompt (see module docstring)."""
    if cfg["model"]["kind"] == "tiny":
        return torch.zeros(1, max_len, dim)
    cache = cfg["model"].get("empty_prompt_cache")
    if cache and Path(cache).is_file():
        emb = torch.load(cache, map_location="cpu")
    else:
        try:
            from transformers import AutoTokenizer, T5EncoderModel
        except ImportError as exc:
            raise MissingWeightsError(
                "the empty-prompt embedding needs the 'transformers' package once (T5 from model_path), "
                "or a precomputed file in model.empty_prompt_cache"
            ) from exc

        from .checkpoint import CheckpointError, check_tokenizer

        root = require_model_path(cfg)
        check_tokenizer(root)
        try:
            tok = AutoTokenizer.from_pretrained(root / "tokenizer")
        except Exception as exc:  # transformers raises many types for a broken tokenizer folder
            raise CheckpointError(f"{root / 'tokenizer'}: the T5 tokenizer does not load ({type(exc).__name__}: "
                                  f"{str(exc).splitlines()[0] if str(exc) else ''}); re-copy the model's "
                                  "tokenizer/ folder") from None
        enc = T5EncoderModel.from_pretrained(root / "text_encoder", torch_dtype=torch.float32)
        ids = tok([""], padding="max_length", max_length=max_len, truncation=True, return_tensors="pt")
        with torch.no_grad():
            emb = enc(ids.input_ids)[0]
        if cache:
            from lightcrafter.io import atomic_path

            with atomic_path(cache) as tmp:  # a killed run never leaves a truncated cache
                torch.save(emb, tmp)
    if emb.shape[1] < max_len:  # pad to the model's text length
        emb = torch.cat([emb, emb.new_zeros(1, max_len - emb.shape[1], emb.shape[2])], dim=1)
    return emb[:, :max_len]


class LatentAffine(nn.Module):
    """Per-latent-channel affine map x * (1 + gain) + bias on (B, F, C, h, w); the identity at init."""

    def __init__(self, channels: int):
        super().__init__()
        self.gain = nn.Parameter(torch.zeros(channels))
        self.bias = nn.Parameter(torch.zeros(channels))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * (1 + self.gain.view(1, 1, -1, 1, 1)) + self.bias.view(1, 1, -1, 1, 1)


class PixelAnchor(nn.Module):
    """Anchor map on pixels for the DCT autoencoder (``model.anchor_space: pixel``, r = ``anchor_kernel_px``):
    the proxy latent is decoded to display values in [-1, 1], mapped by a colour affine map (I + C) x + b
    (RGB) and a (2r+1) x (2r+1) kernel per colour channel (identity + K, edges replicated; r = 0: the
    colour map alone), then encoded again. Every parameter
    starts at zero, so the map is the identity at initialisation (for latents of kept frequencies). Unlike
    :class:`LatentAffine` on DCT coefficients it is the same at every pixel position: no 8-pixel block grid.
    Every latent frame is decoded as its block of 4 frames and encoded back as one (``decode_blocks``): the map
    acts on each frame alone, so it commutes with the blocks, and a window of the temporal tiling that starts past
    the clip's latent frame 0 keeps its first block's 4 frames (decoded as a causal frame 0, as ``decode`` would,
    they were averaged into one, and the tiled anchor jumped at every 4-frame block;
    ``tests/test_refiner_small_scale.py``).
    The autoencoder is held by reference (not a submodule: its buffers stay out of the anchor's weights)."""

    def __init__(self, ae, radius: int):
        super().__init__()
        if not hasattr(ae, "decode_blocks"):
            raise ValueError("model.anchor_kernel_px needs the tiny DCT autoencoder (kind=tiny)")
        self.radius = int(radius)
        k = 2 * self.radius + 1
        self.colour = nn.Parameter(torch.zeros(3, 3))
        self.bias = nn.Parameter(torch.zeros(3))
        self.kernel = nn.Parameter(torch.zeros(3, 1, k, k))
        object.__setattr__(self, "_ae", ae)

    @torch.no_grad()
    def start_at_colour_fit(self, params: dict) -> None:
        """Set the colour map to a per-channel fit ``{"gain": [3], "offset": [3]}`` on display values in [-1, 1]
        (:func:`.baselines.fit_affine_colour`): (I + C) = diag(gain), b = offset; the kernel stays the identity."""
        gain = torch.as_tensor(params["gain"], dtype=self.colour.dtype, device=self.colour.device)
        self.colour.copy_(torch.diag(gain - 1))
        self.bias.copy_(torch.as_tensor(params["offset"], dtype=self.bias.dtype, device=self.bias.device))

    def forward(self, a: torch.Tensor) -> torch.Tensor:
        import torch.nn.functional as F

        ae = self._ae
        shift, scale = ae.shift.view(1, 1, -1, 1, 1), ae.scale.view(1, 1, -1, 1, 1)
        x = ae.decode_blocks(a * scale + shift)  # (B, 3, 4F, H, W)
        x = torch.einsum("oc,bcnhw->bonhw", torch.eye(3, device=x.device) + self.colour, x) \
            + self.bias.view(1, 3, 1, 1, 1)
        b, c, n, h, w = x.shape
        r = self.radius
        ident = torch.zeros_like(self.kernel)
        ident[:, :, r, r] = 1.0
        y = x.permute(0, 2, 1, 3, 4).reshape(b * n, c, h, w)
        y = F.conv2d(F.pad(y, (r, r, r, r), mode="replicate"), ident + self.kernel, groups=3)
        x = y.reshape(b, n, c, h, w).permute(0, 2, 1, 3, 4)
        return (ae.encode_blocks(x) - shift) / scale


def grid_crop_region(grid_hw: tuple[int, int], base_w: int, base_h: int):
    """Centred region of the base (sample) token grid that a (h, w) token grid is resized into,
    aspect preserved -- the crop CogVideoX 1.0 uses for its 3-D RoPE. Returns ((top, left), (bottom, right))."""
    h, w = grid_hw
    if h / w > base_h / base_w:
        rh, rw = base_h, int(round(base_h / h * w))
    else:
        rw, rh = base_w, int(round(base_w / w * h))
    top, left = int(round((base_h - rh) / 2.0)), int(round((base_w - rw) / 2.0))
    return (top, left), (top + rh, left + rw)


def build_transformer(cfg: dict, latent_channels: int, param_dtype: torch.dtype | None = None):
    """The transformer with parameters in ``param_dtype`` (default ``model.dtype``; training passes
    float32: the fp32 master weights of bf16 mixed precision, see :class:`Refiner`)."""
    from diffusers import CogVideoXTransformer3DModel

    m = cfg["model"]
    param_dtype = param_dtype or _dtype(m["dtype"])
    if m["kind"] == "tiny":
        kwargs = dict(m["transformer"])
        kwargs.update(in_channels=2 * latent_channels, out_channels=latent_channels)
        net = CogVideoXTransformer3DModel(**kwargs)  # float32 as built
        if param_dtype != torch.float32:  # diffusers warns on every dtype cast, needed or not
            net = net.to(param_dtype)
    elif m["kind"] == "paper":
        from .checkpoint import read_servable

        root = require_model_path(cfg)
        read_servable(root)  # layout and in_channels: one line naming the file, before loading GBs
        net = CogVideoXTransformer3DModel.from_pretrained(root, subfolder="transformer", torch_dtype=param_dtype)
    else:
        raise ValueError(f"model.kind={m['kind']!r}: use 'tiny' or 'paper'")
    if m.get("gradient_checkpointing"):
        net.enable_gradient_checkpointing()
    return net


def build_autoencoder(cfg: dict):
    m = cfg["model"]
    if m["kind"] == "tiny":
        return DCTPatchAutoencoder(m["ae_coeffs"], m.get("ae_normalisation", "channel"))
    return CogVideoXVAE(str(require_model_path(cfg)), _dtype(m["dtype"]), m["vae_slicing"], m["vae_tiling"])


class Refiner(nn.Module):
    """Frozen autoencoder + trainable transformer + cached empty-prompt embedding.

    Precision: ``model.dtype`` is the *compute* dtype. ``training=True`` keeps the transformer's
    parameters in float32 -- the master weights AdamW updates -- and runs its forward pass under
    ``torch.autocast`` in ``model.dtype`` (bf16 mixed precision as the reference trainers do it: a
    1e-5 step on bf16 parameters rounds away for most weights, as |w| ~ 0.02 has a bf16 spacing of
    ~1.2e-4). Memory: 16 bytes per trainable parameter (fp32 weight, gradient, two AdamW moments),
    ~90 GB for CogVideoX-5B-I2V's 5.6e9, plus activations: 104.5 GiB peak measured on an H200 for 49x480x720
    clips with gradient checkpointing (benchmarks/refiner_step.py). Inference (``training=False``) loads the parameters in
    ``model.dtype``. The autoencoder is frozen and kept in ``model.dtype``.
    """

    def __init__(self, cfg: dict, training: bool = False):
        super().__init__()
        self.cfg = cfg
        self.compute_dtype = _dtype(cfg["model"]["dtype"])
        self.param_dtype = torch.float32 if training else self.compute_dtype
        self.ae = build_autoencoder(cfg)
        self.ae.requires_grad_(False)
        self.transformer = build_transformer(cfg, self.ae.latent_channels, self.param_dtype)
        tc = self.tcfg = self.transformer.config  # read here: a DDP-wrapped transformer has no .config
        # learned positional embeddings (CogVideoX-5B-I2V) serve one latent size and window only
        self.fixed_latent_hw = ((tc.sample_height, tc.sample_width)
                                if getattr(tc, "use_learned_positional_embeddings", False) else None)
        self.fixed_window = ((tc.sample_frames - 1) // tc.temporal_compression_ratio + 1
                             if self.fixed_latent_hw else None)
        self.register_buffer(
            "prompt_embeds", empty_prompt_embedding(cfg, tc.max_text_seq_length, tc.text_embed_dim), persistent=False
        )
        self.proxy_anchor = cfg["model"].get("proxy_anchor", "none")
        from .schedule import build_scheduler

        ab = build_scheduler(cfg, "ddim").alphas_cumprod.double()
        self.register_buffer("alphas_cumprod", ab.float(), persistent=False)
        self.anchor_map = None
        if self.proxy_anchor != "none" and cfg["model"].get("anchor_affine"):
            m = cfg["model"]
            self.anchor_map = (PixelAnchor(self.ae, int(m.get("anchor_kernel_px") or 0))
                               if m.get("anchor_space") == "pixel" else LatentAffine(self.ae.latent_channels))
        if self.proxy_anchor != "none":
            out = self.transformer.proj_out  # CogVideoX's last layer (after the adaptive norm)
            with torch.no_grad():
                out.weight.zero_()
                if out.bias is not None:
                    out.bias.zero_()

    @property
    def latent_channels(self) -> int:
        return self.ae.latent_channels

    @property
    def device(self) -> torch.device:
        return self.alphas_cumprod.device

    def to_configured_device(self) -> "Refiner":
        """Move to the device of the config's ``device`` policy (lightcrafter/devices.py); returns self."""
        from lightcrafter.devices import resolve_device

        return self.to(resolve_device(self.cfg["device"], "refiner.device"))

    def _rotary(self, frames: int, h: int, w: int, device):
        tc = self.tcfg
        if not tc.use_rotary_positional_embeddings:
            return None
        from diffusers.models.embeddings import get_3d_rotary_pos_embed

        if tc.patch_size_t is not None:
            raise NotImplementedError("CogVideoX 1.5 (patch_size_t) RoPE layout is not supported; use CogVideoX-5B-I2V")
        p = tc.patch_size
        gh, gw = h // p, w // p
        crops = grid_crop_region((gh, gw), tc.sample_width // p, tc.sample_height // p)
        return get_3d_rotary_pos_embed(
            embed_dim=tc.attention_head_dim, crops_coords=crops, grid_size=(gh, gw), temporal_size=frames, device=device
        )

    def trainable_parameters(self) -> list:
        """Transformer parameters, then the anchor map's (if any)."""
        extra = list(self.anchor_map.parameters()) if self.anchor_map is not None else []
        return [p for p in self.transformer.parameters() if p.requires_grad] + extra

    def weights(self, transformer=None) -> dict:
        """{"transformer": state dict[, "anchor_map": state dict]} (``transformer``: e.g. an unwrapped copy)."""
        out = {"transformer": (transformer or self.transformer).state_dict()}
        if self.anchor_map is not None:
            out["anchor_map"] = self.anchor_map.state_dict()
        return out

    def load_weights(self, state: dict) -> None:
        """Load what :meth:`weights` wrote (extra keys of a checkpoint dict are ignored)."""
        self.transformer.load_state_dict(state["transformer"])
        if self.anchor_map is not None:
            if "anchor_map" not in state:
                raise KeyError("checkpoint has no anchor_map but model.anchor_affine is on; retrain")
            self.anchor_map.load_state_dict(state["anchor_map"])

    def _abar(self, timestep: torch.Tensor) -> torch.Tensor:
        return self.alphas_cumprod.to(timestep.device)[timestep.long()].view(-1, 1, 1, 1, 1)

    def x0_from_v(self, noisy: torch.Tensor, v: torch.Tensor, timestep: torch.Tensor) -> torch.Tensor:
        """x0 estimate sqrt(abar) z_t - sqrt(1 - abar) v (the scheduler's own conversion)."""
        ab = self._abar(timestep)
        return ab.sqrt() * noisy - (1 - ab).sqrt() * v

    def forward(self, noisy: torch.Tensor, proxy: torch.Tensor, timestep: torch.Tensor,
                anchor: torch.Tensor | None = None, residual_scale: float = 1.0) -> torch.Tensor:
        """noisy, proxy: (B, F, C, h, w) latents; timestep: (B,) ints -> v prediction (B, F, C, h, w).

        ``anchor``: the latent the proxy anchor uses (default ``proxy``; CFG's unconditional branch
        passes the real proxy here and zeros as ``proxy``). Ignored when ``model.proxy_anchor`` is none.
        ``residual_scale``: weight of the transformer's correction on the anchor (``infer.residual_scale``;
        training always uses 1); 0 skips the transformer and returns the anchor's v.
        """
        if noisy.shape != proxy.shape:
            raise ValueError(f"noisy {tuple(noisy.shape)} and proxy {tuple(proxy.shape)} latents must match")
        b, f, _, h, w = noisy.shape
        scale = float(residual_scale) if self.proxy_anchor != "none" else 1.0
        if scale == 0.0:  # the anchor alone: the transformer's correction is not computed
            return self._anchor_v(noisy, proxy if anchor is None else anchor, timestep, 0.0)
        if self.fixed_latent_hw and ((h, w) != self.fixed_latent_hw or f != self.fixed_window):
            raise ValueError(
                f"latent window {f}x{h}x{w} (frames x h x w): the transformer's learned positional embeddings serve "
                f"{self.fixed_window}x{self.fixed_latent_hw[0]}x{self.fixed_latent_hw[1]} only (see "
                "lightcrafter/refiner/checkpoint.py)")
        x = torch.cat([noisy, proxy], dim=2).to(self.param_dtype)
        emb = self.prompt_embeds.to(self.param_dtype).expand(b, -1, -1)
        with torch.autocast(device_type=x.device.type, dtype=self.compute_dtype,
                            enabled=self.compute_dtype != self.param_dtype):
            out = self.transformer(
                hidden_states=x,
                encoder_hidden_states=emb,
                timestep=timestep,
                image_rotary_emb=self._rotary(f, h, w, x.device),
                return_dict=False,
            )[0]
        out = out.float()
        if self.proxy_anchor == "none":
            return out
        return self._anchor_v(noisy, proxy if anchor is None else anchor, timestep, scale * out)

    def anchor_latent(self, a: torch.Tensor) -> torch.Tensor:
        """The proxy anchor's x0 for the proxy latent ``a``: the learned map of ``a`` if any, else ``a``."""
        return self.anchor_map(a) if self.anchor_map is not None else a

    def _anchor_v(self, noisy: torch.Tensor, a: torch.Tensor, timestep: torch.Tensor, out) -> torch.Tensor:
        """v of the proxy anchor (:meth:`anchor_latent` of ``a``) plus the correction ``out``."""
        a = self.anchor_latent(a)
        ab = self._abar(timestep)
        s1 = (1 - ab).sqrt()
        v_anchor = (ab.sqrt() * noisy - a) / s1
        return v_anchor - out / s1 if self.proxy_anchor == "x0" else v_anchor + out
