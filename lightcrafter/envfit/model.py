"""The envmap-fitting objective shared by both solvers (torch, CPU): parameters, map head, TV, loss.

Parameters (the paper's appendix, "Real-World Video Pseudo-Pairs")
-----------------------------------------------------------------
* ``log_map`` (He, We, 3): natural log of a lat-long linear HDR map (default 64 x 128), in the
  :mod:`lightcrafter.envmap` convention (row 0 = zenith, u = (pi - atan2(y, x)) / 2 pi).
* ``yaw`` (radians, about world +Z), ``pitch`` (radians, about world +Y), ``exposure`` (EV, base 2).

Map head (what the renderer sees, "exponentiated at the renderer call site")::

    L = 2**exposure * rotate(exp(log_map), yaw, pitch)

where ``rotate`` is :func:`lightcrafter.envmap.rotate` written in torch: each output texel with
lookup direction d takes the bilinear (horizontal wrap, vertical clamp) value of the input at
R^T d, R = rot_y(pitch) rot_z(yaw); so ``envmap.apply_exposure(envmap.rotate(exp(log_map), yaw,
pitch), exposure)`` equals :func:`env_from_params` (tests check it), and the fitted map is written
*baked* (L itself) in the world frame. Gradients reach yaw/pitch through the bilinear weights.

Objective (the paper's eq. envmap_opt with the appendix's TV; Reinhard per colour channel on
linear radiance, T(x) = x / (1 + x))::

    J(L) = sum_{i in fitted} sum_{p, c} | T(R_i(L))_{p,c} - T(I_i)_{p,c} |  +  lambda_TV * TV(log_map)

The data term is the L1 *norm* (sum over the used pixels p and channels c of every fitted frame
i); an iteration estimates it from one frame drawn uniformly, F * 3 * P_i * mean_{p,c}|...| over the
frame's P_i used pixels (or a uniform sample of them), which is unbiased. TV is the paper's eq.
(tv): a sum over texels (and the three channels) of the absolute forward differences of
``log_map`` along u (with wrap-around, u = We wraps to 0) and along v (no wrap).

Why the sum and not a per-pixel mean: with the mean, lambda_TV = 1e-3 outweighs the data by two
to three orders of magnitude (the true map of the synthetic benchmark scene has lambda TV = 0.89
against a mean data term of 0.003) and nothing but a near-constant map emerges, contradicting the
paper's "low-frequency directional structure (sun position, sky-vs-floor gradient) emerges";
with the sum, TV only decides texels the data barely constrain (speckles). The mean is available
as ``data_reduction='mean'`` (FitSettings).

Zero radiance in log space: a map given for initialisation is floored at
``LOG_FLOOR_REL * mean(map)`` (1e-6 of its mean, i.e. 13.8 nats below it) before the log, so a
black texel becomes a finite, very dark one; an all-zero map cannot be floored and is a DataError.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from lightcrafter import envmap
from lightcrafter.io import DataError

LOG_FLOOR_REL = 1e-6


def reinhard(x):
    """Reinhard tonemap x / (1 + x) (torch or numpy), per channel, x >= 0 linear radiance."""
    return x / (1.0 + x)


def tv_log(log_map: torch.Tensor) -> torch.Tensor:
    """Paper eq. (tv) on a (H, W, C) log map: sum |L[v, u+1] - L[v, u]| (u wraps) + |L[v+1, u] - L[v, u]|."""
    du = torch.roll(log_map, shifts=-1, dims=1) - log_map  # u = W - 1 pairs with u = 0
    dv = log_map[1:] - log_map[:-1]
    return du.abs().sum() + dv.abs().sum()


def l1_tonemapped(pred: torch.Tensor, obs_tonemapped: torch.Tensor) -> torch.Tensor:
    """Mean over pixels and channels of |T(pred) - T(obs)| (``obs_tonemapped`` = T(obs), precomputed);
    :func:`lightcrafter.envfit.fit.data_weights` scales it to the objective's data term."""
    return (reinhard(pred) - obs_tonemapped).abs().mean()


def l1_tonemapped_np(pred: np.ndarray, obs_tonemapped: np.ndarray) -> tuple[float, np.ndarray]:
    """numpy twin of :func:`l1_tonemapped` with its gradient: (loss, d loss / d pred)."""
    pred = np.maximum(np.asarray(pred, np.float64), 0.0)
    diff = reinhard(pred) - obs_tonemapped
    n = diff.size
    grad = np.sign(diff) / ((1.0 + pred) ** 2) / n
    return float(np.abs(diff).sum() / n), grad


