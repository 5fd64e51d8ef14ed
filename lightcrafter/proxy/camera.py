"""Mitsuba sensor from an OpenCV camera, aligned pixel for pixel with the buffers.

* OpenCV: x right, y down, z forward; pixel (row i, col j) centre at (u, v) = (j, i).
* Mitsuba's camera looks down its local +Z with +X to the left and +Y up, so
  ``to_world = c2w @ diag(-1, -1, 1, 1)``.
* Mitsuba's film coordinate (x, y) in [0, 1]^2 spans pixel *corners*, i.e. u_film = (u + 0.5) / W;
  the principal point enters as ``principal_point_offset_x = (W/2 - (cx + 0.5)) / W`` (same for y).
* Square pixels: the horizontal fov is 2 atan(W / (2 fx)); fy must equal fx.
"""

from __future__ import annotations

import math

import mitsuba as mi
import numpy as np

from lightcrafter.io import DataError


def sensor_dict(K: np.ndarray, c2w: np.ndarray, width: int, height: int) -> dict:
    K = np.asarray(K, dtype=np.float64)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if not (fx > 0 and abs(fx - fy) <= 1e-4 * fx):
        raise DataError(f"camera: needs square pixels with fx = fy > 0, got fx={fx}, fy={fy}")
    to_world = np.asarray(c2w, dtype=np.float64) @ np.diag([-1.0, -1.0, 1.0, 1.0])
    return {
        "type": "perspective",
        "fov_axis": "x",
        "fov": math.degrees(2.0 * math.atan(width / (2.0 * fx))),
        "principal_point_offset_x": (width / 2.0 - (cx + 0.5)) / width,
        "principal_point_offset_y": (height / 2.0 - (cy + 0.5)) / height,
        "near_clip": 1e-4,
        "far_clip": 1e7,
        "to_world": mi.ScalarTransform4f(to_world.tolist()),
        "film": {"type": "hdrfilm", "width": int(width), "height": int(height),
                 "rfilter": {"type": "box"}, "pixel_format": "rgb"},
    }


def sensor_from_opencv(K: np.ndarray, c2w: np.ndarray, width: int, height: int):
    return mi.load_dict(sensor_dict(K, c2w, width, height))
