#!/usr/bin/env python
"""Refine the proxies of one split with a trained refiner (thin entry point).

  infer_refiner.py --model DIR/model.pt --pairs PAIRS.jsonl --split test --out OUTDIR [--config-json '{"infer": {...}}']

Per pair: OUTDIR/{pair_id}/{frame:04d}.exr (LINEAR RGB, the inverse display transform of the
refined display frames) and OUTDIR/{pair_id}.mp4 (display preview); OUTDIR/manifest.json last.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import torch

import _cli  # noqa: F401  (puts the repository on sys.path)

from lightcrafter.io import DataError, display_to_linear, to_uint8, write_json, write_rgb_exr, write_video
from lightcrafter.refiner import MissingWeightsError, PairsDataset, load_model, refine_video
from lightcrafter.refiner.data import to_display_frames


def autoencoder_round_trip_psnr_db(model, target, pad_mode: str) -> float:
    """Held-out check that the latent space is not the bottleneck: decode(encode(target)) vs target."""
    from lightcrafter.metrics import video_psnr_db
    from lightcrafter.refiner import pad_to_4k1

    video, n = pad_to_4k1(target[None], pad_mode)
    with torch.no_grad():
        rt = model.ae.decode(model.ae.encode(video))[0, :, :n].clamp(-1, 1)
    return video_psnr_db(to_display_frames(rt), to_display_frames(target))


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
    try:
        model = load_model(a.model, json.loads(a.config_json))
        cfg = model.cfg
        ds = PairsDataset(a.pairs, a.split, cfg["data"]["exposure_ev"], cache=False)
    except (DataError, MissingWeightsError, KeyError, ValueError) as exc:
        print(f"infer_refiner: {exc}", file=sys.stderr)
        return 1
    out = Path(a.out)
    entries = []
    for i in range(len(ds)):
        item = ds[i]
        gen = torch.Generator().manual_seed(cfg["seed"])
        t0 = time.perf_counter()
        refined = refine_video(model, item["proxy"][None], cfg, generator=gen)[0]  # (3, N, H, W) in [-1, 1]
        sec = time.perf_counter() - t0
        ae_psnr = autoencoder_round_trip_psnr_db(model, item["target"], cfg["infer"]["pad_frames"])
        disp = to_display_frames(refined)  # (N, H, W, 3) display
        for f, frame in enumerate(disp):
            write_rgb_exr(out / item["pair_id"] / f"{f:04d}.exr", display_to_linear(frame, cfg["data"]["exposure_ev"]))
        write_video(out / f"{item['pair_id']}.mp4", to_uint8(disp))
        entries.append({"pair_id": item["pair_id"], "frames": f"{out / item['pair_id']}", "num_frames": len(disp),
                        "seconds": round(sec, 3), "ae_round_trip_psnr_db": ae_psnr})
        print(f"infer_refiner: {item['pair_id']}: {len(disp)} frames in {sec:.1f} s", flush=True)
    write_json(out / "manifest.json", {"model": a.model, "split": a.split, "infer": cfg["infer"], "pairs": entries})
    return 0


if __name__ == "__main__":
    sys.exit(main())
