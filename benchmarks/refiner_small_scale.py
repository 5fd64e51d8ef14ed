"""Does the small-scale refiner improve on its proxy? Measured honestly, on any pairs manifest.

Trains the refiner of a config (default: the ``refiner:`` section of config/config.yaml) exactly as
the workflow does (``lightcrafter.refiner.fit.fit_refiner``: validation scenes carved out of the train
split, checkpoint/strength/guidance chosen there, baselines trained on the same fit pairs) for several
training seeds, then measures on the fit (train), validation and held-out test clips:

* ceilings: autoencoder round trip of the target and of the proxy (what the latent space allows);
* the strength curve (0, 0.1, 0.2, 0.3, 0.5, 0.7, 1) at the selected guidance, and the guidance
  curve (1, 2, 4, 6) at the selected strength: PSNR, SSIM and seconds per clip;
* the selected setting against the proxy on every test clip: per-clip refined - proxy (PSNR, SSIM),
  averaged over seeds, with a 95% bootstrap interval over clips (and over clip x seed);
* the baselines: one-step regressor (same network) and per-channel affine colour fit;
* gain against data (``--train-scenes``): the same fit with only the first n train-split scenes
  (a nested sequence, validation carved from them as the workflow would), on the same test clips;
* frame strips (input if the pairs have a source | proxy | refined | regressor | affine | target);
* diagnostic ``anchor_only``: the trained refiner with the transformer's output zeroed (what the
  learned anchor map alone does) against the full refiner, on validation and test clips.

Test clips are only ever scored, never used to choose anything. Writes
results/bench/NAME.json (+ .png via the report's plot, + NAME/ with strips).

    .venv/bin/python benchmarks/refiner_small_scale.py --pairs results/datasets/clean_buffers/pairs.jsonl \
        [--seeds 0 1 2] [--train-scenes 2 6 12] [--name refiner_small_scale]

Relative paths in the manifest resolve against the working directory (run it from the workflow
root that built the pairs). Models are kept in --work (default results/bench/NAME/work) so a rerun
resumes training instead of starting over.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

STRENGTHS = [0.0, 0.1, 0.2, 0.3, 0.5, 0.7, 1.0]
GUIDANCES = [1.0, 2.0, 4.0, 6.0]


def _cfg_from_yaml(path: Path, overrides: dict) -> dict:
    """The resolved ``refiner:`` section of a pipeline config file, its ``extends`` chain followed (a file such as
    config/study.yaml holds only what it changes), with ``overrides`` merged over it."""
    from lightcrafter.config import read_configfile
    from lightcrafter.refiner import resolve_config
    from lightcrafter.refiner.config import _merge

    user = read_configfile(path).get("refiner", {})
    base = {k: v for k, v in user.items() if k != "resources"}
    return resolve_config(_merge(resolve_config(base), overrides)) if overrides else resolve_config(base)


def _subset_manifest(pairs: Path, out: Path, n_scenes: int, seed: int) -> list[str]:
    """Write the manifest with only the first ``n_scenes`` train-split scenes (nested in n) + all test."""
    from lightcrafter.io import read_jsonl, write_jsonl
    from lightcrafter.refiner.validation import pair_group

    recs = read_jsonl(pairs)
    groups = sorted({pair_group(r) for r in recs if r["split"] == "train"},
                    key=lambda g: hashlib.sha256(f"data{seed}:{g}".encode()).hexdigest())
    keep = set(groups[:n_scenes])
    write_jsonl(out, [r for r in recs if r["split"] == "test" or (r["split"] == "train" and pair_group(r) in keep)])
    return sorted(keep)


def main() -> int:
    import numpy as np
    import torch

    from lightcrafter.io import write_json
    from lightcrafter.refiner import DCTPatchAutoencoder, PairsDataset, load_model, read_pairs
    from lightcrafter.refiner.baselines import apply_affine_colour, load_affine_colour, load_regressor, regress_video
    from lightcrafter.refiner.data import to_display_frames
    from lightcrafter.refiner.fit import fit_refiner, refine_fn, score_method
    from lightcrafter.evaluation import bootstrap_ci
    from lightcrafter.refiner.strip import write_strip
    from lightcrafter.refiner.training import _logger
    from lightcrafter.refiner.validation import pair_group
    from lightcrafter.report import plot_bench

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pairs", default="results/datasets/clean_buffers/pairs.jsonl")
    ap.add_argument("--config", default=str(REPO / "config/config.yaml"), help="YAML whose refiner: section is used")
    ap.add_argument("--config-json", default="{}", help="overrides of that refiner config (JSON)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--train-scenes", type=int, nargs="*", default=[], help="data study: train-split scene counts")
    ap.add_argument("--data-seeds", type=int, nargs="+", default=None, help="seeds of the data study (default --seeds)")
    ap.add_argument("--max-fit-clips", type=int, default=6, help="fit (train) clips scored in the curves")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--name", default="refiner_small_scale")
    ap.add_argument("--work", default=None)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    out_json = REPO / "results/bench" / f"{a.name}.json"
    out_dir = out_json.with_suffix("")
    work = Path(a.work) if a.work else out_dir / "work"
    work.mkdir(parents=True, exist_ok=True)
    pairs = Path(a.pairs)
    cfg0 = _cfg_from_yaml(Path(a.config), json.loads(a.config_json))
    ev = cfg0["data"]["exposure_ev"]
    test = PairsDataset(pairs, "test", ev, cache=True)
    if len(test) == 0:
        print(f"{pairs}: no test pairs", file=sys.stderr)
        return 1
    t_all = time.perf_counter()

    def mean_scores(res):
        return {k: round(res[k], 4) for k in ("psnr_db", "ssim", "seconds_per_clip")}

    # --- ceilings (autoencoder round trips; a fixed linear projection, independent of training)
    m = cfg0["model"]
    ae = DCTPatchAutoencoder(m["ae_coeffs"], m["ae_normalisation"]) if m["kind"] == "tiny" else None
    ceilings = {}
    if ae is not None:
        for key in ("target", "proxy"):
            r = score_method(lambda it, k=key: ae.decode(ae.encode(it[k][None]))[0].clamp(-1, 1), test)
            ceilings[f"ae_round_trip_{key}"] = mean_scores(r)
    proxy_test = score_method(lambda it: it["proxy"], test)

    # --- seeds: fit as the workflow does, then curves on fit / val / test clips
    per_seed, diffs, sel_by_seed = [], {}, {}
    for seed in a.seeds:
        cfg = {**cfg0, "seed": seed}
        d = work / f"seed{seed}"
        d.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        summ = fit_refiner(cfg, pairs, d, progress=False, log=_logger(d))
        fit_s = time.perf_counter() - t0
        model = load_model(d / "model.pt")
        chosen = summ["selection"]["chosen"] or {"strength": cfg["infer"]["strength"],
                                                  "guidance_scale": cfg["infer"]["guidance_scale"]}
        sets = {"fit": PairsDataset(pairs, "train", ev, pair_ids=summ["fit_pairs"][: a.max_fit_clips]),
                "val": PairsDataset(pairs, "train", ev, pair_ids=summ["val_pairs"]), "test": test}
        curves = {"strength": {}, "guidance": {}}
        for name, ds in sets.items():
            if len(ds) == 0:
                continue
            curves["strength"][name] = [{"strength": s, **mean_scores(score_method(
                refine_fn(model, model.cfg, s, chosen["guidance_scale"]), ds))} for s in STRENGTHS]
            curves["guidance"][name] = [{"guidance_scale": g, **mean_scores(score_method(
                refine_fn(model, model.cfg, chosen["strength"], g), ds))} for g in GUIDANCES]
            curves["strength"][name + "_proxy"] = mean_scores(score_method(lambda it: it["proxy"], ds))
            print(f"seed {seed} {name}: {curves['strength'][name]}", flush=True)
        sel = score_method(refine_fn(model, model.cfg, chosen["strength"], chosen["guidance_scale"]), test)
        base = {}
        reg = load_regressor(d / "model.pt")
        if reg is not None:
            base["regressor"] = score_method(lambda it: regress_video(reg, it["proxy"][None])[0], test)
        aff = load_affine_colour(d / "model.pt")
        if aff is not None:
            base["affine_colour"] = score_method(lambda it: apply_affine_colour(aff, it["proxy"]), test)
        anchor_only = {}
        if getattr(model, "anchor_map", None) is not None:  # diagnostic: the learned anchor without the transformer
            bare = load_model(d / "model.pt")
            with torch.no_grad():
                bare.transformer.proj_out.weight.zero_()
                bare.transformer.proj_out.bias.zero_()
            for name in ("val", "test"):
                if len(sets[name]):
                    anchor_only[name] = mean_scores(score_method(
                        refine_fn(bare, bare.cfg, chosen["strength"], chosen["guidance_scale"]), sets[name]))
                    anchor_only[name + "_refined"] = mean_scores(score_method(
                        refine_fn(model, model.cfg, chosen["strength"], chosen["guidance_scale"],
                                  residual_scale=1.0), sets[name]))
        for meth, res in [("refined", sel), *base.items()]:
            for rp, rr in zip(proxy_test["pairs"], res["pairs"]):
                for k in ("psnr_db", "ssim"):
                    diffs.setdefault(meth, {}).setdefault(k, {}).setdefault(rp["pair_id"], []).append(rr[k] - rp[k])
        per_seed.append({"seed": seed, "chosen": summ["selection"]["chosen"], "selection_note": summ["selection"]["note"],
                         "val_pairs": summ["val_pairs"], "fit_pairs": summ["fit_pairs"],
                         "fit_seconds": round(fit_s, 1), "train_seconds_per_step": summ["train"]["seconds_per_step"],
                         "selection_seconds": round(summ["selection"]["seconds"], 1),
                         "baseline_train": summ["baselines"], "test_refined": mean_scores(sel),
                         "test_baselines": {k: mean_scores(v) for k, v in base.items()}, "curves": curves,
                         "anchor_only": anchor_only,
                         "selection_table": summ["selection"].get("table")})
        sel_by_seed[seed] = {
            "val_scenes": summ["carve"]["val_groups"], "fit_pairs": len(summ["fit_pairs"]),
            "chosen": summ["selection"]["chosen"], "fit_seconds": round(fit_s, 1), "test_refined": mean_scores(sel),
            "refined_minus_proxy_psnr_db": bootstrap_ci(
                [r["psnr_db"] - p["psnr_db"] for r, p in zip(sel["pairs"], proxy_test["pairs"])]),
            "refined_minus_proxy_ssim": bootstrap_ci(
                [r["ssim"] - p["ssim"] for r, p in zip(sel["pairs"], proxy_test["pairs"])]),
            **{f"test_{k}": mean_scores(v) for k, v in base.items()}}
        print(f"seed {seed}: chosen {chosen}; test refined {mean_scores(sel)} vs proxy {mean_scores(proxy_test)}; "
              f"baselines { {k: mean_scores(v) for k, v in base.items()} }", flush=True)
        if seed == a.seeds[0]:  # frame strips of the first seed
            outs = {"refined": sel, **base}
            for i in range(len(test)):
                item = test[i]
                src = test.source_frames(i)
                cols = ([("input", to_display_frames(src))] if src is not None else []) + [
                    ("proxy", to_display_frames(item["proxy"])),
                    ("refined", to_display_frames(refine_fn(model, model.cfg, chosen["strength"],
                                                            chosen["guidance_scale"])(item)))]
                if reg is not None:
                    cols.append(("regressor", to_display_frames(regress_video(reg, item["proxy"][None])[0])))
                if aff is not None:
                    cols.append(("affine", to_display_frames(apply_affine_colour(aff, item["proxy"]))))
                cols.append(("target", to_display_frames(item["target"])))
                write_strip(out_dir / f"strip_{item['pair_id']}.png", cols)
            del outs

    def ci_block(per_pair: dict) -> dict:
        clip_means = [float(np.mean(v)) for v in per_pair.values()]
        pooled = [x for v in per_pair.values() for x in v]
        return {"per_clip_seed_mean": bootstrap_ci(clip_means), "pooled_clip_x_seed": bootstrap_ci(pooled)}

    differences = {meth: {k: ci_block(v) for k, v in d.items()} for meth, d in diffs.items()}

    # --- gain against data
    data_study = []
    n_groups = len({pair_group(r) for r in read_pairs(pairs, "train")})
    for n in a.train_scenes:
        for seed in (a.data_seeds or a.seeds):
            if n == n_groups and seed in sel_by_seed:  # every train-split scene: the seed run above
                data_study.append({"train_scenes": n, "seed": seed, "same_as": f"seeds[{a.seeds.index(seed)}]",
                                   **sel_by_seed[seed]})
                continue
            sub = work / f"data_n{n}_s{seed}"
            sub.mkdir(parents=True, exist_ok=True)
            scenes = _subset_manifest(pairs, sub / "pairs.jsonl", n, seed)
            if len(scenes) < n:
                print(f"data study: only {len(scenes)} train-split scenes, skipping n={n}", flush=True)
                break
            cfg = {**cfg0, "seed": seed}
            t0 = time.perf_counter()
            summ = fit_refiner(cfg, sub / "pairs.jsonl", sub, progress=False, log=_logger(sub))
            fit_s = time.perf_counter() - t0
            model = load_model(sub / "model.pt")
            chosen = summ["selection"]["chosen"] or {"strength": cfg["infer"]["strength"],
                                                      "guidance_scale": cfg["infer"]["guidance_scale"]}
            sel = score_method(refine_fn(model, model.cfg, chosen["strength"], chosen["guidance_scale"]), test)
            row = {"train_scenes": n, "seed": seed, "scenes": scenes, "val_scenes": summ["carve"]["val_groups"],
                   "fit_pairs": len(summ["fit_pairs"]), "chosen": summ["selection"]["chosen"],
                   "fit_seconds": round(fit_s, 1), "test_refined": mean_scores(sel),
                   "refined_minus_proxy_psnr_db": bootstrap_ci(
                       [r["psnr_db"] - p["psnr_db"] for r, p in zip(sel["pairs"], proxy_test["pairs"])]),
                   "refined_minus_proxy_ssim": bootstrap_ci(
                       [r["ssim"] - p["ssim"] for r, p in zip(sel["pairs"], proxy_test["pairs"])])}
            reg = load_regressor(sub / "model.pt")
            if reg is not None:
                rs = score_method(lambda it: regress_video(reg, it["proxy"][None])[0], test)
                row["test_regressor"] = mean_scores(rs)
            aff = load_affine_colour(sub / "model.pt")
            if aff is not None:
                row["test_affine_colour"] = mean_scores(score_method(lambda it: apply_affine_colour(aff, it["proxy"]), test))
            data_study.append(row)
            print(f"data study n={n} seed={seed}: {row['test_refined']} gain {row['refined_minus_proxy_psnr_db']}",
                  flush=True)

    # --- benchmark JSON (docs/architecture.md shape: points = test strength curve, seed-mean)
    s0 = per_seed[0]
    points = []
    for split in ("test", "val", "fit"):
        rows = [ps["curves"]["strength"].get(split) for ps in per_seed]
        if not all(rows):
            continue
        for j, s in enumerate(STRENGTHS):
            points.append({"series": f"{split}, guidance selected", "setting": s,
                           "seconds": round(float(np.mean([r[j]["seconds_per_clip"] for r in rows])), 4),
                           "value": round(float(np.mean([r[j]["psnr_db"] for r in rows])), 4),
                           "ssim": round(float(np.mean([r[j]["ssim"] for r in rows])), 4)})
    n_train = len(read_pairs(pairs, "train"))
    bench = {
        "name": a.name, "varied": "SDEdit strength (selected guidance; mean over seeds)", "metric": "psnr_db",
        "higher_is_better": True, "machine": {"cores": os.cpu_count(), "platform": platform.platform(),
                                              "torch_threads": a.threads},
        "chosen": (s0["chosen"] or {}).get("strength"), "chosen_series": "test, guidance selected",
        "baseline": {"proxy_psnr_db": round(proxy_test["psnr_db"], 4), "proxy_ssim": round(proxy_test["ssim"], 4)},
        "pairs": {"manifest": str(pairs), "train": n_train, "test": len(test)},
        "config": cfg0, "ceilings": ceilings, "seeds": per_seed, "differences_vs_proxy": differences,
        "data_study": data_study, "strips": sorted(str(p) for p in out_dir.glob("strip_*.png")),
        "notes": "PSNR/SSIM on display values vs the Cycles target; seconds = sampling + decoding per clip on this "
                 "machine's CPU with the given torch threads; strengths above the largest select.strengths lie "
                 "outside the timesteps the model was trained on (train.timesteps = sampler_range)",
        "total_seconds": round(time.perf_counter() - t_all, 1), "points": points,
    }
    write_json(out_json, bench)
    plot_bench(bench, out_json.with_suffix(".png"))
    print(f"proxy alone on test: {proxy_test['psnr_db']:.3f} dB / {proxy_test['ssim']:.4f}; "
          f"differences {json.dumps({m: {k: v['per_clip_seed_mean'] for k, v in d.items()} for m, d in differences.items()})}")
    print(f"wrote {out_json} in {bench['total_seconds']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
