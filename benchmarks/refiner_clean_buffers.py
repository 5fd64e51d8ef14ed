"""Refiner vs PBR proxy on the default run's clean_buffers pairs, against training length and CFG.

Needs results/datasets/clean_buffers/pairs.jsonl (``make bench`` runs the pipeline up to it).
Trains the refiner of ``--config`` (config/config.yaml) once, resuming at each step count of ``--steps`` (the
checkpoints make 200 + 200 more steps identical to 400 straight), and after each evaluates the
held-out test pairs at guidance 6 (paper) and 1 (no guidance): PSNR and SSIM on display values
against the Cycles target, next to the proxy alone; plus, as a diagnostic, the model's one-step
x0 estimate at t = 999 (where zero-terminal-SNR noise carries no signal). Writes results/bench/refiner_clean_buffers.json
(varied: training steps; metric: refined PSNR at CFG 6; also CFG 1 and the proxy's PSNR) + PNG.

    .venv/bin/python benchmarks/refiner_clean_buffers.py [--steps 200 400 800 1600]

More data: run the workflow with more scenes in another folder, then from there
    snakemake results/datasets/clean_buffers/pairs.jsonl -d /tmp/more --configfile more.yaml
(more.yaml: ``scenes: {count: 12}``; the target goes before --configfile, which takes several files)
    cd /tmp/more && python /path/to/benchmarks/refiner_clean_buffers.py --name refiner_clean_buffers_12scenes
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def main() -> int:
    import numpy as np
    import torch

    from lightcrafter.io import write_json
    from lightcrafter.metrics import video_psnr_db, video_ssim
    from lightcrafter.refiner import PairsDataset, load_model, refine_video, resolve_config, train
    from lightcrafter.report import plot_bench
    from refiner_small_scale import _cfg_from_yaml

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pairs", default="results/datasets/clean_buffers/pairs.jsonl",
                    help="pairs manifest; its relative paths resolve against the working directory")
    ap.add_argument("--steps", type=int, nargs="+", default=[200, 400, 800, 1600])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--config", default=str(REPO / "config/config.yaml"),
                    help="pipeline config file whose refiner: section is trained (its extends chain followed)")
    ap.add_argument("--name", default="refiner_clean_buffers",
                    help="benchmark name; writes results/bench/NAME.json (e.g. for a larger data set)")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    cfg = _cfg_from_yaml(Path(a.config), {})
    train_ds = PairsDataset(a.pairs, "train", cfg["data"]["exposure_ev"], cache=True)
    test_ds = PairsDataset(a.pairs, "test", cfg["data"]["exposure_ev"], cache=True)
    from lightcrafter.refiner.data import to_display_frames as disp
    proxy_psnr = float(np.mean([video_psnr_db(disp(test_ds[i]["proxy"]), disp(test_ds[i]["target"]))
                                for i in range(len(test_ds))]))
    proxy_ssim = float(np.mean([video_ssim(disp(test_ds[i]["proxy"]), disp(test_ds[i]["target"]))
                                for i in range(len(test_ds))]))
    points, train_seconds = [], 0.0
    with tempfile.TemporaryDirectory() as work:
        for steps in sorted(a.steps):
            c = resolve_config({**cfg, "train": {**cfg["train"], "max_steps": steps}})
            t0 = time.perf_counter()
            train(c, train_ds, work, progress=False)
            train_seconds += time.perf_counter() - t0
            # Diagnostic: the model's one-step x0 estimate from pure noise (t = 999, zero terminal SNR:
            # z_999 carries no signal, so x0 = -v comes from the proxy alone). If this beats the full
            # sampler, the gap is the sampling trajectory (exposure bias of an undertrained model).
            model = load_model(Path(work) / "model.pt")
            one_step = []
            for i in range(len(test_ds)):
                item = test_ds[i]
                with torch.no_grad():
                    zp = model.ae.encode(item["proxy"][None])
                    z = torch.randn(zp.shape, generator=torch.Generator().manual_seed(0))
                    x0 = -model(z, zp, torch.tensor([999]))
                    one_step.append(video_psnr_db(disp(model.ae.decode(x0)[0].clamp(-1, 1)), disp(item["target"])))
            points.append({"series": "one-step x0 at t=999", "setting": steps, "seconds": round(train_seconds, 2),
                           "value": round(float(np.mean(one_step)), 3)})
            print(points[-1], flush=True)
            for guidance in (6.0, 1.0):
                model = load_model(Path(work) / "model.pt", {"infer": {"guidance_scale": guidance}})
                psnr, ssim, infer_s = [], [], 0.0
                for i in range(len(test_ds)):
                    item = test_ds[i]
                    t1 = time.perf_counter()
                    out = refine_video(model, item["proxy"][None], model.cfg,
                                       generator=torch.Generator().manual_seed(0))[0]
                    infer_s += time.perf_counter() - t1
                    psnr.append(video_psnr_db(disp(out), disp(item["target"])))
                    ssim.append(video_ssim(disp(out), disp(item["target"])))
                points.append({"series": f"refined, CFG {guidance:g}", "setting": steps,
                               "seconds": round(train_seconds, 2), "value": round(float(np.mean(psnr)), 3),
                               "ssim": round(float(np.mean(ssim)), 4), "infer_seconds_per_clip":
                               round(infer_s / max(len(test_ds), 1), 3)})
                print(points[-1], flush=True)
    bench = {
        "name": a.name, "varied": "training steps (optimizer steps, tiny preset)",
        "metric": "psnr_db", "higher_is_better": True,
        "machine": {"cores": os.cpu_count(), "platform": platform.platform()},
        "chosen": cfg["train"]["max_steps"], "chosen_series": "refined, CFG 6",
        "baseline": {"proxy_psnr_db": round(proxy_psnr, 3), "proxy_ssim": round(proxy_ssim, 4)},
        "pairs": {"train": len(train_ds), "test": len(test_ds)},
        "notes": "seconds = cumulative training time; PSNR/SSIM on display values vs the Cycles target, "
                 "mean over held-out test pairs",
        "points": points,
    }
    out = REPO / "results/bench" / f"{a.name}.json"
    write_json(out, bench)
    plot_bench(bench, out.with_suffix(".png"))
    print(f"proxy alone: {proxy_psnr:.2f} dB; wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
