"""Refiner benchmarks (tiny model, CPU) -> results/bench/refiner.json.

Main curve (docs/architecture.md shape): refined PSNR (dB, display values in [0, 1], mean of
per-frame PSNR against the target) vs number of denoising steps (10, 25, 50) with the seconds per
clip (sampling + decoding), on held-out generated toy pairs (lightcrafter.refiner.toy; no pipeline
data is needed). The model is the tiny preset trained here for ``--train-steps`` optimizer steps on
64 generated pairs (a random-init model only produces noise, which would make the seam and step
comparisons meaningless).

Extra keys:
* ``autoencoder``: round-trip PSNR of the DCT patch autoencoder vs kept coefficients, on held-out
  smooth toy clips and on "stress" clips (sharp checker + sigma 0.02 pixel noise) at 96x64.
* ``training``: seconds per optimizer step (4 micro-batches), final loss, and a resume check
  (3 + kill + 3 steps vs 6 straight: identical loss curve?).
* ``tiling``: overlap-fused tiled sampling for 49/97/201/401 pixel frames (random proxy latent on a
  16x24 latent grid = 128x192 px; 10 steps, CFG scale from config, window 3 / overlap 1 latent
  frames): seconds and peak memory. Memory = peak resident set during sampling minus the resident
  set before it, in a fresh subprocess per length; the peak mark (VmHWM) is reset through
  /proc/self/clear_refs first (fallback: ru_maxrss growth). ``latent_mb`` is one full-length
  float32 latent, for comparison.
* ``seam``: fused tiling vs naive independent chunks (disjoint windows, same initial noise), mean
  absolute temporal difference at chunk-boundary transitions vs inside chunks.
  ``analytic``: a window-context analytic denoiser (see WindowContextDenoiser) in latent space --
  the meaningful test of the fusion mechanism. ``trained_tiny``: the tiny model trained here, on
  decoded 49-frame clips, with autoencoder block edges as the fair "inside" comparison.

    .venv/bin/python benchmarks/refiner.py      # ~5-8 minutes on one core
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import numpy as np  # noqa: E402
import torch  # noqa: E402

from lightcrafter.io import write_json  # noqa: E402
from lightcrafter.metrics import temporal_difference, video_psnr_db  # noqa: E402
from lightcrafter.refiner import (  # noqa: E402
    DCTPatchAutoencoder, load_model, plan_windows, refine_video, resolve_config, sample_latent, train,
)
from lightcrafter.refiner.toy import ToyDataset, toy_pair  # noqa: E402

TRAIN_HW = (32, 48)
TILING_LATENT_HW = (16, 24)  # latent grid of the tiling timing/memory runs (= 128x192 pixels)


def _disp(v: torch.Tensor) -> np.ndarray:
    """(3, N, H, W) in [-1, 1] -> (N, H, W, 3) display in [0, 1]."""
    from lightcrafter.refiner.data import to_display_frames

    return to_display_frames(v)


def bench_autoencoder() -> list[dict]:
    rows = []
    clips = {s: [toy_pair(2000 + i, height=64, width=96, stress=s)["target"][None] for i in range(3)]
             for s in (False, True)}
    for coeffs in ([16, 4, 4], [32, 8, 8], [40, 12, 12], [64, 16, 16], [128, 32, 32], [256, 256, 256]):
        ae = DCTPatchAutoencoder(coeffs)
        row = {"coeffs": coeffs, "latent_channels": ae.latent_channels}
        for stress, vids in clips.items():
            row["psnr_db_stress" if stress else "psnr_db_smooth"] = float(np.mean(
                [video_psnr_db(_disp(ae.decode(ae.encode(v))[0].clamp(-1, 1)), _disp(v[0])) for v in vids]))
        rows.append(row)
    return rows


def bench_training(out: Path, steps: int, lr: float) -> dict:
    cfg = resolve_config({"train": {"max_steps": steps, "lr": lr, "warmup_steps": 20, "checkpoint_every": 10**9}})
    res = train(cfg, ToyDataset(64, height=TRAIN_HW[0], width=TRAIN_HW[1]), out / "model", progress=False)
    small = resolve_config({"train": {"max_steps": 6, "checkpoint_every": 10**9}})
    straight = train(small, ToyDataset(3), out / "r_a", progress=False)["losses"]
    train(small, ToyDataset(3), out / "r_b", progress=False, stop_after=3)
    resumed = train(small, ToyDataset(3), out / "r_b", progress=False)["losses"]
    return {"optimizer_steps": steps, "micro_batches_per_step": cfg["train"]["grad_accum"], "lr": lr,
            "seconds_per_optimizer_step": res["seconds_per_step"], "final_loss_mean_last20": float(np.mean(res["losses"][-20:])),
            "first_loss_mean_first20": float(np.mean(res["losses"][:20])), "train_hw": list(TRAIN_HW),
            "resume_bit_for_bit": straight == resumed, "resume_check": "6 straight vs 3 + kill + 3 (CPU)"}


def _status_kb(key: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    raise KeyError(key)


def _reset_peak_rss() -> str:
    """Reset the kernel's peak-RSS mark (VmHWM) if allowed; say which measure is used."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return "VmHWM (peak RSS, reset via /proc/self/clear_refs before sampling) - VmRSS before sampling"
    except OSError:
        return "ru_maxrss growth (peak RSS could not be reset; underestimates when loading peaked higher)"


