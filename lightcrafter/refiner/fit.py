"""Fit a refiner end to end: carve validation, train, select on validation, train the baselines.

:func:`fit_refiner` is what ``scripts/train_refiner.py`` runs:

1. **Carve** validation scenes out of the train split (:mod:`.validation`; ``select.val_scenes``).
   The rest (the *fit* pairs) is all that any model or baseline is trained on.
2. **Train** the diffusion refiner on the fit pairs (:func:`.training.train`), keeping the weights at
   ``select.checkpoints`` and at the last step as candidates.
3. **Select** on validation: every (candidate step, ``select.strengths``, ``select.guidance_scales``,
   ``select.residual_scales``) refines up to ``select.max_val_pairs`` validation clips (taken round-robin
   over validation scenes) with the run's sampler and seed, once, and each (``select.correction_blurs_px``,
   ``select.correction_blurs_frames``) is applied to that sample; the highest mean ``select.metric`` wins
   (ties: the earlier step, then the smaller strength, then the smaller guidance, then the full model, then
   the correction least blurred). Residual scale 0 is the learned anchor map of the proxy alone (trained
   jointly with the transformer): when the transformer's correction does not generalise to unseen scenes,
   validation says so and the refiner falls back to its anchor. A candidate is not chosen, whatever its score,
   whose clips carry more block-grid texture than ``select.max_block_ratio`` times the proxy's
   (:func:`block_ratio`), step at the 4-frame blocks more than ``select.max_jump_ratio`` times their targets
   (:func:`jump_ratio`), or are less consistent over time than ``select.min_warp_ssim_ratio`` times the
   proxy's (:func:`warp_ssim_ratio`); each limit applies when set. Without validation scenes nothing is
   selected and ``infer.*`` is used as configured.
4. **Baselines** (``baselines.*``): the one-step regressor (same network, trained on the fit pairs for
   ``baselines.regressor_steps``) and the affine colour fit, both scored on the same validation clips.
5. Writes ``out_dir/model.pt`` last: the chosen weights, the config with the chosen ``infer.*``
   (:data:`.training.SELECTED_INFER_KEYS`), the selection table, the baselines and the carve-out.

Resumable: a killed run resumes training from its checkpoints (bit-exact) and redoes the cheap,
deterministic selection. Test pairs are never read.
"""

from __future__ import annotations

import copy
import itertools
import logging
import time
from pathlib import Path

import numpy as np
import torch

from lightcrafter.io import DataError

from .baselines import apply_affine_colour, fit_affine_colour, regress_video
from .data import PairsDataset, read_pairs
from .model import Refiner
from .sampler import blur_correction, refine_parts, resolved_correction_blurs, resolved_residual_scale
from .scoring import clip_scores
from .training import SELECTED_INFER_KEYS, load_model, run_fingerprint, save_checkpoint, snapshot_path, train
from .validation import carve_validation, pair_group

DIFFUSION_FINAL = "diffusion.pt"
REGRESSOR_DIR = "regressor"


def _round_robin(records: list[dict], ids: list[str], limit: int) -> list[str]:
    """Up to ``limit`` pair ids of ``ids``, alternating over their groups (manifest order inside one)."""
    by_group: dict[str, list[str]] = {}
    for r in records:
        if r["pair_id"] in ids:
            by_group.setdefault(pair_group(r), []).append(r["pair_id"])
    out = []
    for row in itertools.zip_longest(*[by_group[g] for g in sorted(by_group)]):
        out += [p for p in row if p is not None]
    return out[: max(int(limit), 0)]


def score_method(fn, dataset, block_grid: bool = False, temporal: dict | None = None) -> dict:
    """Apply ``fn(item) -> (3, N, H, W)`` to every item; per-pair scores, means and seconds per clip.
    ``block_grid``: also ``block_ratio``, the mean over pairs of the output's block-grid texture over the
    proxy's (:func:`block_ratio`). ``temporal``: a dict (reused across calls, it caches each pair's target flow
    and proxy Warp-SSIM): also ``warp_ssim_ratio``, the mean over pairs of :func:`warp_ssim_ratio`."""
    return score_variants(lambda item: {None: fn(item)}, dataset, block_grid, temporal)[None]


