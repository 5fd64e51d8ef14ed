"""Cycles as reference: R rendered from ground-truth buffers vs the Cycles ground-truth frames.

Input is the pipeline's layout under ``--results`` (default ``results``)::

    scenes/{scene}/scene.json                        trajectory ``motion``: orbit_static | dynamic_moving |
                                                     static_rotating_light (anything else is kept as is)
    gt/{scene}/{traj}/buffers.json, cameras.json     ground-truth buffers
    gt/{scene}/{traj}/rgb/{light}.json               Cycles frames rgb/{light}/{frame:04d}.exr
    proxy_gt/{scene}/{traj}/{light}.json (optional)  R frames from rule render_proxy_gt; reused if present

For every (scene, trajectory, lighting) with Cycles frames, R renders the clip from the GT buffers
under the same lighting (``--spp``, visibility 'auto': aggregated for static scenes, per frame when objects move) unless rule render_proxy_gt already
did, and PSNR (dB, peak 1, on display values: lightcrafter.io.linear_to_display at 0 EV) is computed per
frame against Cycles. Output ``results/bench/proxy_vs_cycles.json`` (docs/architecture.md shape):
``points`` = one per motion config (setting = motion, seconds = R seconds per frame, value = mean PSNR),
``clips`` = per clip detail, ``speed_ratio`` copied from results/bench/proxy_spp.json.

What the gap is made of (R cannot model it; see ``gap_notes`` in the output): Cycles renders
``max_bounces`` of interreflection (R: direct light only, so R is darker in concave regions and
lacks colour bleeding), a 1.5 px Blackman-Harris pixel filter (R: 1 px box, pixel-aligned with the
buffers), Cycles' Principled BSDF (energy-conserving multiscatter GGX, Fresnel-weighted diffuse, F82
metals) vs the paper's Lambert + single-scatter Cook-Torrance, smooth true geometry vs per-pixel
quads (silhouettes, shadows from the view-aggregated mesh), and Monte Carlo noise of both at their spp.

    .venv/bin/python benchmarks/proxy_vs_cycles.py --results results
"""

from __future__ import annotations

import argparse
import csv
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lightcrafter import io  # noqa: E402
from lightcrafter.metrics import display_psnr_db  # noqa: E402


def find_clips(results: Path) -> list[tuple[str, str, str, Path]]:
    """(scene, traj, light, gt_dir) of every GT clip with Cycles frames and buffers."""
    out = []
    for bj in sorted(results.glob("gt/*/*/buffers.json")):
        gt = bj.parent
        for rj in sorted((gt / "rgb").glob("*.json")):
            out.append((gt.parent.name, gt.name, rj.stem, gt))
    return out


def cycles_job_seconds(logs: Path, scene: str, traj: str, light: str) -> float | None:
    """Wall seconds of the Snakemake render_rgb job (its benchmark TSV), if the pipeline wrote one."""
    tsv = logs / "benchmark" / "render_rgb" / f"{scene}_{traj}_{light}.tsv"
    if not tsv.is_file():
        return None
    rows = list(csv.DictReader(tsv.open(), delimiter="\t"))
    return float(rows[0]["s"]) if rows else None


