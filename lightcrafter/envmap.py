"""Environment maps: the ONE lat-long direction <-> pixel convention of the project.

Convention (Blender world frame: right-handed, Z up; identical to Cycles' Environment Texture,
equirectangular projection, Linear interpolation)
----------------------------------------------------------------------------------------
An envmap is a linear HDR RGB array ``E`` of shape (H, W, 3), row 0 at the top.
A *lookup direction* ``d = (x, y, z)`` (unit, world frame) maps to

* ``u = (pi - atan2(y, x)) / (2 pi)``  in [0, 1), wrapping horizontally;
  u = 0.5 (image centre column) looks along +X, u = 0.25 along +Y, u = 0.75 along -Y;
* ``v = acos(z) / pi``                  in [0, 1]; v = 0 (top row) is +Z (zenith);

and continuous pixel coordinates ``col = u W - 0.5``, ``row = v H - 0.5`` (pixel centres at
integers, bilinear interpolation, horizontal wrap, vertical clamp).

Rotation about Z: the radiance arriving from world direction ``d`` is ``E(lookup(Rz(-theta) d))``
with ``theta = rotation_z_rad`` (plus a trajectory's per-frame ``light_rotation_z_rad``): a feature
the unrotated map shows in direction ``m`` appears in direction ``Rz(theta) m`` (counter-clockwise
seen from above). This is what Blender computes for ``Texture Coordinate(Generated) ->
Mapping(vector_type TEXTURE, rotation (0, 0, theta)) -> Environment Texture``, the world built by
``lightcrafter.blender.build``; the Cycles convention test (tests/test_proxy_convention.py) checks
it end to end.

Global fitted yaw/pitch (envmap fitting) are applied by resampling the data
(:func:`rotate`), exposure in EV by :func:`apply_exposure`.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from lightcrafter.io import DataError, read_exr

# Mitsuba's ``envmap`` local frame is Y up with u = atan2(x, -z)/2pi. This to_world maps our
# lookup convention onto it exactly in azimuth (see mitsuba_data for the vertical half pixel).
MITSUBA_TO_WORLD = np.array(
    [[0.0, 0.0, 1.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)


def rot_z(theta_rad: float) -> np.ndarray:
    """3x3 right-handed rotation about +Z by ``theta_rad`` (counter-clockwise seen from above)."""
    c, s = np.cos(theta_rad), np.sin(theta_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_y(theta_rad: float) -> np.ndarray:
    """3x3 right-handed rotation about +Y by ``theta_rad``."""
    c, s = np.cos(theta_rad), np.sin(theta_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def direction_to_uv(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lookup direction(s) (..., 3), any length > 0 -> (u, v) in [0, 1) x [0, 1] (see module doc)."""
    d = np.asarray(d, dtype=np.float64)
    n = np.linalg.norm(d, axis=-1)
    n = np.where(n > 0, n, 1.0)
    x, y, z = d[..., 0] / n, d[..., 1] / n, d[..., 2] / n
    u = np.mod((np.pi - np.arctan2(y, x)) / (2 * np.pi), 1.0)
    v = np.arccos(np.clip(z, -1.0, 1.0)) / np.pi
    return u, v


