"""Errors of G-buffer estimator weights on a finished run's ground-truth clips, per split.

Compares weights files (the shipped ones, an earlier shipped version from git, a file trained elsewhere) on the
same frames: every other frame of every trajectory of the run's scenes, from the trajectory's source-light
Cycles video (what Phi sees) against its ground-truth buffers. The ``train`` split's scenes are validation for
a choice between weights (the estimator never trains on them: its set is config/estimator.yaml's); the
``test`` split reports it. Errors as :func:`lightcrafter.recon.estimator.buffer_errors` (camera-space
normals rotated to world; depth after a per-frame median scale): albedo_psnr_db (linear, peak 1;
higher is better), normal_deg, depth_abs_rel, roughness_mae, metallic_mae, mask_iou.

    .venv/bin/python benchmarks/estimator_weights.py [--results results] \\
        [--weights shipped=shipped previous=git:2d477eb mine=path/to/model.pt]

``git:REV`` reads lightcrafter/recon/weights/gbuffer_estimator.pt at that revision. Writes
results/bench/estimator_weights.json (benchmark shape of docs/architecture.md; ``setting`` is the label, each
series a split and an error; plus a ``table``, so that the report's error-against-run-time section, which
skips benchmarks with tables, does not plot it) and prints the table.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from lightcrafter import io  # noqa: E402
from lightcrafter.layout import Layout  # noqa: E402

ERRORS = ("albedo_psnr_db", "normal_deg", "depth_abs_rel", "roughness_mae", "metallic_mae", "mask_iou")
SHIPPED_IN_GIT = "lightcrafter/recon/weights/gbuffer_estimator.pt"


def weights_file(spec: str, tmp: Path) -> Path:
    """The file a ``--weights`` value names: ``shipped``, ``git:REV`` (the shipped file at REV) or a path."""
    from lightcrafter.recon.weights import SHIPPED_WEIGHTS

    if spec == "shipped":
        return SHIPPED_WEIGHTS
    if spec.startswith("git:"):
        rev = spec[4:]
        res = subprocess.run(["git", "show", f"{rev}:{SHIPPED_IN_GIT}"], cwd=REPO, capture_output=True)
        if res.returncode:
            raise io.DataError(f"--weights {spec}: git has no {SHIPPED_IN_GIT} at {rev!r} "
                               f"({res.stderr.decode().strip().splitlines()[-1] if res.stderr else 'no output'}); "
                               "name a commit that shipped weights")
        out = tmp / f"{rev}.pt"
        out.write_bytes(res.stdout)
        return out
    return Path(spec)


def split_frames(results: Path, split: str) -> list[tuple[np.ndarray, io.Buffers, np.ndarray]]:
    """(display RGB, ground-truth buffers, c2w) of every other frame of the split's trajectories."""
    from lightcrafter.clip import read_clip
    from lightcrafter.recon import estimator as est

    frames = []
    for spec, t in Layout(str(results)).split_trajectories(split):
        clip = results / "gt" / spec["scene_id"] / t["id"]
        video = clip / "rgb" / t["source_light"]
        if not (clip / "buffers.json").is_file() or not video.is_dir():
            raise io.DataError(f"{clip}: ground truth not rendered; run `snakemake ground_truth` first")
        views, _ = read_clip(clip)
        samples = est.load_clip_samples(clip, video)
        frames += [(s.rgb.numpy().transpose(1, 2, 0), views[i].buffers, views[i].c2w)
                   for i, s in enumerate(samples)][::2]
    return frames


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", type=Path, default=REPO / "results")
    ap.add_argument("--weights", nargs="+", default=["shipped=shipped"], help="label=shipped|git:REV|path")
    ap.add_argument("--splits", nargs="+", default=["train", "test"])
    ap.add_argument("--out", type=Path, default=None, help="default: <results>/bench/estimator_weights.json")
    a = ap.parse_args(argv)
    import torch

    from lightcrafter.recon import estimator as est

    torch.set_num_threads(min(2, os.cpu_count() or 1))
    labels = {}
    for w in a.weights:
        label, sep, spec = w.partition("=")
        if not sep or not label or not spec:
            raise io.DataError(f"--weights {w!r}: expected label=shipped|git:REV|path")
        labels[label] = spec
    frames = {s: split_frames(a.results, s) for s in a.splits}
    for s, f in frames.items():
        if not f:
            raise io.DataError(f"{a.results}/scenes: no {s}-split scene with ground truth; pick --splits the run has")
    points, table = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for label, spec in labels.items():
            model = est.load(weights_file(spec, Path(tmp)))
            for split, val in frames.items():
                t0 = time.perf_counter()
                errs = est._validation_errors(model, val)
                sec = (time.perf_counter() - t0) / len(val)
                table.append((label, split, len(val), errs))
                points += [{"series": f"{split}_{k}", "setting": label, "seconds": round(sec, 4), "value": errs[k]}
                           for k in ERRORS]
    out = a.out or a.results / "bench" / "estimator_weights.json"
    io.write_json(out, {
        "name": "estimator_weights", "varied": "estimator weights (label: " + ", ".join(f"{k}={v}" for k, v in
                                                                              labels.items()) + ")",
        "metric": "train_albedo_psnr_db", "higher_is_better": True, "chosen": None,
        "machine": {"cores": os.cpu_count(), "platform": platform.platform()},
        "frames": {s: len(f) for s, f in frames.items()}, "points": points,
        "table": [{"weights": label, "split": split, "frames": n, **{k: errs[k] for k in ERRORS}}
                  for label, split, n, errs in table],
        "note": "train-split scenes are validation for a choice between weights, test-split scenes report it; "
                "seconds: estimator inference and scoring per frame; albedo_psnr_db and mask_iou are "
                "higher-is-better, the other errors lower-is-better"})
    print(f"{'weights':12s} {'split':6s} {'frames':>6s} " + " ".join(f"{k:>15s}" for k in ERRORS))
    for label, split, n, errs in table:
        print(f"{label:12s} {split:6s} {n:6d} " + " ".join(f"{errs[k]:15.3f}" for k in ERRORS))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except io.DataError as exc:
        print(f"estimator_weights: {exc}", file=sys.stderr)
        sys.exit(1)
