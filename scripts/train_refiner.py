#!/usr/bin/env python
"""Train the refiner on the train split of a pairs manifest (thin entry point).

  train_refiner.py --pairs results/datasets/clean_buffers/pairs.jsonl --config-json '{"preset": "tiny"}' --out DIR

Writes DIR/model.pt (final weights + config), DIR/checkpoints/ (resumable), DIR/train.log,
DIR/loss_curve.json. Rerunning after a kill resumes from the last checkpoint.
"""

import argparse
import json
import sys

import torch

import _cli  # noqa: F401  (puts the repository on sys.path)

from lightcrafter.io import DataError
from lightcrafter.refiner import MissingWeightsError, PairsDataset, resolve_config, train


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pairs", required=True)
    ap.add_argument("--config-json", default="{}")
    ap.add_argument("--out", required=True)
    ap.add_argument("--threads", type=int, default=None)
    a = ap.parse_args()
    if a.threads:
        torch.set_num_threads(a.threads)
    try:
        cfg = resolve_config(json.loads(a.config_json))
        ds = PairsDataset(a.pairs, "train", cfg["data"]["exposure_ev"], limit=cfg["data"]["max_train_pairs"],
                          cache=cfg["data"]["cache_pixels"])
        if len(ds) == 0:
            raise DataError(f"{a.pairs}: no pairs with split == 'train'")
        res = train(cfg, ds, a.out)
    except (DataError, MissingWeightsError, KeyError, ValueError) as exc:
        print(f"train_refiner: {exc}", file=sys.stderr)
        return 1
    print(f"train_refiner: {res['step']} steps, final loss {res['losses'][-1]:.4f}, "
          f"{res['seconds_per_step']:.3f} s/optimizer step -> {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
