"""Pair manifests: the registry of dataset variants and the held-out benchmarks (contract in docs/architecture.md).

A *pair* is (proxy video, target video) with the same frames, both folders of linear EXR frames
``{i:04d}.exr`` with a manifest ``<folder>.json``. Kinds:

* ``synthetic``: the proxy is R(Align(Phi(source video)), L_target) -- the artifact-matched proxy --
  and the target the Cycles video under L_target (one pair per train scene, trajectory and target
  lighting); variant ``clean_buffers`` uses R on ground-truth buffers instead (the ablation that
  shows why artifact matching matters);
* ``real``: the proxy is R(Phi(I), L_hat_source) with the environment map fitted to the real video I,
  the target is I itself (pseudo-pairs).

Training sets (``results/datasets/{variant}/pairs.jsonl``, split ``train`` only) are named by
:data:`VARIANTS`; the workflow reads this registry (workflow/rules/common.smk), so adding a variant
is one entry here. Held-out evaluation sets (``results/benchmarks/{bench}/pairs.jsonl``, split
``test``) are shared by every variant, so all variants are scored on the same clips: ``synthetic``
(test scenes, Phi proxies, with the oracle proxy from ground-truth buffers recorded beside),
``real`` (test real clips, the paper's DL3DV protocol 1: relight back to the fitted source light and
compare with the input video) and ``mit`` (MIT Multi-Illumination, when config ``mit.root`` is set).

A clip that the reconstruction stack could not reconstruct (its proxy manifest says ``skipped``) is
left out of every manifest and counted in ``summary.json`` beside it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from lightcrafter.io import DataError, read_exr, read_json
from lightcrafter.layout import Layout


@dataclass(frozen=True)
class Variant:
    """kinds: pair kinds in the training set; synthetic_proxy: 'proxy' (artifact-matched, from Phi) or
    'proxy_gt' (clean ground-truth buffers); doc: one line for the report."""

    kinds: tuple[str, ...]
    synthetic_proxy: str = "proxy"
    doc: str = ""
    label: str = ""  # the report's row label


VARIANTS: dict[str, Variant] = {
    "full": Variant(("synthetic", "real"), "proxy", "artifact-matched synthetic pairs + real pseudo-pairs (the paper)",
                    "Ours (full)"),
    "no_real": Variant(("synthetic",), "proxy", "artifact-matched synthetic pairs only (ablation: no real data)",
                       "Ours (no real)"),
    "no_synthetic": Variant(("real",), "proxy", "real pseudo-pairs only (ablation: no synthetic data)",
                            "Ours (no synthetic)"),
    "clean_buffers": Variant(("synthetic",), "proxy_gt", "synthetic pairs with proxies from ground-truth buffers "
                             "(ablation: no artifact matching)", "Ours (clean buffers: no artifact matching)"),
}
BENCHMARKS = ("synthetic", "real", "mit")
ONE_FRAME_BENCHMARKS = ("mit",)  # pairs of one frame (MIT multi-illumination photographs): no temporal metric
REFINER_SPLITS = ("train", "test")


def variant(name: str) -> Variant:
    if name not in VARIANTS:
        raise DataError(f"dataset variant {name!r} unknown; use one of {sorted(VARIANTS)}")
    return VARIANTS[name]


# ----------------------------------------------------------------------------- specs (no file access)
def synthetic_specs(layout: Layout, plans: dict[str, dict], split: str, proxy: str = "proxy") -> list[dict]:
    """One spec per (scene, trajectory, target light) of scenes in ``split``; ``plans`` maps scene id ->
    scene plan ({"split", "trajectories": [{"id", "source_light", "target_lights"}]})."""
    specs = []
    for scene_id in sorted(plans):
        plan = plans[scene_id]
        if plan["split"] != split:
            continue
        for traj in plan["trajectories"]:
            for light in traj["target_lights"]:
                folder = layout.proxy(scene_id, traj["id"], light) if proxy == "proxy" \
                    else layout.proxy_gt(scene_id, traj["id"], light)
                specs.append({
                    "pair_id": f"{scene_id}_{traj['id']}_{light}", "kind": "synthetic",
                    "scene_id": scene_id, "trajectory": traj["id"], "motion": traj.get("motion"),
                    "source_light": traj["source_light"], "target_light": light, "split": split,
                    "proxy": folder, "target": layout.gt_rgb(scene_id, traj["id"], light),
                    "source": layout.gt_rgb(scene_id, traj["id"], traj["source_light"]),
                    **({"oracle_proxy": layout.proxy_gt(scene_id, traj["id"], light)} if split == "test" else {}),
                })
    return sorted(specs, key=lambda s: s["pair_id"])


def real_specs(layout: Layout, real_clips: dict[str, dict], split: str) -> list[dict]:
    """One spec per real clip of ``split``; ``real_clips`` maps clip id -> {"split", "video", ...}."""
    specs = []
    for clip_id in sorted(real_clips):
        c = real_clips[clip_id]
        if c["split"] != split:
            continue
        specs.append({"pair_id": f"real_{clip_id}", "kind": "real", "clip_id": clip_id, "video": c.get("video"),
                      "split": split, "proxy": layout.pseudo_input(clip_id), "target": layout.real_frames(clip_id),
                      "source": layout.real_frames(clip_id), "source_light": "fitted", "target_light": "fitted"})
    return specs


def variant_specs(name: str, layout: Layout, plans: dict, real_clips: dict) -> list[dict]:
    """Training-set specs of variant ``name`` (split train)."""
    v = variant(name)
    specs = []
    if "synthetic" in v.kinds:
        specs += synthetic_specs(layout, plans, "train", v.synthetic_proxy)
    if "real" in v.kinds:
        specs += real_specs(layout, real_clips, "train")
    return specs


def mit_specs(layout: Layout, mit_pairs: dict) -> list[dict]:
    """MIT Multi-Illumination pairs (lightcrafter.mit_multi_illum): the source image's scene state rendered
    under the map fitted to the captured target image, against that image."""
    return [{"pair_id": pid, "kind": "real", "clip_id": p["source"], "scene_id": p["scene"], "split": "test",
             "proxy": layout.pseudo_input(pid), "target": layout.real_frames(p["target"]),
             "source": layout.real_frames(p["source"]), "source_light": "dir_source",
             "target_light": f"dir_{p['target_dir']}"} for pid, p in sorted(mit_pairs.items())]


def benchmark_specs(bench: str, layout: Layout, plans: dict, real_clips: dict, mit_pairs: dict | None = None) -> list[dict]:
    if bench == "synthetic":
        return synthetic_specs(layout, plans, "test", "proxy")
    if bench == "real":
        return real_specs(layout, real_clips, "test")
    if bench == "mit":
        return mit_specs(layout, mit_pairs or {})
    raise DataError(f"benchmark {bench!r} unknown; use one of {BENCHMARKS}")


def spec_inputs(specs: list[dict]) -> list[str]:
    """Manifests a set of specs needs (what the workflow passes as rule inputs)."""
    files = []
    for s in specs:
        for key in ("proxy", "target", "oracle_proxy"):
            if key in s:
                files.append(f"{s[key]}.json")
    return list(dict.fromkeys(files))


# ----------------------------------------------------------------------------- records (reads frames)
def _frame_info(folder: Path) -> tuple[int, int, int]:
    """(num_frames, width, height) of a folder of consecutive ``{frame:04d}.exr`` frames from 0."""
    if not folder.is_dir():
        raise DataError(f"{folder}: frame folder not found; run the stage that renders it")
    n = 0
    while (folder / f"{n:04d}.exr").is_file():
        n += 1
    if n == 0:
        raise DataError(f"{folder}: no 0000.exr; the render is incomplete, rerun it")
    # hidden files (a killed writer's ".0001.x.tmp.exr") are not frames; the next render of the folder removes them
    extra = sorted(p.name for p in folder.glob("[!.]*.exr") if not p.name[:4].isdigit() or int(p.name[:4]) >= n)
    if extra:
        raise DataError(f"{folder}: frames are not consecutive from 0000 (stray {extra[:3]}); rerun the render")
    h, w = next(iter(read_exr(folder / "0000.exr", ("R", "G", "B")).values())).shape
    return n, int(w), int(h)


def skipped_reason(folder: str | Path, root: Path) -> str | None:
    """The reason a frame folder's producer skipped it (its manifest has ``skipped``), else None."""
    man = Path(root) / f"{folder}.json"
    if not man.is_file():
        raise DataError(f"{man}: manifest missing; the stage that writes {folder} has not finished, rerun it")
    data = read_json(man)
    return data.get("skipped") if isinstance(data, dict) else None


