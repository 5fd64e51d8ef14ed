"""Error budget of the reconstruction stack Phi: where the proxy's decibels go.

For every synthetic test pair of a finished run (results/), R renders the target lighting from

* ``oracle``: ground-truth buffers and cameras (the oracle proxy, at the run's ``proxy`` settings);
* ``gt+phi:<component>``: ground truth with ONE component taken from Phi's aligned clip;
* ``phi``: Phi's aligned buffers and cameras (the run's proxy);
* ``phi+gt:<component>``: Phi with ONE component taken from ground truth;
* R's own error: ``oracle@frame`` (the ground truth rendered with the per-frame shadow mesh that Phi's
  clips get from ``visibility: auto``), ``oracle@16x`` (16 x ``proxy.spp``; the oracle against it is R's
  sampling noise) and ``oracle+oidn`` (the oracle through Intel Open Image Denoise, when ``pyoidn``
  imports; else the row says why it is missing).

Components (lightcrafter.io.Buffers and the clip's cameras): ``cameras`` (K and c2w), ``depth``
(z-depth where both are surface), ``normals`` (world), ``ground_normals`` (the normals of the ground only:
pixels whose ground-truth normal is within 2 degrees of world +Z, lightcrafter.recon.evaluate.ground_pixels;
Phi snaps its ground to one plane, and that plane's tilt decides the shading of most of a frame under a low
sun), ``albedo``, ``roughness_metallic``, ``mask`` (which pixels are surface: pixels only the donor sees
take all of the donor's values there), and ``albedo_colour``: the albedo's colour over the whole clip, the
per-channel least-squares gain taking Phi's albedo to the truth's (lightcrafter.recon.evaluate.albedo_colour_gain;
one video cannot tell it from the light's colour), so ``gt+phi:albedo_colour`` is the true albedo in Phi's
colour and ``phi+gt:albedo_colour`` Phi's albedo in the true colour. The target lighting is the scene's own
on synthetic pairs, so the environment map is not a Phi component here (real clips fit it:
results/summary/reconstruction.json reports their pseudo-input error).

Scores are PSNR (dB) and SSIM on display values (lightcrafter.io.linear_to_display) against the Cycles
target, means over pairs of per-frame means. Writes results/bench/phi_budget.json (the benchmark shape of
docs/architecture.md plus a ``table``) and prints the table::

    .venv/bin/python benchmarks/phi_budget.py [--results results] [--split test] [--max-pairs N]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lightcrafter import io  # noqa: E402
from lightcrafter.clip import FrameView, read_clip  # noqa: E402
from lightcrafter.layout import Layout  # noqa: E402

COMPONENTS = ("cameras", "depth", "normals", "ground_normals", "albedo", "roughness_metallic", "mask")


def swap(base: FrameView, donor: FrameView, component: str, ground: np.ndarray | None = None) -> FrameView:
    """``base`` with one component taken from ``donor`` (same frame, same size). ``ground_normals`` needs
    ``ground`` (H, W) bool, the ground-truth view's ground (lightcrafter.recon.evaluate.ground_pixels)."""
    if component == "cameras":
        return FrameView(base.buffers, donor.K, donor.c2w, base.key + "#cam")
    b, d = base.buffers, donor.buffers
    bv = (b.mask > 0.5) & np.isfinite(b.depth)
    dv = (d.mask > 0.5) & np.isfinite(d.depth)
    both = bv & dv
    out = io.Buffers(depth=b.depth.copy(), normal=b.normal.copy(), albedo=b.albedo.copy(),
                     roughness=b.roughness.copy(), metallic=b.metallic.copy(), mask=b.mask.copy())
    if component == "depth":
        out.depth = np.where(both, d.depth, b.depth).astype(np.float32)
    elif component == "normals":
        out.normal = np.where(both[..., None], d.normal, b.normal).astype(np.float32)
    elif component == "ground_normals":
        if ground is None:
            raise ValueError("component 'ground_normals' needs the ground-truth view's ground pixels (ground=)")
        out.normal = np.where((both & ground)[..., None], d.normal, b.normal).astype(np.float32)
    elif component == "albedo":
        out.albedo = np.where(both[..., None], d.albedo, b.albedo).astype(np.float32)
    elif component == "roughness_metallic":
        out.roughness = np.where(both, d.roughness, b.roughness).astype(np.float32)
        out.metallic = np.where(both, d.metallic, b.metallic).astype(np.float32)
    elif component == "mask":
        only_d = dv & ~bv
        for k in ("depth", "roughness", "metallic", "mask"):
            setattr(out, k, np.where(only_d, getattr(d, k), getattr(out, k)).astype(np.float32))
        for k in ("normal", "albedo"):
            setattr(out, k, np.where(only_d[..., None], getattr(d, k), getattr(out, k)).astype(np.float32))
        gone = bv & ~dv
        out.depth[gone] = np.inf
        out.mask[gone] = 0.0
        out.normal[gone] = 0.0
    else:
        raise ValueError(f"component {component!r}: use one of {COMPONENTS}")
    return FrameView(out, base.K, base.c2w, f"{base.key}#{component}")


