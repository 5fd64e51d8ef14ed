"""Synthetic envmap-fitting problems with a known answer (tests and benchmarks).

A clip of analytic buffers (:mod:`lightcrafter.proxy.synthetic`: spheres of several materials on a
grey ground, an orbiting or static camera, OpenCV cameras, world Z up) written with
lightcrafter.clip.write_clip, and its "video": R's own render (:class:`ProxyRenderer`) of every
frame under a known map, written as linear EXR frames ``{i:04d}.exr``. Maps: :func:`sky_map`
(smooth sky/ground gradient with a broad warm lobe, optionally a small sun) in the
lightcrafter.envmap convention.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lightcrafter import envmap, io
from lightcrafter.clip import write_clip
from lightcrafter.proxy import synthetic as syn
from lightcrafter.proxy.clip import resolve_visibility
from lightcrafter.proxy.lighting import Lighting
from lightcrafter.proxy.renderer import FrameView, ProxyRenderer, RenderSettings

SPHERES = (
    syn.Sphere((0.0, 0.0, 0.5), 0.5, (0.8, 0.8, 0.8), 0.6, 0.0),
    syn.Sphere((0.9, 0.6, 0.3), 0.3, (0.8, 0.3, 0.2), 0.3, 0.0),
    syn.Sphere((-0.7, 0.8, 0.35), 0.35, (0.9, 0.9, 0.9), 0.25, 1.0),
    syn.Sphere((0.6, -0.8, 0.25), 0.25, (0.3, 0.5, 0.9), 0.8, 0.0),
)


def sky_map(height: int = 64, width: int = 128, sun: float = 0.0, sun_dir=(0.5, 0.3, 0.6),
            lobe_dir=(-0.6, 0.5, 0.4)) -> np.ndarray:
    """Linear (H, W, 3) map: blue sky above, brown ground below, a broad warm lobe around
    ``lobe_dir`` and (``sun`` > 0) a sun of ``sun`` times the sky's radiance in the texel(s) around
    ``sun_dir`` (world directions)."""
    d = envmap.pixel_directions(height, width)
    z = d[..., 2:3]
    sky = np.where(z > 0, np.array([0.45, 0.6, 0.95]) * (0.6 + 0.4 * z), np.array([0.35, 0.28, 0.2]) * (0.8 + 0.2 * z))
    lobe_dir = np.asarray(lobe_dir, float) / np.linalg.norm(lobe_dir)
    c = np.clip(d @ lobe_dir, 0, 1)[..., None]
    env = sky + np.array([2.0, 1.3, 0.6]) * c**6
    if sun > 0:
        sd = np.asarray(sun_dir, float) / np.linalg.norm(sun_dir)
        u, v = envmap.direction_to_uv(sd)
        r, cidx = int(min(v * height, height - 1)), int(u * width) % width
        env[r, cidx] = sun * np.mean(np.array([0.45, 0.6, 0.95]))
    return env.astype(np.float32)


def orbit_cameras(n: int, width: int, height: int, radius: float = 3.2, height_m: float = 1.8,
                  arc_rad: float = 0.6, static: bool = False):
    K = syn.intrinsics(width, height, 0.9)
    angles = np.zeros(n) if static else np.linspace(0.0, arc_rad, n)
    c2ws = [syn.look_at([radius * np.cos(a - 0.8), radius * np.sin(a - 0.8), height_m], [0, 0, 0.3]) for a in angles]
    return K, c2ws


def write_synthetic_clip(root: str | Path, n: int = 5, width: int = 32, height: int = 24, static: bool = False,
                         spheres=SPHERES, ground=syn.Ground((0.5, 0.5, 0.5), 0.7, 0.0, 6.0)) -> Path:
    """Write a clip (buffers, cameras, manifest) to ``root``; returns it."""
    root = Path(root)
    K, c2ws = orbit_cameras(n, width, height, static=static)
    serve = [0] * n if static else list(range(n))
    for j in sorted(set(serve)):
        io.write_buffers(root / "buffers" / f"{j:04d}.exr",
                         syn.raycast_buffers(K, c2ws[j], width, height, list(spheres), ground))
    write_clip(root, serve=serve, K=[K] * n, c2w=c2ws, width=width, height=height, fps=24, camera_static=static,
               scene_static=True, units="metres", producer={"stage": "synthetic-envfit"}, content_id=f"syn{n}x{width}",
               consistent_depth=True)
    return root


def render_video(clip: str | Path, env: np.ndarray, frames_dir: str | Path, spp: int = 64, seed: int = 1234,
                 settings: RenderSettings = RenderSettings(visibility="auto")) -> np.ndarray:
    """R's render of every frame of ``clip`` under ``env`` (world frame), written to ``frames_dir``."""
    from lightcrafter.clip import read_clip

    views, info = read_clip(clip)
    s = resolve_visibility(RenderSettings(**{**settings.__dict__, "spp": spp, "seed": seed}), info.scene_static,
                           info.consistent_depth)
    r = ProxyRenderer(Lighting(env=np.asarray(env, np.float32)), s)
    r.prepare(views)
    frames = np.stack([r.render(v, frame=i) for i, v in enumerate(views)])
    for i, f in enumerate(frames):
        io.write_rgb_exr(Path(frames_dir) / f"{i:04d}.exr", f)
    return frames


__all__ = ["FrameView", "SPHERES", "orbit_cameras", "render_video", "sky_map", "write_synthetic_clip"]