def tiling_child(model_path: str, frames: int, steps: int) -> None:
    torch.set_num_threads(1)
    model = load_model(model_path)
    h, w = TILING_LATENT_HW
    n_lat = (frames - 1) // 4 + 1
    zp = torch.randn(1, n_lat, model.latent_channels, h, w, generator=torch.Generator().manual_seed(frames))
    method = _reset_peak_rss()
    base_kb = _status_kb("VmRSS") if method.startswith("VmHWM") else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    z = sample_latent(model, zp, model.cfg, num_steps=steps, generator=torch.Generator().manual_seed(0))
    sec = time.perf_counter() - t0
    peak_kb = _status_kb("VmHWM") if method.startswith("VmHWM") else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    inf = model.cfg["infer"]
    print(json.dumps({"frames": frames, "latent_frames": n_lat, "seconds": sec,
                      "windows": len(plan_windows(n_lat, inf["window"], inf["overlap"])),
                      "peak_memory_growth_mb": (peak_kb - base_kb) / 1024, "latent_mb": z.numel() * 4 / 2**20,
                      "memory_measure": method, "finite": bool(torch.isfinite(z).all())}))


def bench_tiling(model_path: Path, steps: int) -> list[dict]:
    rows = []
    for n in (49, 97, 201, 401):
        r = subprocess.run([sys.executable, __file__, "--tiling-child", str(model_path), str(n), str(steps)],
                           capture_output=True, text=True, check=True)
        rows.append(json.loads(r.stdout.strip().splitlines()[-1]))
        print(f"tiling {n} frames: {rows[-1]}", flush=True)
    return rows


def _transition_classes(num_frames: int, window: int) -> dict[str, list[int]]:
    """Indices i of transitions i -> i+1, classified against chunk and autoencoder-block edges."""
    n_lat = (num_frames - 1) // 4 + 1
    block_starts = {4 * s - 3 for s in range(1, n_lat)}  # first pixel frame of latent s >= 1
    chunk_starts = {4 * s - 3 for s in range(window, n_lat, window)}
    classes = {"chunk_boundary": [], "other_block_boundary": [], "inside_block": []}
    for i in range(num_frames - 1):
        nxt = i + 1
        key = "chunk_boundary" if nxt in chunk_starts else "other_block_boundary" if nxt in block_starts else "inside_block"
        classes[key].append(i)
    return classes


