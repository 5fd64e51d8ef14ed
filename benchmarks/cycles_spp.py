"""Error against run time of the Cycles ground truth: samples per pixel vs PSNR to a high-spp reference.

Renders frame 0 of the ``orbit`` trajectory of lightcrafter.blender.testing.tiny_spec under
lighting L0 at each spp level and once at ``--ref-spp`` with a different seed (so the reference
does not share the low-spp samples), and writes

    results/bench/cycles_spp.json   (shape of docs/architecture.md, metric psnr_db)
    results/bench/cycles_spp.png    PSNR against seconds, chosen spp marked

PSNR (dB, peak 1) is computed on *display* values (lightcrafter.io.linear_to_display, 0 EV:
sRGB-encoded, clipped to [0, 1]), i.e. what the refiner sees; ``psnr_linear_db`` (linear radiance
clipped to [0, 1]) is recorded beside it. Seconds are the wall time of posing the frame and one render
call (scene update, path tracing, EXR write/read) with the default Cycles CPU threads. The chosen spp is the smallest
level whose display PSNR is at least ``--target-db``.

    .venv/bin/python benchmarks/cycles_spp.py            # ~1-2 minutes on 2 cores at 96x64
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


def render_rgb_once(built, spec: dict, spp: int, seed: int) -> tuple[np.ndarray, float]:
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
    )
    t0 = time.perf_counter()
    build.set_frame(built, spec["trajectories"][0]["frames"][0])
    ch = render.render_layers()
    seconds = time.perf_counter() - t0
    return np.stack([ch[f"Combined.{c}"] for c in "RGB"], axis=-1), seconds


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spp", type=int, nargs="+", default=[1, 2, 4, 8, 16, 32, 64])
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--width", type=int, default=96)
    ap.add_argument("--height", type=int, default=64)
    ap.add_argument("--target-db", type=float, default=30.0, help="display PSNR the chosen spp must reach")
    ap.add_argument("--out", type=Path, default=Path("results/bench/cycles_spp.json"))
    args = ap.parse_args(argv)

    with tempfile.TemporaryDirectory(prefix="lc_bench_") as tmp:
        spec = testing.tiny_spec(Path(tmp), width=args.width, height=args.height, num_frames=1)
        built = build.build_scene(spec, light_id="L0")
        ref, ref_seconds = render_rgb_once(built, spec, args.ref_spp, seed=12345)
        ref_display = io.linear_to_display(ref)
        points = []
        for spp in args.spp:
            img, seconds = render_rgb_once(built, spec, spp, seed=0)
            points.append(
                {
                    "setting": spp,
                    "seconds": round(seconds, 3),
                    "value": round(psnr_db(io.linear_to_display(img), ref_display), 2),
                    "psnr_linear_db": round(psnr_db(np.clip(img, 0, 1), np.clip(ref, 0, 1)), 2),
                }
            )
            print(
                f"spp {spp:4d}: {seconds:6.2f} s  PSNR display {points[-1]['value']:.2f} dB  "
                f"linear {points[-1]['psnr_linear_db']:.2f} dB",
                flush=True,
            )
    good = [p["setting"] for p in points if p["value"] >= args.target_db]
    chosen = min(good) if good else max(p["setting"] for p in points)
    result = {
        "name": "cycles_spp",
        "varied": "spp",
        "metric": "psnr_db",
        "higher_is_better": True,
        "machine": {"cores": os.cpu_count(), "platform": platform.platform()},
        "chosen": chosen,
        "points": points,
        "reference": {"spp": args.ref_spp, "seconds": round(ref_seconds, 3), "seed": 12345},
        "resolution": {"width": args.width, "height": args.height},
        "psnr_on": "display values: lightcrafter.io.linear_to_display (0 EV, sRGB, clipped), peak 1",
        "scene": "lightcrafter.blender.testing.tiny_spec, trajectory 'orbit' frame 0, lighting L0",
        "rule": f"smallest spp with display PSNR >= {args.target_db} dB",
    }
    io.write_json(args.out, result)
    _plot(result, args.out.with_suffix(".png"))
    print(f"chosen spp {chosen}; wrote {args.out} and {args.out.with_suffix('.png')}")
    return 0


def _plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pts = result["points"]
    fig, ax = plt.subplots(figsize=(5, 3.5), dpi=120)
    ax.plot([p["seconds"] for p in pts], [p["value"] for p in pts], "o-")
    for p in pts:
        ax.annotate(
            str(p["setting"]), (p["seconds"], p["value"]), textcoords="offset points", xytext=(4, -10), fontsize=8
        )
        if p["setting"] == result["chosen"]:
            ax.plot(p["seconds"], p["value"], "r*", ms=14, label=f"chosen: {p['setting']} spp")
    ax.set_xscale("log")
    ax.set_xlabel("seconds per frame (log)")
    ax.set_ylabel("PSNR vs reference, display [dB]")
    res = result["resolution"]
    ax.set_title(f"Cycles spp ({res['width']}x{res['height']}, ref {result['reference']['spp']} spp)")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="lower right")
    fig.tight_layout()
    with io.atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
