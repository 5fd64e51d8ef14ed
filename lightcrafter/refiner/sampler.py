"""Inference: CFG on the proxy latent + overlap-fused temporal tiling + one global scheduler step.

Classifier-free guidance: ``v = v_uncond + s * (v_cond - v_uncond)`` where the conditional branch
sees the proxy latent and the unconditional branch sees a zeroed proxy latent (the training dropout
value); the empty-prompt embedding is identical in both, so guidance acts on the proxy only.
"""

from __future__ import annotations

import torch

from .schedule import build_scheduler
from .tiling import fused_prediction, plan_windows


def guided_prediction(model, z: torch.Tensor, zp: torch.Tensor, t, guidance_scale: float) -> torch.Tensor:
    """v prediction of one window with CFG on the proxy (zeroed proxy = unconditional)."""
    tt = torch.full((z.shape[0],), int(t), dtype=torch.long, device=z.device)
    cond = model(z, zp, tt)
    if guidance_scale == 1.0:
        return cond
    uncond = model(z, torch.zeros_like(zp), tt)
    return uncond + guidance_scale * (cond - uncond)


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
) -> torch.Tensor:
    """Denoise a full-length latent conditioned on ``proxy_latent`` (B, F, C, h, w).

    mode ``fused``: the paper's overlap fusion. mode ``chunks``: the naive baseline -- disjoint
    windows denoised independently (same initial noise), concatenated; used only for benchmarks.
    """
    inf = cfg["infer"]
    num_steps = num_steps or inf["num_steps"]
    gs = inf["guidance_scale"] if guidance_scale is None else guidance_scale
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
                              window=window, overlap=0, generator=generator, init_noise=init_noise[:, s:e])
            )
        return torch.cat(parts, dim=1)
    sched = build_scheduler(cfg)
    sched.set_timesteps(num_steps)
    z = init_noise.clone() * sched.init_noise_sigma
    windows = plan_windows(z.shape[1], window, overlap)
    is_dpm = type(sched).__name__ == "CogVideoXDPMScheduler"
    old_x0 = None
    timesteps = sched.timesteps
    for i, t in enumerate(timesteps):
        def predict(s, e, _z=z, _t=t):
            return guided_prediction(model, _z[:, s:e], proxy_latent[:, s:e], _t, gs)

        v = fused_prediction(predict, tuple(z.shape), windows, inf["min_tent_weight"])
        if is_dpm:  # stochastic step; needs the previous x0 prediction and the previous timestep
            z, old_x0 = sched.step(v, old_x0, t, timesteps[i - 1] if i > 0 else None, z,
                                   generator=generator, return_dict=False)
        else:
            z = sched.step(v, t, z, return_dict=False)[0]
    return z


@torch.no_grad()
def refine_video(model, proxy_video: torch.Tensor, cfg: dict, generator=None, **kw) -> torch.Tensor:
    """(B, 3, N, H, W) proxy in [-1, 1] -> refined video in [-1, 1], same N (padding per config)."""
    from .frames import pad_to_4k1

    video, n = pad_to_4k1(proxy_video, cfg["infer"]["pad_frames"])
    zp = model.ae.encode(video)
    z = sample_latent(model, zp, cfg, generator=generator, **kw)
    return model.ae.decode(z)[:, :, :n].clamp(-1, 1)
