"""Inference: CFG on the proxy latent + overlap-fused temporal tiling + one global scheduler step.

Classifier-free guidance: ``v = v_uncond + s * (v_cond - v_uncond)`` where the conditional branch
sees the proxy latent and the unconditional branch sees a zeroed proxy latent (the training dropout
value); the empty-prompt embedding is identical in both, so guidance acts on the proxy only. With a
proxy anchor (model.py) both branches keep the anchor on the real proxy.

Start (SDEdit, as diffusers' ``CogVideoXVideoToVideoPipeline``): with ``strength`` s the sampler keeps
the last ``k = int(num_steps * s)`` of the ``num_steps`` trailing timesteps and starts from the clean
proxy latent noised to the first kept timestep, ``add_noise(proxy_latent, noise, t_k)``. s = 1 keeps
every step and starts from pure noise exactly as before (zero terminal SNR: t = 999 carries no
signal); k = 0 (s = 0, or s < 1 / num_steps) returns the proxy latent unchanged, so the decoded
output is the proxy through the autoencoder.
"""

from __future__ import annotations

import torch

from .schedule import build_scheduler
from .tiling import fused_prediction, plan_windows


def guided_prediction(model, z: torch.Tensor, zp: torch.Tensor, t, guidance_scale: float,
                      residual_scale: float = 1.0) -> torch.Tensor:
    """v prediction of one window with CFG on the proxy (zeroed proxy = unconditional).

    ``residual_scale`` (``infer.residual_scale``) weighs the correction on a proxy anchor (model.py)."""
    tt = torch.full((z.shape[0],), int(t), dtype=torch.long, device=z.device)
    kw = {} if residual_scale == 1.0 else {"residual_scale": residual_scale}
    cond = model(z, zp, tt, **kw)
    if guidance_scale == 1.0 or residual_scale == 0.0:  # the anchor alone has no proxy-free branch to guide
        return cond
    if getattr(model, "proxy_anchor", "none") != "none":
        uncond = model(z, torch.zeros_like(zp), tt, anchor=zp, **kw)
    else:
        uncond = model(z, torch.zeros_like(zp), tt)
    return uncond + guidance_scale * (cond - uncond)


def kept_timesteps(timesteps: torch.Tensor, num_steps: int, strength: float) -> torch.Tensor:
    """The timesteps an SDEdit run of ``strength`` visits (diffusers' ``get_timesteps``)."""
    if not 0.0 <= strength <= 1.0:
        raise ValueError(f"strength={strength}: must be in [0, 1]")
    k = min(int(num_steps * strength), num_steps)
    return timesteps[num_steps - k:]


@torch.no_grad()
def sample_latent(
    model,
    proxy_latent: torch.Tensor,
    cfg: dict,
    *,
    num_steps: int | None = None,
    guidance_scale: float | None = None,
    window: int | None = None,
    overlap: int | None = None,
    generator: torch.Generator | None = None,
    init_noise: torch.Tensor | None = None,
    mode: str = "fused",
    strength: float | None = None,
    residual_scale: float | None = None,
) -> torch.Tensor:
    """Denoise a full-length latent conditioned on ``proxy_latent`` (B, F, C, h, w).

    mode ``fused``: the paper's overlap fusion. mode ``chunks``: the naive baseline -- disjoint
    windows denoised independently (same initial noise), concatenated; used only for benchmarks.
    ``strength`` (default ``infer.strength``): see the module docstring. ``residual_scale`` (default
    ``infer.residual_scale``): weight of the transformer's correction on a proxy anchor.
    """
    inf = cfg["infer"]
    num_steps = num_steps or inf["num_steps"]
    gs = inf["guidance_scale"] if guidance_scale is None else guidance_scale
    strength = float(inf.get("strength", 1.0) if strength is None else strength)
    rs = resolved_residual_scale(cfg, residual_scale)
    window = window or inf["window"]
    overlap = inf["overlap"] if overlap is None else overlap
    if init_noise is None:
        init_noise = torch.randn(proxy_latent.shape, generator=generator)  # CPU generator: device-independent
    init_noise = init_noise.to(proxy_latent.device)
    if mode == "chunks":
        n = proxy_latent.shape[1]
        parts = []
        for s in range(0, n, window):
            e = min(n, s + window)
            parts.append(
                sample_latent(model, proxy_latent[:, s:e], cfg, num_steps=num_steps, guidance_scale=gs,
                              window=window, overlap=0, generator=generator, init_noise=init_noise[:, s:e],
                              strength=strength, residual_scale=rs)
            )
        return torch.cat(parts, dim=1)
    sched = build_scheduler(cfg)
    sched.set_timesteps(num_steps)
    if strength >= 1.0:
        timesteps = sched.timesteps
        z = init_noise.clone() * sched.init_noise_sigma
    else:
        timesteps = kept_timesteps(sched.timesteps, num_steps, strength)
        if len(timesteps) == 0:
            return proxy_latent.clone()
        t0 = timesteps[:1].repeat(proxy_latent.shape[0])
        z = sched.add_noise(proxy_latent, init_noise, t0.to(proxy_latent.device)) * sched.init_noise_sigma
    windows = plan_windows(z.shape[1], window, overlap)
    is_dpm = type(sched).__name__ == "CogVideoXDPMScheduler"
    old_x0 = None
    for i, t in enumerate(timesteps):
        def predict(s, e, _z=z, _t=t):
            return guided_prediction(model, _z[:, s:e], proxy_latent[:, s:e], _t, gs, rs)

        v = fused_prediction(predict, tuple(z.shape), windows, inf["min_tent_weight"])
        if is_dpm:  # stochastic step; needs the previous x0 prediction and the previous timestep
            z, old_x0 = sched.step(v, old_x0, t, timesteps[i - 1] if i > 0 else None, z,
                                   generator=generator, return_dict=False)
        else:
            z = sched.step(v, t, z, return_dict=False)[0]
    return z


