#!/usr/bin/env python
"""Ship the G-buffer estimator trained on config/estimator.yaml's set as the project's pretrained weights.

  ship_estimator.py --results ../estimator_run/results [--config config/estimator.yaml] [--check-frames 4]
  ship_estimator.py --add-member --results ../estimator_seed1_run/results --config config/estimator_seed1.yaml

Copies ``results/recon/estimator/model.pt`` to lightcrafter/recon/weights/gbuffer_estimator.pt and writes
beside it:

* ``gbuffer_estimator.json`` (provenance): the commit it was trained at, the config file and the
  estimator settings, data counts (scenes, clips, training and validation frames), the validation curve
  (errors against seconds of training) with the step kept, and the errors on the check set below;
* ``gbuffer_estimator_check.npz``: a few held-out validation frames (display RGB and ground-truth
  buffers, float16) on which tests/test_shipped_estimator.py recomputes those errors.

``--add-member`` keeps the shipped weights and adds the run's model as one more member of an ensemble
(:class:`lightcrafter.recon.estimator.EstimatorEnsemble`, whose predictions are averaged; a run of the same set
under another seed, e.g. ``config/estimator_seed1.yaml``): the file becomes an ensemble file, the provenance lists
every member's record under ``members`` (each with its own check-set errors) and records the ensemble's errors on
the shipped check set, which stays as it was.
"""

from __future__ import annotations

import argparse
import hashlib
import shutil
import subprocess
from pathlib import Path

import _cli

from lightcrafter.io import DataError

#: provenance keys of the shipped file alone (a member record keeps the others: its own parameters and errors)
HEAD_KEYS = ("format", "weights", "sha256", "bytes", "check_set")


def _commit() -> dict:
    def git(*args):
        return subprocess.run(["git", *args], cwd=_cli.REPO, capture_output=True, text=True).stdout

    dirty = [line[3:] for line in git("status", "--porcelain").splitlines() if line.strip()]
    return {"commit": git("rev-parse", "HEAD").strip() or None,
            "dirty_files": [f for f in dirty if not f.startswith("lightcrafter/recon/weights/")]}


def _data_counts(a, st) -> dict:
    """Data counts of a provenance record: frames, clips, scenes and the validation clip of the run."""
    val_clip = Path(st["clips"][-1]) if Path(st["clips"][-1]).is_absolute() else a.results.parent / st["clips"][-1]
    return {"train_frames": st.get("train_frames"), "val_frames": st.get("val_frames"), "clips": len(st["clips"]),
            "scenes": len({Path(c).parent.parent.name for c in st["clips"]}),
            "validation_clip": f"{val_clip.parent.parent.name}/{val_clip.parent.name}"}


def _write_check_set(a, validation_clip: str) -> list[int]:
    """Write the check set (``a.check_frames`` frames of the run's validation clip, "scene/trajectory") beside
    the weights; returns the frame indices."""
    import numpy as np

    from lightcrafter import io
    from lightcrafter.clip import read_clip
    from lightcrafter.recon import estimator as est
    from lightcrafter.recon.weights import SHIPPED_WEIGHTS, check_set_path

    scene, traj = validation_clip.split("/")
    spec_dir = a.results / "gt" / scene / traj
    views, _ = read_clip(spec_dir)
    spec = io.read_json(a.results / "scenes" / scene / "scene.json")
    src = next(t for t in spec["trajectories"] if t["id"] == traj)["source_light"]
    samples = est.load_clip_samples(spec_dir, spec_dir / "rgb" / src)
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
    return [int(i) for i in pick]