class ExternalLoss(torch.autograd.Function):
    """A scalar loss of a map computed outside torch: ``fn(env_numpy) -> (loss, d loss / d env)``.
    Both solvers' data terms enter the shared torch graph (map head, TV, Adam) through it."""

    @staticmethod
    def forward(ctx, env: torch.Tensor, fn) -> torch.Tensor:
        loss, grad = fn(env.detach().numpy())
        ctx.grad = torch.from_numpy(np.asarray(grad).reshape(env.shape)).to(env.dtype)
        return torch.tensor(float(loss), dtype=env.dtype)

    @staticmethod
    def backward(ctx, g: torch.Tensor):
        return g * ctx.grad, None


def log_of_map(env: np.ndarray, where: str = "<init map>") -> np.ndarray:
    """Floored natural log of a linear map (see module doc); all-zero maps raise DataError."""
    env = np.asarray(env, np.float64)
    mean = float(np.mean(env))
    if not np.isfinite(env).all() or mean <= 0:
        raise DataError(f"{where}: initial envmap is all zero or not finite; give a map with positive radiance "
                        "or no map (constant grey default)")
    return np.log(np.maximum(env, LOG_FLOOR_REL * mean)).astype(np.float32)


def resize_map(env: np.ndarray, height: int, width: int) -> np.ndarray:
    """Resample a lat-long map to (height, width): area average when shrinking by whole factors,
    else bilinear lookup at the new texel centres (lightcrafter.envmap.sample_bilinear)."""
    env = np.asarray(env, np.float32)
    h, w = env.shape[:2]
    if (h, w) == (height, width):
        return env.copy()
    if h % height == 0 and w % width == 0:
        fh, fw = h // height, w // width
        return env.reshape(height, fh, width, fw, 3).mean(axis=(1, 3)).astype(np.float32)
    u = (np.arange(width) + 0.5) / width
    v = (np.arange(height) + 0.5) / height
    if h > height or w > width:  # pre-blur by box-averaging to the nearest whole factor above
        fh, fw = max(1, h // height), max(1, w // width)
        hh, ww = (h // fh) * fh, (w // fw) * fw
        env = env[:hh, :ww].reshape(hh // fh, fh, ww // fw, fw, 3).mean(axis=(1, 3))
    return envmap.sample_bilinear(env, u[None, :], v[:, None]).astype(np.float32)


@dataclass
class EnvParams:
    """Optimised tensors (float32, requires_grad): log_map (H, W, 3), yaw, pitch (rad), exposure (EV)."""

    log_map: torch.Tensor
    yaw: torch.Tensor
    pitch: torch.Tensor
    exposure: torch.Tensor

    @classmethod
    def create(cls, log_map: np.ndarray, yaw: float = 0.0, pitch: float = 0.0, exposure: float = 0.0) -> "EnvParams":
        def t(x):
            return torch.tensor(np.asarray(x, np.float32), dtype=torch.float32).clone().requires_grad_(True)

        return cls(t(log_map), t(yaw), t(pitch), t(exposure))

    def tensors(self, fit_rotation: bool = True, fit_exposure: bool = True, fit_map: bool = True) -> list[torch.Tensor]:
        out = [self.log_map] if fit_map else []
        if fit_rotation:
            out += [self.yaw, self.pitch]
        if fit_exposure:
            out.append(self.exposure)
        return out

    def numpy(self) -> dict:
        return {"log_map": self.log_map.detach().numpy().copy(), "yaw_rad": float(self.yaw.detach()),
                "pitch_rad": float(self.pitch.detach()), "exposure_ev": float(self.exposure.detach())}


def rotation_grid(dirs: np.ndarray, yaw: float, pitch: float, width: int, height: int):
    """Source position of every output texel of :func:`lightcrafter.envmap.rotate` as a
    ``grid_sample`` grid over the map padded with one wrapped column on each side, and its analytic
    derivatives by yaw and pitch. ``dirs`` (N, 3): output texel directions. Returns (grid (N, 2),
    d grid / d yaw (N, 2), d grid / d pitch (N, 2)), float64, align_corners=True convention."""
    cy, sy, cp, sp_ = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp_], [0.0, 1.0, 0.0], [-sp_, 0.0, cp]])
    drz = np.array([[-sy, -cy, 0.0], [cy, -sy, 0.0], [0.0, 0.0, 0.0]])
    dry = np.array([[-sp_, 0.0, cp], [0.0, 0.0, 0.0], [-cp, 0.0, -sp_]])
    # row-vector form of R^T d, one contiguous row per component: numpy's arctan2 of a strided and a
    # contiguous operand picks its SIMD or scalar loop from run to run (1-ulp differences that Adam grows)
    x, y, z = np.ascontiguousarray((dirs @ (ry @ rz)).T)
    rho2 = x * x + y * y
    rho = np.sqrt(rho2)
    u = np.mod((math.pi - np.arctan2(y, x)) / (2 * math.pi), 1.0)
    v = np.arctan2(rho, z) / math.pi  # = acos(z) for unit src
    col = u * width - 0.5  # in [-0.5, W - 0.5): + 1 in the padded map
    row_raw = v * height - 0.5
    row = np.clip(row_raw, 0.0, height - 1.0)
    sx, sy_ = 2.0 / (width + 1), 2.0 / max(height - 1, 1)
    grid = np.stack([(col + 1.0) * sx - 1.0, row * sy_ - 1.0], axis=-1)
    inside = (row_raw > 0.0) & (row_raw < height - 1.0)  # a clamped row does not move
    ok = rho2 > 1e-24
    safe_rho2 = np.where(ok, rho2, 1.0)
    safe_rho = np.sqrt(safe_rho2)
    derivs = []
    for m in (ry @ drz, dry @ rz):
        d = dirs @ m
        dx, dy, dz = d[:, 0], d[:, 1], d[:, 2]
        datan = np.where(ok, (x * dy - y * dx) / safe_rho2, 0.0)  # d atan2(y, x)
        drho = np.where(ok, (x * dx + y * dy) / safe_rho, 0.0)
        dv = (z * drho - rho * dz) / np.maximum(rho2 + z * z, 1e-24) / math.pi
        dcol = -datan / (2 * math.pi) * width
        drow = np.where(inside, dv * height, 0.0)
        derivs.append(np.stack([dcol * sx, drow * sy_], axis=-1))
    return grid, derivs[0], derivs[1]