def score_variants(fn, dataset, block_grid: bool = False, temporal: dict | None = None,
                   jump: bool = False) -> dict:
    """:func:`score_method` for ``fn(item) -> {key: (3, N, H, W)}``, several outputs made from one run over a
    clip (e.g. one sample and each correction blur applied to it): ``{key: scores}``, every key's seconds per
    clip being that shared run's. ``jump``: also ``jump_ratio``, the mean over pairs of :func:`jump_ratio`."""
    rows: dict = {}
    secs = []
    for i in range(len(dataset)):
        item = dataset[i]
        t0 = time.perf_counter()
        outs = fn(item)
        secs.append(time.perf_counter() - t0)
        target_jump = _block_jump_value(item["target"]) if jump else None
        for key, out in outs.items():
            row = {"pair_id": item["pair_id"], **clip_scores(out, item["target"])}
            if block_grid:
                row["block_ratio"] = block_ratio(out, item["proxy"])
            if temporal is not None:
                row["warp_ssim_ratio"] = warp_ssim_ratio(out, item, temporal)
            if jump:
                row["jump_ratio"] = jump_ratio(out, item["target"], target_jump)
            rows.setdefault(key, []).append(row)
    res = {}
    for key, kr in rows.items():
        res[key] = {"pairs": kr, "psnr_db": float(np.mean([r["psnr_db"] for r in kr])),
                    "ssim": float(np.mean([r["ssim"] for r in kr])), "seconds_per_clip": float(np.mean(secs))}
        for name in ("block_ratio", "warp_ssim_ratio", "jump_ratio"):
            if name in kr[0]:
                res[key][name] = float(np.mean([r[name] for r in kr]))
    return res


def warp_ssim_ratio(video, item: dict, cache: dict) -> float:
    """Temporal consistency of a refined clip relative to its proxy's: Warp-SSIM of ``video`` over Warp-SSIM of
    ``item["proxy"]``, both with the optical flow of ``item["target"]`` (the flow source of the evaluation,
    :func:`lightcrafter.evaluation.warp_ssim`; 1 = as consistent as the proxy). Clips (3, N, H, W) in [-1, 1].
    A clip without an answer (one frame, frames too small for OpenCV's DIS flow, no unoccluded pixel) counts as 1.
    ``cache`` keeps each pair's flow and proxy Warp-SSIM by pair id."""
    from lightcrafter.evaluation import compute_flows, no_flow_reason, warp_ssim

    from .data import to_display_frames

    key = item["pair_id"]
    if key not in cache:
        target = to_display_frames(item["target"])
        if no_flow_reason(target):  # one frame, or frames too small for DIS
            cache[key] = None
        else:
            flows = compute_flows(target)
            cache[key] = (flows, warp_ssim(to_display_frames(item["proxy"]), flows=flows).value)
    if cache[key] is None or not cache[key][1]:
        return 1.0
    flows, proxy_value = cache[key]
    value = warp_ssim(to_display_frames(video), flows=flows).value
    return 1.0 if value is None else float(value / proxy_value)


def block_ratio(video, proxy) -> float:
    """Block-grid texture of a refined clip relative to its proxy's: the larger of the 8- and 16-pixel
    :func:`lightcrafter.evaluation.blockiness` ratios (refined / proxy; 1 = no grid added). Clips too small or
    too flat for the metric count as 1. Both clips (3, N, H, W) in [-1, 1]."""
    from lightcrafter.evaluation import blockiness

    from .data import to_display_frames

    a, b = to_display_frames(video), to_display_frames(proxy)
    ratios = []
    for period in (8, 16):
        ra, rb = blockiness(a, period).value, blockiness(b, period).value
        if ra is not None and rb:
            ratios.append(ra / rb)
    return float(max(ratios)) if ratios else 1.0


def _block_jump_value(video) -> float | None:
    """:func:`lightcrafter.evaluation.block_jump` of a (3, N, H, W) clip in [-1, 1] (None: no answer)."""
    from lightcrafter.evaluation import block_jump

    from .data import to_display_frames

    return block_jump(to_display_frames(video)).value


_NOT_GIVEN = object()


def jump_ratio(video, target, target_jump=_NOT_GIVEN) -> float:
    """Temporal steps of a refined clip at the autoencoder's 4-frame blocks relative to its target's: the
    :func:`lightcrafter.evaluation.block_jump` of ``video`` over that of ``target`` (1 = the target's; the
    refiner's goal is within 10 %). A clip without an answer (too short, no change between boundaries) counts
    as 1. Both (3, N, H, W) in [-1, 1]. ``target_jump``: the target's own jump when already computed (one per
    clip for every output scored against it; None when it has no answer)."""
    ra = _block_jump_value(video)
    rb = _block_jump_value(target) if target_jump is _NOT_GIVEN else target_jump
    return float(ra / rb) if ra is not None and rb else 1.0


