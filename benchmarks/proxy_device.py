"""The forward renderer R on each Mitsuba variant (``llvm_ad_rgb`` on the CPU, ``cuda_ad_rgb`` on a GPU):
seconds per frame at the paper's size, interleaved, and whether the variants render the same picture.

Scene: proxy_spp's analytic buffers (four spheres on a grey ground, ``forest.exr`` rotated 0.5 rad) at
``--width`` x ``--height`` (default 720x480, the paper's clips): ``--spp`` samples (the default config's
``proxy.spp``), multi-jittered, cast shadows from this frame's pixel-centre mesh (``visibility='frame'``),
environment background, no denoiser. Timed renders reuse the meshes the warm-up built, as the frames of
a static clip do; mesh building and denoising are not in the seconds.

Each variant lives in its own worker process (Mitsuba types are variant specific), built once and warmed
up (kernels compiled for this wavefront size). The parent then asks the workers in turn for one timed
render (A, B, A, B, ...): seconds are each variant's median over ``--repeats`` with its range, and the
speed ratio (first variant's seconds / each other's, per interleaved pair) its median with its range.
A variant the node cannot run (no GPU, no libLLVM) is reported as not run, with Mitsuba's reason.

Agreement: each variant's ``--spp`` frame against its own ``--ref-spp`` frame (sampling noise, display
PSNR, dB), and the variants' reference frames against each other (they should agree to the noise
level). ``--save-ref DIR`` writes each variant's reference frame (linear RGB, float32 .npy) and
``--compare-ref FILE`` scores each variant's reference against one saved elsewhere, e.g. the CPU
variant's frame from another machine when the GPU node has no libLLVM.

    .venv/bin/python benchmarks/proxy_device.py [--variants llvm_ad_rgb cuda_ad_rgb] [--repeats 5]
    -> results/bench/proxy_device.json
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import platform
import sys
import time
import traceback
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from lightcrafter import io  # noqa: E402
from lightcrafter.evaluation import PSNR_CAP_DB  # noqa: E402
from lightcrafter.metrics import display_psnr_db  # noqa: E402
from lightcrafter.speed import median_range, ratio_median_range  # noqa: E402

# The variants' reference frames use the same seed and sampler, so they share their samples and differ
# by floating-point detail only (82.8 dB apart on an H200 node); independent noise alone would put two
# 1024-spp frames ~45 dB apart. Below this floor the variants render different pictures (no cast shadows
# on cuda_ad_rgb gave 23.3 dB).
AGREEMENT_FLOOR_DB = 60.0


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    """Display PSNR (dB) capped at the evaluation's PSNR_CAP_DB: identical frames would be infinite."""
    return round(min(display_psnr_db(a, b), PSNR_CAP_DB), 3)


def _worker(variant: str, conn, a: dict) -> None:
    """Build R under ``variant`` and answer the parent's requests: ('time',) -> seconds of one render;
    ('image', spp, seed) -> the linear frame; ('stop',)."""
    try:
        os.environ["LIGHTCRAFTER_MI_VARIANT"] = variant
        import drjit as dr

        from lightcrafter import envmap
        from lightcrafter.lights import resolve_hdri
        from lightcrafter.proxy.lighting import Lighting
        from lightcrafter.proxy.mitsuba_setup import ensure_variant
        from lightcrafter.proxy.renderer import FrameView, ProxyRenderer, RenderSettings
        from proxy_spp import ROT_Z, bench_scene

        ensure_variant()
        if variant.startswith("llvm"):
            dr.set_thread_count(a["threads"])
        K, c2w, b = bench_scene(a["width"], a["height"])
        view = FrameView(b, K, c2w, "bench")
        settings = RenderSettings(spp=a["spp"], seed=0, visibility="frame")
        r = ProxyRenderer(Lighting(env=envmap.load(resolve_hdri(a["hdri"])), rotation_z_rad=ROT_Z), settings)
        t0 = time.perf_counter()
        r.render(view)  # warm-up: kernels compiled, BVH built
        warm_s = time.perf_counter() - t0
        conn.send(("ready", {"variant": variant, "warmup_seconds": round(warm_s, 3)}))
    except Exception as exc:  # noqa: BLE001 - reported as "not run" with the reason
        conn.send(("error", f"{type(exc).__name__}: {str(exc).strip().splitlines()[0] if str(exc).strip() else ''}"
                   f" ({traceback.extract_tb(exc.__traceback__)[-1].name})"))
        return
    while True:
        msg = conn.recv()
        try:
            if msg[0] == "time":
                t0 = time.perf_counter()
                img = r.render(view)
                dt = time.perf_counter() - t0
                conn.send(("ok", dt, bool(np.isfinite(img).all())))
            elif msg[0] == "image":
                r.settings = RenderSettings(**{**settings.__dict__, "spp": msg[1], "seed": msg[2]})
                img = np.asarray(r.render(view), dtype=np.float32)
                r.settings = settings
                conn.send(("ok", img))
            else:
                return
        except Exception as exc:  # noqa: BLE001 - the parent stops with this reason
            conn.send(("error", f"{type(exc).__name__}: {exc}"))
            return


