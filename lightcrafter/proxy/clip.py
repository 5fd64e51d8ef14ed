"""Render a whole clip from files: buffers.json + cameras.json + scene.json -> frames, mp4, manifest.

Inputs (docs/architecture.md): ``buffers.json`` (``frames``: for every frame index the buffer EXR
serving it, relative to its folder; ``cameras``: the cameras file) and ``cameras.json``.
Outputs for ``out_dir`` = ``.../{light}``:

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

from lightcrafter import io
from lightcrafter.proxy.edits import MaterialEdit, apply_edits
from lightcrafter.proxy.lighting import Lighting, lighting_from_spec
from lightcrafter.proxy.renderer import FrameView, ProxyRenderer, RenderSettings
from lightcrafter.scenes import lighting as lighting_entry
from lightcrafter.scenes import trajectory


def read_clip(buffers_json: str | Path) -> tuple[list[FrameView], dict]:
    """Load and validate every frame of a buffer manifest; returns (views, manifest)."""
    buffers_json = Path(buffers_json)
    if buffers_json.is_dir():
        buffers_json = buffers_json / "buffers.json"
    man = io.read_json(buffers_json)
    root = buffers_json.parent
    frames = man.get("frames")
    if not isinstance(frames, list) or not frames or not all(isinstance(f, str) for f in frames):
        raise io.DataError(f"{buffers_json}: 'frames' must be a non-empty list of buffer EXR paths")
    cam_path = root / man.get("cameras", "cameras.json")
    width, height, K, c2w = io.read_cameras(cam_path)
    if len(K) != len(frames):
        raise io.DataError(f"{cam_path}: {len(K)} cameras but {buffers_json} lists {len(frames)} frames")
    if "num_frames" in man and int(man["num_frames"]) != len(frames):
        raise io.DataError(f"{buffers_json}: num_frames={man['num_frames']} but {len(frames)} frame entries")
    cache: dict[str, io.Buffers] = {}
    views = []
    for i, rel in enumerate(frames):
        path = root / rel
        if rel not in cache:
            b = io.read_buffers(path)
            if b.shape != (height, width):
                raise io.DataError(f"{path}: buffer is {b.shape[1]}x{b.shape[0]} but {cam_path} says {width}x{height}")
            cache[rel] = b
        views.append(FrameView(buffers=cache[rel], K=K[i], c2w=c2w[i], key=str(path)))
    return views, man


def resolve_visibility(settings: RenderSettings, trajectory: dict) -> RenderSettings:
    """Visibility 'auto': the clip-aggregated shadow mesh for a static scene, this frame's own mesh
    when objects move (``scene_static`` false or motion ``dynamic_moving``): aggregating depth maps
    over time would leave ghost occluders where objects used to be."""
    if settings.visibility != "auto":
        return settings
    static = trajectory.get("scene_static", trajectory.get("motion") != "dynamic_moving")
    return replace(settings, visibility="aggregate" if static else "frame")


def frame_path(out_dir: Path, i: int) -> Path:
    return Path(out_dir) / f"{i:04d}.exr"


def _complete(path: Path, shape) -> bool:
    if not path.is_file():
        return False
    try:
        return io.read_rgb_exr(path).shape[:2] == tuple(shape)
    except io.DataError:
        return False


def render_views(views: list[FrameView], lighting: Lighting, settings: RenderSettings, out_dir: Path,
                 edits: list[MaterialEdit] = (), cache: bool = True) -> tuple[list[np.ndarray], ProxyRenderer, float]:
    """Render (or reuse complete) frames into ``out_dir``; returns (frames, renderer, render seconds)."""
    if edits:
        views = [FrameView(apply_edits(v.buffers, edits), v.K, v.c2w, v.key + "#edited") for v in views]
    renderer = ProxyRenderer(lighting, settings, cache=cache)
    shape = views[0].buffers.shape
    todo = [i for i in range(len(views)) if not _complete(frame_path(out_dir, i), shape)]
    t0 = time.perf_counter()
    if todo:
        renderer.prepare(views)
        for i in todo:
            io.write_rgb_exr(frame_path(out_dir, i), renderer.render(views[i], frame=i))
    seconds = time.perf_counter() - t0
    return [io.read_rgb_exr(frame_path(out_dir, i)) for i in range(len(views))], renderer, seconds


def render_clip(buffers_json: str | Path, scene_json: str | Path, light_id: str, out_dir: str | Path, *,
                traj_id: str | None = None, settings: RenderSettings = RenderSettings(), exposure_ev: float = 0.0,
                edits: list[MaterialEdit] = ()) -> dict:
    """Render every frame of the clip under lighting ``light_id`` of ``scene_json``; return the manifest."""
    out_dir = Path(out_dir)
    views, man = read_clip(buffers_json)
    spec = io.read_json(scene_json)
    clip_dir = Path(buffers_json) if Path(buffers_json).is_dir() else Path(buffers_json).parent
    traj_id = traj_id or man.get("trajectory") or clip_dir.resolve().name
    traj = trajectory(spec, traj_id, str(scene_json))
    if len(traj["frames"]) != len(views):
        raise io.DataError(f"{scene_json}: trajectory {traj_id!r} has {len(traj['frames'])} "
                           f"frames but {buffers_json} has {len(views)}")
    lighting = lighting_from_spec(spec, light_id, traj_id, exposure_ev=exposure_ev, where=str(scene_json))
    settings = resolve_visibility(settings, traj)
    # Frames of other inputs (re-rendered buffers, another light or settings) are never reused.
    upstream = clip_dir / "buffers" / ".inputs.json"
    inputs = {
        "what": "proxy", "buffers_manifest": man, "buffers_stamp": upstream.read_text() if upstream.is_file() else None,
        "cameras": io.read_json(clip_dir / "cameras.json") if (clip_dir / "cameras.json").is_file() else None,
        "lighting": lighting_entry(spec, light_id, str(scene_json)),
        "trajectory": traj, "settings": _settings_dict(settings), "exposure_ev": exposure_ev,
        "edits": [_edit_identity(e) for e in edits],
    }
    io.claim_frame_dir(out_dir, inputs)
    io.stamp_frame_dir(out_dir, inputs)
    frames, renderer, seconds = render_views(views, lighting, settings, out_dir, edits)
    fps = float(spec.get("fps", 24))
    preview = out_dir.with_suffix(".mp4")
    io.write_video(preview, io.to_uint8(io.linear_to_display(np.stack(frames))), fps=fps)
    h, w = frames[0].shape[:2]
    manifest = {
        "format": "lightcrafter.proxy/1",
        "scene_id": spec.get("scene_id"), "trajectory": traj_id, "light": light_id,
        "width": w, "height": h, "num_frames": len(frames), "fps": fps,
        "frames": [f"{out_dir.name}/{i:04d}.exr" for i in range(len(frames))],
        "preview": preview.name, "radiance": "linear scene-referred (no view transform)",
        "buffers": str(buffers_json),
        "render": {"engine": "mitsuba", "renderer": "lightcrafter.proxy", **_settings_dict(settings),
                   "exposure_ev": exposure_ev, "edits": len(edits)},
        "stats": {**asdict(renderer.stats), "render_seconds": round(seconds, 3)},
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