def proxy_frames(results: Path, scene: str, traj: str, light: str, gt: Path, spp: int, visibility: str,
                 work: Path) -> tuple[list[np.ndarray], float, str]:
    """R frames of the clip and seconds per frame (reuses rule render_proxy_gt's output if present)."""
    man_path = results / "proxy_gt" / scene / traj / f"{light}.json"
    if man_path.is_file():
        man = io.read_json(man_path)
        frames = [io.read_rgb_exr(man_path.parent / f) for f in man["frames"]]
        sec = man.get("stats", {}).get("render_seconds")
        if sec and man.get("stats", {}).get("frames"):
            return frames, float(sec) / man["stats"]["frames"], "render_proxy_gt"
    from lightcrafter.proxy.clip import read_clip, render_views, resolve_visibility
    from lightcrafter.proxy.lighting import lighting_from_spec
    from lightcrafter.proxy.renderer import RenderSettings

    spec = io.read_json(results / "scenes" / scene / "scene.json")
    views, info = read_clip(gt)
    lighting = lighting_from_spec(spec, light, traj)
    settings = resolve_visibility(RenderSettings(spp=spp, visibility=visibility), info.scene_static, info.consistent_depth)
    t0 = time.perf_counter()
    frames, renderer, _ = render_views(views, lighting, settings, work / f"{scene}_{traj}_{light}")
    return frames, (time.perf_counter() - t0) / len(frames), "this benchmark"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", default="results")
    ap.add_argument("--logs", default="logs")
    ap.add_argument("--out", default=None, help="default: RESULTS/bench/proxy_vs_cycles.json")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--visibility", default="auto", choices=["auto", "aggregate", "frame", "primary", "none"])
    ap.add_argument("--threads", type=int, default=None)
    a = ap.parse_args()
    results = Path(a.results)
    out = Path(a.out or results / "bench" / "proxy_vs_cycles.json")
    if a.threads:
        import drjit as dr

        dr.set_thread_count(a.threads)
    clips = find_clips(results)
    if not clips:
        raise SystemExit(f"error: {results}/gt/*/*/buffers.json with rgb/*.json: no ground-truth clip found")
    rows = []
    with tempfile.TemporaryDirectory(prefix="lc_proxy_vs_cycles_") as tmp:
        for scene, traj, light, gt in clips:
            spec = io.read_json(results / "scenes" / scene / "scene.json")
            motion = next((t.get("motion", "unknown") for t in spec["trajectories"] if t["id"] == traj), "unknown")
            rgb_man = io.read_json(gt / "rgb" / f"{light}.json")
            cyc = [io.read_rgb_exr(gt / f) for f in rgb_man["frames"]]
            ours, sec, source = proxy_frames(results, scene, traj, light, gt, a.spp, a.visibility, Path(tmp))
            psnrs = [display_psnr_db(p, c) for p, c in zip(ours, cyc)]
            ratio = float(np.mean([p.mean() for p in ours]) / max(np.mean([c.mean() for c in cyc]), 1e-12))
            job = cycles_job_seconds(Path(a.logs), scene, traj, light)
            rows.append({"scene": scene, "trajectory": traj, "light": light, "motion": motion,
                         "frames": len(psnrs), "psnr_db_per_frame": [round(v, 3) for v in psnrs],
                         "psnr_db": round(float(np.mean(psnrs)), 3), "r_seconds_per_frame": round(sec, 4),
                         "r_source": source, "mean_radiance_ratio_r_over_cycles": round(ratio, 4),
                         "cycles_spp": rgb_man.get("render", {}).get("spp"),
                         "cycles_max_bounces": rgb_man.get("render", {}).get("max_bounces"),
                         "cycles_job_seconds_per_frame": None if job is None else round(job / len(psnrs), 3)})
            print(f"{scene}/{traj}/{light} ({motion}): {rows[-1]['psnr_db']:.2f} dB, R {sec:.3f} s/frame", flush=True)
    points = []
    for motion in sorted({r["motion"] for r in rows}):
        sel = [r for r in rows if r["motion"] == motion]
        points.append({"setting": motion, "seconds": round(float(np.mean([r["r_seconds_per_frame"] for r in sel])), 4),
                       "value": round(float(np.mean([r["psnr_db"] for r in sel])), 3), "clips": len(sel)})
    spp_bench = results / "bench" / "proxy_spp.json"
    speed = None
    if spp_bench.is_file():
        sb = io.read_json(spp_bench)
        speed = {"source": str(spp_bench), "at_equal_error": sb.get("speed_ratio_at_equal_error"),
                 "at_equal_noise": sb.get("speed_ratio_at_equal_noise")}
    jobs = [r["cycles_job_seconds_per_frame"] for r in rows if r["cycles_job_seconds_per_frame"]]
    result = {
        "name": "proxy_vs_cycles", "varied": "motion", "metric": "psnr_db", "higher_is_better": True,
        "machine": {"cores": os.cpu_count(), "platform": platform.platform()},
        "chosen": None, "points": points, "clips": rows,
        "r_settings": {"spp": a.spp, "visibility": a.visibility},
        "speed_ratio": speed,
        "seconds_per_frame": {
            "r_here": round(float(np.mean([r["r_seconds_per_frame"] for r in rows])), 4) if rows else None,
            "cycles_pipeline_jobs": round(float(np.mean(jobs)), 3) if jobs else None,
            "note": "measured in different runs (the pipeline's Cycles jobs, R here), so no ratio is formed: "
                    "speed_ratio is the interleaved one of results/bench/proxy_spp.json"},
        "gap_notes": ("R is direct lighting only (Cycles: max_bounces interreflection), 1 px box vs 1.5 px "
                      "Blackman-Harris filter, paper BRDF vs Cycles Principled (energy-conserving, multiscatter), "
                      "per-pixel quads vs true geometry, MC noise of both; PSNR on display values."),
    }
    io.write_json(out, result)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