class _RotationGrid(torch.autograd.Function):
    """(yaw, pitch) -> sampling grid of :func:`rotation_grid`, gradient by its analytic Jacobian."""

    @staticmethod
    def forward(ctx, yaw: torch.Tensor, pitch: torch.Tensor, dirs: np.ndarray, width: int, height: int):
        grid, d_yaw, d_pitch = rotation_grid(dirs, float(yaw), float(pitch), width, height)
        ctx.jac = (d_yaw, d_pitch)
        ctx.dtype = yaw.dtype
        return torch.from_numpy(grid.reshape(1, height, width, 2))

    @staticmethod
    def backward(ctx, g: torch.Tensor):
        g = g.detach().numpy().reshape(-1, 2)
        d_yaw, d_pitch = ctx.jac
        return (torch.tensor(float((g * d_yaw).sum()), dtype=ctx.dtype),
                torch.tensor(float((g * d_pitch).sum()), dtype=ctx.dtype), None, None, None)


class MapHead:
    """L = 2**exposure * rotate(exp(log_map), yaw, pitch) for maps of one size (directions cached)."""

    def __init__(self, height: int, width: int):
        self.height, self.width = int(height), int(width)
        self.dirs = envmap.pixel_directions(self.height, self.width).reshape(-1, 3)  # float64

    def rotate(self, env: torch.Tensor, yaw: torch.Tensor, pitch: torch.Tensor) -> torch.Tensor:
        """Differentiable :func:`lightcrafter.envmap.rotate` of a (H, W, C) map (float64 inside).

        Bilinear lookup (horizontal wrap, vertical clamp) by ``grid_sample`` on the map padded with
        one wrapped column on each side; gradients reach yaw and pitch through the sample positions
        (:func:`rotation_grid`, analytic; a clamped row, beyond the outermost texel centres, has none,
        as in the numpy reference)."""
        grid = _RotationGrid.apply(yaw, pitch, self.dirs, self.width, self.height)
        padded = torch.cat([env[:, -1:], env, env[:, :1]], dim=1).permute(2, 0, 1).unsqueeze(0).to(torch.float64)
        out = torch.nn.functional.grid_sample(padded, grid, mode="bilinear", padding_mode="border", align_corners=True)
        return out[0].permute(1, 2, 0).to(env.dtype)

    def __call__(self, params: EnvParams) -> torch.Tensor:
        env = torch.exp(params.log_map)
        env = self.rotate(env, params.yaw, params.pitch)
        return env * torch.exp2(params.exposure)

    def baked(self, params: EnvParams) -> np.ndarray:
        """The map R renders with, (H, W, 3) float32 linear, world frame."""
        with torch.no_grad():
            return self(params).numpy().astype(np.float32)


def make_adam(params: EnvParams, lr: float, betas: tuple[float, float], fit_rotation: bool = True,
              fit_exposure: bool = True, fit_map: bool = True):
    """torch.optim.Adam (fused CPU kernel, same update) over the optimised tensors; both solvers use it."""
    tensors = params.tensors(fit_rotation, fit_exposure, fit_map)
    if not tensors:
        raise ValueError("nothing to optimise: enable fit_map, fit_rotation or fit_exposure")
    return torch.optim.Adam(tensors, lr=lr, betas=tuple(betas), fused=True)
