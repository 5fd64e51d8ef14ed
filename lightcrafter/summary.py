"""Counts of what the ground-truth stage rendered, against what a naive renderer would render.

"Leave out what a scene does not need" in numbers: buffers are lighting-independent (one set per
trajectory, not one per lighting), a static camera over a static scene needs one buffer frame,
and a lighting no pair uses is never rendered.
"""

from __future__ import annotations

from pathlib import Path

from .io import read_json


def ground_truth_summary(gt_root: str | Path, specs: list[dict]) -> dict:
    """Count frames on disk (from the manifests) and the naive counts for the same trajectories.

    naive_rgb_frames: every lighting of the scene, every frame.
    naive_buffer_frames: buffers rendered with every radiance render (per used lighting, per frame).
    """
    gt_root = Path(gt_root)
    out = {"trajectories": 0, "rgb_frames": 0, "buffer_frames": 0, "naive_rgb_frames": 0,
           "naive_buffer_frames": 0, "by_motion": {}}
    for spec in specs:
        n, n_light = int(spec["num_frames"]), len(spec["lightings"])
        for t in spec["trajectories"]:
            tdir = gt_root / spec["scene_id"] / t["id"]
            buf = read_json(tdir / "buffers.json")
            buffer_files = len(set(buf["frames"]))
            rgb = sum(len(read_json(tdir / "rgb" / f"{light}.json")["frames"]) for light in t["render_lights"])
            m = out["by_motion"].setdefault(t["motion"], {"trajectories": 0, "rgb_frames": 0, "buffer_frames": 0})
            m["trajectories"] += 1
            m["rgb_frames"] += rgb
            m["buffer_frames"] += buffer_files
            out["trajectories"] += 1
            out["rgb_frames"] += rgb
            out["buffer_frames"] += buffer_files
            out["naive_rgb_frames"] += n * n_light
            out["naive_buffer_frames"] += n * len(t["render_lights"])
    out["rgb_frames_saved"] = out["naive_rgb_frames"] - out["rgb_frames"]
    out["buffer_frames_saved"] = out["naive_buffer_frames"] - out["buffer_frames"]
    return out