def refine_fn(model, cfg: dict, strength: float, guidance_scale: float, num_steps: int | None = None,
              residual_scale: float | None = None, correction_blur_px: float | None = None,
              correction_blur_frames: float | None = None):
    """A clip -> refined clip function with the run's per-clip seed (as ``scripts/infer_refiner.py``); the
    residual scale and the correction's blurs default to ``infer``'s. :func:`refine_blurs_fn` with one blur."""
    blur = resolved_correction_blurs(cfg, correction_blur_px, correction_blur_frames)
    fn = refine_blurs_fn(model, cfg, strength, guidance_scale, resolved_residual_scale(cfg, residual_scale), [blur],
                         num_steps=num_steps)
    return lambda item: fn(item)[blur]


def refine_blurs_fn(model, cfg: dict, strength: float, guidance_scale: float, residual_scale: float,
                    blurs: list[tuple[float, float]], num_steps: int | None = None):
    """A clip -> ``{(correction_blur_px, correction_blur_frames): refined clip}`` function: the clip sampled once
    with the run's per-clip seed, then each correction blur applied to that sample -- what
    ``scripts/infer_refiner.py`` makes with that blur, at the cost of one sample."""
    def fn(item):
        gen = torch.Generator().manual_seed(cfg["seed"])
        out, anchor = refine_parts(model, item["proxy"][None], cfg, generator=gen, strength=strength,
                                   guidance_scale=guidance_scale, residual_scale=residual_scale, num_steps=num_steps,
                                   with_anchor=any(px > 0 or fr > 0 for px, fr in blurs))
        return {(px, fr): (out if anchor is None else blur_correction(out, anchor, px, fr).clamp(-1, 1)).cpu()[0]
                for px, fr in blurs}
    return fn


def _limits(sel: dict) -> list[tuple[str, float, str]]:
    """The selection's limits that are set: (table key, bound, "max" | "min")."""
    keys = (("max_block_ratio", "block_ratio", "max"), ("max_jump_ratio", "jump_ratio", "max"),
            ("min_warp_ssim_ratio", "warp_ssim_ratio", "min"))
    return [(key, float(sel[name]), kind) for name, key, kind in keys if sel.get(name) is not None]


def _within_limits(row: dict, limits) -> bool:
    return all(row[k] <= b if kind == "max" else row[k] >= b for k, b, kind in limits)


def _least_violating(table: list[dict], limits) -> list[dict]:
    """When no candidate is within every limit: for each upper limit in turn (block grid, then 4-frame jump),
    those within it if any, else the least violating; then, with a Warp-SSIM limit, the most consistent over
    time among them."""
    pool = table
    for key, bound, kind in limits:
        if kind == "max":
            within = [r for r in pool if r[key] <= bound]
            pool = within or [r for r in pool if r[key] == min(x[key] for x in pool)]
        else:
            pool = [r for r in pool if r[key] == max(x[key] for x in pool)]
    return pool


def _candidate_model(cfg: dict, out_dir: Path, step: int, final_step: int, ae_state: dict) -> Refiner:
    if step == final_step:
        return load_model(out_dir / DIFFUSION_FINAL, apply_selection=False)
    model = Refiner(cfg)
    model.load_weights(torch.load(snapshot_path(out_dir, step), map_location="cpu", weights_only=False))
    model.ae.load_state_dict(ae_state)
    return model.to_configured_device().eval()


