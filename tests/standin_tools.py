#!/usr/bin/env python
"""Format stand-ins for the paper stack's three tools: they write MegaSAM's, DiffusionRenderer's and
DiffusionLight's native output formats from a clip's frames so that the paper-stack code path
(command templates, native-format adapters, skip-and-count, retries, clean-up) runs on a CPU.

They are NOT reconstructions: depth is a fixed ground-plane-like ramp, cameras dolly forward, normals
face the camera, materials are constants, the map is a sky gradient. Only the files' layout, names,
dtypes, shapes and pixel grids are the tools' own (lightcrafter.recon.paper_stack module docstrings).

  standin_tools.py megasam FRAMES OUT CLIP            # OUT/outputs_cvd/CLIP_sgd_cvd_hr.npz (cvd_opt.py)
                                                      # one frame: OUT/UniDepth/outputs/CLIP/00000.npz
  standin_tools.py diffusion_renderer FRAMES_ROOT OUT # OUT/gbuffer_frames/<clip>/0000.<i>.<pass>.jpg
  standin_tools.py diffusion_light FRAME0_DIR OUT     # OUT/hdr/<stem>.exr (exposure2hdr.py)

Failure modes for tests (environment): ``STANDIN_FAIL=<clip>[,<clip>]`` exits 3 for those clips,
``STANDIN_HANG=<clip>`` sleeps an hour for that clip (a tool that hangs: the timeout must stop it),
``STANDIN_HANG_ONCE=<tool>:<marker file>`` makes that tool hang only while the marker file does not
exist, creating it first (a tool that times out on the first attempt and succeeds on the retry).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import numpy as np  # noqa: E402

DR_SIZE = (160, 88)          # cosmos1's 1280 x 704 output, divided by 8 (a 3:2 video is stretched to it)


def _frames(folder: Path) -> list[np.ndarray]:
    import imageio.v3 as iio

    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in (".png", ".jpg"))
    if not files:
        sys.exit(f"standin: no frames in {folder}")
    return [np.asarray(iio.imread(p))[..., :3] for p in files]


def _failure_modes(clip: str, tool: str) -> None:
    if clip in os.environ.get("STANDIN_FAIL", "").split(","):
        print(f"standin: failing on {clip} as asked (STANDIN_FAIL)", file=sys.stderr)
        sys.exit(3)
    if clip in os.environ.get("STANDIN_HANG", "").split(","):
        time.sleep(3600)
    which, _, marker = os.environ.get("STANDIN_HANG_ONCE", "").partition(":")
    if which == tool and marker and not Path(marker).exists():
        Path(marker).write_text(clip)
        time.sleep(3600)


def _ramp(h: int, w: int) -> np.ndarray:
    """z-depth of a level camera over a ground plane (near at the bottom), capped far at the top."""
    y = (np.arange(h, dtype=np.float32) + 0.5) / h
    return np.repeat(np.clip(1.5 / np.maximum(y - 0.3, 0.05), 0.5, 30.0)[:, None], w, axis=1)


def megasam(frames_dir: str, out: str, clip: str) -> None:
    import cv2

    from lightcrafter.camera import intrinsics
    from lightcrafter.recon.paper_stack import megasam as ms

    _failure_modes(clip, "megasam")
    frames = _frames(Path(frames_dir))
    H0, W0 = frames[0].shape[:2]
    if len(frames) == 1:  # MegaSAM's UniDepth stage only (demo_mega-sam.py)
        g = ms.unidepth_map(W0, H0)
        d = Path(out) / "UniDepth" / "outputs" / clip
        d.mkdir(parents=True, exist_ok=True)
        np.savez(d / "00000.npz", depth=_ramp(g.height, g.width), fov=np.float64(60.0))
        return
    w1, h1, w, h = ms.working_grid(W0, H0)
    images = np.stack([cv2.resize(f, (w1, h1), interpolation=cv2.INTER_AREA)[:h, :w] for f in frames])
    T = len(frames)
    c2w = np.repeat(np.eye(4, dtype=np.float32)[None], T, axis=0)
    c2w[:, 2, 3] = 0.02 * np.arange(T)                  # dolly forward along the optical axis
    depths = np.clip(np.repeat(_ramp(h, w)[None], T, axis=0), 1e-3, 1e2).astype(np.float16)
    K = intrinsics(w, h, np.radians(60.0)).astype(np.float32)
    d = Path(out) / "outputs_cvd"
    d.mkdir(parents=True, exist_ok=True)
    np.savez(d / f"{clip}_sgd_cvd_hr.npz", images=images, depths=depths, intrinsic=K, cam_c2w=c2w)


def diffusion_renderer(frames_root: str, out: str) -> None:
    import cv2
    import imageio.v3 as iio

    clips = sorted(p for p in Path(frames_root).iterdir() if p.is_dir())
    loose = [p.name for p in Path(frames_root).iterdir() if p.is_file()]
    if len(clips) != 1 or loose:   # --group_mode folder would render every sub-folder as a clip
        sys.exit(f"standin: {frames_root} holds {len(clips)} clip folder(s) and {len(loose)} loose file(s); expected one clip")
    clip = clips[0].name
    _failure_modes(clip, "diffusion_renderer")
    d = Path(out) / "gbuffer_frames" / clip
    d.mkdir(parents=True, exist_ok=True)
    w, h = DR_SIZE
    normal_gl = np.zeros((h, w, 3), np.uint8)
    normal_gl[...] = (127, 127, 255)                    # (0, 0, 1): facing the camera, OpenGL axes
    y = np.linspace(0, 255, h, dtype=np.float32)[:, None, None]
    depth = np.repeat(np.repeat(255 - y, w, axis=1), 3, axis=2).astype(np.uint8)
    for i, f in enumerate(_frames(clips[0])):
        passes = {"basecolor": cv2.resize(f, (w, h), interpolation=cv2.INTER_LINEAR), "normal": normal_gl, "depth": depth,
                  "roughness": np.full((h, w, 3), 178, np.uint8), "metallic": np.zeros((h, w, 3), np.uint8)}
        for name, img in passes.items():
            iio.imwrite(d / f"0000.{i:04d}.{name}.jpg", img, extension=".jpg", quality=85)


def diffusion_light(frame0_dir: str, out: str) -> None:
    from lightcrafter import io

    files = sorted(Path(frame0_dir).glob("*.png"))
    if len(files) != 1:
        sys.exit(f"standin: {frame0_dir} holds {len(files)} images; expected the clip's first frame")
    _failure_modes(files[0].stem, "diffusion_light")
    h = 32
    v = (np.arange(h, dtype=np.float32) + 0.5) / h
    sky = np.stack([0.6 + 0.4 * (1 - v), 0.7 + 0.4 * (1 - v), 1.0 + 0.6 * (1 - v)], axis=-1)
    env = np.repeat(sky[:, None, :], 2 * h, axis=1).astype(np.float32)
    env[h // 4 - 2: h // 4 + 2, 3 * h // 2 - 2: 3 * h // 2 + 2] = 40.0   # a sun
    io.write_rgb_exr(Path(out) / "hdr" / f"{files[0].stem}.exr", env)


if __name__ == "__main__":
    tool, *args = sys.argv[1:]
    {"megasam": megasam, "diffusion_renderer": diffusion_renderer, "diffusion_light": diffusion_light}[tool](*args)
