"""Error against run time of the forward renderer R, and of Blender Cycles on the *same* proxy scene.

Scene: analytic buffers (lightcrafter.proxy.synthetic) of four spheres (rough and glossy
dielectrics, a mirror-like and a rough metal) on a grey ground, 96x64, lit by the bundled
``forest.exr`` rotated by 0.5 rad. Both renderers get the same per-pixel quad mesh (the one R builds
from the buffers), the same per-face materials and shading normals, the same envmap and camera,
direct lighting only (Cycles ``max_bounces`` 0; R with ``visibility='primary'``: shadows from the
same quads), a 1 px box filter and ``--threads`` CPU threads each.

Error: PSNR in dB (peak 1) on *display* values (lightcrafter.io.linear_to_display, 0 EV).
  * ``points``        : R at each spp vs a ``--ref-spp`` render of R (other seed);
  * ``cycles_points`` : Cycles at each spp vs the same R reference (what the brief asks; it
    plateaus at the model gap between Cycles' Principled BSDF and the paper's BRDF);
  * ``cycles_points_own_ref``: Cycles vs its own ``--cycles-ref-spp`` render (noise only).
Seconds: wall time of one render call after an untimed warm-up (R: kernels compiled, Cycles: kernels
loaded, persistent data), i.e. the per-frame cost inside a clip.
Speed ratio at equal error: Cycles seconds / R seconds at the same PSNR, interpolated linearly in
(log seconds, PSNR) on each curve, at the highest PSNR both curves reach (and at fixed levels). The two
renderers' curves are timed in ``--rounds`` interleaved rounds (R's curve, Cycles' curve, R's, Cycles', ...),
a ratio per round; reported as the median with its range over rounds (``points`` carry the median seconds).

    .venv/bin/python benchmarks/proxy_spp.py      # ~2-4 minutes on 2 cores
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lightcrafter import envmap, io  # noqa: E402
from lightcrafter.metrics import display_psnr_db  # noqa: E402
from lightcrafter.proxy import synthetic as syn  # noqa: E402
from lightcrafter.proxy.geometry import pixel_quad_mesh  # noqa: E402
from lightcrafter.proxy.lighting import Lighting  # noqa: E402
from lightcrafter.proxy.renderer import FrameView, ProxyRenderer, RenderSettings  # noqa: E402
from lightcrafter.speed import median_range  # noqa: E402

ROT_Z = 0.5


def bench_scene(width: int, height: int):
    K = syn.intrinsics(width, height, 0.87)
    c2w = syn.look_at([3.2, -2.4, 1.7], [0.0, 0.0, 0.35])
    spheres = [syn.Sphere((0.0, 0.0, 0.45), 0.45, (0.9, 0.9, 0.9), 0.05, 1.0),
               syn.Sphere((0.9, 0.6, 0.3), 0.3, (0.8, 0.2, 0.1), 0.5, 0.0),
               syn.Sphere((-0.7, 0.8, 0.35), 0.35, (0.2, 0.5, 0.9), 0.15, 0.0),
               syn.Sphere((0.6, -0.8, 0.25), 0.25, (0.9, 0.7, 0.3), 0.4, 1.0)]
    b = syn.raycast_buffers(K, c2w, width, height, spheres, syn.Ground((0.5, 0.5, 0.5), 0.7, 0.0, 6.0))
    return K, c2w, b


def time_r(renderer: ProxyRenderer, view: FrameView, spp: int, seed: int, repeats: int) -> tuple[np.ndarray, float]:
    renderer.settings = RenderSettings(**{**renderer.settings.__dict__, "spp": spp, "seed": seed})
    renderer.render(view)  # warm-up: kernel compilation for this wavefront size
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        img = renderer.render(view)
        best = min(best, time.perf_counter() - t0)
    return img, best


def seconds_at(points: list[dict], target_db: float) -> float | None:
    """Seconds needed to reach ``target_db``, interpolating in (log seconds, PSNR); None if never."""
    pts = sorted(points, key=lambda p: p["seconds"])
    best = -np.inf
    for p0, p1 in zip(pts, pts[1:]):
        if p0["value"] >= target_db:
            return p0["seconds"]
        if p1["value"] >= target_db > p0["value"]:
            f = (target_db - p0["value"]) / (p1["value"] - p0["value"])
            return float(np.exp(np.log(p0["seconds"]) + f * (np.log(p1["seconds"]) - np.log(p0["seconds"]))))
        best = max(best, p0["value"])
    return pts[-1]["seconds"] if pts and pts[-1]["value"] >= target_db else None


def ratios(r_points, c_points, levels) -> dict:
    out = {}
    for lv in levels:
        tr, tc = seconds_at(r_points, lv), seconds_at(c_points, lv)
        out[f"{lv:.1f}"] = None if tr is None or tc is None else round(tc / tr, 2)
    return out


def curve(spps, values, seconds) -> list[dict]:
    """Points of a spp ladder: its PSNR values (the same images every round) and one set of seconds."""
    return [{"setting": spp, "seconds": round(float(sec), 5), "value": round(v, 3)}
            for spp, v, sec in zip(spps, values, seconds)]


def round_ratios(r_spp, r_values, r_rounds, c_spp, c_values, c_rounds, common: float, levels) -> dict:
    """Per-round speed ratios (Cycles / R seconds at equal PSNR) at the common best PSNR and at ``levels``,
    as the median and range over the interleaved rounds (``*_rounds``: per round, the seconds per spp)."""
    per_round = []
    for r_sec, c_sec in zip(r_rounds, c_rounds):
        rp, cp = curve(r_spp, r_values, r_sec), curve(c_spp, c_values, c_sec)
        per_round.append({"common_best": ratios(rp, cp, [common])[f"{common:.1f}"], "levels": ratios(rp, cp, levels)})
    return {"at_common_best_db": round(common, 2),
            "ratio_at_common_best": median_range([pr["common_best"] for pr in per_round]),
            "at_levels_db": {f"{lv:.1f}": median_range([pr["levels"][f"{lv:.1f}"] for pr in per_round])
                             for lv in levels},
            "per_round": per_round}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="results/bench/proxy_spp.json")
    ap.add_argument("--width", type=int, default=96)
    ap.add_argument("--height", type=int, default=64)
    ap.add_argument("--spp", type=int, nargs="+", default=[1, 2, 4, 8, 16, 32, 64, 128])
    ap.add_argument("--cycles-spp", type=int, nargs="+", default=[1, 2, 4, 8, 16, 32, 64, 128, 256])
    ap.add_argument("--ref-spp", type=int, default=2048)
    ap.add_argument("--cycles-ref-spp", type=int, default=1024)
    ap.add_argument("--threads", type=int, default=1, help="CPU threads for each renderer")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved rounds: R's curve, then Cycles', timed "
                    "once per round (median and range of the per-round ratios)")
    ap.add_argument("--target-db", type=float, default=30.0, help="chosen spp: smallest reaching this PSNR")
    ap.add_argument("--hdri", default="builtin:forest.exr")
    a = ap.parse_args()

    import drjit as dr

    from lightcrafter.lights import resolve_hdri
    from lightcrafter.proxy.cycles_scene import render_pixel_mesh
    from lightcrafter.proxy.mitsuba_setup import ensure_variant

    variant = ensure_variant()
    dr.set_thread_count(a.threads)
    K, c2w, b = bench_scene(a.width, a.height)
    env_path = resolve_hdri(a.hdri)
    env = envmap.load(env_path)
    view = FrameView(b, K, c2w, "bench")
    r = ProxyRenderer(Lighting(env=env, rotation_z_rad=ROT_Z), RenderSettings(visibility="primary"))
    ref, ref_s = time_r(r, view, a.ref_spp, seed=12345, repeats=1)
    mesh = pixel_quad_mesh(b.depth, b.mask > 0.5, K, c2w, b.normal)
    cref = render_pixel_mesh(mesh, b, env_path, ROT_Z, K, c2w, [a.cycles_ref_spp], threads=a.threads,
                             max_bounces=0, seed=99)[0][0]
    r_rounds, c_rounds = [], []  # per round: [(image, seconds)] per spp; R then Cycles in every round
    for k in range(a.rounds):
        r_rounds.append([time_r(r, view, spp, seed=0, repeats=1) for spp in a.spp])
        c_rounds.append(render_pixel_mesh(mesh, b, env_path, ROT_Z, K, c2w, list(a.cycles_spp), threads=a.threads,
                                          max_bounces=0, seed=7, repeats=1))
        print(f"round {k + 1}/{a.rounds}: R {sum(t for _, t in r_rounds[-1]):.2f} s, Cycles "
              f"{sum(t for _, t in c_rounds[-1]):.2f} s over the spp ladders", flush=True)
    r_sec = [[t for _, t in rd] for rd in r_rounds]  # seconds per round and spp
    c_sec = [[t for _, t in rd] for rd in c_rounds]
    r_val = [display_psnr_db(img, ref) for img, _ in r_rounds[0]]  # seeded: the same images every round
    c_val = [display_psnr_db(img, ref) for img, _ in c_rounds[0]]
    c_own_val = [display_psnr_db(img, cref) for img, _ in c_rounds[0]]
    points = curve(a.spp, r_val, np.median(r_sec, axis=0))
    c_points = curve(a.cycles_spp, c_val, np.median(c_sec, axis=0))
    c_own = curve(a.cycles_spp, c_own_val, np.median(c_sec, axis=0))
    for p in points:
        print(f"R       spp {p['setting']:5d}: {p['seconds']:8.4f} s  {p['value']:6.2f} dB", flush=True)
    for p, q in zip(c_points, c_own):
        print(f"Cycles  spp {p['setting']:5d}: {p['seconds']:8.4f} s  {p['value']:6.2f} dB (own ref {q['value']:6.2f})",
              flush=True)
    r_own = [dict(p) for p in points]
    common = min(max(p["value"] for p in points), max(p["value"] for p in c_points))
    common_own = min(max(p["value"] for p in r_own), max(p["value"] for p in c_own))
    chosen = next((p["setting"] for p in points if p["value"] >= a.target_db), points[-1]["setting"])
    levels = [20.0, 25.0, 30.0, 35.0]
    result = {
        "name": "proxy_spp", "varied": "spp", "metric": "psnr_db", "higher_is_better": True,
        "machine": {"cores": os.cpu_count(), "platform": platform.platform(), "threads_used": a.threads,
                    "mitsuba_variant": variant},
        "chosen": chosen, "target_db": a.target_db,
        "points": points,
        "cycles_points": c_points,
        "cycles_points_own_ref": c_own,
        "reference": {"renderer": "R", "spp": a.ref_spp, "seed": 12345, "seconds": round(ref_s, 4),
                      "cycles_own_ref_spp": a.cycles_ref_spp},
        "cycles_vs_r_reference_psnr_db": round(display_psnr_db(cref, ref), 3),
        "speed_ratio_at_equal_error": {
            "definition": "Cycles seconds / R seconds reaching the same display PSNR; each vs R's reference",
            **round_ratios(a.spp, r_val, r_sec, a.cycles_spp, c_val, c_sec, common, levels),
        },
        "speed_ratio_at_equal_noise": {
            "definition": "as above, but each renderer against its own high-spp reference (noise only)",
            **round_ratios(a.spp, r_val, r_sec, a.cycles_spp, c_own_val, c_sec, common_own, levels),
        },
        "rounds": a.rounds,
        "seconds_per_frame_at_chosen": next(p["seconds"] for p in points if p["setting"] == chosen),
        "resolution": {"width": a.width, "height": a.height},
        "scene": "4 spheres on a ground plane, forest.exr rotated 0.5 rad, direct light only, same quad mesh",
    }
    io.write_json(a.out, result)
    plot(result, Path(a.out).with_suffix(".png"))
    print(f"wrote {a.out}")


def plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for key, label, style in (("points", "R (Mitsuba, ours)", "o-"), ("cycles_points", "Cycles vs R ref", "s-"),
                              ("cycles_points_own_ref", "Cycles vs own ref", "s--")):
        pts = result[key]
        ax.semilogx([p["seconds"] for p in pts], [p["value"] for p in pts], style, label=label)
        for p in pts:
            ax.annotate(str(p["setting"]), (p["seconds"], p["value"]), fontsize=6)
    ch = next(p for p in result["points"] if p["setting"] == result["chosen"])
    ax.plot([ch["seconds"]], [ch["value"]], "r*", markersize=14, label=f"chosen {result['chosen']} spp")
    ax.set_xlabel("seconds per frame")
    ax.set_ylabel("PSNR (dB, display)")
    ax.set_title("proxy renderer: error vs time (96x64)")
    ax.legend(fontsize=7)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    with io.atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)


if __name__ == "__main__":
    main()
