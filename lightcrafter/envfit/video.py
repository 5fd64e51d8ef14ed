"""The observed video of an envmap fit: linear EXR frames checked against the clip, and which
pixels of which frames the objective uses.

* Frames: ``{frames_dir}/{i:04d}.exr`` (linear scene-referred RGB, channels R, G, B), exactly one per
  clip frame and of the clip's size; anything else is a :class:`~lightcrafter.io.DataError` naming
  the file and the fix. Small negatives (>= -2 % of the mean, compression ringing) are clamped to 0.
* Fitted frames: every ``stride``-th frame {0, stride, 2 stride, ...} (the paper: every fourth).
  A fitted frame that is entirely black (max 0) is dropped (a lens cap or a fade carries no
  information about the light; the list of dropped frames is reported); all dropped -> DataError.
* Saturated pixels: a pixel with any channel at or above the clip level is left out (its true
  radiance is unknown). ``saturation_level=None`` detects the level: the video's maximum, if at
  least ``AUTO_CLIP_FRACTION`` (0.5 %, and at least 4) of the fitted frames' pixels reach it
  exactly (to 1e-6 relative): a plateau, as an 8-bit video decoded to linear has at 1.0; a rendered
  HDR video has its maximum in a pixel or two, so nothing is cut. A video whose few clipped pixels
  escape the detection should pass its level (e.g. 1.0 for frames decoded from 8-bit with
  io.display_to_linear at 0 EV). ``saturation_level=0`` or a negative value disables the test.
* Used pixels of a fitted frame: observed radiance usable (above) and R defines the pixel: a surface
  pixel (buffer mask and finite depth), or a background pixel when R shows the background (it
  then renders the environment there). A clip whose fitted frames have no usable *surface* pixel
  cannot be fitted (DataError naming its buffers.json).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lightcrafter import io
from lightcrafter.clip import ClipInfo, FrameView, manifest_path
from lightcrafter.proxy.geometry import valid_depth

AUTO_CLIP_FRACTION = 5e-3
AUTO_CLIP_MIN_PIXELS = 4
CLIP_REL_TOL = 1e-6
NEGATIVE_TOLERANCE_REL = 0.02


@dataclass
class Video:
    """Observed frames and the fit's pixel selection.

    frames: every frame (N, H, W, 3) float32 linear; fitted: indices of the frames the objective
    samples from; used: {frame index: flat pixel indices (int64, sorted)}; dropped_black: fitted
    frames left out for being black; saturation_level: the level used (None: none).
    """

    frames: np.ndarray
    fitted: list[int]
    used: dict[int, np.ndarray]
    dropped_black: list[int] = field(default_factory=list)
    saturation_level: float | None = None
    saturated_pixels: int = 0

    def observed(self, i: int) -> np.ndarray:
        """(P, 3) float32 linear radiance of the used pixels of frame ``i``."""
        return self.frames[i].reshape(-1, 3)[self.used[i]]


def frame_path(frames_dir: str | Path, i: int) -> Path:
    return Path(frames_dir) / f"{i:04d}.exr"


def read_frames(frames_dir: str | Path, info: ClipInfo) -> np.ndarray:
    """All frames (N, H, W, 3) of ``frames_dir``; one-line DataError on any mismatch with the clip."""
    frames_dir = Path(frames_dir)
    if not frames_dir.is_dir():
        raise io.DataError(f"{frames_dir}: frame folder not found; give the folder of the video's linear EXR frames")
    names = sorted(p.name for p in frames_dir.iterdir() if re.fullmatch(r"\d{4}\.exr", p.name))
    expected = [f"{i:04d}.exr" for i in range(info.num_frames)]
    if names != expected:
        missing = sorted(set(expected) - set(names))
        extra = sorted(set(names) - set(expected))
        what = f"missing {missing[:3]}" if missing else f"unexpected {extra[:3]}"
        raise io.DataError(f"{frames_dir}: {len(names)} frames ({what}) but clip {manifest_path(info.root)} has "
                           f"{info.num_frames}; give the frames of this clip (0000.exr..{info.num_frames - 1:04d}.exr)")
    out = np.empty((info.num_frames, info.height, info.width, 3), np.float32)
    for i in range(info.num_frames):
        path = frame_path(frames_dir, i)
        rgb = io.read_rgb_exr(path)
        if rgb.shape[:2] != (info.height, info.width):
            raise io.DataError(f"{path}: frame is {rgb.shape[1]}x{rgb.shape[0]} but clip {manifest_path(info.root)} is "
                               f"{info.width}x{info.height}; give frames at the clip's resolution")
        tol = NEGATIVE_TOLERANCE_REL * float(np.mean(np.maximum(rgb, 0.0)))
        if (rgb < -tol).any():
            raise io.DataError(f"{path}: {int((rgb < -tol).any(-1).sum())} pixel(s) with negative radiance; "
                               "the frames must be linear radiance >= 0")
        out[i] = np.maximum(rgb, 0.0)
    return out


def fitted_frames(num_frames: int, stride: int) -> list[int]:
    """The frames the objective samples from: {0, stride, 2 stride, ...} < num_frames."""
    return list(range(0, int(num_frames), max(1, int(stride))))


def detect_saturation(frames: np.ndarray) -> float | None:
    """The clip level of a video whose maximum forms a plateau (see module doc), else None."""
    m = float(frames.max())
    if m <= 0:
        return None
    at_max = (frames >= m * (1 - CLIP_REL_TOL)).any(axis=-1)
    n = int(at_max.sum())
    return m if n >= AUTO_CLIP_MIN_PIXELS and n >= AUTO_CLIP_FRACTION * at_max.size else None


def select(frames: np.ndarray, views: list[FrameView], info: ClipInfo, frames_dir: str | Path, stride: int = 4,
           saturation_level: float | None = None, use_background: bool = True) -> Video:
    """Choose fitted frames and used pixels (module doc); DataError when nothing can be fitted."""
    fitted = fitted_frames(len(frames), stride)
    sub = frames[fitted]
    if float(sub.max()) <= 0:
        raise io.DataError(f"{frames_dir}: every fitted frame ({len(fitted)} of every {stride}th) is black; nothing "
                           "to fit the light to: check the frames' exposure / decoding")
    level = detect_saturation(sub) if saturation_level is None else (saturation_level if saturation_level > 0 else None)
    used, dropped, n_sat, n_surface, n_surface_all = {}, [], 0, 0, 0
    for i in fitted:
        f = frames[i].reshape(-1, 3)
        if float(f.max()) <= 0:
            dropped.append(i)
            continue
        ok = np.ones(len(f), bool)
        if level is not None:
            sat = (f >= level * (1 - CLIP_REL_TOL)).any(axis=-1)
            n_sat += int(sat.sum())
            ok &= ~sat
        b = views[i].buffers
        surface = valid_depth(b.depth, b.mask).ravel()
        n_surface_all += int(surface.sum())
        n_surface += int((surface & ok).sum())
        if not use_background:
            ok &= surface
        idx = np.flatnonzero(ok)
        if len(idx):
            used[i] = idx
    if n_surface == 0:
        if n_surface_all and level is not None and n_sat:
            raise io.DataError(f"{frames_dir}: every surface pixel of the fitted frames is saturated (>= {level:g}); "
                               "give frames that are not clipped (lower exposure) or pass a higher saturation level")
        raise io.DataError(f"{manifest_path(info.root)}: no valid pixel (mask and finite depth) with a usable "
                           f"observation in fitted frames {fitted}; rerun the reconstruction that wrote the clip")
    return Video(frames=frames, fitted=sorted(used), used=used, dropped_black=dropped, saturation_level=level,
                 saturated_pixels=n_sat)
