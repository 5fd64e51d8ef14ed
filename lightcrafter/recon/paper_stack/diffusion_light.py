"""DiffusionLight adapter: its camera-aligned lat-long HDR -> an envmap in OUR world frame.

Native format (verified in the public code)
-------------------------------------------
Read in github.com/DiffusionLight/DiffusionLight (commit 7130ec4):

* ``inpaint.py`` inpaints a chrome ball of ``--ball_size`` pixels at the centre of the input image
  (resized to a 1024 x 1024 square by default) for each exposure in ``--ev`` ("0,-2.5,-5") and
  saves the ball crop as ``{output_dir}/square/{image_stem}_ev{-00|-25|-50}.png``.
* ``ball2envmap.py`` unwraps each ball to a ``H x 2H`` equirectangular map (``--envmap_height``
  256): it builds the map at ``--scale`` (4) times the resolution on the grid
  ``h = linspace(0, 2 pi, 2 H s)`` (columns) and ``v = linspace(0, pi, H s)`` (rows), direction
  ``r = (sin v cos h, sin v sin h, cos v)``, takes the mirror normal ``N = normalise(r + (1, 0, 0))``
  (so the viewer is at +x) and samples the ball image at ``grid_sample`` coordinates
  ``(-N_y, -N_z)`` (align_corners=True: image left = +y, image top = +z), then downsamples by ``s``
  (skimage ``resize``, anti-aliased).
* ``exposure2hdr.py`` merges the brackets (gamma 2.4 linearisation, luminance-based merge) into
  ``{output_dir}/{image_stem}.exr`` (ezexr: float32 channels R, G, B), linear radiance with the
  EV0 image's white at 1: a relative scale, not absolute.

Direction convention derived from those steps (physical reading of the mirror ball, orthographic,
looking along the camera's optical axis): in the map's own coordinates +x points back at the
camera, +y to the camera's left, +z up. Hence, in OpenCV camera axes (x right, y down, z forward)::

    d_cam = (-y_DL, -z_DL, -x_DL)        (a reflection: the map's (x, y, z) labels are left-handed)

so the **centre of the map looks forward** (along the optical axis), a quarter width from the left
edge looks to the camera's **left**, three quarters to its **right**, the top row **up** (image up),
the left/right edges **backwards**. This is the same *layout* as the project's convention for a
camera looking along +X with Z up (``lightcrafter.envmap``: u = 0.5 is +X, u = 0.25 is +Y).
Pixel centres: output column c looks at ``h = 2 pi ((c + 0.5) s - 0.5) / (2 H s - 1)``, row r at
``v = pi ((r + 0.5) s - 0.5) / (H s - 1)`` (the linspace grid after the s-fold downsampling);
:func:`to_world` inverts this exactly (``supersample`` = the run's ``--scale``).

The frame is the **camera of the image DiffusionLight was given** (the video's first frame); the
chrome ball sits at the image centre and is treated as seen along the optical axis. Not verifiable
from the code: how well the inpainted ball's reflection matches that ideal (it is a generated image).

Output: a lat-long map in the project's convention (u = (pi - atan2(y, x)) / 2 pi, v = acos(z) / pi,
world Z up) in OUR world frame, given the first frame's OpenCV c2w: the initialisation of
environment-map fitting. Radiance stays relative (DiffusionLight's EV0 scale).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from lightcrafter import envmap
from lightcrafter.io import DataError

DEFAULT_SUPERSAMPLE = 4      # ball2envmap.py --scale


def camera_to_native(d_cam: np.ndarray) -> np.ndarray:
    """OpenCV camera directions (..., 3) -> DiffusionLight's map coordinates (x back, y left, z up)."""
    d = np.asarray(d_cam, np.float64)
    return np.stack([-d[..., 2], -d[..., 0], -d[..., 1]], axis=-1)


def native_to_camera(d_dl: np.ndarray) -> np.ndarray:
    """DiffusionLight's map coordinates (..., 3) -> OpenCV camera directions ``(-y, -z, -x)``."""
    d = np.asarray(d_dl, np.float64)
    return np.stack([-d[..., 1], -d[..., 2], -d[..., 0]], axis=-1)


def native_pixel(d_cam: np.ndarray, height: int, width: int, supersample: int = DEFAULT_SUPERSAMPLE):
    """Continuous (col, row) in a ``height`` x ``width`` DiffusionLight map of OpenCV camera directions."""
    d = camera_to_native(d_cam)
    d = d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12)
    h = np.mod(np.arctan2(d[..., 1], d[..., 0]), 2 * np.pi)
    v = np.arccos(np.clip(d[..., 2], -1.0, 1.0))
    s = int(supersample)
    col = ((h / (2 * np.pi)) * (width * s - 1) + 0.5) / s - 0.5
    row = ((v / np.pi) * (height * s - 1) + 0.5) / s - 0.5
    return col, row


def camera_directions(height: int, width: int, supersample: int = DEFAULT_SUPERSAMPLE) -> np.ndarray:
    """OpenCV camera direction (H, W, 3) that each pixel centre of a DiffusionLight map looks at."""
    s = int(supersample)
    h = 2 * np.pi * ((np.arange(width) + 0.5) * s - 0.5) / (width * s - 1)
    v = np.pi * ((np.arange(height) + 0.5) * s - 0.5) / (height * s - 1)
    v, h = np.meshgrid(v, h, indexing="ij")
    d_dl = np.stack([np.sin(v) * np.cos(h), np.sin(v) * np.sin(h), np.cos(v)], axis=-1)
    return native_to_camera(d_dl)


def load(path: str | os.PathLike) -> np.ndarray:
    """DiffusionLight's HDR EXR as validated float32 (H, 2H, 3); other shapes raise DataError."""
    path = Path(path)
    env = envmap.load(path)
    h, w = env.shape[:2]
    if w != 2 * h:
        raise DataError(f"{path}: DiffusionLight map must be 2:1 equirectangular (H, 2H), got {w}x{h}; use exposure2hdr.py's EXR")
    return env


def to_world(env_native: np.ndarray, c2w_first: np.ndarray, out_height: int | None = None,
             supersample: int = DEFAULT_SUPERSAMPLE) -> np.ndarray:
    """Resample a camera-aligned DiffusionLight map into the project's lat-long convention in our
    world: output pixel with world lookup direction d takes the native map at the camera direction
    ``R^T d`` (``R`` = rotation of ``c2w_first``, the first frame's OpenCV camera-to-world), bilinear
    with horizontal wrap. Output (out_height or H, 2 x that, 3) float32, relative radiance."""
    env = np.asarray(env_native, np.float32)
    h, w = env.shape[:2]
    ho = int(out_height or h)
    R = np.asarray(c2w_first, np.float64)[:3, :3]
    d_cam = envmap.pixel_directions(ho, 2 * ho) @ R      # row-vector form of R^T d
    col, row = native_pixel(d_cam, h, w, supersample)
    return envmap.sample_bilinear(env, (col + 0.5) / w, (row + 0.5) / h).astype(np.float32)


def find_output(out_dir: str | os.PathLike) -> Path | None:
    """The single ``*.exr`` a DiffusionLight run left under ``out_dir`` (None if none; several -> DataError)."""
    out_dir = Path(out_dir)
    found = sorted(p for p in out_dir.rglob("*.exr") if p.is_file())
    if not found:
        return None
    if len(found) > 1:
        raise DataError(f"{out_dir}: {len(found)} EXR files ({', '.join(p.name for p in found[:4])}); "
                        f"leave only exposure2hdr.py's map of the first frame there")
    return found[0]
