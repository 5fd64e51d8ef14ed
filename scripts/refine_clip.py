#!/usr/bin/env python
"""Refine one proxy video with a trained refiner (scene edits, any user clip): no target needed.

  refine_clip.py --model results/refiner/full/model.pt --proxy results/edits/light/proxy \
      --out results/edits/light/refined [--strip-with results/proxy/s0003/t0/L1 ...]

Writes OUT/{i:04d}.exr (linear), OUT.mp4, OUT.json (manifest, last) and, with --strip-with, a frame
strip OUT/../strip.png (labelled columns: the given folders | proxy | refined; rows: first, middle and
last frame) and OUT/../side_by_side.mp4.
"""

import argparse
import time
from pathlib import Path

import numpy as np
import torch

import _cli  # puts the repository on sys.path; run() is the one error path

from lightcrafter import io


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", required=True)
    ap.add_argument("--proxy", required=True, help="folder of linear frames (its manifest <folder>.json beside it)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--strip-with", nargs="*", default=[], help="folders shown before proxy and refined")
    ap.add_argument("--strip-labels", nargs="*", default=None, help="their column labels (default: folder names)")
    ap.add_argument("--out-label", default="refined", help="label of the refined column")
    ap.add_argument("--config-json", default="{}", help="overrides of the stored config (e.g. infer.pad_frames, "
                    "device)")
    ap.add_argument("--threads", type=int, default=None)
    a = ap.parse_args()
    if a.threads:
        torch.set_num_threads(a.threads)
    from lightcrafter.refiner import load_model, refine_video
    from lightcrafter.refiner.data import load_frames, to_display_frames
    from lightcrafter.io import side_by_side_video

    proxy_dir, out = Path(a.proxy), Path(a.out)
    man = io.read_json(proxy_dir.with_suffix(".json"))
    if man.get("skipped"):
        raise io.DataError(f"{proxy_dir}: the proxy was left out ({man['skipped']})")
    model = load_model(a.model, _cli.json_arg(a.config_json) or None)
    cfg = model.cfg
    ev = cfg["data"]["exposure_ev"]
    proxy = load_frames(proxy_dir, int(man["num_frames"]), ev)
    gen = torch.Generator().manual_seed(cfg["seed"])
    t0 = time.perf_counter()
    disp = to_display_frames(refine_video(model, proxy[None], cfg, generator=gen)[0])
    sec = time.perf_counter() - t0
    for i, f in enumerate(disp):
        io.write_frame_exr(out / f"{i:04d}.exr", io.display_to_linear(f, ev))
    io.write_video(out.with_suffix(".mp4"), io.to_uint8(disp), fps=float(man.get("fps", 24)))
    folders = [Path(p) for p in a.strip_with] + [proxy_dir, out]
    if a.strip_with:
        from lightcrafter.refiner.strip import strip_frames, write_strip

        labels = list(a.strip_labels or [Path(f).name for f in a.strip_with]) + ["proxy", a.out_label]
        if len(labels) != len(folders):
            raise io.DataError(f"--strip-labels: {len(a.strip_labels)} labels for {len(a.strip_with)} --strip-with folders")
        rows = strip_frames(len(disp))  # first, middle and last frame
        columns = [(lab, np.stack([io.linear_to_display(io.read_rgb_exr(f / f"{i:04d}.exr"), ev) for i in rows]))
                   for lab, f in zip(labels, folders)]
        write_strip(out.parent / "strip.png", columns, frames=list(range(len(rows))))
        side_by_side_video(folders, out.parent / "side_by_side.mp4")
    io.write_json(out.with_suffix(".json"), {"format": "lightcrafter.refined/1", "model": a.model, "proxy": str(proxy_dir),
                                             "num_frames": len(disp), "frames": [f"{out.name}/{i:04d}.exr"
                                                                                 for i in range(len(disp))],
                                             "seconds": round(sec, 2), "infer": cfg["infer"]})
    print(f"refine_clip: {len(disp)} frames in {sec:.1f} s -> {out}")
    return 0


if __name__ == "__main__":
    from lightcrafter.refiner import MissingWeightsError

    _cli.run(main, "refine_clip", (io.DataError, FileNotFoundError, MissingWeightsError, KeyError, ValueError))
