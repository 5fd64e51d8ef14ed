"""Render a whole clip with R: a clip (lightcrafter.clip contract) + a lighting -> frames, mp4, manifest.

R renders *any* clip the same way: Blender ground truth, Phi estimates, aligned estimates, real-video
reconstructions, edited buffers. The lighting is a :class:`~lightcrafter.proxy.lighting.Lighting`
object or a lighting file (``lightcrafter.lighting/1``); scene specs give one with
:func:`~lightcrafter.proxy.lighting.lighting_from_spec`. Outputs for ``out_dir`` = ``.../{name}``:

    {out_dir}/{frame:04d}.exr   linear HDR RGB, written atomically (complete frames are skipped on rerun)
    {out_dir}.mp4               display preview (lightcrafter.io.linear_to_display, exposure 0 EV)
    {out_dir}.json              manifest, written last; frame paths relative to its folder

Every input is checked before the first frame is rendered; a bad input raises DataError naming
the file and nothing is written.
"""

from __future__ import annotations

import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from lightcrafter import clip as clipmod
from lightcrafter import io
from lightcrafter.clip import FrameView, read_clip
from lightcrafter.proxy.edits import MaterialEdit, apply_edits
from lightcrafter.proxy.lighting import Lighting, lighting_from_file, lighting_identity
from lightcrafter.proxy.renderer import ProxyRenderer, RenderSettings

__all__ = ["read_clip", "render_clip", "render_views", "resolve_visibility"]


def resolve_visibility(settings: RenderSettings, scene_static: bool, consistent_depth: bool = True) -> RenderSettings:
    """Visibility 'auto': the clip-aggregated shadow mesh when no object moves and the frames' depth maps
    agree (ground truth), this frame's own mesh otherwise: aggregating depth maps over time would leave
    ghost occluders where objects used to be, and a reconstruction's frames disagree by more than the
    shadow offset, so their merged layers shadow each other (measured: a near-black proxy)."""
    if settings.visibility != "auto":
        return settings
    return replace(settings, visibility="aggregate" if scene_static and consistent_depth else "frame")


def _complete(shape):
    def reader(path):
        if io.read_rgb_exr(path).shape[:2] != tuple(shape):
            raise io.DataError(f"{path}: frame of another size")
    return reader


def render_views(views: list[FrameView], lighting: Lighting, settings: RenderSettings, out_dir: Path,
                 edits: list[MaterialEdit] = (), cache: bool = True,
                 inputs=None, visibility_from: ProxyRenderer | None = None,
                 response=None) -> tuple[list[np.ndarray], ProxyRenderer, float]:
    """Render (or reuse complete) frames into ``out_dir``; returns (frames, renderer, render seconds).

    ``inputs`` (JSON-able) names what the frames come from: frames of other inputs are re-rendered.
    ``visibility_from``: a renderer already prepared on these views with the same geometry settings
    (its clip visibility mesh is reused instead of rebuilt; the frames are the same).
    ``response``: a camera response (``apply(rgb) -> rgb``, e.g. lightcrafter.envfit.response) applied
    to every frame before it is written; it must be part of ``inputs``.
    """
    if edits:
        views = [FrameView(apply_edits(v.buffers, edits), v.K, v.c2w, v.key + "#edited") for v in views]
    renderer = ProxyRenderer(lighting, settings, cache=cache)
    folder = clipmod.FrameFolder(out_dir, inputs)
    todo = folder.missing(range(len(views)), _complete(views[0].buffers.shape))
    t0 = time.perf_counter()
    if todo:
        folder.stamp()
        renderer.prepare(views, like=visibility_from)
        for i in todo:
            frame = renderer.render(views[i], frame=i)
            io.write_frame_exr(folder.path(i), frame if response is None else response.apply(frame))
    seconds = time.perf_counter() - t0
    return [io.read_rgb_exr(folder.path(i)) for i in range(len(views))], renderer, seconds


def render_clip(clip: str | Path, lighting: Lighting | str | Path, out_dir: str | Path, *,
                settings: RenderSettings = RenderSettings(), edits: list[MaterialEdit] = (),
                extra: dict | None = None, visibility_from: ProxyRenderer | None = None, response=None) -> dict:
    """Render every frame of ``clip`` (folder or its buffers.json) under ``lighting``; return the manifest.

    Visibility 'auto' follows the clip's own ``scene_static`` flag. ``extra`` is copied into the manifest
    (scene id, trajectory, light id, pair kind ...). ``visibility_from``, ``response`` (a camera
    response with ``apply`` and ``as_dict``, recorded in the manifest): see :func:`render_views`.
    """
    out_dir = Path(out_dir)
    views, info = read_clip(clip)
    if not isinstance(lighting, Lighting):
        lighting_src = str(lighting)
        lighting = lighting_from_file(lighting)
    else:
        lighting_src = None
    n_rot = len(lighting.frame_rotation_z_rad)
    if n_rot not in (0, len(views)):
        raise io.DataError(f"{lighting_src or 'lighting'}: {n_rot} per-frame rotations but clip "
                           f"{info.root} has {len(views)} frames; rebuild the lighting for this clip")
    settings = resolve_visibility(settings, info.scene_static, info.consistent_depth)
    # Frames of other inputs (a re-made clip, another lighting or settings) are never reused.
    inputs = {"what": "proxy", "clip": clipmod.identity(info.root), "lighting": lighting_identity(lighting),
              "settings": _settings_dict(settings), "edits": [_edit_identity(e) for e in edits]}
    if response is not None:
        inputs["response"] = response.as_dict()
    frames, renderer, seconds = render_views(views, lighting, settings, out_dir, edits, inputs=inputs,
                                             visibility_from=None if edits else visibility_from, response=response)
    preview = out_dir.with_suffix(".mp4")
    io.write_video(preview, io.to_uint8(io.linear_to_display(np.stack(frames))), fps=info.fps)
    h, w = frames[0].shape[:2]
    manifest = {
        "format": "lightcrafter.proxy/1",
        "width": w, "height": h, "num_frames": len(frames), "fps": info.fps,
        "frames": [f"{out_dir.name}/{i:04d}.exr" for i in range(len(frames))],
        "preview": preview.name,
        "radiance": ("linear scene-referred (no view transform)" if response is None
                     else "linear, through the fitted camera response (see 'response')"),
        "clip": str(clipmod.manifest_path(info.root)), "lighting": lighting_src,
        "render": {"engine": "mitsuba", "renderer": "lightcrafter.proxy", **_settings_dict(settings),
                   "edits": len(edits)},
        "stats": {**asdict(renderer.stats), "render_seconds": round(seconds, 3)},
        **({} if response is None else {"response": response.as_dict()}),
        **(extra or {}),
    }
    io.write_json(out_dir.with_suffix(".json"), manifest)
    return manifest


def _edit_identity(e: MaterialEdit) -> dict:
    """An edit's values, with its mask as a digest (a repr would elide most of the array)."""
    import hashlib

    d = {k: v for k, v in asdict(e).items() if k != "mask"}
    d["mask"] = None if e.mask is None else hashlib.sha256(np.ascontiguousarray(e.mask, np.float32).tobytes()).hexdigest()
    return d


def _settings_dict(s: RenderSettings) -> dict:
    d = asdict(s)
    d["visibility_mesh"] = dict(d["visibility_mesh"])
    return d
