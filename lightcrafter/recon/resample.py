"""Put a clip onto another pixel grid of the same camera (e.g. the paper stack's MegaSAM working grid
back onto the video's grid), so that R renders proxies the size of their targets.

The grids are related by an axis-aligned map (a resize and a crop; lightcrafter.recon.paper_stack.
megasam.PixelMap): target pixel (x, y) sits at (sx x + ox, sy y + oy) in the source grid. Buffers are
sampled at the nearest source pixel (depth, normals and materials of one surface point stay
together; nothing is interpolated across a depth edge); target pixels outside the source grid are
invalid (mask 0), except within ``extend_px`` source pixels of its edge, where they take the nearest edge
pixel's buffers (z-depth, normal and materials copied: a fronto-parallel continuation of the edge).
MegaSAM crops its resized frame to multiples of 8 pixels (720x480 -> 543x362 -> 536x360): without the
extension the video's right 9 and bottom 3 pixels would be holes in every proxy. Intrinsics:
K_target = A^-1 K_source with A = [[sx, 0, ox], [0, sy, oy], [0, 0, 1]].
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lightcrafter import clip as clipmod
from lightcrafter import io


def resample_buffers(b: io.Buffers, x: np.ndarray, y: np.ndarray, extend_px: float = 0.0) -> io.Buffers:
    """``b`` sampled at the nearest pixel of (x, y) (source pixel coordinates); samples more than
    ``extend_px`` outside the grid are invalid, those within take the nearest edge pixel."""
    h, w = b.shape
    xi, yi = np.rint(x).astype(int), np.rint(y).astype(int)
    e = float(extend_px)
    inside = (x >= -0.5 - e) & (x <= w - 0.5 + e) & (y >= -0.5 - e) & (y <= h - 0.5 + e)
    xi, yi = np.clip(xi, 0, w - 1), np.clip(yi, 0, h - 1)
    take = lambda a: a[yi, xi]  # noqa: E731
    mask = take(b.mask) * inside
    valid = mask > 0.5
    return io.Buffers(depth=np.where(valid, take(b.depth), np.inf).astype(np.float32),
                      normal=np.where(valid[..., None], take(b.normal), 0.0).astype(np.float32),
                      albedo=np.where(valid[..., None], take(b.albedo), 0.0).astype(np.float32),
                      roughness=np.where(valid, take(b.roughness), 0.0).astype(np.float32),
                      metallic=np.where(valid, take(b.metallic), 0.0).astype(np.float32),
                      mask=valid.astype(np.float32))


MAX_PIXEL_ASPECT_ERROR = 0.01   # a tool's integer rounding of one side (< 1 px over >= 100 px)


def square_pixels(K: np.ndarray) -> np.ndarray:
    """K with fx = fy = sqrt(fx fy) when they differ by less than MAX_PIXEL_ASPECT_ERROR: a tool that
    resizes to whole pixels rounds one side (96x64 -> UniDepth's 640x427, not 426.7), which makes the
    mapped pixels non-square by that rounding only; R needs square pixels."""
    K = np.array(K, np.float64)
    fx, fy = K[0, 0], K[1, 1]
    if fx > 0 and fy > 0 and fx != fy and abs(fx / fy - 1.0) < MAX_PIXEL_ASPECT_ERROR:
        K[0, 0] = K[1, 1] = float(np.sqrt(fx * fy))
    return K


def onto_grid(src_clip, out_clip, width: int, height: int, sx: float, ox: float, sy: float, oy: float,
              extend_px: float = 0.0) -> dict:
    """Write ``out_clip``: ``src_clip`` sampled onto a ``width`` x ``height`` grid (see module docstring)."""
    views, info = clipmod.read_clip(src_clip)
    xs = sx * np.arange(width, dtype=np.float64) + ox
    ys = sy * np.arange(height, dtype=np.float64) + oy
    X, Y = np.meshgrid(xs, ys)
    A = np.array([[sx, 0.0, ox], [0.0, sy, oy], [0.0, 0.0, 1.0]])
    inputs = {"what": "resampled", "src": clipmod.identity(info.root), "grid": [width, height, sx, ox, sy, oy],
              "extend_px": float(extend_px)}
    frames = clipmod.buffer_frames(out_clip, inputs)
    distinct = info.distinct_frames
    for i in frames.missing(distinct, io.read_buffers):
        frames.stamp()
        io.write_buffers(frames.path(i), resample_buffers(views[i].buffers, X, Y, extend_px))
    serve = [distinct[[info.frames[d] for d in distinct].index(rel)] for rel in info.frames]
    keep = {k: v for k, v in info.manifest.items() if k not in (
        "format", "width", "height", "num_frames", "fps", "buffer_frames", "frames", "cameras", "confidence",
        "camera_static", "scene_static", "units", "producer", "content_id")}
    return clipmod.write_clip(
        out_clip, serve=serve, K=[square_pixels(np.linalg.inv(A) @ v.K) for v in views], c2w=[v.c2w for v in views],
        width=width, height=height, fps=info.fps, camera_static=info.camera_static, scene_static=info.scene_static,
        units=info.units, producer={"stage": "resample", "source": info.producer}, content_id=io.fingerprint(inputs),
        extra=keep)


def onto_video_grid(tool_clip, out_clip, video_width: int, video_height: int) -> dict:
    """The paper stack's clip (MegaSAM's working grid for a video of this size) onto the video's grid;
    the strip MegaSAM's crop removed continues the edge (module docstring)."""
    from lightcrafter.recon.paper_stack.megasam import WORKING_MULTIPLE, working_map

    m = io.read_json(Path(tool_clip) / clipmod.MANIFEST).get("source_map") or vars(working_map(video_width, video_height))
    return onto_grid(tool_clip, out_clip, video_width, video_height, m["sx"], m["ox"], m["sy"], m["oy"],
                     extend_px=WORKING_MULTIPLE)