def build_records(specs: list[dict], root: str | Path = ".", variant_name: str | None = None) -> tuple[list[dict], dict]:
    """pairs.jsonl records for ``specs`` (paths stay relative to ``root``) and a summary (counts, skips).

    Proxy and target must have the same frame count and size; a skipped proxy drops its pair.
    """
    root = Path(root)
    records, skipped = [], []
    for s in specs:
        reason = skipped_reason(s["proxy"], root) or skipped_reason(s["target"], root)
        if reason:
            skipped.append({"pair_id": s["pair_id"], "reason": reason})
            continue
        n_p, w_p, h_p = _frame_info(root / s["proxy"])
        n_t, w_t, h_t = _frame_info(root / s["target"])
        if (n_p, w_p, h_p) != (n_t, w_t, h_t):
            raise DataError(f"pair {s['pair_id']}: proxy {s['proxy']} has {n_p} frames {w_p}x{h_p}, target {s['target']} "
                            f"has {n_t} frames {w_t}x{h_t}; rerender one of them")
        rec = {**s, "num_frames": n_p, "width": w_p, "height": h_p}
        if variant_name:
            rec["variant"] = variant_name
        records.append(rec)
    summary = {"pairs": len(records), "by_kind": {k: sum(r["kind"] == k for r in records) for k in ("synthetic", "real")},
               "skipped": skipped}
    return records, summary