class WindowContextDenoiser(torch.nn.Module):
    """Analytic denoiser with window context, a stand-in for a generative model's per-window drift.

    x0_hat = proxy + gamma * (per-channel mean of z_t over the window's frames and pixels), returned
    as the v prediction of the CogVideoX parameterisation. Early in sampling z_t is mostly noise, so
    each window commits to its own global offset (like lighting drifting per chunk); independent
    chunks keep different offsets, fused windows share theirs through the overlaps.
    """

    def __init__(self, alphas_cumprod: torch.Tensor, gamma: float = 0.5):
        super().__init__()
        self.ab, self.gamma = alphas_cumprod.float(), gamma

    def forward(self, z, zp, t):
        ab = self.ab[t].view(-1, 1, 1, 1, 1)
        x0 = zp + self.gamma * z.mean(dim=(1, 3, 4), keepdim=True)
        eps = (z - ab.sqrt() * x0) / (1 - ab).clamp_min(1e-8).sqrt()
        return ab.sqrt() * eps - (1 - ab).sqrt() * x0


def bench_seam_analytic(cfg: dict, latent_channels: int, steps: int, seeds=(300, 301, 302)) -> dict:
    """Latent-space seam test with :class:`WindowContextDenoiser` (guidance 1)."""
    from lightcrafter.refiner import build_scheduler

    model = WindowContextDenoiser(build_scheduler(cfg).alphas_cumprod)
    n_lat, window = 25, cfg["infer"]["window"]
    chunk = [i for i in range(n_lat - 1) if (i + 1) % window == 0]
    inside = [i for i in range(n_lat - 1) if (i + 1) % window]
    res = {m: {"chunk_boundary": [], "inside_chunk": []} for m in ("fused", "chunks", "proxy")}
    for seed in seeds:
        g = torch.Generator().manual_seed(seed)
        zp = torch.cumsum(0.1 * torch.randn(1, n_lat, latent_channels, 4, 6, generator=g), dim=1)  # smooth proxy
        noise = torch.randn(zp.shape, generator=g)
        outs = {"proxy": zp}
        for mode in ("fused", "chunks"):
            outs[mode] = sample_latent(model, zp, cfg, num_steps=steps, guidance_scale=1.0, init_noise=noise, mode=mode)
        for m, z in outs.items():
            td = (z[0, 1:] - z[0, :-1]).abs().mean(dim=(1, 2, 3))
            res[m]["chunk_boundary"].append(float(td[chunk].mean()))
            res[m]["inside_chunk"].append(float(td[inside].mean()))
    out = {m: {k: float(np.mean(v)) for k, v in d.items()} for m, d in res.items()}
    for m in out:
        out[m]["seam_ratio"] = out[m]["chunk_boundary"] / out[m]["inside_chunk"]
    out["setup"] = (f"analytic WindowContextDenoiser (gamma 0.5), latent space, {n_lat} latent frames "
                    f"(97 pixel frames), window {window} / overlap {cfg['infer']['overlap']}, {steps} steps, "
                    f"guidance 1, seeds {list(seeds)}; |z[i+1]-z[i]| mean over channels and pixels")
    return out


def bench_seam(model, steps: int, seeds=(300, 301, 302)) -> dict:
    window = model.cfg["infer"]["window"]
    classes = _transition_classes(49, window)
    acc = {m: {k: [] for k in classes} for m in ("fused", "chunks", "target", "proxy")}
    for seed in seeds:
        p = toy_pair(seed, num_frames=49, height=TRAIN_HW[0], width=TRAIN_HW[1])
        zp = model.ae.encode(p["proxy"][None])
        noise = torch.randn(zp.shape, generator=torch.Generator().manual_seed(seed))
        vids = {"target": p["target"], "proxy": p["proxy"]}
        for mode in ("fused", "chunks"):
            z = sample_latent(model, zp, model.cfg, num_steps=steps, init_noise=noise, mode=mode)
            vids[mode] = model.ae.decode(z)[0].clamp(-1, 1)
        for m, v in vids.items():
            td = temporal_difference(_disp(v))
            for k, idx in classes.items():
                acc[m][k].append(float(td[idx].mean()))
    out = {m: {k: float(np.mean(v)) for k, v in d.items()} for m, d in acc.items()}
    for m in out:
        out[m]["seam_ratio"] = out[m]["chunk_boundary"] / out[m]["other_block_boundary"]
    out["transitions"] = {k: len(v) for k, v in classes.items()}
    out["setup"] = f"49 frames {TRAIN_HW[1]}x{TRAIN_HW[0]}, window {window} latent, {steps} steps, seeds {list(seeds)}"
    return out


