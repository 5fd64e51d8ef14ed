#!/usr/bin/env python
"""Train the refiner on the train split of a pairs manifest (thin entry point over
lightcrafter.refiner.fit.fit_refiner: validation carve-out, training, selection, baselines).

  train_refiner.py --pairs results/datasets/clean_buffers/pairs.jsonl --config-json '{"preset": "tiny"}' --out DIR

Writes DIR/model.pt last (chosen weights, config with the inference settings chosen on validation,
selection table, baselines), DIR/selection.json (the same summary, readable), DIR/checkpoints/
(resumable), DIR/candidates/, DIR/regressor/, DIR/train.log, DIR/loss_curve.json. Rerunning after a
kill resumes from the last checkpoint.
"""

import argparse
import json
from pathlib import Path

import torch

import _cli  # puts the repository on sys.path; run() is the one error path

from lightcrafter.io import DataError, write_json
from lightcrafter.refiner import MissingWeightsError, resolve_config
from lightcrafter.refiner.fit import fit_refiner
from lightcrafter.refiner.training import _logger


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pairs", required=True)
    ap.add_argument("--config-json", default="{}")
    ap.add_argument("--out", required=True)
    ap.add_argument("--threads", type=int, default=None)
    a = ap.parse_args()
    if a.threads:
        torch.set_num_threads(a.threads)
    cfg = resolve_config(_cli.json_arg(a.config_json))
    from lightcrafter.devices import resolve_device

    resolve_device(cfg["device"], "refiner.device")  # a GPU job on a node without one stops here, at once
    Path(a.out).mkdir(parents=True, exist_ok=True)
    res = fit_refiner(cfg, a.pairs, a.out, log=_logger(Path(a.out)))
    if "rank" in res:  # a non-zero rank of data-parallel training: rank 0 writes the outputs
        return 0
    write_json(Path(a.out) / "selection.json", res)
    tr, chosen = res["train"], res["selection"]["chosen"]
    print(f"train_refiner: {tr['steps']} steps ({tr['seconds_per_step']:.3f} s/optimizer step); "
          f"{res['selection']['note']}; chosen {chosen} -> {a.out}")
    return 0


if __name__ == "__main__":
    _cli.run(main, "train_refiner", (DataError, MissingWeightsError, KeyError, ValueError))
