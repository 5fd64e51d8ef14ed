"""MegaSAM adapter: its final ``.npz`` -> z-depth, per-frame K and c2w in the project's conventions.

Native format (verified in the public code, not guessed)
--------------------------------------------------------
Read in github.com/mega-sam/mega-sam (commit c2e0099) and its camera-tracking submodule
github.com/mega-sam/base (commit ee9ac6a, a DROID-SLAM derivative):

* ``cvd_opt/cvd_opt.py`` (consistent video depth, the last stage) writes
  ``{output_dir}/{scene_name}_sgd_cvd_hr.npz`` (``output_dir`` defaults to ``outputs_cvd``) with
  ``np.savez`` and four keys:

  - ``images``   (T, H, W, 3) uint8, **RGB** (the tracker stores OpenCV's BGR channel-first frames
    and both scripts flip the channel axis before saving);
  - ``depths``   (T, H, W) float16 = ``clip(1 / disparity, 1e-3, 1e2)``: the optimised disparity is
    inverted, so this is **depth, not disparity**; it is **z-depth** (the optimiser unprojects it as
    ``depth * K^-1 [u, v, 1]``, a ray with unit z), in the tracker's own scale (arbitrary per video;
    the tracker normalises mono-depth so that its 98th-percentile disparity is 2). Pixels at the
    1e2 ceiling are "too far to tell" (sky, far background);
  - ``intrinsic`` (3, 3) float32: ONE pinhole K shared by all frames (fx, fy, cx, cy of frame 0;
    the tracker's principal point starts at (W/2, H/2) of the input frames);
  - ``cam_c2w``  (T, 4, 4) float32: ``SE3(poses).inv().matrix()`` of the tracker's poses, which
    are world-to-camera (DROID-SLAM convention), so these are **camera-to-world**.

* ``camera_tracking_scripts/test_demo.py`` resizes every input frame (OpenCV INTER_AREA) to
  ``h1 = int(h0 * sqrt(384 * 512 / (h0 * w0)))``, ``w1 = int(w0 * sqrt(...))`` and keeps the
  top-left ``(h1 - h1 % 8, w1 - w1 % 8)``: the npz arrays live on this *working grid*, not the
  input's. The intrinsics are scaled with the frame (``* w1 / w0``), so K refers to the working grid.
  It also writes ``outputs/{scene}_droid.npz`` (same keys, float32 depth before the video-depth
  optimisation); :func:`load` reads either.
* ``droid_slam/geom/projective_ops.py`` (base): pinhole ``x = fx X / Z + cx`` over
  ``torch.arange`` pixel grids: camera axes x right, y down, z forward (**OpenCV**), pixel centres at
  integer coordinates (the project's convention, so K is taken as is).
* ``droid_slam/depth_video.py`` initialises every pose to identity and bundle adjustment starts at
  ``t0 = 1``, so frame 0 stays fixed: MegaSAM's world is its first camera's frame (y down).
  :func:`to_world` re-bases on ``cam_c2w[0]`` anyway, so a variant that moves frame 0 still works.

Not verifiable from the code: the metric scale (there is none) and the accuracy of the clipped
far range; MegaSAM saves no validity mask or uncertainty in this file.

Our conventions (output)
------------------------
* **World**: a fixed axis change of MegaSAM's first camera (x right, y down, z forward), right-handed
  and Z up *if the first camera is level*::

      X = x_cam0,   Y = z_cam0,   Z = -y_cam0        (WORLD_FROM_CAM0, a proper rotation, det = +1)

  so the first camera sits at the origin looking along +Y with image-up along +Z. Gravity is only
  as plausible as the first frame is level (no roll or pitch estimate is made here).
* **Cameras**: OpenCV axes (unchanged, MegaSAM's are OpenCV), ``c2w[t] = W @ inv(C0) @ C_t``.
* **Units**: "arbitrary": depth and camera translations share MegaSAM's per-video scale.
* **Depth**: z-depth (float32), +inf where invalid (at or beyond ``far_clip``).

One-frame clips (the static-camera path)
----------------------------------------
MegaSAM's tracker needs ``--warmup 8`` keyframes with motion: a one-frame clip (MIT's images) cannot
be tracked. For those the megasam command runs only MegaSAM's metric-depth stage,
``UniDepth/scripts/demo_mega-sam.py``, which writes ``{outdir}/{scene}/{frame}.npz`` with ``depth``
(H, W) float32 metric z-depth and ``fov`` (degrees, horizontal: ``2 atan(W / 2 fx)``) for the frame
resized (OpenCV INTER_AREA, aspect kept) to a long side of 640 px (:func:`unidepth_map`);
:func:`load_unidepth` reads it. The camera is level at the origin looking along +Y (c2w =
WORLD_FROM_CAM0), K from ``fov`` with the principal point at the image centre; units "metres"
(UniDepth's metric estimate).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lightcrafter.io import DataError

KEYS = ("images", "depths", "intrinsic", "cam_c2w")
FAR_CEILING = 1e2            # cvd_opt.py clips depth to [1e-3, 1e2]
DEFAULT_FAR_CLIP = 0.99 * FAR_CEILING   # float16 stores 100 exactly; anything this far is "too far"
WORKING_AREA = 384 * 512     # test_demo.py resizes frames to about this many pixels
WORKING_MULTIPLE = 8         # ... and crops them to multiples of 8

# X = x_cam0, Y = z_cam0, Z = -y_cam0 (rows: our axes in MegaSAM's first-camera frame)
WORLD_FROM_CAM0 = np.array([[1.0, 0.0, 0.0, 0.0],
                            [0.0, 0.0, 1.0, 0.0],
                            [0.0, -1.0, 0.0, 0.0],
                            [0.0, 0.0, 0.0, 1.0]])


# ----------------------------------------------------------------------------- pixel grids
@dataclass(frozen=True)
class PixelMap:
    """An axis-aligned map from the *source video's* pixel coordinates to a tool's pixel coordinates.

    ``x_tool = sx * x_src + ox``, ``y_tool = sy * y_src + oy`` with pixel centres at integers in
    both (so a plain resize by s has ``o = 0.5 s - 0.5``; a crop subtracts its offset). ``width``
    and ``height`` are the tool image's size in pixels.
    """

    sx: float
    ox: float
    sy: float
    oy: float
    width: int
    height: int

    @staticmethod
    def resize_crop(src_w: int, src_h: int, resized_w: int, resized_h: int, left: int = 0, top: int = 0,
                    out_w: int | None = None, out_h: int | None = None) -> "PixelMap":
        """A resize of the whole source frame to (resized_w, resized_h) with the half-pixel
        convention (OpenCV, torchvision, PIL), then a crop starting at (left, top)."""
        sx, sy = resized_w / src_w, resized_h / src_h
        return PixelMap(sx=sx, ox=0.5 * sx - 0.5 - left, sy=sy, oy=0.5 * sy - 0.5 - top,
                        width=int(resized_w if out_w is None else out_w),
                        height=int(resized_h if out_h is None else out_h))

    def scale_K(self, K_src: np.ndarray) -> np.ndarray:
        """Intrinsics of the tool image given the source's (for tests and fixtures)."""
        A = np.array([[self.sx, 0.0, self.ox], [0.0, self.sy, self.oy], [0.0, 0.0, 1.0]])
        return A @ np.asarray(K_src, np.float64)

    def coords_from(self, other: "PixelMap") -> tuple[np.ndarray, np.ndarray]:
        """For every pixel centre of ``other``'s image, this map's (x, y) pixel coordinates,
        (other.height, other.width) each: where to sample this tool's image to land on ``other``'s grid."""
        xs = (np.arange(other.width, dtype=np.float64) - other.ox) / other.sx
        ys = (np.arange(other.height, dtype=np.float64) - other.oy) / other.sy
        x = self.sx * xs + self.ox
        y = self.sy * ys + self.oy
        return np.broadcast_to(x[None, :], (other.height, other.width)), np.broadcast_to(y[:, None], (other.height, other.width))


