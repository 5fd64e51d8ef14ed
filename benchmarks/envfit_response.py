"""The camera response of the envmap fit (``envfit.fit_response``): what it gains, on real clips and on a control.

For every real clip of a finished run (results/recon/real/*, the video's linear frames results/real/*/rgb)
and, as a control, every synthetic clip of one split (Phi's reconstruction of the trajectory and its
source-light Cycles video, which has no camera curve), it fits the map with the run's ``envfit`` settings
and ``fit_response`` off, renders the pseudo-input, then fits the response on the fitted frames
(:func:`lightcrafter.envfit.fit.fit_camera_response`, what ``fit_response: true`` does) and applies it to
the same frames. Per clip: the pseudo-input's display PSNR against the video (dB, mean over all frames)
without and with the response, the fitted gamma and channel gains, and seconds. The real clips of the
run's train split choose the setting; those of the test split report it.

    .venv/bin/python benchmarks/envfit_response.py --results results [--split train]

Writes results/bench/envfit_response.json (the benchmark shape of docs/architecture.md: a point per group of
clips, ``real:train``, ``real:test``, ``synthetic control:<split>``, and setting, off or on).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lightcrafter import io  # noqa: E402
from lightcrafter.layout import Layout  # noqa: E402


def score(clip_dir: Path, frames_dir: Path, settings, render, tmp: Path) -> dict:
    """Fit without the response, then fit and apply it to the same pseudo-input frames."""
    from lightcrafter.envfit.fit import fit_camera_response, fit_envmap, prepare
    from lightcrafter.metrics import display_psnr_db

    t0 = time.perf_counter()
    m = fit_envmap(clip_dir, frames_dir, tmp, replace(settings, fit_response=False), render)
    fit_seconds = time.perf_counter() - t0
    problem = prepare(clip_dir, frames_dir, settings, render)
    response, stats = fit_camera_response(problem, tmp / "lighting.json", settings.seed)
    pseudo = [io.read_rgb_exr(tmp / f) for f in io.read_json(tmp / "pseudo.json")["frames"]]
    video = problem.video.frames
    with_response = [display_psnr_db(response.apply(p), v) for p, v in zip(pseudo, video)]
    return {"psnr_db_without": round(m["pseudo_psnr_db"]["mean"], 3),
            "psnr_db_with": round(float(np.mean(np.minimum(with_response, 100.0))), 3),
            "gamma": round(response.gamma, 4), "gain_rgb": [round(g, 4) for g in response.gain_rgb],
            "fit_seconds": round(fit_seconds, 2), "response_seconds": stats["seconds"]}


def main(argv: list[str] | None = None) -> int:
    from lightcrafter.config import effective_config
    from lightcrafter.config.models import Envfit
    from lightcrafter.clip import is_skipped
    from lightcrafter.envfit.fit import FitSettings
    from lightcrafter.ingest import real_clips
    from lightcrafter.proxy import render_settings

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", type=Path, default=Path("results"))
    ap.add_argument("--config", type=Path, default=None, help="the run's config file (default: config/config.yaml)")
    ap.add_argument("--split", default="train", help="split of the synthetic control clips")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args(argv)
    cfg = effective_config([str(a.config)] if a.config else None)
    fit = Envfit(**cfg["envfit"]).model_dump()
    settings = FitSettings(**{k: tuple(v) if k == "betas" else v for k, v in fit.items()}, threads=a.threads)
    render = render_settings(cfg["proxy"])
    L = Layout(str(a.results))
    real_split = {cid: c["split"] for cid, c in real_clips(cfg["real"], seed=cfg["seed"]).items()}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for clip_dir in sorted(Path(a.results, "recon", "real").glob("*/buffers.json")):
            name = clip_dir.parent.name
            if is_skipped(clip_dir.parent):
                continue
            row = {"clip": name, "kind": "real", "split": real_split.get(name)}
            row.update(score(clip_dir.parent, Path(L.real_frames(name)), settings, render, Path(tmp) / name))
            rows.append(row)
            print(row, flush=True)
        for spec, t in L.split_trajectories(a.split):
            sid, tid = spec["scene_id"], t["id"]
            clip = Path(L.recon_clip("synthetic", f"{sid}_{tid}"))
            if not (clip / "buffers.json").is_file() or is_skipped(clip):
                continue
            row = {"clip": f"{sid}_{tid}_{t['source_light']}", "kind": "synthetic control", "split": a.split}
            row.update(score(clip, Path(L.gt_rgb(sid, tid, t["source_light"])), settings, render,
                             Path(tmp) / row["clip"]))
            rows.append(row)
            print(row, flush=True)
    if not rows:
        raise SystemExit(f"error: {a.results} has no real clip and no {a.split} synthetic clip; run the pipeline first")
    summary = {}
    for kind in sorted({(r["kind"], r["split"]) for r in rows}, key=str):
        sel = [r for r in rows if (r["kind"], r["split"]) == kind]
        summary[f"{kind[0]}:{kind[1]}"] = {
            "clips": len(sel), "psnr_db_without_mean": round(float(np.mean([r["psnr_db_without"] for r in sel])), 3),
            "psnr_db_with_mean": round(float(np.mean([r["psnr_db_with"] for r in sel])), 3),
            "gamma_range": [min(r["gamma"] for r in sel), max(r["gamma"] for r in sel)],
            "seconds_without": round(sum(r["fit_seconds"] for r in sel), 2),
            "seconds_with": round(sum(r["fit_seconds"] + r["response_seconds"] for r in sel), 2)}
    points = [{"series": group, "setting": setting, "seconds": v[f"seconds_{key}"], "value": v[f"psnr_db_{key}_mean"]}
              for group, v in summary.items() for setting, key in (("off", "without"), ("on", "with"))]
    out = a.out or Path(a.results, "bench", "envfit_response.json")
    io.write_json(out, {"name": "envfit_response", "varied": "envfit.fit_response", "metric": "psnr_db",
                        "higher_is_better": True, "chosen": "on" if settings.fit_response else "off",
                        "machine": {"cores": os.cpu_count(), "platform": platform.platform()},
                        "units": {"psnr_db": "display PSNR of the pseudo-input against the video, dB (mean over a "
                                             "group's clips)",
                                  "seconds": "the envmap fits' seconds summed over a group's clips (with: the "
                                             "curve's too)",
                                  "gamma": "unitless, out = gain * x ** gamma on linear RGB"},
                        "points": points, "clips": rows, "summary": summary})
    for k, v in summary.items():
        print(f"{k:28s} {v['clips']} clips: {v['psnr_db_without_mean']:.2f} -> {v['psnr_db_with_mean']:.2f} dB, "
              f"gamma {v['gamma_range'][0]:.2f}-{v['gamma_range'][1]:.2f}")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
