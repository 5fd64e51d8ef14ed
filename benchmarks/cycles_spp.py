"""Error against run time of the Cycles ground truth: samples per pixel vs PSNR to a high-spp reference,
for five settings: raw path tracing, an indirect-light clamp, and the OIDN denoiser with its high, balanced
and fast networks (render.denoise_quality).

Renders frame 0 of the first trajectory of the default run's first scene (results/scenes/s0000, at the
config's resolution; --tiny uses lightcrafter.blender.testing.tiny_spec instead) under its source
lighting at each spp level and once at ``--ref-spp`` raw with a different seed (so the reference
does not share the low-spp samples), and writes

    results/bench/cycles_spp.json   (shape of docs/architecture.md, metric psnr_db)
    results/bench/cycles_spp.png    PSNR against seconds, chosen spp marked

PSNR (dB, peak 1) is computed on *display* values (lightcrafter.io.linear_to_display, 0 EV:
sRGB-encoded, clipped to [0, 1]), i.e. what the refiner sees; ``psnr_linear_db`` (linear radiance
clipped to [0, 1]) is recorded beside it, and ``firefly_fraction``: the share of pixels whose display
value exceeds the reference's by more than 0.25 (isolated bright speckles). Seconds are the wall time
of posing the frame and one render call (scene update, path tracing, denoising, EXR write/read) on one
Cycles CPU thread, as a render_rgb job runs (``--threads``). The chosen setting is the cheapest (series, spp)
whose display PSNR is at least ``--target-db`` and whose firefly fraction is under 1e-3.

    .venv/bin/python benchmarks/cycles_spp.py            # ~3 minutes on one thread at the default's 192x128
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lightcrafter import io  # noqa: E402
from lightcrafter.metrics import psnr_db  # noqa: E402
from lightcrafter.blender import build, render, testing  # noqa: E402


def render_rgb_once(
    built, spec: dict, spp: int, seed: int, denoiser=None, clamp_indirect=0.0, quality="high", threads=None,
) -> tuple[np.ndarray, float]:
    """Linear RGB (H, W, 3) of frame 0 at ``spp`` samples and the seconds it took.

    The frame is re-posed inside the timed block, as render_rgb does for every frame, so the
    per-frame scene update (BVH refit, environment importance map) is counted.
    """
    spec = dict(spec, render=dict(spec["render"], seed=seed))
    build.configure_render(
        spec,
        samples=spp,
        max_bounces=int(spec["render"]["max_bounces"]),
        filter_width_px=render.RGB_FILTER_WIDTH_PX,
        film_transparent=False,
        buffers=False,
        denoiser=denoiser,
        denoise_quality=quality,
        clamp_indirect=clamp_indirect,
        threads=threads,
    )
    t0 = time.perf_counter()
    build.set_frame(built, spec["trajectories"][0]["frames"][0])
    ch = render.render_layers()
    seconds = time.perf_counter() - t0
    return np.stack([ch[f"Combined.{c}"] for c in "RGB"], axis=-1), seconds


#: series -> (denoiser, indirect clamp, OIDN quality); "denoised" is OIDN's high-quality network
SERIES = {"raw": (None, 0.0, "high"), "clamped": (None, 1.0, "high"), "denoised": ("oidn", 0.0, "high"),
          "denoised_balanced": ("oidn", 0.0, "balanced"), "denoised_fast": ("oidn", 0.0, "fast")}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spp", type=int, nargs="+", default=[1, 2, 4, 8, 16, 32, 64])
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--scene", type=Path, default=Path("results/scenes/s0000/scene.json"))
    ap.add_argument("--tiny", action="store_true", help="use the hand-built tiny scene instead of a pipeline scene")
    ap.add_argument("--width", type=int, default=None, help="override the scene's resolution")
    ap.add_argument("--height", type=int, default=None)
    ap.add_argument("--target-db", type=float, default=35.0,
                    help="display PSNR the chosen setting must reach (35 dB: the targets stay far above what "
                         "proxies and refined clips reach, 12-25 dB)")
    ap.add_argument("--threads", type=int, default=1,
                    help="Cycles CPU threads (default 1, as a render_rgb job of the workflow; 0 = all)")
    ap.add_argument("--series", nargs="+", choices=list(SERIES), default=list(SERIES))
    ap.add_argument("--out", type=Path, default=Path("results/bench/cycles_spp.json"))
    args = ap.parse_args(argv)

    with tempfile.TemporaryDirectory(prefix="lc_bench_") as tmp:
        if args.tiny or not args.scene.is_file():
            spec = testing.tiny_spec(Path(tmp), width=args.width or 96, height=args.height or 64, num_frames=1)
            light, what = "L0", "lightcrafter.blender.testing.tiny_spec, trajectory 'orbit' frame 0, lighting L0"
        else:
            spec = io.read_json(args.scene)
            if args.width:
                spec["resolution"] = {"width": args.width, "height": args.height}
            light = spec["trajectories"][0]["source_light"]
            what = f"{args.scene}, trajectory {spec['trajectories'][0]['id']} frame 0, lighting {light}"
        res = spec["resolution"]
        built = build.build_scene(spec, light_id=light)
        ref, ref_seconds = render_rgb_once(built, spec, args.ref_spp, seed=12345, threads=args.threads or None)
        ref_display = io.linear_to_display(ref)
        points = []
        for series in args.series:
            den, clamp, quality = SERIES[series]
            for spp in args.spp:
                img, seconds = render_rgb_once(built, spec, spp, seed=0, denoiser=den, clamp_indirect=clamp,
                                               quality=quality, threads=args.threads or None)
                disp = io.linear_to_display(img)
                points.append({
                    "series": series, "setting": spp, "seconds": round(seconds, 3),
                    "value": round(psnr_db(disp, ref_display), 2),
                    "psnr_linear_db": round(psnr_db(np.clip(img, 0, 1), np.clip(ref, 0, 1)), 2),
                    "firefly_fraction": float(((disp - ref_display).max(axis=-1) > 0.25).mean()),
                })
                p = points[-1]
                print(f"{series:17s} spp {spp:4d}: {seconds:6.2f} s  PSNR display {p['value']:.2f} dB  "
                      f"fireflies {p['firefly_fraction']:.4f}", flush=True)
    good = [p for p in points if p["value"] >= args.target_db and p["firefly_fraction"] < 1e-3]
    best = min(good, key=lambda p: p["seconds"]) if good else max(points, key=lambda p: p["value"])
    result = {
        "name": "cycles_spp",
        "varied": "spp (series: raw, clamped = indirect clamp 1.0, denoised = OIDN's high-quality network, "
                  "denoised_balanced / denoised_fast = its balanced / fast network)",
        "metric": "psnr_db",
        "higher_is_better": True,
        "machine": {"cores": os.cpu_count(), "platform": platform.platform()},
        "threads": args.threads or "all",  # Cycles CPU threads of every render timed here
        "chosen": best["setting"],
        "chosen_series": best["series"],
        "points": points,
        "reference": {"spp": args.ref_spp, "seconds": round(ref_seconds, 3), "seed": 12345, "denoiser": None},
        "resolution": res,
        "psnr_on": "display values: lightcrafter.io.linear_to_display (0 EV, sRGB, clipped), peak 1",
        "scene": what,
        "rule": f"cheapest (series, spp) with display PSNR >= {args.target_db} dB and firefly fraction < 1e-3",
    }
    io.write_json(args.out, result)
    from lightcrafter.report import plot_bench

    plot_bench(result, args.out.with_suffix(".png"))
    print(f"chosen: {best['series']} at {best['setting']} spp; wrote {args.out} and {args.out.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