def working_grid(width: int, height: int) -> tuple[int, int, int, int]:
    """MegaSAM's working grid for a ``width`` x ``height`` video: (resized_w, resized_h, w, h), the
    resize before and the size after the crop to multiples of 8 (camera_tracking_scripts/test_demo.py)."""
    f = math.sqrt(WORKING_AREA / (height * width))
    h1, w1 = int(height * f), int(width * f)
    return w1, h1, w1 - w1 % WORKING_MULTIPLE, h1 - h1 % WORKING_MULTIPLE


def working_map(width: int, height: int) -> PixelMap:
    """The :class:`PixelMap` from a ``width`` x ``height`` source video to MegaSAM's npz arrays."""
    w1, h1, w, h = working_grid(width, height)
    return PixelMap.resize_crop(width, height, w1, h1, out_w=w, out_h=h)


# ----------------------------------------------------------------------------- loading
@dataclass
class MegaSamResult:
    """MegaSAM's reconstruction in the project's conventions (module docstring).

    rgb (T, H, W, 3) uint8 display frames on MegaSAM's grid; depth (T, H, W) float32 z-depth in
    arbitrary units, +inf where invalid; valid (T, H, W) bool; K (T, 3, 3) pixels; c2w (T, 4, 4)
    OpenCV camera -> our world (X = x_cam0, Y = z_cam0, Z = -y_cam0); c2w_native (T, 4, 4) as
    saved; far_fraction: share of pixels at or beyond the far clip.
    """

    rgb: np.ndarray
    depth: np.ndarray
    valid: np.ndarray
    K: np.ndarray
    c2w: np.ndarray
    c2w_native: np.ndarray
    far_fraction: float
    path: Path

    @property
    def num_frames(self) -> int:
        return int(self.depth.shape[0])

    @property
    def height(self) -> int:
        return int(self.depth.shape[1])

    @property
    def width(self) -> int:
        return int(self.depth.shape[2])


