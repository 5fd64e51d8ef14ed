"""Render *the same proxy scene* with Blender Cycles (for the convention test and the benchmarks).

The mesh (vertices, triangles), per-face materials (linear albedo, roughness, metallic) and
per-face shading normals that R renders are handed to Cycles unchanged: a Principled BSDF driven
by face attributes, custom split normals, the same lat-long HDRI through Texture Coordinate
(Generated) -> Mapping (TEXTURE, rotation z) -> Environment Texture -> Background (exactly the world
``lightcrafter.blender.build`` creates), the same OpenCV camera, a 1 px box filter, no denoiser, no
adaptive sampling, view transform Standard (linear output).

Runs Blender in a separate process (one scene per process): :func:`render` writes a job file and
calls ``python -m lightcrafter.proxy.cycles_scene JOB``; each requested spp is rendered after one
untimed warm-up render, and the seconds of each timed render are returned.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from lightcrafter.io import read_rgb_exr


def render(vertices: np.ndarray, faces: np.ndarray, face_albedo: np.ndarray, face_roughness: np.ndarray,
           face_metallic: np.ndarray, face_normal: np.ndarray, env_path: str | Path, rotation_z_rad: float,
           K: np.ndarray, c2w: np.ndarray, width: int, height: int, spps: list[int], *, strength: float = 1.0,
           max_bounces: int = 0, threads: int = 1, seed: int = 0, work_dir: str | Path | None = None,
           timeout_s: float = 900, repeats: int = 1) -> list[tuple[np.ndarray, float]]:
    """Render with Cycles at every spp in ``spps``; returns [(linear RGB (H, W, 3), seconds)]
    (seconds: the minimum over ``repeats`` identical renders)."""
    tmp_ctx = tempfile.TemporaryDirectory(prefix="lc_cycles_proxy_") if work_dir is None else None
    wd = Path(work_dir or tmp_ctx.name)
    wd.mkdir(parents=True, exist_ok=True)
    try:
        np.savez(wd / "mesh.npz", vertices=np.asarray(vertices, np.float32), faces=np.asarray(faces, np.int64),
                 albedo=np.asarray(face_albedo, np.float32), roughness=np.asarray(face_roughness, np.float32),
                 metallic=np.asarray(face_metallic, np.float32), normal=np.asarray(face_normal, np.float32))
        job = {"mesh": str(wd / "mesh.npz"), "env": str(env_path), "rotation_z_rad": float(rotation_z_rad),
               "strength": float(strength), "K": np.asarray(K).tolist(), "c2w": np.asarray(c2w).tolist(),
               "width": int(width), "height": int(height), "spps": [int(s) for s in spps],
               "max_bounces": int(max_bounces), "threads": int(threads), "seed": int(seed), "out": str(wd),
               "repeats": int(repeats)}
        (wd / "job.json").write_text(json.dumps(job))
        proc = subprocess.run([sys.executable, "-m", "lightcrafter.proxy.cycles_scene", str(wd / "job.json")],
                              capture_output=True, text=True, timeout=timeout_s,
                              cwd=str(Path(__file__).resolve().parents[2]))
        if proc.returncode != 0:
            raise RuntimeError(f"Cycles proxy render failed: {proc.stderr.strip().splitlines()[-5:]}")
        times = json.loads((wd / "times.json").read_text())
        return [(read_rgb_exr(wd / f"spp{s:05d}.exr"), float(times[str(s)])) for s in spps]
    finally:
        if tmp_ctx is not None:
            tmp_ctx.cleanup()


def _build(job: dict):
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    d = np.load(job["mesh"])
    verts, faces = d["vertices"].astype(float), d["faces"].astype(int)
    mesh = bpy.data.meshes.new("proxy")
    mesh.from_pydata(verts.tolist(), [], faces.tolist())
    mesh.update()
    nf = len(faces)
    alb = mesh.attributes.new("albedo", "FLOAT_COLOR", "FACE")
    rgba = np.concatenate([d["albedo"], np.ones((nf, 1), np.float32)], axis=1)
    alb.data.foreach_set("color", rgba.ravel())
    for name in ("roughness", "metallic"):
        a = mesh.attributes.new(name, "FLOAT", "FACE")
        a.data.foreach_set("value", d[name].astype(np.float32).ravel())
    mesh.normals_split_custom_set(np.repeat(d["normal"], 3, axis=0).tolist())
    ob = bpy.data.objects.new("proxy", mesh)
    scene.collection.objects.link(ob)
    mat = bpy.data.materials.new("proxy")
    mat.use_nodes = True
    nt = mat.node_tree
    bsdf = nt.nodes["Principled BSDF"]
    for name, sock, out in (("albedo", "Base Color", "Color"), ("roughness", "Roughness", "Fac"),
                            ("metallic", "Metallic", "Fac")):
        node = nt.nodes.new("ShaderNodeAttribute")
        node.attribute_name = name
        nt.links.new(node.outputs[out], bsdf.inputs[sock])
    mesh.materials.append(mat)
    # world: the ground-truth renderer's own environment set-up (same node chain and importance map)
    from lightcrafter.blender import build

    build._add_world({"id": "proxy", "hdri": job["env"], "strength": job["strength"],
                      "rotation_z_rad": job["rotation_z_rad"]})
    # camera
    K, c2w = np.array(job["K"]), np.array(job["c2w"])
    w, h = job["width"], job["height"]
    cam = bpy.data.cameras.new("cam")
    cam.sensor_fit = "HORIZONTAL"
    cam.angle_x = 2.0 * math.atan(w / (2.0 * K[0, 0]))
    cam.shift_x = -(K[0, 2] - (w - 1) / 2.0) / w
    cam.shift_y = (K[1, 2] - (h - 1) / 2.0) / w
    cam.clip_start, cam.clip_end = 1e-3, 1e4
    cob = bpy.data.objects.new("cam", cam)
    scene.collection.objects.link(cob)
    from mathutils import Matrix

    cob.matrix_world = Matrix((c2w @ build.BLENDER_FROM_OPENCV).tolist())
    scene.camera = cob
    r = scene.render
    r.engine = "CYCLES"
    r.resolution_x, r.resolution_y, r.resolution_percentage = w, h, 100
    r.use_persistent_data = True
    r.threads_mode = "FIXED"
    r.threads = job["threads"]
    r.image_settings.file_format = "OPEN_EXR"
    r.image_settings.color_depth = "32"
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    cy = scene.cycles
    cy.device = "CPU"
    cy.use_adaptive_sampling = False
    cy.use_denoising = False
    cy.seed = job["seed"]
    cy.filter_type = "BOX"
    cy.filter_width = 1.0
    cy.max_bounces = job["max_bounces"]
    cy.diffuse_bounces = cy.glossy_bounces = job["max_bounces"]
    cy.transmission_bounces = cy.transparent_max_bounces = 0
    cy.sample_clamp_direct = cy.sample_clamp_indirect = 0.0
    cy.use_light_tree = False
    return scene


def _main(job_path: str) -> None:
    import time

    from lightcrafter.blender.build import import_bpy

    job = json.loads(Path(job_path).read_text())
    bpy = import_bpy(job["threads"])  # the pool sized to the job's Cycles threads, as the render jobs'
    scene = _build(job)
    out = Path(job["out"])
    times = {}
    scene.cycles.samples = 1
    scene.render.filepath = str(out / "warmup.exr")
    bpy.ops.render.render(write_still=False)  # untimed: kernel load, BVH, importance map
    for s in job["spps"]:
        scene.cycles.samples = s
        path = out / f"spp{s:05d}.exr"
        scene.render.filepath = str(path)
        best = float("inf")
        for _ in range(max(1, job.get("repeats", 1))):  # minimum over repeats: robust to a shared machine
            t0 = time.perf_counter()
            bpy.ops.render.render(write_still=True)  # includes writing a 96x64 EXR (~ms)
            best = min(best, time.perf_counter() - t0)
        times[str(s)] = best
        # re-write as the project's plain RGB EXR
        from lightcrafter.io import read_exr, write_rgb_exr

        ch = read_exr(path)
        keys = {k.split(".")[-1]: k for k in ch}
        write_rgb_exr(path, np.stack([ch[keys[c]] for c in "RGB"], axis=-1))
    (out / "times.json").write_text(json.dumps(times))


if __name__ == "__main__":
    _main(sys.argv[1])


def render_pixel_mesh(mesh, buffers, env_path, rotation_z_rad, K, c2w, spps, **kw) -> list[tuple[np.ndarray, float]]:
    """:func:`render` for a :class:`~lightcrafter.proxy.geometry.PixelMesh` shaded by ``buffers``
    (each face takes the albedo / roughness / metallic / normal of its buffer pixel)."""
    h, w = buffers.shape
    fp = np.maximum(mesh.face_pixel, 0)
    return render(mesh.vertices, mesh.faces, buffers.albedo.reshape(-1, 3)[fp], buffers.roughness.ravel()[fp],
                  buffers.metallic.ravel()[fp], buffers.normal.reshape(-1, 3)[fp], env_path, rotation_z_rad,
                  K, c2w, w, h, spps, **kw)