def recolour(view: FrameView, gain: np.ndarray, tag: str) -> FrameView:
    """``view`` with its albedo times the per-channel ``gain`` (clipped to [0, 1]); everything else kept."""
    albedo = np.clip(view.buffers.albedo * gain, 0.0, 1.0).astype(np.float32)
    return FrameView(replace(view.buffers, albedo=albedo), view.K, view.c2w, f"{view.key}#{tag}")


def _display(frames, exposure_ev=0.0) -> np.ndarray:
    return np.stack([io.linear_to_display(f, exposure_ev) for f in frames])


def _scores(video: np.ndarray, target: np.ndarray) -> dict:
    from lightcrafter import evaluation as ev

    return {"psnr_db": ev.framewise_psnr(video, target).value, "ssim": ev.framewise_ssim(video, target).value}


def _oidn(frames: list[np.ndarray]) -> list[np.ndarray] | str:
    """Denoise linear HDR frames with Intel OIDN (pyoidn), or say why not."""
    from lightcrafter.proxy.denoise import available, denoise_hdr

    why = available()
    return f"not computed: {why}" if why else [denoise_hdr(f) for f in frames]


def budget_rows(gt_views, phi_views, settings, scene_static: bool):
    """(row name, settings, views) for every row of the budget of one clip."""
    from lightcrafter.proxy.clip import resolve_visibility
    from lightcrafter.recon.evaluate import albedo_colour_gain, ground_pixels

    s_gt = resolve_visibility(settings, scene_static, True)
    s_phi = resolve_visibility(settings, scene_static, False)
    rows = [("oracle", s_gt, gt_views), ("oracle@frame", replace(s_gt, visibility="frame"), gt_views),
            ("oracle@16x", replace(s_gt, spp=settings.spp * 16), gt_views), ("phi", s_phi, phi_views)]
    grounds = [ground_pixels(g.buffers) for g in gt_views]  # once per frame, not once per component
    frames = list(zip(gt_views, phi_views, grounds))
    for c in COMPONENTS:
        # a mixed clip whose depth or cameras come from Phi is as inconsistent over frames as Phi's
        phi_geom = c in ("cameras", "depth", "mask")
        rows.append((f"gt+phi:{c}", s_phi if phi_geom else s_gt, [swap(g, p, c, gr) for g, p, gr in frames]))
        rows.append((f"phi+gt:{c}", s_phi, [swap(p, g, c, gr) for g, p, gr in frames]))
    # the albedo's colour over the whole clip (the per-channel least-squares gain taking Phi's albedo to the
    # truth's), which one video cannot tell from the light's: the truth's albedo in Phi's colour, and Phi's
    # albedo in the truth's
    gain = albedo_colour_gain([p.buffers for p in phi_views], [g.buffers for g in gt_views])
    undo = 1.0 / np.maximum(gain, 1e-6)
    rows.append(("gt+phi:albedo_colour", s_gt, [recolour(g, undo, "albedo_colour") for g in gt_views]))
    rows.append(("phi+gt:albedo_colour", s_phi, [recolour(p, gain, "albedo_colour") for p in phi_views]))
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", type=Path, default=Path("results"))
    ap.add_argument("--config", type=Path, default=None, help="the run's config file (default: config/config.yaml)")
    ap.add_argument("--split", default="test")
    ap.add_argument("--max-pairs", type=int, default=None)
    ap.add_argument("--rows", default=None, help="comma-separated rows to render (default: all), e.g. oracle,phi")
    ap.add_argument("--phi-settings", default=None, help="JSON of recon settings (DefaultSettings fields) over the "
                    "run's: Phi is re-run on each clip's source video with them and aligned, clips the run left out "
                    "included (default: the run's aligned clips)")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--strips", type=Path, default=None, help="folder for a PNG strip per pair: input | oracle "
                    "proxy | Phi proxy | target (default: beside --out, phi_budget_strips/)")
    a = ap.parse_args()
    from lightcrafter.proxy import render_settings
    from lightcrafter.proxy.clip import render_views
    from lightcrafter.proxy.lighting import lighting_from_spec

    L = Layout(str(a.results))
    out = a.out or a.results / "bench" / "phi_budget.json"
    cfg = _run_config(a)
    settings = render_settings(cfg["proxy"])
    pairs = [(spec, t, light) for spec, t in L.split_trajectories(a.split) for light in t.get("target_lights", [])]
    pairs = pairs[: a.max_pairs] if a.max_pairs else pairs
    if not pairs:
        raise SystemExit(f"error: no {a.split} pairs under {a.results}/scenes; run the default target first (make run)")
    from lightcrafter.refiner.strip import write_strip

    strips = a.strips or out.parent / "phi_budget_strips"
    rows_wanted = set(a.rows.split(",")) if a.rows else None
    per_pair, seconds = [], {}
    with tempfile.TemporaryDirectory(prefix="lc_phi_budget_") as tmp:
        for spec, t, light in pairs:
            sid, tid = spec["scene_id"], t["id"]
            aligned = Path(L.aligned_clip_manifest(sid, tid))
            if a.phi_settings is None and (not aligned.is_file() or io.read_json(aligned).get("skipped")):
                print(f"{sid}_{tid}: Phi left it out; not in the budget", flush=True)
                continue
            gt_views, info = read_clip(L.gt_clip(sid, tid))
            if a.phi_settings is not None:
                aligned_dir = _rerun_phi(L, cfg, sid, tid, t, json.loads(a.phi_settings), Path(tmp) / "phi")
                if aligned_dir is None:  # left out by Phi with these settings (printed); not in the budget
                    continue
                phi_views, _ = read_clip(aligned_dir)
            else:
                phi_views, _ = read_clip(L.aligned_clip(sid, tid))
            tfolder = Path(L.gt_rgb(sid, tid, light))
            target = _display([io.read_rgb_exr(tfolder / f"{i:04d}.exr") for i in range(len(gt_views))])
            lighting = lighting_from_spec(spec, light, tid, where=str(L.scene_spec(sid)))
            row = {"pair_id": f"{sid}_{tid}_{light}", "motion": t.get("motion"), "rows": {}}
            videos = {}
            for name, s, views in budget_rows(gt_views, phi_views, settings, info.scene_static):
                if rows_wanted and name not in rows_wanted:
                    continue
                t0 = time.perf_counter()
                frames, _, _ = render_views(views, lighting, s, Path(tmp) / row["pair_id"] / name.replace(":", "_"),
                                            cache=False)
                seconds[name] = seconds.get(name, 0.0) + time.perf_counter() - t0
                videos[name] = _display(frames)
                row["rows"][name] = _scores(videos[name], target)
                if name == "oracle":
                    den = _oidn(frames)
                    row["rows"]["oracle+oidn"] = den if isinstance(den, str) else _scores(_display(den), target)
                if name == "oracle@16x":
                    row["rows"]["oracle_vs_16x"] = _scores(videos["oracle"], videos[name])
                print(f"{row['pair_id']} {name}: {row['rows'][name]['psnr_db']:.2f} dB "
                      f"SSIM {row['rows'][name]['ssim']:.3f}", flush=True)
            src = Path(L.gt_rgb(sid, tid, t["source_light"]))
            cols = [("input", _display([io.read_rgb_exr(src / f"{i:04d}.exr") for i in range(len(gt_views))]))]
            cols += [(label, videos[k]) for k, label in (("oracle", "oracle proxy"), ("phi", "Phi proxy")) if k in videos]
            write_strip(strips / f"{row['pair_id']}.png", cols + [("target", target)])
            per_pair.append(row)
    if not per_pair:
        raise SystemExit(f"error: every {a.split} clip was left out by Phi; nothing to budget")
    names = list(per_pair[0]["rows"])
    table = {}
    for n in names:
        vals = [p["rows"][n] for p in per_pair if isinstance(p["rows"].get(n), dict)]
        if not vals:
            table[n] = {"not_computed": per_pair[0]["rows"][n]}
            continue
        table[n] = {k: float(np.mean([v[k] for v in vals])) for k in ("psnr_db", "ssim")}
    ref = table.get("oracle", {}).get("psnr_db"), table.get("phi", {}).get("psnr_db")
    for n, r in table.items():
        if "psnr_db" in r:
            r["vs_oracle_db"] = None if ref[0] is None else r["psnr_db"] - ref[0]
            r["vs_phi_db"] = None if ref[1] is None else r["psnr_db"] - ref[1]
    points = [{"series": n, "setting": n, "seconds": round(seconds.get(n, 0.0), 2), "value": r.get("psnr_db")}
              for n, r in table.items()]
    io.write_json(out, {
        "name": "phi_budget", "varied": "which buffer component comes from Phi and which from ground truth",
        "metric": "psnr_db", "higher_is_better": True, "split": a.split, "pairs": len(per_pair),
        "machine": {"cores": os.cpu_count(), "platform": platform.platform()},
        "proxy": cfg["proxy"], "table": table, "per_pair": per_pair, "points": points,
        "note": "PSNR/SSIM on display values against the Cycles target; oracle_vs_16x is R's sampling noise "
                "(the oracle against 16x its samples), not a comparison with the target",
    })
    print(f"\n{'row':28s} {'PSNR dB':>8s} {'SSIM':>6s} {'vs oracle':>9s} {'vs phi':>7s}")
    for n, r in table.items():
        if "psnr_db" in r:
            d = [f"{r[k]:+9.2f}" if r[k] is not None else f"{'-':>9s}" for k in ("vs_oracle_db", "vs_phi_db")]
            print(f"{n:28s} {r['psnr_db']:8.2f} {r['ssim']:6.3f} {d[0]} {d[1]}")
        else:
            print(f"{n:28s} {r['not_computed']}")
    print(f"wrote {out} ({len(per_pair)} pairs)")
    return 0