def _receive(p, conn, timeout_s: float) -> tuple:
    """The worker's next message, or ("error", why) when it died or did not answer in ``timeout_s``."""
    if not conn.poll(timeout_s):
        return ("error", f"no answer in {timeout_s:.0f} s (worker {'alive' if p.is_alive() else 'exited'})")
    try:
        return conn.recv()
    except EOFError:
        return ("error", f"the worker exited (code {p.exitcode})")


def _answer(v: str, p, conn, timeout_s: float) -> tuple:
    """:func:`_receive`, where an error stops the benchmark with one line naming the variant."""
    msg = _receive(p, conn, timeout_s)
    if msg[0] == "error":
        raise SystemExit(f"proxy_device: {v}: {msg[1]}")
    return msg


def run(a: argparse.Namespace, other_ref: np.ndarray | None = None) -> dict:
    ctx = mp.get_context("spawn")
    params = {k: getattr(a, k) for k in ("width", "height", "spp", "threads", "hdri")}
    workers, not_run, warm, procs = {}, {}, {}, []
    try:
        for v in a.variants:  # started one at a time: each warm-up compiles with all threads
            parent, child = ctx.Pipe()
            p = ctx.Process(target=_worker, args=(v, child, params), daemon=True)
            p.start()
            procs.append(p)
            child.close()  # the worker holds the only other end: its exit is an EOF here, not a hang
            kind, payload = _receive(p, parent, a.start_timeout)
            if kind == "ready":
                workers[v], warm[v] = (p, parent), payload["warmup_seconds"]
                print(f"{v}: ready (warm-up {payload['warmup_seconds']} s)", flush=True)
            else:
                not_run[v] = payload
                print(f"{v}: not run: {payload}", flush=True)
                p.terminate()
        if not workers:
            raise SystemExit("proxy_device: no Mitsuba variant could render here: "
                             + "; ".join(f"{k}: {v}" for k, v in not_run.items()))

        timeout_s = a.start_timeout
        seconds = {v: [] for v in workers}
        finite = {v: True for v in workers}
        for _ in range(a.repeats):  # interleaved: A, B, A, B, ...
            for v, (p, conn) in workers.items():
                conn.send(("time",))
                _, dt, ok = _answer(v, p, conn, timeout_s)
                seconds[v].append(dt)
                finite[v] &= ok
        images, refs = {}, {}
        for v, (p, conn) in workers.items():
            conn.send(("image", a.spp, 1))
            images[v] = _answer(v, p, conn, timeout_s)[1]
            conn.send(("image", a.ref_spp, 12345))
            refs[v] = _answer(v, p, conn, timeout_s)[1]
            conn.send(("stop",))
    finally:
        for p in procs:
            p.join(10)
            if p.is_alive():
                p.terminate()

    names = list(workers)
    per_variant = {}
    for v in names:
        per_variant[v] = {
            "seconds_per_frame": median_range(seconds[v], 4),
            "warmup_seconds": warm[v],
            "all_finite": finite[v] and bool(np.isfinite(images[v]).all() and np.isfinite(refs[v]).all()),
            "psnr_vs_own_reference_db": _psnr(images[v], refs[v]),
        }
    base = names[0]
    ratios = {f"{base}/{v}": ratio_median_range(seconds[base], seconds[v]) for v in names[1:]}
    agreement = {f"{x}_vs_{y}": _psnr(refs[y], refs[x]) for i, x in enumerate(names) for y in names[i + 1:]}
    if other_ref is not None:
        for v in names:
            agreement[f"{v}_vs_{Path(a.compare_ref).name}"] = _psnr(refs[v], other_ref)
    if a.save_ref:
        Path(a.save_ref).mkdir(parents=True, exist_ok=True)
        for v in names:
            tmp = Path(a.save_ref) / f".{v}_ref.tmp.npy"
            np.save(tmp, refs[v])
            os.replace(tmp, Path(a.save_ref) / f"{v}_ref.npy")
    return {
        "name": "proxy_device",
        "machine": {"cores": len(os.sched_getaffinity(0)), "platform": platform.platform(), "llvm_threads": a.threads,
                    "python": platform.python_version()},
        "scene": f"proxy_spp's 4 spheres on a ground, {a.hdri} rotated 0.5 rad, visibility='frame'",
        "resolution": {"width": a.width, "height": a.height}, "spp": a.spp, "reference_spp": a.ref_spp,
        "repeats": a.repeats, "order": "interleaved: " + ", ".join(names) + ", ... (one timed render each)",
        "variants": per_variant,
        "speed_ratio": {"definition": "first variant's seconds / the other's, per interleaved pair", **ratios},
        "reference_agreement_psnr_db": agreement, "psnr_cap_db": PSNR_CAP_DB,
        "references_agree": {k: bool(v >= AGREEMENT_FLOOR_DB) for k, v in agreement.items()},
        "agreement_floor_db": AGREEMENT_FLOOR_DB,
        "not_run": not_run,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="results/bench/proxy_device.json")
    ap.add_argument("--variants", nargs="+", default=["llvm_ad_rgb", "cuda_ad_rgb"])
    ap.add_argument("--width", type=int, default=720)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--spp", type=int, default=None, help="default: the default config's proxy.spp")
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=len(os.sched_getaffinity(0)),
                    help="LLVM variant's CPU threads (default: the CPUs this process may use)")
    ap.add_argument("--hdri", default="builtin:forest.exr")
    ap.add_argument("--start-timeout", type=float, default=240.0,
                    help="seconds a worker may take to warm up, or to answer one request")
    ap.add_argument("--save-ref", default=None, help="folder for each variant's reference frame (.npy)")
    ap.add_argument("--compare-ref", default=None, help="a reference frame (.npy) saved by --save-ref elsewhere")
    a = ap.parse_args()
    if a.spp is None:
        from lightcrafter.config import raw_config, validate

        a.spp = int(validate(raw_config())["proxy"]["spp"])
    if a.repeats < 1:
        raise SystemExit(f"proxy_device: --repeats {a.repeats}: needs at least one timed render per variant")
    other = None
    if a.compare_ref:  # checked before rendering: a wrong path or size costs nothing
        try:
            other = np.load(a.compare_ref)
        except (OSError, ValueError) as exc:
            raise SystemExit(f"proxy_device: --compare-ref {a.compare_ref}: cannot read it ({exc}); pass a frame "
                             "saved by --save-ref") from None
        if other.shape != (a.height, a.width, 3):
            raise SystemExit(f"proxy_device: --compare-ref {a.compare_ref}: a {other.shape} frame, this run renders "
                             f"{(a.height, a.width, 3)}; pass the --width/--height it was saved with")
    result = run(a, other)
    io.write_json(a.out, result)
    for v, r in result["variants"].items():
        s = r["seconds_per_frame"]
        print(f"{v}: {s['median']} s/frame (range {s['min']}-{s['max']}), "
              f"{r['psnr_vs_own_reference_db']} dB vs its {a.ref_spp}-spp frame")
    for k, v in result["reference_agreement_psnr_db"].items():
        print(f"{k}: {v} dB{'' if v >= AGREEMENT_FLOOR_DB else f' (below {AGREEMENT_FLOOR_DB} dB: different pictures)'}")
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