def select_on_validation(cfg: dict, out_dir: Path, steps: list[int], ae_state: dict, val_ds,
                         log: logging.Logger) -> tuple[dict, int]:
    """Step 3 of the module docstring over the candidate ``steps`` saved in ``out_dir`` (the last one being
    ``train.max_steps``'s final weights): the selection record (chosen settings, the table of every candidate,
    the proxy's validation score) and the chosen step."""
    sel = cfg["select"]
    max_steps = int(cfg["train"]["max_steps"])
    table = []
    limits = _limits(sel)
    lim = [k for k, _b, _kind in limits]  # the table keys the limits need, in the limits' order
    flow_cache: dict | None = {} if "warp_ssim_ratio" in lim else None
    all_blurs = sorted(itertools.product(sorted(sel["correction_blurs_px"]), sorted(sel["correction_blurs_frames"])))
    for step in steps:
        model = _candidate_model(cfg, out_dir, step, max_steps, ae_state)
        for s, g, rs in itertools.product(sorted(sel["strengths"]), sorted(sel["guidance_scales"]),
                                          sorted(sel["residual_scales"], reverse=True)):
            if float(rs) == 0.0 and (float(g) != min(sel["guidance_scales"]) or float(s) != min(sel["strengths"])):
                continue  # the anchor alone ignores guidance and, to rounding, strength: score it once per step,
                # at the smallest of each
            blurs = [(0.0, 0.0)] if float(rs) == 0.0 else all_blurs  # the anchor alone has no correction to blur
            scores = score_variants(refine_blurs_fn(model, cfg, float(s), float(g), float(rs), blurs), val_ds,
                                    block_grid="block_ratio" in lim, temporal=flow_cache, jump="jump_ratio" in lim)
            for (bl, bf), sc in scores.items():
                row = {"step": step, "strength": float(s), "guidance_scale": float(g), "residual_scale": float(rs),
                       "correction_blur_px": float(bl), "correction_blur_frames": float(bf),
                       "psnr_db": sc["psnr_db"], "ssim": sc["ssim"], "seconds_per_clip": sc["seconds_per_clip"]}
                row.update({k: sc[k] for k in lim})
                if limits:
                    row["admissible"] = _within_limits(row, limits)
                table.append(row)
                log.info("validation step %d strength %.2f guidance %.1f residual %.1f blur %.1f px %.1f frames: "
                         "%.3f dB, SSIM %.4f%s", step, s, g, rs, bl, bf, sc["psnr_db"], sc["ssim"],
                         "".join(f", {k} {sc[k]:.3f}" for k in lim))
    metric = sel["metric"]
    within = [r for r in table if r.get("admissible", True)]
    pool = within
    if not pool:
        pool = _least_violating(table, limits)
        log.info("no candidate is within the selection's limits %s; the least violating is chosen", limits)
    # ties go to the earlier step, the smaller strength and guidance, the full model (residual 1) and the
    # correction least blurred
    best = max(pool, key=lambda r: (r[metric], -r["step"], -r["strength"], -r["guidance_scale"],
                                    r["residual_scale"], -r["correction_blur_px"], -r["correction_blur_frames"]))
    chosen = {"step": best["step"], "metric": metric, "value": best[metric],
              **{k: best[k] for k in SELECTED_INFER_KEYS}}
    chosen.update({k: best[k] for k in lim})
    proxy = score_method(lambda item: item["proxy"], val_ds)
    log.info("chosen on validation: %s (proxy alone %.3f dB)", chosen, proxy["psnr_db"])
    return {"chosen": chosen, "table": table, "val_proxy": {k: proxy[k] for k in ("psnr_db", "ssim")},
            "num_val_pairs": len(val_ds), "candidates": len(table), "admissible_candidates": len(within)}, best["step"]


