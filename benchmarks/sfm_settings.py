"""Structure-from-motion settings of Phi against ground-truth cameras: registration, rotation error, seconds.

For every synthetic clip of one split of a finished run (results/) whose ground-truth camera moves, each
trial (``recon.sfm`` of the run's config with some keys replaced) runs
:func:`lightcrafter.recon.cameras.estimate_cameras` on the clip's source video (display frames, the video
Phi sees). Trials are interleaved per clip (A, B, C, A, B, C, ...) so that their seconds share the
machine's state. Per trial:

* ``registered_fraction``: registered frames over ALL moving-camera frames, a clip SfM rejects counting
  as 0 registered (the reconstruction issue's goal: >= 95 %);
* ``rotation_deg_median``: median over the clips SfM kept of each clip's median camera-orientation error
  (degrees) after the best rotation between the reconstruction's world and the ground truth's (SfM's
  world is an arbitrary similarity; rotation errors do not depend on its scale or origin);
* ``failed``: clips rejected (ReconstructionError), ``seconds``: total SfM time.

Choose settings on ``--split train`` (or the recon split), report the chosen ones on ``--split test``::

    .venv/bin/python benchmarks/sfm_settings.py --split train [--trials '{"up2": {"upscale": 2}}']

Writes results/bench/sfm_settings_<split>.json (the benchmark shape of docs/architecture.md).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lightcrafter import io  # noqa: E402
from lightcrafter.clip import read_clip  # noqa: E402
from lightcrafter.layout import Layout  # noqa: E402

DEFAULT_TRIALS = {
    "config": {},
    "upscale2": {"upscale": 2},
    "tri4_inl15": {"init_min_tri_angle_deg": 4.0, "abs_pose_min_num_inliers": 15},
    "upscale2_tri4_inl15": {"upscale": 2, "init_min_tri_angle_deg": 4.0, "abs_pose_min_num_inliers": 15},
}


def best_rotation(est_c2w: np.ndarray, gt_c2w: np.ndarray) -> np.ndarray:
    """The world rotation R (3x3) that best maps estimated camera orientations onto the ground truth's
    (R R_est ~ R_gt in the least-squares sense, over frames)."""
    from lightcrafter.recon.align import closest_rotation

    return closest_rotation(sum(g[:3, :3] @ e[:3, :3].T for e, g in zip(est_c2w, gt_c2w)))


def rotation_errors_deg(est_c2w: np.ndarray, gt_c2w: np.ndarray) -> np.ndarray:
    """Per-frame angle (degrees) between R R_est and R_gt, R from :func:`best_rotation`."""
    from lightcrafter.recon.evaluate import rotation_angle_deg

    R = best_rotation(est_c2w, gt_c2w)
    return np.array([rotation_angle_deg(R @ e[:3, :3], g[:3, :3]) for e, g in zip(est_c2w, gt_c2w)])


def summarize(rows: list[dict]) -> dict:
    """Per-trial figures over clips (see the module docstring)."""
    frames = sum(r["frames"] for r in rows)
    if frames == 0:
        raise ValueError("no moving-camera clips to score")
    kept = [r["rotation_deg"] for r in rows if r["rotation_deg"] is not None]
    return {"clips": len(rows), "failed": [r["clip"] for r in rows if r["rotation_deg"] is None],
            "registered_fraction": sum(r["registered"] for r in rows) / frames,
            "rotation_deg_median": float(np.median(kept)) if kept else None,
            "seconds": round(sum(r["seconds"] for r in rows), 2)}


def main() -> int:
    from lightcrafter.config import effective_config
    from lightcrafter.recon.cameras import ReconstructionError, SfMSettings, estimate_cameras
    from lightcrafter.recon.default import read_video_frames

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", type=Path, default=Path("results"))
    ap.add_argument("--config", type=Path, default=None, help="the run's config file (default: config/config.yaml)")
    ap.add_argument("--split", default="train")
    ap.add_argument("--trials", default=None, help="JSON {name: {recon.sfm key: value}} (default: "
                    + json.dumps(DEFAULT_TRIALS) + ")")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    cfg = effective_config([str(a.config)] if a.config else None)
    base = dict(cfg["recon"]["sfm"])
    fov_deg = cfg["recon"]["fov_x_deg"] or cfg["scenes"]["fov_x_deg"]
    trials = json.loads(a.trials) if a.trials else DEFAULT_TRIALS
    L = Layout(str(a.results))
    per_trial: dict[str, list[dict]] = {name: [] for name in trials}
    for spec, t in L.split_trajectories(a.split):
        sid, tid = spec["scene_id"], t["id"]
        gt, _ = read_clip(L.gt_clip(sid, tid))
        gt_c2w = np.stack([g.c2w for g in gt])
        if np.abs(gt_c2w - gt_c2w[0]).max() < 1e-9:
            continue  # static camera: nothing for SfM to register
        _, u8 = read_video_frames(L.gt_rgb(sid, tid, t["source_light"]))
        for name, over in trials.items():
            t0 = time.perf_counter()
            row = {"clip": f"{sid}_{tid}", "frames": len(u8)}
            try:
                track = estimate_cameras(u8, np.radians(fov_deg), SfMSettings(**{**base, **over}),
                                         name=f"{sid}_{tid}")
                row.update(registered=int(track.registered.sum()),
                           rotation_deg=float(np.median(rotation_errors_deg(track.c2w, gt_c2w))),
                           static_detected=bool(track.static))
            except ReconstructionError as exc:
                row.update(registered=0, rotation_deg=None, error=str(exc))
            row["seconds"] = round(time.perf_counter() - t0, 2)
            per_trial[name].append(row)
            rot = "failed" if row["rotation_deg"] is None else f"{row['rotation_deg']:.2f} deg"
            print(f"{row['clip']} {name}: {row['registered']}/{row['frames']} registered, {rot}, "
                  f"{row['seconds']:.1f} s", flush=True)
    if not any(per_trial.values()):
        raise SystemExit(f"error: no moving-camera {a.split} clips under {a.results}/scenes; run the default target "
                         "first (make run) or choose another --split")
    table = {name: summarize(rows) for name, rows in per_trial.items()}
    out = a.out or a.results / "bench" / f"sfm_settings_{a.split}.json"
    io.write_json(out, {
        "name": "sfm_settings", "varied": "recon.sfm settings", "metric": "rotation_deg_median",
        "higher_is_better": False, "split": a.split, "base": base, "fov_x_deg": fov_deg, "trials": trials,
        "machine": {"cores": os.cpu_count(), "platform": platform.platform()},
        "table": table, "per_clip": per_trial,
        "points": [{"series": "rotation_deg_median", "setting": n, "seconds": r["seconds"],
                    "value": r["rotation_deg_median"]} for n, r in table.items()],
    })
    print(f"\n{'trial':24s} {'registered':>10s} {'rot med deg':>11s} {'failed':>6s} {'seconds':>8s}")
    for n, r in table.items():
        rot = "-" if r["rotation_deg_median"] is None else f"{r['rotation_deg_median']:.2f}"
        print(f"{n:24s} {r['registered_fraction']:10.1%} {rot:>11s} {len(r['failed']):6d} {r['seconds']:8.1f}")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
