"""Judging a fitted map the same way for both solvers.

* :class:`TrueObjective`: the objective of :mod:`.model` on *every* fitted frame and all its used
  pixels, with R itself (:class:`ProxyRenderer`, the standard renderer, MIS) at a high sample count
  and a fixed seed: sum (or mean, as the fit's data_reduction) of |T(R) - T(I)| + lambda_TV TV(log map); also
  the display PSNR (lightcrafter.metrics.display_psnr_db) of the re-render on the fitted frames.
* :func:`sh_coefficients` / :func:`sh_error`: low-order real spherical-harmonic projection of a map
  (solid-angle weighted, optionally restricted to the upper hemisphere, the part a scene on a
  ground plane sees), and the relative coefficient error after the best yaw alignment.
"""

from __future__ import annotations

import numpy as np

from lightcrafter import envmap
from lightcrafter.metrics import display_psnr_db
from lightcrafter.proxy.lighting import Lighting
from lightcrafter.proxy.renderer import ProxyRenderer, RenderSettings

from .model import reinhard


class TrueObjective:
    """R at ``spp`` (seed fixed) on all fitted frames of a :class:`~.fit.Problem`."""

    def __init__(self, problem, spp: int = 256, seed: int = 4242, lambda_tv: float = 1e-3, reduction: str = "sum"):
        from dataclasses import replace

        self.problem = problem
        self.settings = replace(problem.render, spp=int(spp), seed=int(seed))
        self.lambda_tv = float(lambda_tv)
        self.reduction = reduction
        self._base = None

    def _renderer(self, env: np.ndarray) -> ProxyRenderer:
        r = ProxyRenderer(Lighting(env=np.asarray(env, np.float32)), self.settings)
        r.prepare(self.problem.views, like=self._base)  # R's clip visibility mesh, built once for every map
        if self._base is None:
            self._base = r
        return r

    def renders(self, env: np.ndarray) -> dict[int, np.ndarray]:
        r = self._renderer(env)
        p = self.problem
        return {i: r.render(p.views[i], frame=i) for i in p.video.fitted}

    def __call__(self, env: np.ndarray, log_map: np.ndarray | None = None) -> dict:
        p = self.problem
        imgs = self.renders(env)
        data, psnr = [], []
        for i, img in imgs.items():
            px = p.video.used[i]
            pred = img.reshape(-1, 3)[px].astype(np.float64)
            obs = p.video.frames[i].reshape(-1, 3)[px].astype(np.float64)
            err = np.abs(reinhard(pred) - reinhard(obs))
            data.append(float(err.sum()) if self.reduction == "sum" else float(err.mean()))
            psnr.append(display_psnr_db(img, p.video.frames[i]))
        tv = 0.0
        if log_map is not None:
            lm = np.asarray(log_map, np.float64)
            tv = float(np.abs(np.roll(lm, -1, axis=1) - lm).sum() + np.abs(lm[1:] - lm[:-1]).sum())
        d = float(np.sum(data) if self.reduction == "sum" else np.mean(data))
        return {"objective": d + self.lambda_tv * tv, "data": d, "tv": tv, "psnr_db": float(np.mean(psnr)),
                "psnr_db_per_frame": [round(x, 3) for x in psnr]}


def _sh_basis(d: np.ndarray, order: int) -> np.ndarray:
    """Real SH basis up to ``order`` (<= 2) at unit directions d (..., 3): (..., (order+1)^2)."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    b = [0.282095 * np.ones_like(x)]
    if order >= 1:
        b += [0.488603 * y, 0.488603 * z, 0.488603 * x]
    if order >= 2:
        b += [1.092548 * x * y, 1.092548 * y * z, 0.315392 * (3 * z * z - 1), 1.092548 * x * z,
              0.546274 * (x * x - y * y)]
    return np.stack(b, axis=-1)


def sh_coefficients(env: np.ndarray, order: int = 2, upper_only: bool = True) -> np.ndarray:
    """((order+1)^2, 3) SH coefficients of a lat-long map (solid-angle weights; lower hemisphere
    zeroed when ``upper_only``)."""
    env = np.asarray(env, np.float64)
    h, w = env.shape[:2]
    d = envmap.pixel_directions(h, w)
    theta = (np.arange(h) + 0.5) / h * np.pi
    dw = (np.sin(theta) * (np.pi / h) * (2 * np.pi / w))[:, None] * np.ones((1, w))
    if upper_only:
        dw = dw * (d[..., 2] > 0)
    basis = _sh_basis(d, order)
    return np.einsum("hwk,hwc,hw->kc", basis, env, dw)


def sh_error(env_fit: np.ndarray, env_true: np.ndarray, order: int = 2, upper_only: bool = True,
             yaw_steps: int = 128) -> dict:
    """Relative SH-coefficient error ||c_fit - c_true|| / ||c_true|| before and after the yaw (about +Z,
    on the fitted map, whole-column steps of 2 pi / W when ``yaw_steps`` = W) that minimises it."""
    ct = sh_coefficients(env_true, order, upper_only)
    norm = float(np.linalg.norm(ct))
    e0 = float(np.linalg.norm(sh_coefficients(env_fit, order, upper_only) - ct) / norm)
    w = env_fit.shape[1]
    best, best_yaw = e0, 0.0
    for k in range(yaw_steps):
        yaw = 2 * np.pi * k / yaw_steps
        rolled = envmap.rotate(env_fit, yaw) if yaw_steps != w else np.roll(env_fit, -k, axis=1)
        e = float(np.linalg.norm(sh_coefficients(rolled, order, upper_only) - ct) / norm)
        if e < best:
            best, best_yaw = e, yaw
    if best_yaw > np.pi:
        best_yaw -= 2 * np.pi
    return {"relative_error": e0, "aligned_relative_error": best, "alignment_yaw_rad": best_yaw, "order": order,
            "upper_hemisphere_only": upper_only}


__all__ = ["RenderSettings", "TrueObjective", "sh_coefficients", "sh_error"]