def fit_refiner(cfg: dict, pairs_path, out_dir, *, root=None, progress: bool = True,
                log: logging.Logger | None = None) -> dict:
    """Steps 1-5 of the module docstring; returns the summary stored in ``model.pt`` (bar weights)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    log = log or logging.getLogger("lightcrafter.refiner.fit")
    sel, base, data = cfg["select"], cfg["baselines"], cfg["data"]
    records = read_pairs(pairs_path, "train")
    if data["max_train_pairs"] is not None:
        records = records[: int(data["max_train_pairs"])]
    if not records:
        raise DataError(f"{pairs_path}: no pairs with split == 'train'")
    carve = carve_validation(records, sel["val_scenes"], cfg["seed"])
    log.info("validation: %s (val scenes %s)", carve["note"], carve["val_groups"])
    kw = dict(exposure_ev=data["exposure_ev"], root=root)
    fit_ds = PairsDataset(pairs_path, "train", cache=data["cache_pixels"], pair_ids=carve["fit"], **kw)
    val_ids = _round_robin(records, carve["val"], sel["max_val_pairs"])
    val_ds = PairsDataset(pairs_path, "train", cache=True, pair_ids=val_ids, **kw)
    selecting = len(val_ds) > 0

    max_steps = int(cfg["train"]["max_steps"])
    steps = sorted({int(s) for s in sel["checkpoints"] if 0 < int(s) < max_steps} | {max_steps}) if selecting \
        else [max_steps]
    t0 = time.perf_counter()
    res = train(cfg, fit_ds, out_dir, snapshot_steps=steps, final_name=DIFFUSION_FINAL, progress=progress)
    train_seconds = time.perf_counter() - t0
    if res["rank"] != 0:  # data-parallel training: rank 0 selects and writes the model
        return {"train": {"steps": res["step"], "seconds_per_step": res["seconds_per_step"]}, "rank": res["rank"]}
    final = torch.load(out_dir / DIFFUSION_FINAL, map_location="cpu", weights_only=False)

    fingerprint = run_fingerprint(cfg, fit_ds)
    for step in [s for s in steps if s != max_steps]:
        p = snapshot_path(out_dir, step)
        if not p.is_file() or torch.load(p, map_location="cpu", weights_only=False).get("fingerprint") != fingerprint:
            log.info("candidate step %d was not saved by this training run (a finished run resumed with new "
                     "select.checkpoints?); skipped -- delete %s to retrain with it", step, out_dir)
            steps.remove(step)
    summary: dict = {"carve": carve, "val_pairs": val_ds.pair_ids, "fit_pairs": fit_ds.pair_ids,
                     "train": {"steps": res["step"], "seconds_per_step": res["seconds_per_step"],
                               "seconds_this_run": train_seconds, "candidate_steps": list(steps)}}
    weight_keys = ("transformer", "anchor_map")
    chosen_sd = {k: final[k] for k in weight_keys if k in final}
    t0 = time.perf_counter()
    if selecting:
        summary["selection"], best_step = select_on_validation(cfg, out_dir, steps, final["ae"], val_ds, log)
        summary["selection"]["note"] = carve["note"]
        if best_step != max_steps:
            snap = torch.load(snapshot_path(out_dir, best_step), map_location="cpu", weights_only=False)
            chosen_sd = {k: snap[k] for k in weight_keys if k in snap}
    else:
        summary["selection"] = {"chosen": None, "note": carve["note"] if float(sel["val_scenes"]) > 0
                                else "selection off (select.val_scenes = 0)"}
    summary["selection"]["seconds"] = time.perf_counter() - t0

    baselines: dict = {}
    if int(base["regressor_steps"]) > 0:
        rcfg = copy.deepcopy(cfg)
        rcfg["train"]["max_steps"] = int(base["regressor_steps"])
        t0 = time.perf_counter()
        rres = train(rcfg, fit_ds, out_dir / REGRESSOR_DIR, objective="regression", final_name="model.pt",
                     progress=progress)
        rst = torch.load(out_dir / REGRESSOR_DIR / "model.pt", map_location="cpu", weights_only=False)
        baselines["regressor"] = {**{k: rst[k] for k in weight_keys if k in rst}, "ae": rst["ae"],
                                  "steps": rres["step"], "seconds_this_run": time.perf_counter() - t0}
        if selecting:
            reg = Refiner(cfg)
            reg.load_weights(rst)
            reg.ae.load_state_dict(rst["ae"])
            reg.to_configured_device()
            sc = score_method(lambda item: regress_video(reg.eval(), item["proxy"][None])[0], val_ds)
            baselines["regressor"]["val"] = {k: sc[k] for k in ("psnr_db", "ssim")}
    if base["affine_colour"]:
        baselines["affine_colour"] = fit_affine_colour(fit_ds)
        if selecting:
            sc = score_method(lambda item: apply_affine_colour(baselines["affine_colour"], item["proxy"]), val_ds)
            baselines["affine_colour"]["val"] = {k: sc[k] for k in ("psnr_db", "ssim")}

    out_cfg = copy.deepcopy(cfg)
    if summary["selection"]["chosen"]:
        out_cfg["infer"].update({k: summary["selection"]["chosen"][k] for k in SELECTED_INFER_KEYS})
    save_checkpoint(out_dir / "model.pt", {**chosen_sd, "ae": final["ae"], "config": out_cfg,
                                           "selection": summary["selection"], "baselines": baselines,
                                           "carve": carve, "train": summary["train"]})
    summary["baselines"] = {k: {kk: vv for kk, vv in v.items() if kk not in ("transformer", "anchor_map", "ae")}
                            for k, v in baselines.items()}
    return summary
