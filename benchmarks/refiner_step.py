"""The paper refiner preset's optimizer step at CogVideoX-5B-I2V size: peak GPU memory and seconds per step.

No weights can be downloaded, so the step runs on a random checkpoint of the released *size* and layout
(lightcrafter.refiner.standin, ``full_size``: the transformer at 5B-I2V's widths in bf16, the VAE at
CogVideoX's defaults, a one-layer T5 at the text width) and on two synthetic 49-frame 720x480 pairs in
memory (lightcrafter.refiner.toy). The ``paper`` preset trains through the workflow's own
``lightcrafter.refiner.training.train``: fp32 master weights, bf16 autocast, gradient checkpointing,
``grad_accum`` micro-batches, each proxy VAE-encoded (sliced, tiled) in the step, each target encoded
once and cached in CPU memory, AdamW. Checkpoint writes are skipped (at 5B one is ~67 GB: fp32 weights and two
AdamW moments); everything else is the job's step.

Reported: parameters, seconds of each optimizer step (the first includes the kernels' first use and
the first target encodings; the median is over the others), peak CUDA memory allocated and reserved (GiB),
and what ``profiles/slurm`` should ask for. ``--size tiny`` runs the same path on the rehearsal's tiny
checkpoint (48x32), as the CPU test does.

    python benchmarks/refiner_step.py --device cuda [--steps 3]   -> results/bench/refiner_step.json
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import shutil
import signal
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lightcrafter import io  # noqa: E402

SIZES = {"full": {"width": 720, "height": 480, "frames": 49}, "tiny": {"width": 48, "height": 32, "frames": 49}}


class ToyPairs:
    """Two synthetic pairs held in memory, the dataset interface training reads: ``ds[i]`` ->
    {pair_id, proxy, target} as (3, N, H, W) in [-1, 1]."""

    def __init__(self, n: int, frames: int, height: int, width: int):
        from lightcrafter.refiner.toy import toy_pair

        self.items = []
        for i in range(n):
            p = toy_pair(i, num_frames=frames, height=height, width=width)
            self.items.append({"pair_id": f"p{i}", "proxy": p["proxy"], "target": p["target"]})
        self.pair_ids = [it["pair_id"] for it in self.items]

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, i: int) -> dict:
        return self.items[i]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="results/bench/refiner_step.json")
    ap.add_argument("--size", choices=sorted(SIZES), default="full")
    ap.add_argument("--device", choices=["cpu", "cuda"], default="cuda")
    ap.add_argument("--steps", type=int, default=3, help="optimizer steps (each of the preset's grad_accum micro-batches)")
    ap.add_argument("--work", default=None, help="folder for the checkpoint (~11 GB at full size) and the run; its model/ and refiner/ are removed "
                    "afterwards (default: a temporary folder)")
    a = ap.parse_args()
    if a.steps < 2:
        raise SystemExit(f"refiner_step: --steps {a.steps}: needs at least 2 (the first step is reported apart)")
    import torch

    size = SIZES[a.size]
    cuda = a.device == "cuda"
    if cuda and not torch.cuda.is_available():
        raise SystemExit(f"refiner_step: --device cuda: torch {torch.__version__} sees no CUDA GPU; run it on a GPU node")
    work_ctx = tempfile.TemporaryDirectory() if a.work is None else None
    work = Path(a.work or work_ctx.name)
    # a killed run (the GPU check's timeout sends SIGTERM) still removes the ~11 GB checkpoint
    signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(f"refiner_step: stopped by signal {signum}"))
    try:
        result = _measure(a, torch, size, cuda, work)
    finally:
        if work_ctx is not None:
            work_ctx.cleanup()
        else:
            shutil.rmtree(work / "model", ignore_errors=True)
            shutil.rmtree(work / "refiner", ignore_errors=True)
    io.write_json(a.out, result)
    print({k: result[k] for k in ("transformer_parameters", "step_seconds", "peak_cuda_allocated_gib",
                                  "peak_cuda_reserved_gib", "checkpoint_write_seconds", "train_call_seconds")})
    print(f"wrote {a.out}")


def _measure(a, torch, size: dict, cuda: bool, work: Path) -> dict:
    import lightcrafter.refiner.training as training
    from lightcrafter.refiner import resolve_config
    from lightcrafter.refiner.standin import write_tiny_checkpoint

    t0 = time.perf_counter()
    model_dir = write_tiny_checkpoint(work / "model", height_px=size["height"], width_px=size["width"],
                                      frames=size["frames"], full_size=a.size == "full", device=a.device)
    write_s = time.perf_counter() - t0
    print(f"checkpoint written in {write_s:.1f} s", flush=True)
    ds = ToyPairs(2, size["frames"], size["height"], size["width"])
    # the stand-in's VAE has random weights: its round-trip floor is off (min_ae_round_trip_db is for real weights)
    cfg = resolve_config({"preset": "paper", "device": a.device,
                          "model": {"model_path": str(model_dir), "min_ae_round_trip_db": None},
                          "train": {"max_steps": a.steps + 1, "checkpoint_every": 10**9, "num_workers": 0}})
    training.save_checkpoint = lambda path, state: None  # the step, not its 67 GB write (module docstring)
    if cuda:  # the checkpoint's initialisation is not counted
        torch.cuda.empty_cache()
        torch.cuda.reset_peak_memory_stats()
    t0 = time.perf_counter()
    res = training.train(cfg, ds, work / "refiner", stop_after=a.steps, progress=False)
    train_s = time.perf_counter() - t0
    from safetensors import safe_open

    n_params = 0
    for f in (model_dir / "transformer").glob("*.safetensors"):
        with safe_open(f, "pt") as st:
            n_params += sum(math.prod(st.get_slice(k).get_shape()) for k in st.keys())
    steps = res["step_seconds"]
    peak = torch.cuda.max_memory_allocated() / 2**30 if cuda else None
    reserved = torch.cuda.max_memory_reserved() / 2**30 if cuda else None
    result = {
        "name": "refiner_step", "size": a.size, "device": a.device,
        "gpu": torch.cuda.get_device_name(0) if cuda else None,
        "machine": {"cores": os.cpu_count(), "platform": platform.platform(), "torch": torch.__version__},
        "clip": {**size, "latent_window": cfg["train"]["latent_window"]},
        "preset": {k: cfg["model"][k] for k in ("dtype", "gradient_checkpointing", "vae_slicing", "vae_tiling")}
        | {"grad_accum": cfg["train"]["grad_accum"], "param_dtype": "float32 (masters)", "optimizer": "AdamW"},
        "transformer_parameters": n_params,
        "checkpoint_write_seconds": round(write_s, 2),
        "train_call_seconds": round(train_s, 2),
        "step_seconds": [round(x, 3) for x in steps],
        "seconds_per_step_after_first": {"median": round(statistics.median(steps[1:]), 3),
                                         "min": round(min(steps[1:]), 3), "max": round(max(steps[1:]), 3),
                                         "n": len(steps) - 1},
        "losses": [round(x, 5) for x in res["losses"]],
        "peak_cuda_allocated_gib": round(peak, 2) if peak is not None else None,
        "peak_cuda_reserved_gib": round(reserved, 2) if reserved is not None else None,
    }
    return result


if __name__ == "__main__":
    main()
