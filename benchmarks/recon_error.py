"""Error against run time of the reconstruction stack Phi (default backend).

Reads the default run (results/: the estimator and its training curve, the test and train clips) and writes
results/bench/recon_error.json (shape of docs/architecture.md) with series:

* ``estimator_normal_deg`` / ``estimator_depth_abs_rel``: the G-buffer estimator's validation errors against
  seconds of training (the curve its training rule recorded), so a user can pick its budget;
* ``normals_predicted`` / ``normals_from_depth``: Phi's normal error (degrees, after Align) with the
  estimator's normals or normals derived from its depth, against Phi's seconds per frame: the
  ``*_validation`` series on train-split clips choose the option (``chosen``), the others report it on the
  held-out test clips;
* ``phi_seconds_per_frame``: Phi's seconds per frame at the default resolution (the run's clips) and at the
  paper's 720x480 on a 49-frame orbit rendered by R from analytic buffers of textured spheres on a
  checker ground (structure from motion + estimator inference; the value is the estimator's normal error
  on that clip, whose ground truth is exact).

    .venv/bin/python benchmarks/recon_error.py [--results results] [--skip-paper-size]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lightcrafter import clip as clipmod  # noqa: E402
from lightcrafter import io  # noqa: E402
from lightcrafter.layout import Layout  # noqa: E402

ESTIMATOR = None  # the weights file of the run's config (recon.estimator.weights), set by main()


def _phi_errors(results: Path, normals: str, clips: list[tuple[str, str, str]], work: Path) -> tuple[float, float]:
    """Mean normal error (deg) over clips and Phi seconds per frame with the given normals option."""
    from lightcrafter.recon.align import align_clip
    from lightcrafter.recon.cameras import ReconstructionError
    from lightcrafter.recon.default import DefaultSettings, reconstruct_default
    from lightcrafter.recon.evaluate import clip_errors

    L = Layout(str(results))
    errs, secs, frames = [], 0.0, 0
    for scene, traj, src in clips:
        est, al = work / normals / f"{scene}_{traj}", work / normals / f"{scene}_{traj}_aligned"
        t0 = time.perf_counter()
        try:
            m = reconstruct_default(Path(L.gt_rgb(scene, traj, src)), est, estimator_path=ESTIMATOR, fps=24,
                                    scene_static=True, settings=DefaultSettings(normals=normals, fov_x_deg=50.0))
        except ReconstructionError:
            continue
        secs += time.perf_counter() - t0
        frames += m["num_frames"]
        align_clip(est, L.gt_clip(scene, traj), al)
        errs.append(clip_errors(est, al, L.gt_clip(scene, traj))["normal_deg"])
    return float(np.mean(errs)) if errs else float("nan"), secs / max(frames, 1)


def _paper_size_clip(work: Path, width=720, height=480, n=49, spp=4):
    """A 49-frame orbit at 720x480 rendered by R from exact buffers of textured spheres on a checker ground."""
    from lightcrafter.clip import FrameView
    from lightcrafter.proxy import synthetic as syn
    from lightcrafter.proxy.lighting import Lighting
    from lightcrafter.proxy.renderer import ProxyRenderer, RenderSettings

    K = syn.intrinsics(width, height, np.radians(50))
    spheres = [syn.Sphere((0.6 * np.cos(a), 0.6 * np.sin(a), 0.3), 0.3, albedo=c)
               for a, c in zip((0, 2.1, 4.2), ((0.8, 0.2, 0.2), (0.2, 0.7, 0.2), (0.2, 0.3, 0.8)))]
    env = np.ones((32, 64, 3), np.float32)
    env[:12] *= 2.0
    r = ProxyRenderer(Lighting(env=env), RenderSettings(spp=spp, visibility="frame"))
    views, frames = [], []
    for i in range(n):
        a = np.radians(i)  # 1 degree per frame, the paper's orbit
        c2w = syn.look_at([4 * np.cos(a), 4 * np.sin(a), 2.0], [0, 0, 0.2])
        b = syn.raycast_buffers(K, c2w, width, height, spheres, syn.Ground(half_size_m=8))
        P = np.nan_to_num(__import__("lightcrafter.proxy.geometry", fromlist=["unproject"]).unproject(b.depth, K, c2w))
        checker = ((np.floor(P[..., 0] / 0.25) + np.floor(P[..., 1] / 0.25)) % 2)[..., None]
        ground = (b.normal[..., 2:] > 0.99) & (P[..., 2:] < 1e-3)
        b.albedo = np.where(ground, 0.15 + 0.6 * checker, b.albedo).astype(np.float32)
        views.append(FrameView(b, K, c2w, f"f{i}"))
        frames.append(r.render(views[-1], i))
    for i, f in enumerate(frames):
        io.write_rgb_exr(work / "paper_video" / f"{i:04d}.exr", f)
    return views


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", type=Path, default=Path("results"))
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--skip-paper-size", action="store_true")
    ap.add_argument("--config", type=Path, default=None, help="the run's config file (default: config/config.yaml)")
    a = ap.parse_args()
    L = Layout(str(a.results))
    out = a.out or a.results / "bench" / "recon_error.json"
    global ESTIMATOR
    from lightcrafter.config import effective_config
    from lightcrafter.recon.weights import weights_path

    cfg = effective_config([str(a.config)] if a.config else None)
    ESTIMATOR = weights_path(cfg["recon"]["estimator"]["weights"], L.estimator())
    if not Path(ESTIMATOR).is_file():
        raise SystemExit(f"error: {ESTIMATOR} not found; run `snakemake results/summary/reconstruction.json` first")
    summary = io.read_json(L.summary("reconstruction"))
    points = []
    w = cfg["recon"]["estimator"]["weights"]
    from lightcrafter.recon.weights import SHIPPED_PROVENANCE, member_records

    # the estimator's training curves: this run's, or each shipped member's (an ensemble's second member on
    # series ending in _member1, ...)
    curves = [io.read_json(L.estimator_curve())["points"]] if w == "train" else \
        [r["curve"] for r in member_records(io.read_json(SHIPPED_PROVENANCE))] if w == "shipped" else []
    for i, curve in enumerate(curves):
        for p in curve:
            if p["series"] in ("normal_deg", "depth_abs_rel"):
                points.append({**p, "series": f"estimator_{p['series']}" + (f"_member{i}" if i else "")})
    clips = {"validation": [], "test": []}  # Phi's settings are chosen on train-split clips, reported on test
    for cid, e in summary["per_clip"].items():
        split = {"train": "validation", "test": "test"}.get(e.get("split"))
        if split and "skipped" not in e:
            scene, traj = cid.split("_")
            spec = io.read_json(L.scene_spec(scene))
            t = next(t for t in spec["trajectories"] if t["id"] == traj)
            clips[split].append((scene, traj, t["source_light"]))
    chosen_by = {}
    with tempfile.TemporaryDirectory(prefix="lc_recon_bench_") as tmp:
        work = Path(tmp)
        for split in ("validation", "test"):
            for normals in ("predicted", "depth"):
                err, spf = _phi_errors(a.results, normals, clips[split], work / split)
                series = f"normals_{'from_depth' if normals == 'depth' else 'predicted'}" + \
                    ("_validation" if split == "validation" else "")
                points.append({"series": series, "setting": normals, "seconds": round(spf, 4), "value": round(err, 3)})
                if split == "validation":
                    chosen_by[normals] = err
                print(f"{split} clips ({len(clips[split])}), normals {normals}: {err:.2f} deg, {spf:.3f} s/frame",
                      flush=True)
        if summary.get("seconds_per_frame"):
            points.append({"series": "phi_seconds_per_frame", "setting": "default run",
                           "seconds": round(summary["seconds_per_frame"], 4),
                           "value": round(summary["by_motion"]["all"]["normal_deg"], 3)})
        paper = None
        if not a.skip_paper_size:
            from lightcrafter.recon.default import DefaultSettings, reconstruct_default
            from lightcrafter.recon.estimator import buffer_errors

            views = _paper_size_clip(work)
            t0 = time.perf_counter()
            m = reconstruct_default(work / "paper_video", work / "paper_clip", estimator_path=ESTIMATOR, fps=24,
                                    scene_static=True, settings=DefaultSettings(fov_x_deg=50.0))
            spf = (time.perf_counter() - t0) / m["num_frames"]
            est_views, _ = clipmod.read_clip(work / "paper_clip")
            iou = np.mean([buffer_errors({"depth": e.buffers.depth, "normal": e.buffers.normal, "albedo": e.buffers.albedo,
                                          "roughness": e.buffers.roughness, "metallic": e.buffers.metallic,
                                          "mask": e.buffers.mask}, g.buffers, None)["mask_iou"]
                           for e, g in zip(est_views, views)])
            paper = {"seconds_per_frame": spf, "registered": m["phi"].get("registered"), "frames": m["num_frames"],
                     "camera_method": m["phi"].get("method"), "mask_iou": float(iou)}
            points.append({"series": "phi_seconds_per_frame", "setting": "720x480x49", "seconds": round(spf, 4),
                           "value": None})
            print(f"paper size: {spf:.2f} s/frame, registered {paper['registered']}/{paper['frames']}", flush=True)
    finite = {k: v for k, v in chosen_by.items() if np.isfinite(v)}
    chosen = min(finite, key=finite.get) if finite else "predicted"
    io.write_json(out, {
        "name": "recon_error", "varied": "estimator training time; normals source; resolution",
        "metric": "normal_deg", "higher_is_better": False,
        "machine": {"cores": os.cpu_count(), "platform": platform.platform()},
        "chosen": chosen, "chosen_series": f"normals_{'predicted' if chosen == 'predicted' else 'from_depth'}_validation",
        "points": points, "paper_size": paper, "by_motion": summary["by_motion"],
        "moving_camera_frames_registered": summary.get("moving_camera_frames_registered_incl_skipped"),
        "note": "normals option chosen on train-split clips (*_validation series), reported on held-out test clips, "
                "after Align; estimator curve on held-out recon-split clips",
    })
    print(f"wrote {out}; better normals: {chosen}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
