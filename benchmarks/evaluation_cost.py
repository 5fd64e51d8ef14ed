"""Run time of every evaluation metric per clip, and the DIS preset of Warp-SSIM against its error.

Synthetic display clips (no pipeline output needed): a smooth random texture panning 2 px/frame
right and 1 px/frame down with a textured square moving 6 px/frame over it; the "method" is that
video with per-frame gain flicker (+-3 %) and Gaussian noise (sigma 0.01), clipped to [0, 1].
Two sizes: 49 frames of 720x480 (the paper's clips) and 17 frames of 128x96 (the tiny preset).

Timed per clip (wall seconds, and the process's CPU seconds over all threads in ``cpu_seconds``;
OpenCV's and torch's default threads; the 1-minute load average is recorded since other jobs on a
shared machine inflate wall times):
  psnr_db, ssim                      frame-wise against the target (scikit-image)
  warp_ssim_flow, warp_ssim_score    DIS flows + masks of the target, then the masked SSIM of the method
  t_clip_vitb32                      CLIP image embeddings + adjacent cosines, with a randomly
                                     initialised CLIP of ViT-B/32 size (transformers' CLIPConfig()
                                     defaults: 224 px, patch 32, 12 layers, width 768): the run time
                                     of real ViT-B/32 weights; its value is not a T-CLIP score and
                                     is not reported
  lpips                              not timed where the lpips package cannot import (its reason is recorded)

Cost/quality curve (results/bench/evaluation_cost.json, shape of docs/architecture.md): for each DIS
preset, seconds of the flows on the 720x480 clip against the Warp-SSIM of the TARGET scored with
its own flow (a perfect method: 1 is ideal, the shortfall is the flow's error). Chosen: MEDIUM.

    .venv/bin/python benchmarks/evaluation_cost.py            # ~2-3 minutes on 2 cores
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lightcrafter import evaluation as ev  # noqa: E402
from lightcrafter import io  # noqa: E402


def synthetic_pair(n: int, h: int, w: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(target, method) display videos (n, h, w, 3) float32 in [0, 1]."""
    rng = np.random.default_rng(seed)
    pad = 2 * n + 8

    def texture(hh, ww, sigma):
        t = np.stack([gaussian_filter(rng.random((hh, ww)).astype(np.float32), sigma) for _ in range(3)], -1)
        return 0.1 + 0.8 * (t - t.min()) / (t.max() - t.min())

    big = texture(h + pad, w + pad, 2.0)
    side = max(8, min(h, w) // 3)
    square = 0.5 + 0.5 * texture(side, side, 1.5)
    target = []
    for t in range(n):
        f = big[pad - t - 4: pad - t - 4 + h, pad - 2 * t - 4: pad - 2 * t - 4 + w].copy()
        y0, x0 = (h - side) // 2, (6 * t) % max(w - side, 1)
        f[y0:y0 + side, x0:x0 + side] = square
        target.append(f)
    target = np.stack(target).astype(np.float32)
    gains = 1.0 + rng.uniform(-0.03, 0.03, (n, 1, 1, 1))
    method = np.clip(target * gains + rng.normal(0, 0.01, target.shape), 0, 1).astype(np.float32)
    return target, method


CPU_SECONDS: dict = {}


def timed(fn, *args, **kwargs):
    """(output, wall seconds); the process CPU seconds (all threads) go to CPU_SECONDS[fn name]."""
    t0, c0 = time.perf_counter(), time.process_time()
    out = fn(*args, **kwargs)
    CPU_SECONDS[fn.__name__] = time.process_time() - c0
    return out, time.perf_counter() - t0


def vit_b32_embedder():
    """A randomly initialised CLIP of ViT-B/32 size (for timing only) with the standard processor."""
    import torch
    from transformers import CLIPConfig, CLIPImageProcessorPil, CLIPModel

    torch.manual_seed(0)
    return ev.ClipImageEmbedder(CLIPModel(CLIPConfig()), CLIPImageProcessorPil(), "random ViT-B/32-size CLIP (timing only)")


def time_metrics(n: int, h: int, w: int, embedder) -> dict:
    target, method = synthetic_pair(n, h, w)
    row, cpu = {"frames": n, "width": w, "height": h}, {}
    _, row["psnr_db"] = timed(ev.framewise_psnr, method, target)
    cpu["psnr_db"] = CPU_SECONDS["framewise_psnr"]
    _, row["ssim"] = timed(ev.framewise_ssim, method, target)
    cpu["ssim"] = CPU_SECONDS["framewise_ssim"]
    flows, row["warp_ssim_flow"] = timed(ev.compute_flows, target)
    cpu["warp_ssim_flow"] = CPU_SECONDS["compute_flows"]
    ws, row["warp_ssim_score"] = timed(ev.warp_ssim, method, flows=flows)
    cpu["warp_ssim_score"] = CPU_SECONDS["warp_ssim"]
    row["warp_ssim"] = row["warp_ssim_flow"] + row["warp_ssim_score"]
    cpu["warp_ssim"] = cpu["warp_ssim_flow"] + cpu["warp_ssim_score"]
    row["warp_ssim_value_of_synthetic_method"] = ws.value
    if embedder is not None:
        _, row["t_clip_vitb32"] = timed(ev.t_clip, method, embedder=embedder)
        cpu["t_clip_vitb32"] = CPU_SECONDS["t_clip"]
    else:
        row["t_clip_vitb32"] = None
    row["cpu_seconds"] = {k: round(v, 3) for k, v in cpu.items()}
    row["load_average_1min"] = round(os.getloadavg()[0], 2)
    row["lpips"] = None
    try:
        import lpips  # noqa: F401
        row["lpips_status"] = "not timed: needs a local backbone checkpoint (evaluation.lpips_weights)"
    except Exception as exc:  # torchvision's import error beside the CPU torch build, or no lpips
        row["lpips_status"] = f"not computed: lpips cannot be imported here ({type(exc).__name__}: {exc})"
    return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="results/bench/evaluation_cost.json")
    ap.add_argument("--no-clip", action="store_true", help="skip the ViT-B/32-size CLIP timing")
    a = ap.parse_args()

    embedder = None
    if not a.no_clip:
        try:
            embedder = vit_b32_embedder()
        except ImportError as exc:
            print(f"evaluation_cost: T-CLIP not timed ({exc})")
    timing = [time_metrics(49, 480, 720, embedder), time_metrics(17, 96, 128, embedder)]
    for row in timing:
        print({k: v for k, v in row.items()})

    target, _ = synthetic_pair(49, 480, 720)
    points = []
    for preset in ("ULTRAFAST", "FAST", "MEDIUM"):
        flows, secs = timed(ev.compute_flows, target, preset)
        value = ev.warp_ssim(target, flows=flows).value
        points.append({"setting": preset, "seconds": round(secs, 3), "value": value,
                       "valid_fraction": float(np.mean([v.mean() for v in flows.valid]))})
        print(f"DIS {preset}: {secs:.2f} s for 48 transitions (fwd+bwd) at 720x480, Warp-SSIM of the target {value:.5f}")
    result = {
        "name": "evaluation_cost", "varied": "DIS preset (49 frames 720x480)",
        "metric": "warp_ssim_of_target", "higher_is_better": True, "chosen": ev.FLOW_PRESET,
        "machine": {"cores": os.cpu_count(), "platform": platform.platform()},
        "points": points,
        "metric_seconds_per_clip": timing,
    }
    io.write_json(a.out, result)
    from lightcrafter.report import plot_bench

    plot_bench(result, Path(a.out).with_suffix(".png"))
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
