"""The evaluation protocol of a held-out benchmark (``scripts/evaluate_refiner.py`` is its entry point): every method
of every pair against its target, with the metric registry (:data:`lightcrafter.evaluation.METRICS`).

Methods: ``proxy`` (the PBR proxy from Phi buffers), ``oracle_proxy`` (R on ground-truth buffers, where the
benchmark has it), ``refined`` (the refiner with the settings chosen on validation), the baselines the
inference manifest lists (``regressor``, ``affine_colour``), and any external method whose outputs are
dropped into ``external_dir`` in the benchmark's layout::

    {external_dir}/{method}/{pair_id}/{frame:04d}.exr     linear RGB, the target's size and frame count
    (or .png, display sRGB 8-bit)

Display values in [0, 1] at exposure ``exposure_ev`` for all. Per method: the mean over clips with a 95 %
percentile-bootstrap interval over clips (``ci``; :func:`lightcrafter.evaluation.bootstrap_ci`), and
(``vs_proxy``) the paired difference to the proxy with its interval
(:func:`lightcrafter.evaluation.paired_bootstrap_ci`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import evaluation as ev
from .io import DataError, linear_to_display, read_json, read_rgb_exr
from .refiner.data import PairsDataset, load_frames, require_pairs, to_display_frames

METRICS = tuple(ev.METRICS)  # the registry (lightcrafter.evaluation.METRICS), in its order


def folder_video(folder: Path, n: int, exposure_ev: float) -> np.ndarray | None:
    """(N, H, W, 3) display video from linear EXRs (or 8-bit PNGs) in ``folder``; None when absent."""
    if (folder / "0000.exr").is_file():
        return np.stack([linear_to_display(read_rgb_exr(folder / f"{i:04d}.exr"), exposure_ev) for i in range(n)])
    if (folder / "0000.png").is_file():
        import imageio.v3 as iio

        frames = [np.asarray(iio.imread(folder / f"{i:04d}.png"))[..., :3] / 255.0 for i in range(n)]
        return np.stack(frames).astype(np.float32)
    return None


def finite_ci(values) -> dict | None:
    """:func:`lightcrafter.evaluation.bootstrap_ci` of the finite values (None when there are none)."""
    v = [x for x in values if x is not None and np.isfinite(x)]
    return ev.bootstrap_ci(v) if v else None


def evaluate_benchmark(pairs, refined_manifest, split: str = "test", exposure_ev: float = 0.0,
                       lpips_weights=None, clip_weights=None, external_dir=None, root=None) -> dict:
    """Score the methods of every ``split`` pair of the manifest ``pairs`` (refined outputs from the inference
    manifest ``refined_manifest``); returns the JSON-ready result (module docstring). A pair record's relative
    ``oracle_proxy`` folder resolves against ``root`` (default: the working directory); the inference manifest's
    folders and ``external_dir`` are taken as they are written."""
    root = Path(root) if root is not None else Path.cwd()
    ds = require_pairs(PairsDataset(pairs, split, exposure_ev, cache=False), pairs, split, "evaluate")
    manifest = read_json(refined_manifest)
    refined = {e["pair_id"]: e for e in manifest["pairs"]}
    externals = sorted(p.name for p in Path(external_dir).iterdir() if p.is_dir()) if external_dir and \
        Path(external_dir).is_dir() else []
    networks = {"lpips": ev.load_lpips(lpips_weights), "clip": ev.load_clip_embedder(clip_weights)}
    rows, methods, not_computed = [], ["proxy"], {}
    for i in range(len(ds)):
        item, rec = ds[i], ds.records[i]
        e = refined.get(item["pair_id"])
        if e is None:
            raise DataError(f"{refined_manifest}: no refined video for pair {item['pair_id']}; rerun inference")
        n = int(rec["num_frames"])
        tgt = to_display_frames(item["target"])
        videos = {"proxy": to_display_frames(item["proxy"])}
        if rec.get("oracle_proxy"):
            videos["oracle_proxy"] = folder_video(root / rec["oracle_proxy"], n, exposure_ev)
        videos["refined"] = to_display_frames(load_frames(Path(e["frames"]), e["num_frames"], exposure_ev))
        for name, b in sorted((e.get("baselines") or {}).items()):
            videos[name] = to_display_frames(load_frames(Path(b["frames"]), b["num_frames"], exposure_ev))
        for name in externals:
            v = folder_video(Path(external_dir) / name / item["pair_id"], n, exposure_ev)
            if v is not None:
                videos[f"external:{name}"] = v
        ctx = ev.Context.of(tgt, **networks)
        row = {"pair_id": item["pair_id"], "scene_id": rec.get("scene_id"), "clip_id": rec.get("clip_id"),
               "target_light": rec.get("target_light"), "motion": rec.get("motion"),
               "ae_round_trip_psnr_db": e.get("ae_round_trip_psnr_db")}
        for name, v in videos.items():
            if v is None:
                continue
            if v.shape != tgt.shape:
                raise DataError(f"pair {item['pair_id']}: method {name} has {v.shape}, target {tgt.shape}; "
                                "outputs must match the target's frames and size")
            res = ev.evaluate_video(v, ctx)
            row[name] = {k: r.value for k, r in res.items()}
            for k, r in res.items():
                if r.value is None:
                    not_computed[k] = r.status.removeprefix("not computed: ")
            if name not in methods:
                methods.append(name)
        row["target"] = {k: r.value for k, r in ev.evaluate_target(ctx).items()}
        rows.append(row)
    mean, ci, vs_proxy = {}, {}, {}
    tv = {k: [r["target"][k] for r in rows if r["target"].get(k) is not None] for k in rows[0]["target"]}
    mean["target"] = {k: (float(np.mean(v)) if v else None) for k, v in tv.items()}
    for m in methods:
        vals = {k: [r[m][k] for r in rows if m in r and r[m].get(k) is not None] for k in METRICS}
        mean[m] = {k: (float(np.mean(v)) if v else None) for k, v in vals.items()}
        ci[m] = {k: finite_ci(v) for k, v in vals.items()}
        if m != "proxy":
            d = {}
            for k in METRICS:
                both = [(r[m][k], r["proxy"][k]) for r in rows if m in r and r[m].get(k) is not None
                        and r["proxy"].get(k) is not None]
                if both:
                    d[k] = ev.paired_bootstrap_ci([x for x, _ in both], [y for _, y in both])
            vs_proxy[m] = d
    ae = [r["ae_round_trip_psnr_db"] for r in rows if r.get("ae_round_trip_psnr_db") is not None]
    return {"benchmark": Path(pairs).parent.name, "split": split, "num_pairs": len(rows),
            "ae_round_trip_psnr_db_mean": float(np.mean(ae)) if ae else None,
            "display": {"exposure_ev": exposure_ev}, "methods": methods, "metrics": list(METRICS),
            "mean": mean, "ci": ci, "vs_proxy": vs_proxy, "not_computed": not_computed, "pairs": rows,
            "inference": {"infer": manifest.get("infer"), "selection": manifest.get("selection")},
            "external_methods": externals}
