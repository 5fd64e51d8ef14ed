"""Render ground truth for one trajectory of a scene spec: G-buffers + cameras, and linear RGB per lighting.

Output layout (``out_dir`` is the trajectory folder, ``results/gt/{scene}/{traj}``)::

    cameras.json, buffers/{frame:04d}.exr, buffers.json
                                  a clip in the project's clip contract (lightcrafter.clip): G-buffers of
                                  the distinct frames only (``buffer_frames``), all cameras, manifest last
    rgb/{light}/{frame:04d}.exr   linear HDR RGB (scene-referred, no view transform)
    rgb/{light}.mp4               display preview (lightcrafter.io.linear_to_display, exposure 0 EV)
    rgb/{light}.json              manifest, written last

Resumable: every frame is written atomically; frames already present and readable are skipped, and
the manifest is written only when every frame exists. The render functions return how many frames
they actually rendered (0 on a complete rerun).

Sampling choices
----------------
* Buffers, geometry (depth, normal, mask): 1 sample per pixel through a box pixel filter of width
  0.01 px, i.e. one ray through the pixel centre. Depth, normal and mask describe the *same* surface point
  (no blur, no mixed edge pixels, mask exactly 0/1), which matches Cycles' Z pass (one sample per pixel)
  and the OpenCV pixel-centre convention of ``K``.
* Buffers, materials (albedo, roughness, metallic): a second render of the same frame with
  ``MATERIAL_SPP`` samples through the RGB frames' pixel filter (Blackman-Harris, 1.5 px), divided by the
  surface coverage (alpha), i.e. the filter-weighted mean material of the surface seen in the pixel, the
  same average the camera applies to radiance. A point-sampled texture finer than a pixel is aliased noise
  that no estimator can predict from the filtered frame: on the default's woven and tiled grounds the
  point-sampled albedo was only 13.5-16.5 dB from its own 2-px blur. At object outlines the materials of
  the object and what lies behind it mix; where the pixel centre sees a surface the second render missed
  (coverage under 1 %), the centre's values are kept. Light bounces are 0: only first-hit passes are needed.
* RGB: ``spec.render.spp`` samples, Cycles' default Blackman-Harris filter (1.5 px), ``max_bounces``
  from the spec, fixed seed, ``spec.render.denoiser`` (none | oidn), its ``denoise_quality`` (OIDN's network;
  ``target_denoise_quality`` for videos that are only targets: :func:`denoise_quality_of`) and ``clamp_indirect``
  (see benchmarks/cycles_spp.py for the choice of all of them).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from lightcrafter import clip, io
from lightcrafter.blender import build
from lightcrafter.scenes import denoise_networks

BUFFER_SPP = 1
BUFFER_FILTER_WIDTH_PX = 0.01  # Cycles' minimum: a point sample at the pixel centre
RGB_FILTER_WIDTH_PX = 1.5  # Cycles' default Blackman-Harris width
MATERIAL_SPP = 16  # samples of the material render (albedo, roughness, metallic), filtered as the RGB frames
MATERIAL_FILTER_WIDTH_PX = RGB_FILTER_WIDTH_PX
MIN_MATERIAL_COVERAGE = 0.01  # below this surface coverage the material render keeps the pixel centre's values
BACKGROUND_DEPTH = 1e9  # Cycles writes 1e10 on background in the Z pass


# ----------------------------------------------------------------------------- pure helpers
def cameras(spec: dict, traj_id: str) -> tuple[np.ndarray, np.ndarray]:
    """Intrinsics K (N, 3, 3, pixels) and OpenCV camera-to-world c2w (N, 4, 4, world metres) of every frame."""
    traj = build.trajectory(spec, traj_id)
    w, h = spec["resolution"]["width"], spec["resolution"]["height"]
    K = build.intrinsics(w, h, float(spec["camera"]["fov_x_rad"]))
    c2w = np.stack([build.opencv_c2w(f["cam_location_m"], f["cam_target_m"]) for f in traj["frames"]])
    return np.repeat(K[None], len(c2w), axis=0), c2w


def buffer_frame_of(spec: dict, traj_id: str) -> list[int]:
    """For every frame index, the index of the frame whose buffers serve it.

    ``buffer_frames`` = 1 (static camera over a static scene): every frame uses frame 0's buffers;
    ``buffer_frames`` = num_frames: each frame has its own.
    """
    traj = build.trajectory(spec, traj_id)
    n = int(spec["num_frames"])
    nb = int(traj.get("buffer_frames", n))
    if nb == 1:
        return [0] * n
    if nb == n:
        return list(range(n))
    raise io.DataError(f"trajectory {traj_id!r}: buffer_frames={nb}, expected 1 or num_frames={n}; re-sample the scene")


def layers_to_buffers(ch: dict[str, np.ndarray], materials: dict[str, np.ndarray] | None = None) -> io.Buffers:
    """Convert Cycles passes (keys like ``Depth.Z``, ``Normal.X``, ``albedo.R``) to the buffer contract.

    Depth is Cycles' Z pass, already planar camera z in metres (checked against a camera looking
    straight at a plane); background (1e10) becomes +inf. Normals (world space, antialiased in
    general) are re-normalised. Materials are clipped to [0, 1]. Mask = alpha > 0.5 and finite depth.
    ``materials``: the passes of a filtered render of the same frame (module docstring); its albedo,
    roughness and metallic, divided by its alpha (background samples add 0 to a shader AOV), replace ``ch``'s
    wherever its coverage is at least ``MIN_MATERIAL_COVERAGE``.
    """
    if materials is not None:
        cov = materials["Combined.A"].astype(np.float64)
        ok = cov >= MIN_MATERIAL_COVERAGE
        ch = dict(ch)
        for key in [f"{build.AOV_ALBEDO}.{c}" for c in "RGB"] + [f"{build.AOV_ROUGHNESS}.X", f"{build.AOV_METALLIC}.X"]:
            ch[key] = np.where(ok, materials[key] / np.maximum(cov, MIN_MATERIAL_COVERAGE), ch[key])
    depth = ch["Depth.Z"].astype(np.float32)
    mask = (ch["Combined.A"] > 0.5) & np.isfinite(depth) & (depth < BACKGROUND_DEPTH) & (depth > 0)
    normal = np.stack([ch[f"Normal.{c}"] for c in "XYZ"], axis=-1)
    length = np.linalg.norm(normal, axis=-1, keepdims=True)
    mask &= length[..., 0] > 1e-6
    normal = np.where(mask[..., None], normal / np.maximum(length, 1e-12), 0.0)
    albedo = np.clip(np.stack([ch[f"{build.AOV_ALBEDO}.{c}"] for c in "RGB"], axis=-1), 0.0, 1.0)
    return io.Buffers(
        depth=np.where(mask, depth, np.inf).astype(np.float32),
        normal=normal.astype(np.float32),
        albedo=np.where(mask[..., None], albedo, 0.0).astype(np.float32),
        roughness=np.where(mask, np.clip(ch[f"{build.AOV_ROUGHNESS}.X"], 0.0, 1.0), 0.0).astype(np.float32),
        metallic=np.where(mask, np.clip(ch[f"{build.AOV_METALLIC}.X"], 0.0, 1.0), 0.0).astype(np.float32),
        mask=mask.astype(np.float32),
    )


# ----------------------------------------------------------------------------- Blender
def render_layers() -> dict[str, np.ndarray]:
    """Render the current bpy scene once; return its passes as float32 (H, W) arrays keyed ``Pass.Channel``."""
    import bpy

    with tempfile.TemporaryDirectory(prefix="lc_cycles_") as tmp:
        path = Path(tmp) / "layers.exr"
        bpy.context.scene.render.filepath = str(path)
        bpy.ops.render.render(write_still=True)
        ch = io.read_exr(path)
    return {k.split(".", 1)[1]: v for k, v in ch.items()}


def render_buffers(spec: dict, traj_id: str, out_dir, *, threads: int | None = None, device: str = "cpu") -> int:
    """Render G-buffers of the trajectory's distinct frames, cameras.json and buffers.json into ``out_dir``.

    ``device``: Cycles device (build.select_device); the device used is written into the manifest.
    Returns the number of buffer frames rendered (frames already complete are skipped).
    """
    out_dir = Path(out_dir)
    traj = build.trajectory(spec, traj_id)
    serve = buffer_frame_of(spec, traj_id)
    distinct = sorted(set(serve))
    build.import_bpy(threads)
    build.check_inputs(spec)
    inputs = {"what": "buffers", "spec": spec, "trajectory": traj_id, "spp": BUFFER_SPP,
              "filter_px": BUFFER_FILTER_WIDTH_PX,
              "materials": {"spp": MATERIAL_SPP, "filter_px": MATERIAL_FILTER_WIDTH_PX}}
    frames = clip.buffer_frames(out_dir, inputs)
    todo = frames.missing(distinct, io.read_buffers)
    used = None
    if todo:
        built = build.build_scene(spec, light_id=None)
        frames.stamp()
        used = build.configure_render(
            spec,
            samples=BUFFER_SPP,
            max_bounces=0,
            filter_width_px=BUFFER_FILTER_WIDTH_PX,
            film_transparent=True,
            buffers=True,
            threads=threads,
            device=device,
        )
        _note_device(out_dir / "buffers.device", used)
        for i in todo:
            build.set_frame(built, traj["frames"][i])
            build.set_sampling(BUFFER_SPP, BUFFER_FILTER_WIDTH_PX)
            geometry = render_layers()
            build.set_sampling(MATERIAL_SPP, MATERIAL_FILTER_WIDTH_PX)
            io.write_buffers(frames.path(i), layers_to_buffers(geometry, render_layers()))
    K, c2w = cameras(spec, traj_id)
    clip.write_clip(
        out_dir, serve=serve, K=K, c2w=c2w, width=spec["resolution"]["width"], height=spec["resolution"]["height"],
        fps=float(spec.get("fps", 24)), camera_static=bool(traj.get("camera_static", False)),
        scene_static=bool(traj.get("scene_static", True)), units="metres", consistent_depth=True,
        producer={"stage": "blender", "engine": "cycles", "spp": BUFFER_SPP,
                  "pixel_filter": f"box {BUFFER_FILTER_WIDTH_PX} px",
                  "materials": {"spp": MATERIAL_SPP, "pixel_filter": f"blackman-harris {MATERIAL_FILTER_WIDTH_PX} px",
                                "divided_by": "alpha coverage"},
                  "device": _device_record(out_dir, used)},
        content_id=io.fingerprint(inputs),
        extra={"scene_id": spec.get("scene_id"), "trajectory": traj_id, "motion": traj.get("motion")},
    )
    return len(todo)


def _note_device(marker: Path, used: str) -> None:
    """Record the Cycles device before any frame is rendered (``marker``: a small text file beside the
    manifest), so that a run killed after its last frame and before its manifest resumes with it."""
    with io.atomic_path(marker) as tmp:
        tmp.write_text(used + "\n")


def _device_record(manifest_dir: Path, used: str | None, manifest: str = "buffers.json") -> str | None:
    """The Cycles device of this render; a rerun that rendered nothing keeps the device the frames were
    rendered with (the marker :func:`_note_device` wrote), else the previous manifest's."""
    if used is not None:
        return used
    marker = Path(manifest_dir) / (Path(manifest).stem + ".device")
    if marker.is_file():
        return marker.read_text().strip() or None
    old = Path(manifest_dir) / manifest
    if old.is_file():
        data = io.read_json(old)
        return (data.get("producer") or data.get("render") or {}).get("device")
    return None


