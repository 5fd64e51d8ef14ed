#!/usr/bin/env python
"""Ship the G-buffer estimator trained on config/estimator.yaml's set as the project's pretrained weights.

  ship_estimator.py --results ../estimator_run/results [--config config/estimator.yaml] [--check-frames 4]

Copies ``results/recon/estimator/model.pt`` to lightcrafter/recon/weights/gbuffer_estimator.pt and writes
beside it:

* ``gbuffer_estimator.json`` (provenance): the commit it was trained at, the config file and the
  estimator settings, data counts (scenes, clips, training and validation frames), the validation curve
  (errors against seconds of training) with the step kept, and the errors on the check set below;
* ``gbuffer_estimator_check.npz``: a few held-out validation frames (display RGB and ground-truth
  buffers, float16) on which tests/test_shipped_estimator.py recomputes those errors.
"""

from __future__ import annotations

import argparse
import hashlib
import shutil
import subprocess
from pathlib import Path

import _cli

from lightcrafter.io import DataError


def _commit() -> dict:
    def git(*args):
        return subprocess.run(["git", *args], cwd=_cli.REPO, capture_output=True, text=True).stdout

    dirty = [line[3:] for line in git("status", "--porcelain").splitlines() if line.strip()]
    return {"commit": git("rev-parse", "HEAD").strip() or None,
            "dirty_files": [f for f in dirty if not f.startswith("lightcrafter/recon/weights/")]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", type=Path, required=True, help="results/ of the config/estimator.yaml run")
    ap.add_argument("--config", type=Path, default=_cli.REPO / "config" / "estimator.yaml")
    ap.add_argument("--check-frames", type=int, default=4)
    a = ap.parse_args()
    import numpy as np
    import torch

    from lightcrafter import io
    from lightcrafter.clip import read_clip
    from lightcrafter.recon import estimator as est
    from lightcrafter.recon.weights import SHIPPED_PROVENANCE, SHIPPED_WEIGHTS, check_set_path

    model_file = a.results / "recon" / "estimator" / "model.pt"
    curve_file = a.results / "recon" / "estimator" / "curve.json"
    for f in (model_file, curve_file):
        if not f.is_file():
            raise DataError(f"{f} not found; run the config/estimator.yaml target first (see its header)")
    st = torch.load(model_file, map_location="cpu", weights_only=False)
    model = est.load(model_file)
    val_clip = Path(st["clips"][-1]) if Path(st["clips"][-1]).is_absolute() else a.results.parent / st["clips"][-1]
    views, _ = read_clip(val_clip.parent)
    spec_dir = val_clip.parent
    scene, traj = spec_dir.parent.name, spec_dir.name
    spec = io.read_json(a.results / "scenes" / scene / "scene.json")
    src = next(t for t in spec["trajectories"] if t["id"] == traj)["source_light"]
    samples = est.load_clip_samples(spec_dir, a.results / "gt" / scene / traj / "rgb" / src)
    pick = np.unique(np.linspace(0, len(samples) - 1, a.check_frames).round().astype(int))
    rgb = np.stack([samples[i].rgb.numpy().transpose(1, 2, 0) for i in pick])
    bufs = [views[i].buffers for i in pick]
    check = {"rgb": rgb.astype(np.float16), "c2w": np.stack([views[i].c2w for i in pick]).astype(np.float64)}
    for k in ("depth", "normal", "albedo", "roughness", "metallic", "mask"):
        check[k] = np.stack([np.where(np.isfinite(getattr(b, k)), getattr(b, k), 0.0) for b in bufs]).astype(np.float16)
    SHIPPED_WEIGHTS.parent.mkdir(parents=True, exist_ok=True)
    with io.atomic_path(check_set_path()) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **check)
    errors = est.check_set_errors(model, check_set_path())
    with io.atomic_path(SHIPPED_WEIGHTS) as tmp:
        shutil.copyfile(model_file, tmp)
    curve = io.read_json(curve_file)
    cfgtext = a.config.read_text()
    counts = {"train_frames": st.get("train_frames"), "val_frames": st.get("val_frames"), "clips": len(st["clips"]),
              "scenes": len({Path(c).parent.parent.name for c in st["clips"]}),
              "validation_clip": f"{scene}/{traj}", "check_frames": [int(i) for i in pick]}
    selected = next((p for p in curve["points"] if p["setting"] == curve["chosen"] and p["series"] == "normal_deg"), None)
    io.write_json(SHIPPED_PROVENANCE, {
        "format": "lightcrafter.estimator_provenance/1",
        "weights": SHIPPED_WEIGHTS.name, "sha256": hashlib.sha256(SHIPPED_WEIGHTS.read_bytes()).hexdigest(),
        "bytes": SHIPPED_WEIGHTS.stat().st_size,
        "parameters": int(sum(p.numel() for p in model.parameters())),
        **_commit(), "config_file": a.config.name, "config_text": cfgtext,
        "estimator": st["config"], "data": counts,
        "training_seconds": max(p["seconds"] for p in curve["points"]), "selected_step": curve["chosen"],
        "selected_validation_normal_deg": selected and selected["value"],
        "curve": curve["points"], "machine": curve.get("machine"),
        "check_set": check_set_path().name, "check_set_errors": errors,
        "rule": "train_gbuffer_estimator (workflow/rules/reconstruct.smk) under config/estimator.yaml",
    })
    print(f"ship_estimator: {SHIPPED_WEIGHTS} ({SHIPPED_WEIGHTS.stat().st_size / 1e6:.2f} MB), check-set errors "
          + " ".join(f"{k} {v:.4f}" for k, v in errors.items()))
    return 0


if __name__ == "__main__":
    _cli.run(main, "ship_estimator")
