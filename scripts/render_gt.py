"""Render ground truth of one trajectory of one scene with Blender (Cycles); one scene per process.

    render_gt.py --scene scene.json --traj t0 --buffers OUT_DIR          # G-buffers, cameras.json, buffers.json
    render_gt.py --scene scene.json --traj t0 --light L1 --out OUT_DIR   # rgb/L1/*.exr, rgb/L1.mp4, rgb/L1.json

OUT_DIR is the trajectory folder (results/gt/{scene}/{traj}). Bad input (missing or corrupt GLB,
missing HDRI or texture folder, unknown trajectory/lighting) prints one line on stderr naming the
file or key and exits with status 1; no manifest is written. See lightcrafter/blender/render.py.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lightcrafter.io import DataError, read_json  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", required=True, help="scene.json (lightcrafter.scene/1)")
    ap.add_argument("--traj", required=True, help="trajectory id in the scene spec")
    what = ap.add_mutually_exclusive_group(required=True)
    what.add_argument("--buffers", metavar="OUT_DIR", help="render G-buffers + cameras into this trajectory folder")
    what.add_argument("--out", metavar="OUT_DIR", help="render RGB under --light into this trajectory folder")
    ap.add_argument("--light", help="lighting id (with --out)")
    ap.add_argument("--threads", type=int, default=None, help="Cycles CPU threads (default: all)")
    ap.add_argument("--device", default="cpu", help="Cycles device: auto | cpu | cuda | optix (config render.device)")
    args = ap.parse_args(argv)
    if args.out and not args.light:
        ap.error("--out needs --light")
    t0 = time.perf_counter()
    try:
        spec = read_json(args.scene)
        from lightcrafter.blender import render

        if args.buffers:
            n = render.render_buffers(spec, args.traj, args.buffers, threads=args.threads, device=args.device)
            what_done = f"{n} buffer frame(s)"
        else:
            n = render.render_rgb(spec, args.traj, args.light, args.out, threads=args.threads, device=args.device)
            what_done = f"{n} RGB frame(s) under {args.light}"
    except DataError as exc:
        print(f"render_gt: {exc}", file=sys.stderr)
        return 1
    except (KeyError, TypeError, ValueError) as exc:  # a field missing or of the wrong type in scene.json
        print(
            f"render_gt: {args.scene}: malformed scene spec ({type(exc).__name__}: {exc}); re-run sample_scene",
            file=sys.stderr,
        )
        return 1
    print(f"render_gt: {spec.get('scene_id')}/{args.traj}: rendered {what_done} in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    from _cli import set_code_version

    set_code_version()
    sys.exit(main())
