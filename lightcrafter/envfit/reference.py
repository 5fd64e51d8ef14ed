"""Reference solver: every iteration renders the sampled frame with R's environment estimator in
Dr.Jit and differentiates it with Mitsuba's AD (variant from lightcrafter.proxy.mitsuba_setup:
``cuda_ad_rgb`` on a GPU, ``llvm_ad_rgb`` here).

Per iteration: fresh lanes (:meth:`.tracing.Tracer.lanes`, seed from (seed, iteration);
``ref_spp`` per pixel; all used pixels of the frame, or ``ref_pixels`` of them drawn afresh) look
the map up with a differentiable bilinear gather (:func:`.tracing.bilinear_taps_dr`, the
:mod:`lightcrafter.envmap` convention), pixels average their lanes (``dr.block_sum``), Reinhard +
L1 against the video, ``dr.backward`` gives d loss / d L for every texel. The chain from L to the
parameters (exp, exposure, yaw/pitch resampling) and TV are the torch code of :mod:`.model`
shared with the fast solver, and the step is the same ``torch.optim.Adam`` (the Dr.Jit gradient
enters torch through an autograd function), so the two solvers differ only in how R's transport
is sampled.
"""

from __future__ import annotations

import hashlib

import drjit as dr
import mitsuba as mi
import numpy as np
import torch

from .model import ExternalLoss, reinhard
from .tracing import Tracer, bilinear_taps_dr


def iteration_seed(seed: int, iteration: int, salt: str = "ref") -> int:
    h = hashlib.sha256(f"{salt}:{int(seed)}:{int(iteration)}".encode()).digest()
    return int.from_bytes(h[:4], "little")


def render_loss_and_grad(tracer: Tracer, view, pixels: np.ndarray, observed_tm: np.ndarray, env: np.ndarray,
                         spp: int, seed: int) -> tuple[float, np.ndarray, np.ndarray]:
    """Render ``pixels`` of ``view`` under ``env`` (H, W, 3) with Dr.Jit AD; return
    (mean |T(R) - T(I)|, d loss / d env (H, W, 3), rendered radiance (P, 3))."""
    h, w = env.shape[:2]
    lanes = tracer.lanes(view, pixels, spp, seed)
    tex = mi.Float(np.ascontiguousarray(env, np.float32).ravel())
    dr.enable_grad(tex)
    idx, wts = bilinear_taps_dr(lanes.d, h, w)
    rad = mi.Color3f(0.0)
    live = dr.any(lanes.w != 0.0)
    for k in range(4):
        rad += wts[k] * dr.gather(mi.Color3f, tex, idx[k], live)
    lane_rad = lanes.w * rad
    pix = mi.Color3f(*[dr.block_sum(lane_rad[c], lanes.spp) * (1.0 / lanes.spp) for c in range(3)])
    obs = mi.Color3f(*[mi.Float(np.ascontiguousarray(observed_tm[:, c], np.float32)) for c in range(3)])
    diff = dr.abs(pix / (1.0 + pix) - obs)
    loss = dr.sum(diff.x + diff.y + diff.z) * (1.0 / (3 * len(pixels)))
    dr.backward(loss)
    grad = np.asarray(dr.grad(tex), np.float32).reshape(h, w, 3)
    radiance = np.stack([np.asarray(pix[c]) for c in range(3)], -1)
    return float(loss[0]), grad, radiance


class ReferenceObjective:
    """Data term rendered afresh every iteration (module doc)."""

    def __init__(self, tracer: Tracer, views, video, spp: int, pixels: int, seed: int):
        self.tracer, self.views, self.video = tracer, views, video
        self.spp, self.pixels, self.seed = int(spp), int(pixels), int(seed)
        self.observed_tm = {i: reinhard(video.observed(i).astype(np.float32)) for i in video.fitted}

    def _pixels(self, frame: int, iteration: int) -> tuple[np.ndarray, np.ndarray]:
        used = self.video.used[frame]
        if self.pixels <= 0 or self.pixels >= len(used):
            return used, self.observed_tm[frame]
        rng = np.random.default_rng(iteration_seed(self.seed, iteration, "refpix"))
        sel = np.sort(rng.choice(len(used), size=self.pixels, replace=False))
        return used[sel], self.observed_tm[frame][sel]

    def data_loss(self, env: torch.Tensor, frame: int, iteration: int) -> torch.Tensor:
        pixels, obs = self._pixels(frame, iteration)
        seed = iteration_seed(self.seed, iteration)

        def fn(env_np):
            loss, grad, _ = render_loss_and_grad(self.tracer, self.views[frame], pixels, obs, env_np, self.spp, seed)
            return loss, grad

        return ExternalLoss.apply(env, fn)