def denoise_quality_of(spec: dict, traj: dict, light_id: str) -> str:
    """OIDN's network for the video of ``traj`` under ``light_id``: ``render.target_denoise_quality`` for a
    video that is only ever a target (a target light other than the source, outside the recon split), else
    ``render.denoise_quality``. A video Φ reconstructs or the estimator trains on keeps the latter: structure
    from motion on frames of the balanced network lost more clips than on the high one (docs/held_out.md)."""
    quality, target_quality = denoise_networks(spec.get("render", {}))
    target_only = (spec.get("split") != "recon" and light_id in traj.get("target_lights", [])
                   and light_id != traj.get("source_light"))
    return target_quality if target_only else quality


def render_rgb(
    spec: dict, traj_id: str, light_id: str, out_dir, *, threads: int | None = None, spp: int | None = None,
    device: str = "cpu",
) -> int:
    """Render linear HDR RGB frames of the trajectory under lighting ``light_id``, the preview and manifest.

    Only lightings in the trajectory's ``render_lights`` may be rendered. ``spp`` overrides
    ``spec.render.spp``. Returns the number of frames rendered (complete frames are skipped).
    """
    out_dir = Path(out_dir)
    traj = build.trajectory(spec, traj_id)
    if light_id not in traj.get("render_lights", [light_id]):
        raise io.DataError(
            f"lighting {light_id!r}: not in render_lights {traj['render_lights']} of "
            f"trajectory {traj_id!r}; no pair uses it, so it is not rendered"
        )
    rcfg = spec.get("render", {})
    spp = int(spp or rcfg.get("spp", 16))
    n = int(spec["num_frames"])
    build.import_bpy(threads)
    build.check_inputs(spec, light_id)
    denoiser = rcfg.get("denoiser", "none")
    denoise_quality = denoise_quality_of(spec, traj, light_id)
    clamp_indirect = float(rcfg.get("clamp_indirect", 0.0))
    inputs = {"what": "rgb", "spec": spec, "trajectory": traj_id, "light": light_id, "spp": spp,
              "filter_px": RGB_FILTER_WIDTH_PX}
    folder = clip.FrameFolder(out_dir / "rgb" / light_id, inputs)
    todo = folder.missing(range(n), io.read_rgb_exr)
    used = None
    if todo:
        built = build.build_scene(spec, light_id=light_id)
        folder.stamp()
        used = build.configure_render(
            spec,
            samples=spp,
            max_bounces=int(rcfg.get("max_bounces", 4)),
            filter_width_px=RGB_FILTER_WIDTH_PX,
            film_transparent=False,
            buffers=False,
            threads=threads,
            denoiser=denoiser,
            denoise_quality=denoise_quality,
            clamp_indirect=clamp_indirect,
            device=device,
        )
        _note_device(out_dir / "rgb" / f"{light_id}.device", used)
        for i in todo:
            build.set_frame(built, traj["frames"][i])
            ch = render_layers()
            io.write_frame_exr(folder.path(i), np.stack([ch[f"Combined.{c}"] for c in "RGB"], axis=-1))
    files = [folder.path(i) for i in range(n)]
    frames = np.stack([io.read_rgb_exr(f) for f in files])
    io.write_video(
        out_dir / "rgb" / f"{light_id}.mp4", io.to_uint8(io.linear_to_display(frames)), fps=float(spec.get("fps", 24))
    )
    io.write_json(
        out_dir / "rgb" / f"{light_id}.json",
        {
            "format": "lightcrafter.rgb/1",
            "scene_id": spec.get("scene_id"),
            "trajectory": traj_id,
            "light": light_id,
            "width": spec["resolution"]["width"],
            "height": spec["resolution"]["height"],
            "num_frames": n,
            "fps": spec.get("fps", 24),
            "frames": [f"rgb/{light_id}/{i:04d}.exr" for i in range(n)],
            "preview": f"rgb/{light_id}.mp4",
            "radiance": "linear scene-referred (no view transform)",
            "render": {
                "engine": "cycles",
                "spp": spp,
                "max_bounces": int(rcfg.get("max_bounces", 4)),
                "seed": int(rcfg.get("seed", 0)),
                "pixel_filter": f"blackman-harris {RGB_FILTER_WIDTH_PX} px",
                "denoiser": denoiser,
                **({"denoise_quality": denoise_quality} if denoiser == "oidn" else {}),
                "clamp_indirect": clamp_indirect,
                "device": _device_record(out_dir / "rgb", used, f"{light_id}.json"),
            },
        },
    )
    return len(todo)