def _gaussian_taps(sigma: float, dtype, device) -> tuple[int, torch.Tensor]:
    """Radius (3 sigma, at least 1) and the normalised taps of a 1-D Gaussian of ``sigma`` samples."""
    r = max(1, int(round(3.0 * sigma)))
    t = torch.arange(-r, r + 1, dtype=dtype, device=device)
    g = torch.exp(-0.5 * (t / sigma) ** 2)
    return r, g / g.sum()


def gaussian_blur(frames: torch.Tensor, sigma_px: float) -> torch.Tensor:
    """(N, C, H, W) frames blurred by a Gaussian of ``sigma_px`` pixels (separable, 3 sigma radius, edges
    replicated)."""
    import torch.nn.functional as F

    r, g = _gaussian_taps(sigma_px, frames.dtype, frames.device)
    c = frames.shape[1]
    x = F.conv2d(F.pad(frames, (r, r, 0, 0), mode="replicate"), g.view(1, 1, 1, -1).expand(c, 1, 1, -1), groups=c)
    return F.conv2d(F.pad(x, (0, 0, r, r), mode="replicate"), g.view(1, 1, -1, 1).expand(c, 1, -1, 1), groups=c)


def temporal_gaussian_blur(video: torch.Tensor, sigma_frames: float) -> torch.Tensor:
    """(B, C, N, H, W) video blurred along its frames by a Gaussian of ``sigma_frames`` frames (3 sigma radius,
    the first and last frames repeated beyond the clip's ends)."""
    r, g = _gaussian_taps(sigma_frames, video.dtype, video.device)
    n = video.shape[2]
    frames = torch.arange(n, device=video.device)
    out = torch.zeros_like(video)
    for k, w in zip(range(-r, r + 1), g):
        out += w * video[:, :, (frames + k).clamp(0, n - 1)]
    return out


def blur_correction(refined: torch.Tensor, anchor: torch.Tensor, sigma_px: float,
                    sigma_frames: float = 0.0) -> torch.Tensor:
    """``infer.correction_blur_px`` / ``correction_blur_frames``: (B, 3, N, H, W) refined clip whose difference
    from the anchor's output (the transformer's correction, display values) is blurred by a Gaussian of
    ``sigma_px`` pixels in each frame and of ``sigma_frames`` frames along the clip. The tiny preset's
    transformer predicts a token per 2x2 latent patch of 8x8-pixel DCT blocks over 4-frame latent frames, so its
    correction carries a 16-pixel grid and steps every 4 frames; the shading and colour it adds vary slower than
    that, and the anchor keeps the proxy's detail. Both 0 return ``refined``."""
    if sigma_px <= 0 and sigma_frames <= 0:
        return refined
    b, c, n, h, w = refined.shape
    d = refined - anchor
    if sigma_px > 0:
        d = d.permute(0, 2, 1, 3, 4).reshape(b * n, c, h, w)
        d = gaussian_blur(d, sigma_px).reshape(b, n, c, h, w).permute(0, 2, 1, 3, 4)
    if sigma_frames > 0:
        d = temporal_gaussian_blur(d, sigma_frames)
    return anchor + d