def _record(a, st, model, counts: dict, curve_file: Path, errors: dict) -> dict:
    """One trained network's provenance: commit, config, data counts, curve, its own check-set errors."""
    from lightcrafter import io

    curve = io.read_json(curve_file)
    selected = next((p for p in curve["points"] if p["setting"] == curve["chosen"] and p["series"] == "normal_deg"), None)
    return {
        **_commit(), "config_file": a.config.name, "config_text": a.config.read_text(),
        "estimator": st["config"], "data": counts,
        "parameters": int(sum(p.numel() for p in model.parameters())),
        "training_seconds": max(p["seconds"] for p in curve["points"]), "selected_step": curve["chosen"],
        "selected_validation_normal_deg": selected and selected["value"],
        "curve": curve["points"], "machine": curve.get("machine"), "check_set_errors": errors,
        "rule": f"train_gbuffer_estimator (workflow/rules/reconstruct.smk) under config/{a.config.name}",
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", type=Path, required=True, help="results/ of the config/estimator.yaml run")
    ap.add_argument("--config", type=Path, default=_cli.REPO / "config" / "estimator.yaml")
    ap.add_argument("--check-frames", type=int, default=4)
    ap.add_argument("--add-member", action="store_true",
                    help="add the run's model to the shipped weights as one more ensemble member")
    a = ap.parse_args(argv)
    import torch

    from lightcrafter import io
    from lightcrafter.recon import estimator as est
    from lightcrafter.recon.weights import SHIPPED_PROVENANCE, SHIPPED_WEIGHTS, check_set_path, member_records

    model_file = a.results / "recon" / "estimator" / "model.pt"
    curve_file = a.results / "recon" / "estimator" / "curve.json"
    for f in (model_file, curve_file):
        if not f.is_file():
            raise DataError(f"{f} not found; run the {a.config.name} target first (see its header)")
    st = torch.load(model_file, map_location="cpu", weights_only=False)
    model = est.load(model_file)
    if not isinstance(model, est.GBufferNet):
        raise DataError(f"{model_file}: already an ensemble; ship one trained network at a time")
    counts = _data_counts(a, st)
    if a.add_member:
        if not (SHIPPED_WEIGHTS.is_file() and SHIPPED_PROVENANCE.is_file() and check_set_path().is_file()):
            raise DataError(f"{SHIPPED_WEIGHTS}: no shipped weights to add a member to; ship one first (without "
                            "--add-member)")
        members = est.saved_members(SHIPPED_WEIGHTS)
        records = [{k: v for k, v in r.items() if k not in HEAD_KEYS}
                   for r in member_records(io.read_json(SHIPPED_PROVENANCE))]
    else:
        members, records = [], []
        counts["check_frames"] = _write_check_set(a, counts["validation_clip"])
    record = _record(a, st, model, counts, curve_file, errors=est.check_set_errors(model, check_set_path()))
    members.append(st)
    records.append(record)
    if len(members) == 1:
        with io.atomic_path(SHIPPED_WEIGHTS) as tmp:
            shutil.copyfile(model_file, tmp)
    else:
        est.save_ensemble(members, SHIPPED_WEIGHTS)
    shipped = est.load(SHIPPED_WEIGHTS)
    errors = est.check_set_errors(shipped, check_set_path())
    head = {"format": "lightcrafter.estimator_provenance/1", "weights": SHIPPED_WEIGHTS.name,
            "sha256": hashlib.sha256(SHIPPED_WEIGHTS.read_bytes()).hexdigest(), "bytes": SHIPPED_WEIGHTS.stat().st_size,
            "parameters": int(sum(p.numel() for p in shipped.parameters())),
            "check_set": check_set_path().name, "check_set_errors": errors}
    io.write_json(SHIPPED_PROVENANCE, {**record, **head} if len(records) == 1 else {
        **head, "ensemble": f"{len(records)} members, predictions averaged "
                            "(lightcrafter.recon.estimator.EstimatorEnsemble)", "members": records})
    print(f"ship_estimator: {SHIPPED_WEIGHTS} ({SHIPPED_WEIGHTS.stat().st_size / 1e6:.2f} MB, {len(records)} "
          "member(s)), check-set errors "
          + " ".join(f"{k} {v:.4f}" for k, v in errors.items()))
    return 0


if __name__ == "__main__":
    _cli.run(main, "ship_estimator")
