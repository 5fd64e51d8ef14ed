"""Pinhole camera math shared by scene sampling, Blender and the proxy renderer.

OpenCV convention: x right, y down, z forward; pixel centres at integer coordinates, so the
principal point of a centred sensor is ((W - 1) / 2, (H - 1) / 2). World: Z up, metres.
"""

from __future__ import annotations

import math

import numpy as np

from .io import DataError


def intrinsics(width: int, height: int, fov_x_rad: float) -> np.ndarray:
    """3x3 pinhole K in pixels: square pixels, horizontal field of view ``fov_x_rad``."""
    fx = (width / 2.0) / math.tan(fov_x_rad / 2.0)
    return np.array([[fx, 0.0, (width - 1) / 2.0], [0.0, fx, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def opencv_c2w(cam_location_m, cam_target_m) -> np.ndarray:
    """4x4 camera-to-world looking from ``cam_location_m`` at ``cam_target_m``, world +Z up, no roll."""
    eye = np.asarray(cam_location_m, float)
    forward = np.asarray(cam_target_m, float) - eye
    norm = np.linalg.norm(forward)
    if norm < 1e-9:
        raise DataError(f"camera at {eye.tolist()} looks at itself; cam_target_m must differ from cam_location_m")
    forward /= norm
    up = np.array([0.0, 0.0, 1.0]) if abs(forward[2]) < 0.999 else np.array([0.0, 1.0, 0.0])
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, down, forward, eye
    return c2w
