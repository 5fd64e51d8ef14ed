#!/usr/bin/env python
"""Refine the proxies of one split with a trained refiner, and run its baselines (thin entry point).

  infer_refiner.py --model DIR/model.pt --pairs PAIRS.jsonl --split test --out OUTDIR [--config-json '{"infer": {...}}']

The inference settings are the ones stored with the model: when it was selected on validation, the
chosen strength and guidance scale apply whatever --config-json says (other infer keys, e.g.
num_steps, are overridden as given).

Per pair: OUTDIR/{pair_id}/{frame:04d}.exr (LINEAR RGB, the inverse display transform of the refined
display frames), OUTDIR/{pair_id}.mp4 (display preview), OUTDIR/{pair_id}_strip.png (frame strip:
input (the record's source video, if it has one) | proxy | refined | target); the baselines stored
with the model: OUTDIR/baselines/{regressor,affine_colour}/{pair_id}/{frame:04d}.exr; OUTDIR/{pair_id}.json
(the pair's manifest entry, written when its outputs are); OUTDIR/manifest.json last.

Resume: a pair whose OUTDIR/{pair_id}.json names the same model file (size, mtime) and inference
settings is not refined again, so a killed or timed-out job continues at the next pair. The model
runs on the device of the config's ``device`` policy (CUDA for the paper preset).
"""

import argparse
import json
import time
from pathlib import Path

import torch

import _cli  # puts the repository on sys.path; run() is the one error path

from lightcrafter.io import DataError, display_to_linear, to_uint8, write_frame_exr, write_json, write_video
from lightcrafter.refiner import MissingWeightsError, PairsDataset, load_model, refine_video
from lightcrafter.refiner.autoencoder import round_trip_psnr_db
from lightcrafter.refiner.baselines import apply_affine_colour, load_affine_colour, load_regressor, regress_video
from lightcrafter.refiner.data import require_pairs, to_display_frames
from lightcrafter.refiner.strip import write_strip


def write_frames(folder: Path, disp, exposure_ev: float) -> None:
    for f, frame in enumerate(disp):
        write_frame_exr(folder / f"{f:04d}.exr", display_to_linear(frame, exposure_ev))


def resume_stamp(model_path, cfg: dict) -> str:
    """What a pair's outputs depend on besides the pair: the model file and the inference settings."""
    import hashlib

    st = Path(model_path).stat()
    blob = json.dumps([st.st_size, st.st_mtime_ns, cfg["infer"], cfg["seed"]], sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def read_done(path: Path, stamp: str) -> dict | None:
    """The manifest entry of a pair refined by an earlier run with the same stamp, else None."""
    if not path.is_file():
        return None
    try:
        entry = json.loads(path.read_text())
    except ValueError:
        return None
    if entry.pop("resume_stamp", None) != stamp or not Path(entry.get("frames", "")).is_dir():
        return None
    return entry


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", required=True)
    ap.add_argument("--pairs", required=True)
    ap.add_argument("--split", default="test")
    ap.add_argument("--out", required=True)
    ap.add_argument("--config-json", default="{}", help="overrides of the stored config (e.g. infer keys)")
    ap.add_argument("--threads", type=int, default=None)
    a = ap.parse_args()
    if a.threads:
        torch.set_num_threads(a.threads)
    model = load_model(a.model, _cli.json_arg(a.config_json))
    cfg = model.cfg
    regressor = load_regressor(a.model)
    affine = load_affine_colour(a.model)
    ds = require_pairs(PairsDataset(a.pairs, a.split, cfg["data"]["exposure_ev"], cache=False), a.pairs, a.split,
                       "refine")
    out = Path(a.out)
    ev, pad = cfg["data"]["exposure_ev"], cfg["infer"]["pad_frames"]
    entries = []
    stamp = resume_stamp(a.model, cfg)
    for i in range(len(ds)):
        pid = ds.pair_ids[i] if hasattr(ds, "pair_ids") else ds[i]["pair_id"]
        done = read_done(out / f"{pid}.json", stamp)
        if done is not None:
            entries.append(done)
            print(f"infer_refiner: {pid}: already refined (resumed)", flush=True)
            continue
        item = ds[i]
        gen = torch.Generator().manual_seed(cfg["seed"])
        t0 = time.perf_counter()
        refined = refine_video(model, item["proxy"][None], cfg, generator=gen)[0]  # (3, N, H, W) in [-1, 1]
        sec = time.perf_counter() - t0
        disp = to_display_frames(refined)  # (N, H, W, 3) display
        write_frames(out / pid, disp, ev)
        write_video(out / f"{pid}.mp4", to_uint8(disp))
        entry = {"pair_id": pid, "frames": f"{out / pid}", "num_frames": len(disp), "seconds": round(sec, 3),
                 "ae_round_trip_psnr_db": round_trip_psnr_db(model.ae, item["target"], pad),
                 "ae_round_trip_proxy_psnr_db": round_trip_psnr_db(model.ae, item["proxy"], pad),
                 "baselines": {}}
        outputs = {}
        if regressor is not None:
            t0 = time.perf_counter()
            outputs["regressor"] = regress_video(regressor, item["proxy"][None], pad)[0]
            entry["baselines"]["regressor"] = {"seconds": round(time.perf_counter() - t0, 3)}
        if affine is not None:
            t0 = time.perf_counter()
            outputs["affine_colour"] = apply_affine_colour(affine, item["proxy"])
            entry["baselines"]["affine_colour"] = {"seconds": round(time.perf_counter() - t0, 3)}
        for name, video in outputs.items():
            folder = out / "baselines" / name / pid
            write_frames(folder, to_display_frames(video), ev)
            entry["baselines"][name].update({"frames": f"{folder}", "num_frames": len(disp)})
        source = ds.source_frames(i)
        columns = ([("input", to_display_frames(source))] if source is not None else []) + [
            ("proxy", to_display_frames(item["proxy"])), ("refined", disp), ("target", to_display_frames(item["target"]))]
        entry["strip"] = str(write_strip(out / f"{pid}_strip.png", columns))
        entry["strip_columns"] = [c[0] for c in columns]
        write_json(out / f"{pid}.json", {**entry, "resume_stamp": stamp})
        entries.append(entry)
        print(f"infer_refiner: {pid}: {len(disp)} frames in {sec:.1f} s", flush=True)
    write_json(out / "manifest.json", {"model": a.model, "split": a.split, "infer": cfg["infer"],
                                       "selection": {k: v for k, v in (model.selection or {}).items() if k != "table"},
                                       "pairs": entries})
    return 0


if __name__ == "__main__":
    _cli.run(main, "infer_refiner", (DataError, MissingWeightsError, KeyError, ValueError))
