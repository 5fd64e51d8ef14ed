"""Dataset manifests (``results/datasets/{variant}/pairs.jsonl``, contract in docs/architecture.md).

``clean_buffers``: proxies rendered by R from GROUND-TRUTH buffers
(``{out}/proxy_gt/{scene}/{traj}/{light}/{frame:04d}.exr``) paired with the Cycles render under
the same light (``{out}/gt/{scene}/{traj}/rgb/{light}/{frame:04d}.exr``); one pair per
(scene, trajectory, target light). Scenes of split ``recon`` are not refiner data and are skipped.
Frame count and resolution are read from the frames on disk; proxy and target must agree.
"""

from __future__ import annotations

from pathlib import Path

from lightcrafter.io import DataError, read_exr

REFINER_SPLITS = ("train", "test")


def clean_buffers_paths(out: str, scene_id: str, traj_id: str, light: str) -> dict[str, str]:
    """Paths (relative to the workflow root) of one clean-buffers pair's inputs."""
    return {
        "proxy": f"{out}/proxy_gt/{scene_id}/{traj_id}/{light}",
        "proxy_manifest": f"{out}/proxy_gt/{scene_id}/{traj_id}/{light}.json",
        "target": f"{out}/gt/{scene_id}/{traj_id}/rgb/{light}",
        "target_manifest": f"{out}/gt/{scene_id}/{traj_id}/rgb/{light}.json",
    }


def clean_buffers_specs(out: str, plans: dict[str, dict]) -> list[dict]:
    """One spec per (scene, trajectory, target light) of train/test scenes, sorted by pair id.

    ``plans`` maps scene id -> ``scene_plan(scene_id)`` ({"split", "trajectories": [{"id",
    "source_light", "target_lights", ...}]}).
    """
    specs = []
    for scene_id in sorted(plans):
        plan = plans[scene_id]
        if plan["split"] not in REFINER_SPLITS:
            continue
        for traj in plan["trajectories"]:
            for light in traj["target_lights"]:
                specs.append({
                    "pair_id": f"{scene_id}_{traj['id']}_{light}",
                    "scene_id": scene_id,
                    "trajectory": traj["id"],
                    "source_light": traj["source_light"],
                    "target_light": light,
                    "split": plan["split"],
                    **clean_buffers_paths(out, scene_id, traj["id"], light),
                })
    return sorted(specs, key=lambda s: s["pair_id"])


def _frame_info(folder: Path) -> tuple[int, int, int]:
    """(num_frames, width, height) of a folder of consecutive ``{frame:04d}.exr`` frames from 0."""
    if not folder.is_dir():
        raise DataError(f"{folder}: frame folder not found; run the stage that renders it")
    n = 0
    while (folder / f"{n:04d}.exr").is_file():
        n += 1
    if n == 0:
        raise DataError(f"{folder}: no 0000.exr; the render is incomplete, rerun it")
    extra = sorted(p.name for p in folder.glob("*.exr") if not p.name[:4].isdigit() or int(p.name[:4]) >= n)
    if extra:
        raise DataError(f"{folder}: frames are not consecutive from 0000 (stray {extra[:3]}); rerun the render")
    h, w = next(iter(read_exr(folder / "0000.exr", ("R", "G", "B")).values())).shape
    return n, int(w), int(h)


def build_clean_buffers_records(out: str, plans: dict[str, dict], root: str | Path = ".") -> list[dict]:
    """pairs.jsonl records for the clean_buffers variant; paths stay relative to ``root``."""
    root = Path(root)
    records = []
    for s in clean_buffers_specs(out, plans):
        for key in ("proxy_manifest", "target_manifest"):
            if not (root / s[key]).is_file():
                raise DataError(f"{s[key]}: manifest missing; the render of pair {s['pair_id']} is incomplete")
        np_, wp, hp = _frame_info(root / s["proxy"])
        nt, wt, ht = _frame_info(root / s["target"])
        if (np_, wp, hp) != (nt, wt, ht):
            raise DataError(
                f"pair {s['pair_id']}: proxy {s['proxy']} has {np_} frames {wp}x{hp}, target {s['target']} "
                f"has {nt} frames {wt}x{ht}; rerender one of them"
            )
        records.append({
            "pair_id": s["pair_id"], "kind": "synthetic", "variant": "clean_buffers",
            "scene_id": s["scene_id"], "trajectory": s["trajectory"],
            "source_light": s["source_light"], "target_light": s["target_light"],
            "proxy": s["proxy"], "target": s["target"],
            "num_frames": np_, "width": wp, "height": hp, "split": s["split"],
        })
    return records
