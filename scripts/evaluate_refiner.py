#!/usr/bin/env python
"""Score every method on a held-out benchmark against its targets (thin entry point over
lightcrafter.protocol.evaluate_benchmark, the protocol, and lightcrafter.evaluation, the metrics).

  evaluate_refiner.py --pairs results/benchmarks/synthetic/pairs.jsonl --refined OUTDIR/manifest.json \
      --out results/eval/{variant}/synthetic/metrics.json [--lpips-weights DIR] [--clip-weights DIR] \
      [--external-dir DIR]

Methods: ``proxy`` (the PBR proxy from Phi buffers), ``oracle_proxy`` (R on ground-truth buffers, where the
benchmark has it), ``refined`` (the refiner with the settings chosen on validation), the baselines the
inference manifest lists (``regressor``, ``affine_colour``), and any external method whose outputs are
dropped into ``--external-dir`` in the benchmark's layout::

    {external_dir}/{method}/{pair_id}/{frame:04d}.exr     linear RGB, the target's size and frame count
    (or .png, display sRGB 8-bit)

Metrics (lightcrafter.evaluation, display values in [0, 1], exposure --exposure-ev for all): PSNR, SSIM and
LPIPS frame-wise, averaged per clip; Warp-SSIM (DIS flow of the target applied to the method's video,
occlusions masked); T-CLIP. LPIPS and T-CLIP load weights only from the given local folders and are
reported "not computed: <reason>" otherwise. Per method: the mean over clips with a 95 % percentile-
bootstrap interval over clips (``ci``), and (``vs_proxy``) the paired difference to the proxy with its
interval.
"""

import argparse

import _cli  # puts the repository on sys.path; run() is the one error path

from lightcrafter.io import DataError, write_json
from lightcrafter.protocol import evaluate_benchmark


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pairs", required=True)
    ap.add_argument("--refined", required=True)
    ap.add_argument("--split", default="test")
    ap.add_argument("--exposure-ev", type=float, default=0.0)
    ap.add_argument("--lpips-weights", default=None)
    ap.add_argument("--clip-weights", default=None)
    ap.add_argument("--external-dir", default=None)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    result = evaluate_benchmark(a.pairs, a.refined, a.split, a.exposure_ev, a.lpips_weights, a.clip_weights,
                                a.external_dir)
    write_json(a.out, result)
    mean = result["mean"]
    line = "; ".join(f"{m} {mean[m]['psnr_db']:.2f} dB / SSIM {mean[m]['ssim']:.3f}" for m in result["methods"]
                     if mean[m]["psnr_db"] is not None)
    print(f"evaluate_refiner: {result['num_pairs']} pairs; {line}")
    return 0


if __name__ == "__main__":
    _cli.run(main, "evaluate_refiner", (DataError, ValueError))
