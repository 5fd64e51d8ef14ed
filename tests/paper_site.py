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
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
PAPER = REPO / "config" / "paper.yaml"


def make_site(root: Path, dl3dv_scenes: int = 1200, mit_scenes: int = 10) -> dict:
    """Make the folders under ``root``; returns {name: path} and writes ``root/site.yaml``."""
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
    tools = root / "site"
    tools.mkdir(exist_ok=True)
    for tool in ("megasam", "diffusion_renderer", "diffusion_light"):
        (tools / f"{tool}.sh").write_text("#!/bin/sh\nexit 0\n")
        (tools / f"{tool}.sh").chmod(0o755)
    paths = {"glbs": glbs, "hdri": hdri, "textures": tex.parent, "dl3dv": dl3dv, "mit": mit, "model": model,
             "tools": tools}
    site = {
        "extends": str(PAPER),
        "assets": {"dir": str(glbs)},
        "scenes": {"hdri_dir": str(hdri), "ground_textures_dir": str(tex.parent)},
        "real": {"dl3dv": {"root": str(dl3dv)}},
        "mit": {"root": str(mit)},
        "recon": {"paper_stack": {"commands": {
            "megasam": f"{tools}/megasam.sh {{frames}} {{out}} {{clip}}",
            "diffusion_renderer": f"{tools}/diffusion_renderer.sh {{frames_root}} {{out}}",
            "diffusion_light": f"{tools}/diffusion_light.sh {{frame0_dir}} {{out}}"}}},
        "refiner": {"model": {"model_path": str(model)}},
    }
    (root / "site.yaml").write_text(yaml.safe_dump(site, sort_keys=False))
    return {k: str(v) for k, v in paths.items()} | {"site": str(root / "site.yaml")}
