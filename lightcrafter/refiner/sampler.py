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
    rs = float(inf.get("residual_scale", 1.0) if residual_scale is None else residual_scale)
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


@torch.no_grad()
def refine_video(model, proxy_video: torch.Tensor, cfg: dict, generator=None, num_samples: int | None = None,
                 **kw) -> torch.Tensor:
    """(B, 3, N, H, W) proxy in [-1, 1] -> refined video in [-1, 1] on the CPU, same N (padding per
    config; a clip shorter than a fixed window is repeated to it). Runs on the model's device.

    ``num_samples`` (default ``infer.num_samples``): the output is the mean of that many decoded
    samples, drawn one after the other with ``generator`` (pixel space, so any autoencoder works).
    """
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
    return (acc / k).clamp(-1, 1).cpu()
