#!/usr/bin/env python
"""Refined video vs PBR proxy alone, both against the target, on held-out pairs (thin entry point).

  evaluate_refiner.py --pairs PAIRS.jsonl --refined OUTDIR/manifest.json --out results/eval/{variant}/metrics.json

Metrics on display values in [0, 1] (io.linear_to_display, same exposure for all): per-frame PSNR
(dB) and SSIM averaged per video, then over pairs; mean temporal difference. LPIPS/CLIP only with
local weights (--lpips-weights / --clip-weights), else reported as skipped.
"""

import argparse
import sys
from pathlib import Path

import numpy as np

import _cli  # noqa: F401  (puts the repository on sys.path)

from lightcrafter.io import DataError, read_json, write_json
from lightcrafter.metrics import perceptual_metrics, temporal_difference, video_psnr_db, video_ssim
from lightcrafter.refiner.data import PairsDataset, load_frames, to_display_frames


def _disp(t):  # (3, N, H, W) in [-1, 1] -> (N, H, W, 3) in [0, 1]
    return to_display_frames(t)


def _mean_or_none(values):
    values = [v for v in values if v is not None]
    return float(np.mean(values)) if values else None


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
        refined = {e["pair_id"]: e for e in read_json(a.refined)["pairs"]}
        rows, skipped = [], []
        for i in range(len(ds)):
            item = ds[i]
            e = refined.get(item["pair_id"])
            if e is None:
                raise DataError(f"{a.refined}: no refined video for pair {item['pair_id']}; rerun inference")
            tgt, prx = _disp(item["target"]), _disp(item["proxy"])
            ref = _disp(load_frames(Path(e["frames"]), e["num_frames"], a.exposure_ev))
            _, skipped = perceptual_metrics(ref, tgt, a.lpips_weights, a.clip_weights)
            rows.append({
                "pair_id": item["pair_id"],
                "refined": {"psnr_db": video_psnr_db(ref, tgt), "ssim": video_ssim(ref, tgt),
                            "temporal_difference": float(temporal_difference(ref).mean()) if len(ref) > 1 else 0.0},
                "proxy": {"psnr_db": video_psnr_db(prx, tgt), "ssim": video_ssim(prx, tgt),
                          "temporal_difference": float(temporal_difference(prx).mean()) if len(prx) > 1 else 0.0},
                "target_temporal_difference": float(temporal_difference(tgt).mean()) if len(tgt) > 1 else 0.0,
                "ae_round_trip_psnr_db": e.get("ae_round_trip_psnr_db"),
            })
    except DataError as exc:
        print(f"evaluate_refiner: {exc}", file=sys.stderr)
        return 1
    summary = {
        m: {k: float(np.mean([r[m][k] for r in rows])) if rows else None for k in ("psnr_db", "ssim")}
        for m in ("refined", "proxy")
    }
    write_json(a.out, {"split": a.split, "num_pairs": len(rows), "display": {"exposure_ev": a.exposure_ev},
                       "mean": summary, "pairs": rows, "skipped_metrics": skipped,
                       "ae_round_trip_psnr_db_mean": _mean_or_none([r["ae_round_trip_psnr_db"] for r in rows])})
    print(f"evaluate_refiner: {len(rows)} pairs; refined {summary['refined']} vs proxy {summary['proxy']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