def uv_to_direction(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Inverse of :func:`direction_to_uv`: (u, v) -> unit lookup direction (..., 3)."""
    u, v = np.broadcast_arrays(np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64))
    phi = np.pi - 2 * np.pi * u
    theta = np.pi * v
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=-1)


def pixel_directions(height: int, width: int) -> np.ndarray:
    """Unit lookup direction of every pixel centre, (H, W, 3)."""
    v = (np.arange(height) + 0.5) / height
    u = (np.arange(width) + 0.5) / width
    return uv_to_direction(u[None, :], v[:, None])


def sample_bilinear(env: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear lookup of ``env`` (H, W, C) at (u, v): horizontal wrap, vertical clamp."""
    h, w = env.shape[:2]
    col = np.asarray(u) * w - 0.5
    row = np.clip(np.asarray(v) * h - 0.5, 0.0, h - 1.0)
    c0 = np.floor(col).astype(np.int64)
    r0 = np.floor(row).astype(np.int64)
    fc = (col - c0)[..., None]
    fr = (row - r0)[..., None]
    c1 = (c0 + 1) % w
    c0 = c0 % w
    r1 = np.minimum(r0 + 1, h - 1)
    top = env[r0, c0] * (1 - fc) + env[r0, c1] * fc
    bot = env[r1, c0] * (1 - fc) + env[r1, c1] * fc
    return top * (1 - fr) + bot * fr


def radiance(env: np.ndarray, d_world: np.ndarray, rotation_z_rad: float = 0.0) -> np.ndarray:
    """Radiance arriving from world direction(s) ``d_world`` under Z rotation (reference lookup)."""
    look = np.asarray(d_world, dtype=np.float64) @ rot_z(-rotation_z_rad).T
    return sample_bilinear(env, *direction_to_uv(look))


NEGATIVE_TOLERANCE_REL = 0.02  # negatives down to -2 % of the mean radiance are ringing: clamped to 0


def validate(env: np.ndarray, path: str | os.PathLike = "<array>") -> np.ndarray:
    """Return ``env`` as float32 (H, W, 3); NaN/Inf/negative pixels raise DataError naming ``path``.

    Tiny negatives (>= -NEGATIVE_TOLERANCE_REL x mean radiance) are clamped to 0: seven of Blender's
    eight bundled HDRIs have such filtering/compression ringing (worst: night.exr, min -0.0017 at
    mean 0.116; forest.exr, min -0.0022 at mean 0.80). Larger negatives are an error.
    """
    env = np.asarray(env, dtype=np.float32)
    if env.ndim != 3 or env.shape[2] != 3 or env.shape[0] < 2 or env.shape[1] < 2:
        raise DataError(f"{path}: envmap must be (H>=2, W>=2, 3) RGB, got shape {env.shape}")
    bad = ~np.isfinite(env).all(axis=-1)
    if bad.any():
        raise DataError(f"{path}: envmap has {int(bad.sum())} NaN/Inf pixel(s); repair or replace the HDRI")
    tol = NEGATIVE_TOLERANCE_REL * float(np.mean(np.maximum(env, 0.0)))
    neg = (env < -tol).any(axis=-1)
    if neg.any():
        raise DataError(f"{path}: envmap has {int(neg.sum())} negative pixel(s); radiance must be >= 0")
    return np.maximum(env, 0.0)


def load(path: str | os.PathLike) -> np.ndarray:
    """Load a lat-long HDR EXR (channels R, G, B; or a single Y channel) as validated (H, W, 3)."""
    path = Path(path)
    ch = read_exr(path)
    if all(c in ch for c in ("R", "G", "B")):
        env = np.stack([ch["R"], ch["G"], ch["B"]], axis=-1)
    elif "Y" in ch:
        env = np.repeat(ch["Y"][..., None], 3, axis=-1)
    else:
        raise DataError(f"{path}: envmap needs channels R, G, B (or Y), found {sorted(ch)}")
    return validate(env, path)


def apply_exposure(env: np.ndarray, exposure_ev: float = 0.0, strength: float = 1.0) -> np.ndarray:
    """Scale radiance by ``strength * 2**exposure_ev`` (linear; strength = Blender Background strength)."""
    return (np.asarray(env, dtype=np.float32) * np.float32(strength * 2.0**exposure_ev)).astype(np.float32)


def rotate(env: np.ndarray, yaw_rad: float = 0.0, pitch_rad: float = 0.0) -> np.ndarray:
    """Resample ``env`` so its content turns by ``yaw_rad`` about +Z, then ``pitch_rad`` about +Y.

    Output pixel with lookup direction ``d`` takes the input at ``R^T d`` with
    ``R = rot_y(pitch) @ rot_z(yaw)``: a feature seen from direction ``m`` before is seen from
    ``R m`` after. Pure yaw by a whole number of columns is an exact roll of the columns.
    """
    env = np.asarray(env, dtype=np.float32)
    if yaw_rad == 0.0 and pitch_rad == 0.0:
        return env.copy()
    h, w = env.shape[:2]
    R = rot_y(pitch_rad) @ rot_z(yaw_rad)
    src = pixel_directions(h, w) @ R  # row-vector form of R^T d
    return sample_bilinear(env, *direction_to_uv(src)).astype(np.float32)


def mitsuba_data(env: np.ndarray) -> np.ndarray:
    """Data for Mitsuba's ``envmap`` (with ``to_world = MITSUBA_TO_WORLD``) that reproduces
    :func:`sample_bilinear` exactly.

    Mitsuba interpolates rows at ``v (H' - 1)`` (pixel corners at the poles), Cycles at
    ``v H - 0.5``; giving Mitsuba H' = 2H + 1 rows (odd rows = the input rows, even rows = midpoints,
    poles clamped) makes both piecewise-linear in v with the same knots. Columns already agree.
    """
    env = np.asarray(env, dtype=np.float32)
    h = env.shape[0]
    out = np.empty((2 * h + 1,) + env.shape[1:], dtype=np.float32)
    out[1::2] = env
    out[0] = env[0]
    out[-1] = env[-1]
    out[2:-1:2] = 0.5 * (env[:-1] + env[1:])
    return out