@torch.no_grad()
def anchor_video(model, proxy_latent: torch.Tensor) -> torch.Tensor:
    """The decoded output of the proxy anchor alone (what ``residual_scale`` 0 returns, without sampling)."""
    return model.ae.decode(model.anchor_latent(proxy_latent))


def resolved_residual_scale(cfg: dict, residual_scale: float | None) -> float:
    """``residual_scale``, or ``infer.residual_scale`` (default 1) when None."""
    return float(cfg["infer"].get("residual_scale", 1.0) if residual_scale is None else residual_scale)


def resolved_correction_blurs(cfg: dict, sigma_px: float | None, sigma_frames: float | None) -> tuple[float, float]:
    """(``correction_blur_px``, ``correction_blur_frames``): each given value, or ``infer``'s (default 0) when None."""
    inf = cfg["infer"]
    return (float(inf.get("correction_blur_px", 0.0) if sigma_px is None else sigma_px),
            float(inf.get("correction_blur_frames", 0.0) if sigma_frames is None else sigma_frames))


def _corrects(model, cfg: dict, residual_scale: float | None) -> bool:
    """Whether the refined clip carries a transformer correction on top of a proxy anchor (what the correction
    blur acts on)."""
    return resolved_residual_scale(cfg, residual_scale) > 0 and getattr(model, "proxy_anchor", "none") != "none"


@torch.no_grad()
def refine_parts(model, proxy_video: torch.Tensor, cfg: dict, generator=None, num_samples: int | None = None,
                 with_anchor: bool = True, **kw) -> tuple[torch.Tensor, torch.Tensor | None]:
    """The refined clip before any correction blur -- the mean of ``num_samples`` (default ``infer.num_samples``)
    decoded samples drawn one after the other with ``generator``, clamped to [-1, 1] -- and the anchor's own
    output (:func:`anchor_video`, clamped) when ``with_anchor`` and the clip carries a correction to blur, else
    None. (B, 3, N, H, W) on the model's device; ``kw`` goes to :func:`sample_latent`. Selection samples once
    and scores every blur."""
    from .frames import pad_to_4k1, pad_to_latent_frames

    k = int(cfg["infer"].get("num_samples", 1) if num_samples is None else num_samples)
    video, n = pad_to_4k1(proxy_video, cfg["infer"]["pad_frames"])
    video, _ = pad_to_latent_frames(video, getattr(model, "fixed_window", None))  # short clips: repeat to the window
    dev = getattr(model, "device", video.device)
    zp = model.ae.encode(video.to(dev))
    acc = None
    for _ in range(k):
        out = model.ae.decode(sample_latent(model, zp, cfg, generator=generator, **kw))[:, :, :n]
        acc = out if acc is None else acc + out
    anchor = None
    if with_anchor and _corrects(model, cfg, kw.get("residual_scale")):
        anchor = anchor_video(model, zp)[:, :, :n].clamp(-1, 1)
    return (acc / k).clamp(-1, 1), anchor


@torch.no_grad()
def refine_video(model, proxy_video: torch.Tensor, cfg: dict, generator=None, num_samples: int | None = None,
                 correction_blur_px: float | None = None, correction_blur_frames: float | None = None,
                 **kw) -> torch.Tensor:
    """(B, 3, N, H, W) proxy in [-1, 1] -> refined video in [-1, 1] on the CPU, same N (padding per
    config; a clip shorter than a fixed window is repeated to it). Runs on the model's device.

    ``num_samples`` (default ``infer.num_samples``): the output is the mean of that many decoded
    samples, drawn one after the other with ``generator`` (pixel space, so any autoencoder works).
    ``correction_blur_px`` / ``correction_blur_frames`` (default ``infer.*``): :func:`blur_correction` on that
    mean, for a model with a proxy anchor and a residual scale above 0.
    """
    sigma_px, sigma_t = resolved_correction_blurs(cfg, correction_blur_px, correction_blur_frames)
    out, anchor = refine_parts(model, proxy_video, cfg, generator=generator, num_samples=num_samples,
                               with_anchor=sigma_px > 0 or sigma_t > 0, **kw)
    if anchor is not None:
        out = blur_correction(out, anchor, sigma_px, sigma_t).clamp(-1, 1)
    return out.cpu()
