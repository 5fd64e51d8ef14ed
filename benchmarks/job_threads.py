"""Two jobs side by side on a 2-core machine, as ``make run`` runs them: does each keep to its threads?

* ``cycles``: two ``render_gt.py --threads 1`` jobs at once (trajectories t0 and t1 of the default's scene
  s0000 under their source lighting; ``--tiny``: lightcrafter.blender.testing.tiny_spec at 32 spp), with
  Blender's thread pool sized to the job's thread at bpy's import (``pool_sized``, what the scripts do:
  lightcrafter.blender.build.import_bpy) and with bpy imported first, its pool sized to every core
  (``pool_unsized``). Per arm: wall seconds until both jobs end, the two jobs' CPU seconds (user + system),
  and whether both arms wrote the same frames (bit for bit). Every job gets the thread variables Snakemake sets
  (``OMP_NUM_THREADS``, ``OPENBLAS_NUM_THREADS``, ... = its threads), as in the pipeline.
* ``envfit``: two fit_envmap jobs (the default run's real clips ``--envfit-clips``, config envfit and proxy
  settings) one after the other on two threads each (how Snakemake runs a 2-thread rule on 2 cores) against
  side by side on one thread each; whether both give the same fitted parameters. Skipped (with the reason)
  when the run's outputs are missing.

Arms are interleaved (A, B, A, B, ... ``--repeats`` each); ``speed_ratio`` is the first arm's wall seconds over
the second's per interleaved pair, its median and range. Writes results/bench/job_threads.json.

    .venv/bin/python benchmarks/job_threads.py          # ~4 minutes on 2 cores after make run
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from lightcrafter import io  # noqa: E402
from lightcrafter.config import effective_config  # noqa: E402
from lightcrafter.speed import ratio_median_range  # noqa: E402

PY = sys.executable
RENDER = str(REPO / "scripts" / "render_gt.py")
FIT = str(REPO / "scripts" / "fit_envmap.py")
# bpy imported before the script runs: build.import_bpy then leaves Blender's pool as bpy sized it (every core)
UNSIZED = ("import runpy, sys; import bpy; sys.path.insert(0, {scripts!r}); sys.argv = sys.argv[1:]; "
           "runpy.run_path(sys.argv[0], run_name='__main__')")


# what Snakemake's shell() sets to a job's threads (snakemake/shell.py)
THREAD_VARIABLES = ("OMP_NUM_THREADS", "GOTO_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                    "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")


def run_jobs(commands: list[list[str]], parallel: bool, threads: int) -> tuple[float, float]:
    """Wall seconds until every command has ended and their CPU seconds (user + system, children). Each runs
    with the thread variables Snakemake gives a job of ``threads`` threads."""
    env = dict(os.environ, **{k: str(threads) for k in THREAD_VARIABLES})
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()

    def one(cmd):
        res = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, env=env)
        if res.returncode:
            raise SystemExit(f"job_threads: {' '.join(cmd[:3])}: exit {res.returncode}: {res.stderr.strip()[-300:]}")

    if parallel:
        with ThreadPoolExecutor(len(commands)) as pool:
            list(pool.map(one, commands))
    else:
        for cmd in commands:
            one(cmd)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def arm_summary(walls: list[float], cpus: list[float]) -> dict:
    return {"wall_seconds": [round(w, 2) for w in walls], "cpu_seconds": [round(c, 2) for c in cpus],
            "wall_seconds_median": round(statistics.median(walls), 2),
            "cpu_over_wall_median": round(statistics.median([c / w for c, w in zip(cpus, walls)]), 2)}


def same_frames(a: Path, b: Path) -> bool:
    fa, fb = sorted(a.rglob("*.exr")), sorted(b.rglob("*.exr"))
    return bool(fa) and [f.relative_to(a) for f in fa] == [f.relative_to(b) for f in fb] and all(
        x.read_bytes() == y.read_bytes() for x, y in zip(fa, fb))


def bench_cycles(scene: Path, lights: dict[str, str], repeats: int, tmp: Path) -> dict:
    arms = {"pool_unsized": [PY, "-c", UNSIZED.format(scripts=str(REPO / "scripts")), RENDER],
            "pool_sized": [PY, RENDER]}
    walls, cpus = {k: [] for k in arms}, {k: [] for k in arms}
    for r in range(repeats):
        for name, head in arms.items():  # interleaved: unsized, sized, unsized, ...
            out = tmp / f"cycles_{name}_{r}"
            cmds = [head + ["--scene", str(scene), "--traj", t, "--light", light, "--out", str(out / t),
                            "--threads", "1"] for t, light in lights.items()]
            w, c = run_jobs(cmds, parallel=True, threads=1)
            walls[name].append(w)
            cpus[name].append(c)
            print(f"cycles repeat {r}: {name}: {w:.2f} s wall, {c:.2f} s CPU", flush=True)
    return {"jobs": [f"render_gt.py --traj {t} --light {light} --threads 1" for t, light in lights.items()],
            "arms": {k: arm_summary(walls[k], cpus[k]) for k in arms},
            "speed_ratio": {"definition": "pool_unsized wall seconds / pool_sized, per interleaved pair",
                            **ratio_median_range(walls["pool_unsized"], walls["pool_sized"])},
            "same_frames": all(same_frames(tmp / f"cycles_pool_unsized_{r}", tmp / f"cycles_pool_sized_{r}")
                               for r in range(repeats))}


def bench_envfit(results: Path, clips: list[str], repeats: int, tmp: Path) -> dict:
    cfg = effective_config()
    settings, proxy = json.dumps(cfg["envfit"]), json.dumps(cfg["proxy"])
    arms = {"sequential_two_threads": (2, False), "side_by_side_one_thread": (1, True)}
    walls, cpus = {k: [] for k in arms}, {k: [] for k in arms}
    for r in range(repeats):
        for name, (threads, parallel) in arms.items():
            cmds = [[PY, FIT, "--clip", str(results / "recon" / "real" / c),
                     "--frames", str(results / "real" / c / "rgb"), "--out", str(tmp / f"envfit_{name}_{r}" / c),
                     "--settings-json", settings, "--proxy", proxy, "--threads", str(threads)] for c in clips]
            w, cp = run_jobs(cmds, parallel=parallel, threads=threads)
            walls[name].append(w)
            cpus[name].append(cp)
            print(f"envfit repeat {r}: {name}: {w:.2f} s wall, {cp:.2f} s CPU", flush=True)
    same = True
    for r in range(repeats):
        for c in clips:
            a = np.load(tmp / f"envfit_sequential_two_threads_{r}" / c / "params.npz")
            b = np.load(tmp / f"envfit_side_by_side_one_thread_{r}" / c / "params.npz")
            same &= all(np.array_equal(a[k], b[k]) for k in ("log_map", "yaw_rad", "pitch_rad", "exposure_ev"))
    return {"clips": clips, "arms": {k: arm_summary(walls[k], cpus[k]) for k in arms},
            "speed_ratio": {"definition": "sequential_two_threads wall seconds / side_by_side_one_thread, per "
                                          "interleaved pair", **ratio_median_range(walls["sequential_two_threads"],
                                                                             walls["side_by_side_one_thread"])},
            "same_fitted_parameters": bool(same)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", type=Path, default=REPO / "results")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--envfit-clips", nargs=2, default=["cup_f60", "box_f100"])
    ap.add_argument("--parts", nargs="+", choices=["cycles", "envfit"], default=["cycles", "envfit"])
    ap.add_argument("--tiny", action="store_true", help="the Cycles part on the render tests' tiny scene; no envfit")
    ap.add_argument("--out", type=Path, default=REPO / "results" / "bench" / "job_threads.json")
    a = ap.parse_args(argv)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    out = {"name": "job_threads", "machine": {"cores": cores, "platform": platform.platform()},
           "repeats": a.repeats, "order": "interleaved: first arm, second arm, first arm, ...", "not_run": {}}
    with tempfile.TemporaryDirectory(prefix="lc_bench_threads_") as tmp:
        tmp = Path(tmp)
        if a.tiny:
            from lightcrafter.blender import testing

            spec = testing.tiny_spec(tmp, num_frames=3, spp=32)
            scene = tmp / "scene.json"
            io.write_json(scene, spec)
            lights = {"orbit": "L0", "static": "L0"}
        else:
            scene = a.results / "scenes" / "s0000" / "scene.json"
            if not scene.is_file():
                raise SystemExit(f"job_threads: {scene}: missing; run `make run` (or snakemake ground_truth) first")
            spec = io.read_json(scene)
            lights = {t["id"]: t["source_light"] for t in spec["trajectories"][:2]}
        out["scene"] = "tiny_spec" if a.tiny else str(scene.relative_to(REPO) if scene.is_relative_to(REPO) else scene)
        if "cycles" in a.parts:
            out["cycles"] = bench_cycles(scene, lights, a.repeats, tmp)
        missing = [c for c in a.envfit_clips if not (a.results / "recon" / "real" / c / "buffers.json").is_file()]
        if a.tiny or missing or "envfit" not in a.parts:
            out["not_run"]["envfit"] = ("--tiny" if a.tiny else "--parts" if "envfit" not in a.parts
                                        else f"no reconstruction of {missing} in {a.results}: make run")
        else:
            out["envfit"] = bench_envfit(a.results, a.envfit_clips, a.repeats, tmp)
    io.write_json(a.out, out)
    print(f"wrote {a.out}:" + (f" cycles {out['cycles']['speed_ratio']}" if "cycles" in out else "")
          + (f", envfit {out['envfit']['speed_ratio']}" if "envfit" in out else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
