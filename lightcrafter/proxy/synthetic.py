"""Analytic buffers of spheres on a ground plane (exact ray casting in numpy), for tests/benchmarks.

Same conventions as the pipeline: OpenCV camera, K with pixel centres at integers, z-depth in
metres, world-space normals, ground plane z = 0 (Blender world, Z up).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lightcrafter.camera import intrinsics, opencv_c2w
from lightcrafter.io import Buffers
from lightcrafter.proxy.geometry import camera_rays


@dataclass(frozen=True)
class Sphere:
    center_m: tuple[float, float, float]
    radius_m: float
    albedo: tuple[float, float, float] = (0.8, 0.8, 0.8)
    roughness: float = 0.5
    metallic: float = 0.0


@dataclass(frozen=True)
class Ground:
    albedo: tuple[float, float, float] = (0.5, 0.5, 0.5)
    roughness: float = 0.8
    metallic: float = 0.0
    half_size_m: float = 6.0


# Shared camera math, re-exported for the tests and benchmarks that build synthetic clips.
__all__ = ["Ground", "intrinsics", "look_at", "raycast_buffers"]
look_at = opencv_c2w


def raycast_buffers(K: np.ndarray, c2w: np.ndarray, width: int, height: int, spheres=(),
                    ground: Ground | None = Ground()) -> Buffers:
    rays_c = camera_rays(K, height, width)  # z = 1
    R, o = c2w[:3, :3], c2w[:3, 3]
    d = rays_c @ R.T  # world direction with camera-z component 1 => t is z-depth
    best = np.full((height, width), np.inf)
    nrm = np.zeros((height, width, 3))
    alb = np.zeros((height, width, 3))
    rough = np.zeros((height, width))
    metal = np.zeros((height, width))
    if ground is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -o[2] / d[..., 2]
        p = o + d * t[..., None]
        ok = (t > 0) & (np.abs(p[..., 0]) <= ground.half_size_m) & (np.abs(p[..., 1]) <= ground.half_size_m)
        best = np.where(ok, t, best)
        nrm[ok] = (0, 0, 1)
        alb[ok] = ground.albedo
        rough[ok], metal[ok] = ground.roughness, ground.metallic
    for s in spheres:
        c = np.asarray(s.center_m, float)
        oc = o - c
        a = np.sum(d * d, -1)
        b = 2 * np.sum(d * oc, -1)
        cc = np.dot(oc, oc) - s.radius_m**2
        disc = b * b - 4 * a * cc
        with np.errstate(invalid="ignore"):
            t = (-b - np.sqrt(disc)) / (2 * a)
        ok = (disc >= 0) & (t > 0) & (t < best)
        best = np.where(ok, t, best)
        p = o + d * t[..., None]
        nrm[ok] = ((p - c) / s.radius_m)[ok]
        alb[ok] = s.albedo
        rough[ok], metal[ok] = s.roughness, s.metallic
    mask = np.isfinite(best)
    return Buffers(depth=best.astype(np.float32), normal=nrm.astype(np.float32), albedo=alb.astype(np.float32),
                   roughness=rough.astype(np.float32), metallic=metal.astype(np.float32),
                   mask=mask.astype(np.float32))