def _rerun_phi(L, cfg: dict, sid: str, tid: str, traj: dict, over: dict, work: Path) -> Path | None:
    """Phi (default backend, the run's settings with ``over``) on the clip's source video, aligned to ground
    truth; returns the aligned clip folder, or None when Phi leaves the clip out."""
    from lightcrafter.recon.align import align_clip
    from lightcrafter.recon.cameras import ReconstructionError
    from lightcrafter.recon.default import reconstruct_default, settings_from_config
    from lightcrafter.recon.weights import weights_path

    r = cfg["recon"]
    est, al = work / f"{sid}_{tid}", work / f"{sid}_{tid}_aligned"
    try:
        reconstruct_default(Path(L.gt_rgb(sid, tid, traj["source_light"])), est,
                            estimator_path=weights_path(r["estimator"]["weights"], L.estimator()),
                            fps=cfg["scenes"]["fps"],
                            scene_static=traj.get("scene_static", traj.get("motion") != "dynamic_moving"),
                            settings=settings_from_config(cfg, **over), name=f"{sid}_{tid}")
    except ReconstructionError as exc:
        print(f"{sid}_{tid}: {exc}", flush=True)
        return None
    align_clip(est, L.gt_clip(sid, tid), al)
    return al


def _run_config(a) -> dict:
    from lightcrafter.config import effective_config

    return effective_config([str(a.config)] if a.config else None)


if __name__ == "__main__":
    sys.exit(main())
