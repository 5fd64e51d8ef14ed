"""Adapter for the MIT Multi-Illumination dataset (Murmann et al. 2019), the paper's real relighting benchmark
with captured target-light images.

Layout read here (the dataset as distributed, one folder per scene under ``root``)::

    {root}/{scene}/dir_{i}_mip{m}.jpg     the scene under flash direction i (0..24), at mip level m
                                          (mip 2 = 1500x1000, each level halves the size)
    {root}/{scene}/probes/...             chrome and grey light probes (not needed here)

Protocol (paper: mean over 10 scenes x 24 target illuminations): each scene's image under the source
direction is the input "video" (one frame: a static camera); Phi recovers its scene state; a source
environment map cannot relight it to a *captured* flash direction, so the target lighting is taken
from the target image itself: an environment map is fitted with the source's scene state to the
target image (lightcrafter.envfit, like the real pseudo-pairs), R renders the source's scene state
under it (the proxy), the refiner refines it and the result is compared with the captured target.

Clip ids: ``mit_{scene}_d{i}`` (one per scene and direction used).
"""

from __future__ import annotations

import re
from pathlib import Path

from lightcrafter.io import DataError

DIRECTIONS = 25
_NAME = re.compile(r"^dir_(\d+)_mip(\d+)\.(jpg|jpeg|png)$", re.IGNORECASE)


def scan(root: str | Path, mip: int = 2) -> dict[str, dict[int, Path]]:
    """{scene: {direction: image path}} of every scene folder under ``root`` at mip level ``mip``."""
    root = Path(root)
    if not root.is_dir():
        raise DataError(f"{root}: MIT Multi-Illumination folder not found; fix mit.root in config")
    scenes: dict[str, dict[int, Path]] = {}
    for d in sorted(p for p in root.iterdir() if p.is_dir()):
        found = {}
        for f in d.iterdir():
            m = _NAME.match(f.name)
            if m and int(m.group(2)) == mip:
                found[int(m.group(1))] = f
        if found:
            scenes[d.name] = found
    if not scenes:
        raise DataError(f"{root}: no scene folder with dir_<i>_mip{mip}.jpg images; check mit.root and mit.mip")
    return scenes


def safe_id(scene: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "_", scene).strip("_")


def plan(cfg: dict | None) -> dict:
    """The benchmark's clips and pairs from config (``mit: {root, mip, scenes, source_dir, target_dirs}``):
    ``{"clips": {clip_id: {image, scene, direction}}, "pairs": {pair_id: {source, target, scene, ...}}}``.
    Empty when ``mit.root`` is null. Reads the folder listing (not the images)."""
    cfg = cfg or {}
    if not cfg.get("root"):
        return {"clips": {}, "pairs": {}}
    scenes = scan(cfg["root"], int(cfg.get("mip", 2)))
    names = cfg.get("scenes") or sorted(scenes)[: int(cfg.get("max_scenes", 10))]
    src = int(cfg.get("source_dir", 0))
    targets = cfg.get("target_dirs") or [i for i in range(DIRECTIONS) if i != src]
    clips, pairs = {}, {}
    for s in names:
        if s not in scenes:
            raise DataError(f"{cfg['root']}: no scene {s!r}; mit.scenes lists only folders that exist")
        imgs = scenes[s]
        for i in [src, *targets]:
            if i not in imgs:
                raise DataError(f"{Path(cfg['root']) / s}: no dir_{i}_mip{cfg.get('mip', 2)} image; fix mit.target_dirs")
            clips[f"mit_{safe_id(s)}_d{i}"] = {"image": str(imgs[i]), "scene": s, "direction": i}
        for j in targets:
            pairs[f"mit_{safe_id(s)}_d{src}_to_d{j}"] = {"scene": s, "source": f"mit_{safe_id(s)}_d{src}",
                                                        "target": f"mit_{safe_id(s)}_d{j}", "target_dir": j}
    return {"clips": clips, "pairs": pairs}