def read_npz(path: Path, keys: tuple[str, ...], tool: str, fix: str) -> dict[str, np.ndarray]:
    """The ``keys`` arrays of a tool's npz; DataError (one line naming the file) when it cannot be read
    or lacks a key (``fix`` says what to do)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in keys if k not in z.files]
            if missing:
                raise DataError(f"{path}: {tool} npz lacks key(s) {missing} (has {sorted(z.files)}); {fix}")
            return {k: np.asarray(z[k]) for k in keys}
    except DataError:
        raise
    except Exception as exc:  # zipfile / pickle / format errors
        raise DataError(f"{path}: unreadable npz ({type(exc).__name__}: {exc}); rerun {tool}") from exc


def to_world(cam_c2w: np.ndarray) -> np.ndarray:
    """MegaSAM camera-to-world (T, 4, 4) -> ours: ``WORLD_FROM_CAM0 @ inv(C0) @ C_t`` (OpenCV axes kept)."""
    c = np.asarray(cam_c2w, np.float64)
    return WORLD_FROM_CAM0 @ np.linalg.inv(c[0]) @ c


def load(path: str | os.PathLike, far_clip: float = DEFAULT_FAR_CLIP) -> MegaSamResult:
    """Read a MegaSAM npz (``*_sgd_cvd_hr.npz`` or ``*_droid.npz``) and convert it (module docstring).

    Depths >= ``far_clip`` (MegaSAM's 1e2 ceiling by default) or non-finite / <= 0 are invalid (+inf).
    Raises DataError (one line naming the file) on a missing file or key or a wrong shape.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: MegaSAM npz not found; check the megasam command's output")
    arrays = read_npz(path, KEYS, "MegaSAM", "point the megasam command at cvd_opt.py's *_sgd_cvd_hr.npz")
    images, depths, K, c2w = (arrays[k] for k in KEYS)
    if depths.ndim != 3 or depths.shape[0] == 0:
        raise DataError(f"{path}: 'depths' must be (T, H, W), got {depths.shape}")
    t, h, w = depths.shape
    if images.shape != (t, h, w, 3) or images.dtype != np.uint8:
        raise DataError(f"{path}: 'images' must be uint8 (T, H, W, 3) = {(t, h, w, 3)}, got {images.dtype} {images.shape}")
    if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise DataError(f"{path}: 'intrinsic' must be one finite 3x3 K with positive focal lengths, got shape {K.shape}")
    if c2w.shape != (t, 4, 4) or not np.isfinite(c2w).all():
        raise DataError(f"{path}: 'cam_c2w' must be finite (T, 4, 4) = {(t, 4, 4)}, got {c2w.shape}")
    d = depths.astype(np.float32)
    finite = np.isfinite(d) & (d > 0)
    far = finite & (d >= far_clip)
    valid = finite & ~far
    d = np.where(valid, d, np.inf).astype(np.float32)
    Ks = np.repeat(K.astype(np.float64)[None], t, axis=0)
    return MegaSamResult(rgb=images, depth=d, valid=valid, K=Ks, c2w=to_world(c2w),
                         c2w_native=c2w.astype(np.float64), far_fraction=float(far.mean()), path=path)


# ----------------------------------------------------------------------------- one-frame clips
UNIDEPTH_LONG_SIDE = 640     # demo_mega-sam.py's LONG_DIM
UNIDEPTH_KEYS = ("depth", "fov")


def unidepth_map(width: int, height: int) -> PixelMap:
    """The :class:`PixelMap` from a ``width`` x ``height`` frame to UniDepth's npz (long side 640)."""
    if width > height:
        w, h = UNIDEPTH_LONG_SIDE, int(round(UNIDEPTH_LONG_SIDE * height / width))
    else:
        w, h = int(round(UNIDEPTH_LONG_SIDE * width / height)), UNIDEPTH_LONG_SIDE
    return PixelMap.resize_crop(width, height, w, h)


def load_unidepth(path: str | os.PathLike, frame: np.ndarray) -> MegaSamResult:
    """One frame's UniDepth npz (module docstring) and the frame itself (uint8 RGB, source size) ->
    a one-frame :class:`MegaSamResult` on UniDepth's grid: level camera, K from the npz's fov."""
    import cv2

    from lightcrafter.camera import intrinsics

    path = Path(path)
    arrays = read_npz(path, UNIDEPTH_KEYS, "UniDepth",
                      "a one-frame clip's megasam command must run UniDepth/scripts/demo_mega-sam.py only")
    depth, fov = arrays["depth"].astype(np.float32), float(arrays["fov"].reshape(-1)[0])
    H0, W0 = frame.shape[:2]
    grid = unidepth_map(W0, H0)
    if depth.shape != (grid.height, grid.width):
        raise DataError(f"{path}: depth is {depth.shape[1]}x{depth.shape[0]} but UniDepth's grid of a {W0}x{H0} frame is "
                        f"{grid.width}x{grid.height}; run the released demo_mega-sam.py on the clip's frame")
    if not (0.0 < fov < 180.0):
        raise DataError(f"{path}: fov {fov} is not a field of view in degrees; rerun UniDepth")
    valid = np.isfinite(depth) & (depth > 0)
    rgb = cv2.resize(np.ascontiguousarray(frame), (grid.width, grid.height), interpolation=cv2.INTER_AREA)
    K = intrinsics(grid.width, grid.height, math.radians(fov))
    return MegaSamResult(rgb=rgb[None], depth=np.where(valid, depth, np.inf)[None].astype(np.float32), valid=valid[None],
                         K=K[None], c2w=WORLD_FROM_CAM0[None].copy(), c2w_native=np.eye(4)[None], far_fraction=0.0, path=path)


def find_unidepth(out_dir: str | os.PathLike) -> Path | None:
    """The one UniDepth npz a one-frame clip's megasam run left under ``out_dir`` (None: none)."""
    found = sorted(p for p in Path(out_dir).rglob("*.npz") if p.is_file())
    if len(found) > 1:
        raise DataError(f"{out_dir}: {len(found)} npz files for a one-frame clip; leave exactly UniDepth's {{frame}}.npz there")
    return found[0] if found else None


def find_output(out_dir: str | os.PathLike) -> Path | None:
    """The npz a MegaSAM run left under ``out_dir``: the only ``*.npz``, or the only
    ``*_sgd_cvd_hr.npz`` among several; None when there is none. Several candidates -> DataError."""
    out_dir = Path(out_dir)
    found = sorted(p for p in out_dir.rglob("*.npz") if p.is_file())
    if not found:
        return None
    if len(found) == 1:
        return found[0]
    final = [p for p in found if p.name.endswith("_sgd_cvd_hr.npz")]
    if len(final) == 1:
        return final[0]
    raise DataError(f"{out_dir}: {len(found)} npz files ({', '.join(p.name for p in found[:4])}...); "
                    f"leave exactly one *_sgd_cvd_hr.npz there")

