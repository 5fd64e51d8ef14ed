"""Why the small-scale refiner does not beat its proxy: its validation gain against training steps, model
size and training data, on any pairs manifest.

The workflow's fit (``lightcrafter.refiner.fit.fit_refiner``) carves validation scenes out of the train
split, trains on the rest (the *fit* groups: synthetic scenes, real clips) and scores candidates on the
validation clips. This benchmark runs that fit once per (model size, fit groups):

* model size: ``--layers`` transformer blocks of the config's tiny CogVideoX transformer (default 2);
* data: the first ``--fit-groups`` fit groups in sorted order; the validation groups are the same in every
  run (a group's rank in the carve-out does not depend on the others, lightcrafter.refiner.validation);
* steps: one training run to ``--max-steps`` keeps candidates at ``--steps``.

For every run and step it records, on the validation clips: the proxy alone, the learned anchor alone
(residual scale 0) and the full refiner (residual scale 1), each at its best strength, guidance and correction
blurs of ``select``; and, at that setting, the full refiner on up to ``--max-fit-clips`` of the clips it was trained
on. Refined minus proxy on the fit clips against the validation clips tells "cannot fit even its training
clips" (more steps or a larger model would help) from "fits them but does not carry over to unseen
scenes" (more data would). Test clips are never read. Writes results/bench/NAME.json and prints a table::

    .venv/bin/python benchmarks/refiner_scale.py --pairs results/datasets/full/pairs.jsonl \\
        [--layers 2 4] [--fit-groups 1 3] [--max-steps 400] [--steps 50 100 200]

Relative paths in the manifest resolve against the working directory (run it from the workflow root that
built the pairs). Training resumes from --work (default results/bench/NAME/work) when rerun.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import platform
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def subset_manifest(pairs: Path, out: Path, n_fit_groups: int | None, val_scenes, seed: int) -> tuple[dict, list]:
    """Write the train records of the validation groups and of the first ``n_fit_groups`` fit groups
    (all when None) to ``out``; returns the carve-out of the full train split and the fit groups kept."""
    from lightcrafter.refiner.validation import carve_validation, pair_group

    lines = [ln for ln in pairs.read_text().splitlines() if ln.strip()]
    records = [json.loads(ln) for ln in lines]
    train = [r for r in records if r.get("split") == "train"]
    carve = carve_validation(train, val_scenes, seed)
    fit_groups = carve["fit_groups"][:n_fit_groups] if n_fit_groups else carve["fit_groups"]
    keep = set(carve["val_groups"]) | set(fit_groups)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("".join(ln + "\n" for ln, r in zip(lines, records)
                           if r.get("split") == "train" and pair_group(r) in keep))
    return carve, fit_groups


def main() -> int:
    import torch

    from lightcrafter.io import write_json
    from lightcrafter.refiner import PairsDataset
    from lightcrafter.refiner.fit import DIFFUSION_FINAL, _candidate_model, fit_refiner, refine_fn, score_method
    from lightcrafter.refiner.training import _logger

    from refiner_small_scale import _cfg_from_yaml

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pairs", default="results/datasets/full/pairs.jsonl")
    ap.add_argument("--config", default=str(REPO / "config/config.yaml"), help="YAML whose refiner: section is used")
    ap.add_argument("--config-json", default="{}", help="overrides of that refiner config (JSON)")
    ap.add_argument("--layers", type=int, nargs="+", default=[2], help="transformer blocks (model size)")
    ap.add_argument("--fit-groups", type=int, nargs="+", default=[0],
                    help="fit groups trained on (0 = all of them); the validation groups never change")
    ap.add_argument("--max-steps", type=int, default=400)
    ap.add_argument("--steps", type=int, nargs="*", default=[50, 100, 200], help="candidate steps below --max-steps")
    ap.add_argument("--max-fit-clips", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--name", default="refiner_scale")
    ap.add_argument("--work", default=None)
    ap.add_argument("--out", default=None, help="JSON path (default results/bench/NAME.json of the repository)")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    out_json = Path(a.out) if a.out else REPO / "results/bench" / f"{a.name}.json"
    work = Path(a.work) if a.work else out_json.with_suffix("") / "work"
    pairs = Path(a.pairs)
    if not pairs.is_file():
        print(f"{pairs}: no such pairs manifest; run the workflow first (make run) or pass --pairs", file=sys.stderr)
        return 1
    base = _cfg_from_yaml(Path(a.config), json.loads(a.config_json))
    base["seed"] = a.seed
    base["train"]["max_steps"] = a.max_steps
    base["select"]["checkpoints"] = sorted(s for s in a.steps if 0 < s < a.max_steps)
    base["baselines"]["regressor_steps"] = 0  # not what this benchmark measures
    base["select"]["residual_scales"] = sorted(set(base["select"]["residual_scales"]) | {0.0, 1.0})
    ev = base["data"]["exposure_ev"]
    t_all = time.perf_counter()
    runs = []
    for layers in a.layers:
        for n_fit in a.fit_groups:
            cfg = copy.deepcopy(base)
            cfg["model"]["transformer"] = {**cfg["model"]["transformer"], "num_layers": layers}
            d = work / f"layers{layers}_fit{n_fit or 'all'}"
            manifest = d / "pairs.jsonl"
            carve, fit_groups = subset_manifest(pairs, manifest, n_fit or None, cfg["select"]["val_scenes"], a.seed)
            t0 = time.perf_counter()
            summ = fit_refiner(cfg, manifest, d, progress=False, log=_logger(d))
            fit_s = time.perf_counter() - t0
            if not summ["selection"].get("table"):
                print(f"{manifest}: no validation clips ({summ['selection']['note']})", file=sys.stderr)
                return 1
            table, proxy_val = summ["selection"]["table"], summ["selection"]["val_proxy"]
            fit_ds = PairsDataset(manifest, "train", ev, pair_ids=summ["fit_pairs"][: a.max_fit_clips])
            proxy_fit = score_method(lambda it: it["proxy"], fit_ds)
            ae_state = torch.load(d / DIFFUSION_FINAL, map_location="cpu", weights_only=False)["ae"]
            rows = []
            for step in summ["train"]["candidate_steps"]:
                best = {}
                for rs in (0.0, 1.0):
                    cands = [r for r in table if r["step"] == step and r["residual_scale"] == rs]
                    best[rs] = max(cands, key=lambda r: r["psnr_db"])
                full = best[1.0]
                model = _candidate_model(cfg, d, step, a.max_steps, ae_state)
                on_fit = score_method(refine_fn(model, cfg, full["strength"], full["guidance_scale"],
                                                residual_scale=1.0, correction_blur_px=full["correction_blur_px"],
                                                correction_blur_frames=full["correction_blur_frames"]), fit_ds)
                rows.append({
                    "step": step, "strength": full["strength"], "guidance_scale": full["guidance_scale"],
                    "correction_blur_px": full["correction_blur_px"],
                    "correction_blur_frames": full["correction_blur_frames"],
                    "val_refined_psnr_db": round(full["psnr_db"], 3), "val_refined_ssim": round(full["ssim"], 4),
                    "val_anchor_psnr_db": round(best[0.0]["psnr_db"], 3),
                    "val_refined_minus_proxy_db": round(full["psnr_db"] - proxy_val["psnr_db"], 3),
                    "fit_refined_psnr_db": round(on_fit["psnr_db"], 3),
                    "fit_refined_minus_proxy_db": round(on_fit["psnr_db"] - proxy_fit["psnr_db"], 3)})
                print(f"layers {layers} fit groups {n_fit or 'all'} step {step}: {rows[-1]}", flush=True)
            params = sum(p.numel() for p in model.transformer.parameters())
            runs.append({"layers": layers, "transformer_parameters": int(params),
                         "fit_groups": len(fit_groups),
                         "fit_pairs": len(summ["fit_pairs"]), "val_groups": carve["val_groups"],
                         "val_pairs": summ["val_pairs"], "val_proxy_psnr_db": round(proxy_val["psnr_db"], 3),
                         "fit_proxy_psnr_db": round(proxy_fit["psnr_db"], 3),
                         "train_seconds_per_step": summ["train"]["seconds_per_step"], "fit_seconds": round(fit_s, 1),
                         "steps": rows})
    # the report's curve shape (docs/architecture.md): validation gain over the proxy against training seconds
    points = [{"series": f"{r['layers']} blocks, {r['fit_groups']} fit groups", "setting": s["step"],
               "seconds": round(s["step"] * r["train_seconds_per_step"], 1), "value": s["val_refined_minus_proxy_db"]}
              for r in runs for s in r["steps"]]
    result = {"name": "refiner_scale", "varied": "training steps (series: transformer blocks, fit groups)",
              "metric": "validation refined - proxy PSNR (dB)", "higher_is_better": True, "chosen": None,
              "baseline": {"proxy alone": 0.0}, "points": points,
              "pairs": str(pairs), "seed": a.seed, "max_steps": a.max_steps,
              "question": "does the tiny refiner's gain over its proxy on validation scenes grow with steps, "
                          "model size or data?",
              "runs": runs, "seconds": round(time.perf_counter() - t_all, 1),
              "machine": {"cores": os.cpu_count(), "threads": a.threads, "platform": platform.platform()}}
    write_json(out_json, result)
    print(f"\n{'layers':>6} {'fit groups':>10} {'step':>5} {'val refined-proxy dB':>21} "
          f"{'val anchor-proxy dB':>20} {'fit refined-proxy dB':>21}")
    for r in runs:
        for s in r["steps"]:
            print(f"{r['layers']:>6} {r['fit_groups']:>10} {s['step']:>5} {s['val_refined_minus_proxy_db']:>21.3f} "
                  f"{s['val_anchor_psnr_db'] - r['val_proxy_psnr_db']:>20.3f} {s['fit_refined_minus_proxy_db']:>21.3f}")
    print(f"wrote {out_json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