def bench_steps(model, seeds=(1000, 1001, 1002), guidance_scale=None) -> tuple[list[dict], float]:
    pairs = [toy_pair(s, height=TRAIN_HW[0], width=TRAIN_HW[1]) for s in seeds]
    proxy_psnr = float(np.mean([video_psnr_db(_disp(p["proxy"]), _disp(p["target"])) for p in pairs]))
    points = []
    for steps in (10, 25, 50):
        ps, secs = [], []
        for p in pairs:
            t0 = time.perf_counter()
            out = refine_video(model, p["proxy"][None], model.cfg, generator=torch.Generator().manual_seed(0),
                               num_steps=steps, guidance_scale=guidance_scale)[0]
            secs.append(time.perf_counter() - t0)
            ps.append(video_psnr_db(_disp(out), _disp(p["target"])))
        points.append({"setting": steps, "seconds": float(np.mean(secs)), "value": float(np.mean(ps))})
        print(f"steps {steps}: {points[-1]}", flush=True)
    return points, proxy_psnr


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] == "--tiling-child":
        tiling_child(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]))
        return 0
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(REPO / "results/bench/refiner.json"))
    ap.add_argument("--train-steps", type=int, default=400)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--tiling-steps", type=int, default=10)
    ap.add_argument("--seam-steps", type=int, default=25)
    a = ap.parse_args()
    torch.set_num_threads(1)
    t_all = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        ae_rows = bench_autoencoder()
        print("autoencoder", ae_rows, flush=True)
        training = bench_training(tmp, a.train_steps, a.lr)
        print("training", training, flush=True)
        model = load_model(tmp / "model/model.pt")
        points, proxy_psnr = bench_steps(model)
        points_cfg1, _ = bench_steps(model, guidance_scale=1.0)
        seam = {"analytic": bench_seam_analytic(model.cfg, model.latent_channels, a.seam_steps),
                "trained_tiny": bench_seam(model, a.seam_steps)}
        print("seam", seam, flush=True)
        tiling = bench_tiling(tmp / "model/model.pt", a.tiling_steps)
    cfg = model.cfg
    result = {
        "name": "refiner", "varied": "denoising_steps", "metric": "psnr_db", "higher_is_better": True,
        "machine": {"cores": os.cpu_count(), "platform": platform.platform(), "torch_threads": 1},
        "chosen": cfg["infer"]["num_steps"], "points": points,
        "proxy_psnr_db": proxy_psnr, "points_guidance_1": points_cfg1,
        "eval_setup": f"3 held-out toy pairs, 9 frames {TRAIN_HW[1]}x{TRAIN_HW[0]}, sampler {cfg['infer']['sampler']}, "
                      f"CFG {cfg['infer']['guidance_scale']}; seconds = sampling + decoding per clip",
        "autoencoder": ae_rows, "training": training, "tiling": tiling,
        "tiling_setup": f"random proxy latent {TILING_LATENT_HW[0]}x{TILING_LATENT_HW[1]} (= 128x192 px), "
                        f"{a.tiling_steps} steps, CFG {cfg['infer']['guidance_scale']}, window "
                        f"{cfg['infer']['window']} / overlap {cfg['infer']['overlap']} latent frames; one fresh "
                        "subprocess per length; memory measure in each row",
        "seam": seam, "total_seconds": time.perf_counter() - t_all,
    }
    write_json(a.out, result)
    print(f"wrote {a.out} in {result['total_seconds']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
