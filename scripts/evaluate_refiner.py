#!/usr/bin/env python
"""Refined video, its baselines and the PBR proxy alone, all against the target, on held-out pairs
(thin entry point).

  evaluate_refiner.py --pairs PAIRS.jsonl --refined OUTDIR/manifest.json --out results/eval/{variant}/metrics.json

Methods: ``proxy`` (the PBR proxy alone), ``refined`` (the refiner with the settings chosen on
validation), and every baseline the inference manifest lists (``regressor``: the same network as a
one-step deterministic regressor; ``affine_colour``: per-channel affine colour fit on the training
pairs). Metrics on display values in [0, 1] (io.linear_to_display, same exposure for all): per-frame
PSNR (dB) and SSIM averaged per video, then over pairs; mean temporal difference. ``vs_proxy``: per
method, the mean over pairs of (method - proxy) with a 95% percentile-bootstrap interval over pairs.
LPIPS/CLIP only with local weights (--lpips-weights / --clip-weights), else reported as skipped.
"""

import argparse
import sys
from pathlib import Path

import numpy as np

import _cli  # noqa: F401  (puts the repository on sys.path)

from lightcrafter.io import DataError, read_json, write_json
from lightcrafter.metrics import perceptual_metrics, temporal_difference, video_psnr_db, video_ssim
from lightcrafter.refiner.data import PairsDataset, load_frames, to_display_frames
from lightcrafter.refiner.scoring import bootstrap_mean_ci

METRICS = ("psnr_db", "ssim")


def _disp(t):  # (3, N, H, W) in [-1, 1] -> (N, H, W, 3) in [0, 1]
    return to_display_frames(t)


def _mean_or_none(values):
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else None


def _scores(video, tgt) -> dict:
    return {"psnr_db": video_psnr_db(video, tgt), "ssim": video_ssim(video, tgt),
            "temporal_difference": float(temporal_difference(video).mean()) if len(video) > 1 else 0.0}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pairs", required=True)
    ap.add_argument("--refined", required=True)
    ap.add_argument("--split", default="test")
    ap.add_argument("--exposure-ev", type=float, default=0.0)
    ap.add_argument("--lpips-weights", default=None)
    ap.add_argument("--clip-weights", default=None)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    try:
        ds = PairsDataset(a.pairs, a.split, a.exposure_ev, cache=False)
        manifest = read_json(a.refined)
        refined = {e["pair_id"]: e for e in manifest["pairs"]}
        rows, skipped, methods = [], [], ["proxy", "refined"]
        for i in range(len(ds)):
            item = ds[i]
            e = refined.get(item["pair_id"])
            if e is None:
                raise DataError(f"{a.refined}: no refined video for pair {item['pair_id']}; rerun inference")
            tgt, prx = _disp(item["target"]), _disp(item["proxy"])
            ref = _disp(load_frames(Path(e["frames"]), e["num_frames"], a.exposure_ev))
            _, skipped = perceptual_metrics(ref, tgt, a.lpips_weights, a.clip_weights)
            row = {"pair_id": item["pair_id"], "refined": _scores(ref, tgt), "proxy": _scores(prx, tgt),
                   "target_temporal_difference": float(temporal_difference(tgt).mean()) if len(tgt) > 1 else 0.0,
                   "ae_round_trip_psnr_db": e.get("ae_round_trip_psnr_db"),
                   "ae_round_trip_proxy_psnr_db": e.get("ae_round_trip_proxy_psnr_db")}
            for name, b in sorted((e.get("baselines") or {}).items()):
                row[name] = _scores(_disp(load_frames(Path(b["frames"]), b["num_frames"], a.exposure_ev)), tgt)
                if name not in methods:
                    methods.append(name)
            rows.append(row)
        missing = [m for m in methods if any(m not in r for r in rows)]
        if missing:
            raise DataError(f"{a.refined}: baselines {missing} exist for some pairs only; rerun inference")
    except DataError as exc:
        print(f"evaluate_refiner: {exc}", file=sys.stderr)
        return 1
    summary = {m: {k: float(np.mean([r[m][k] for r in rows])) if rows else None for k in (*METRICS, "temporal_difference")}
               for m in methods}
    vs_proxy = {}
    if rows:
        for m in methods:
            if m != "proxy":
                vs_proxy[m] = {k: bootstrap_mean_ci([r[m][k] - r["proxy"][k] for r in rows]) for k in METRICS}
    write_json(a.out, {"split": a.split, "num_pairs": len(rows), "display": {"exposure_ev": a.exposure_ev},
                       "methods": methods, "mean": summary, "vs_proxy": vs_proxy, "pairs": rows,
                       "inference": {"infer": manifest.get("infer"), "selection": manifest.get("selection")},
                       "skipped_metrics": skipped,
                       "ae_round_trip_psnr_db_mean": _mean_or_none([r["ae_round_trip_psnr_db"] for r in rows]),
                       "ae_round_trip_proxy_psnr_db_mean": _mean_or_none([r["ae_round_trip_proxy_psnr_db"] for r in rows])})
    line = "; ".join(f"{m} {summary[m]['psnr_db']:.2f} dB / SSIM {summary[m]['ssim']:.3f}" for m in methods) if rows else ""
    print(f"evaluate_refiner: {len(rows)} pairs; {line}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
