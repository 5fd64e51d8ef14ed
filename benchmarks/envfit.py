"""Envmap fitting: reference solver (R + Mitsuba AD every iteration) vs fast solver (sparse transport).

Clip: analytic ground-truth buffers (lightcrafter.envfit.synthetic: four spheres of different
materials on a grey ground, an orbiting camera) at the default pipeline's size (``--width`` x
``--height``, ``--frames``), its "video" rendered by R (``--video-spp``) under a known map (``--hdri``,
area-averaged to 64 x 128). Both solvers run the paper's settings (FitSettings defaults: 2000
iterations, Adam lr 2e-3, lambda_TV 1e-3, every fourth frame) from the same initial map.

Measured
--------
* ``points``: the TRUE objective (sum over the fitted frames' used pixels and channels of
  |T(R) - T(I)| + 1e-3 TV(log L)), evaluated by R itself (ProxyRenderer, MIS, ``--eval-spp``, fixed
  seed) at snapshots of each solver, against the solver's wall seconds since it started (the common
  set-up before it - clip, video, R's visibility mesh, initial map - is reported apart as
  ``prepare_seconds``; evaluation time is excluded). ``series`` = solver, ``setting`` = iteration.
  ``psnr_points``: display PSNR (lightcrafter.metrics.display_psnr_db) of the same renders vs the video.
* ``speedup``: reference seconds for its 2000 iterations / fast seconds to reach the reference's
  final true objective (interpolated in log seconds), also with the shared preparation added to both. The
  two solvers run in ``--rounds`` interleaved rounds (fast, reference, fast, reference, ...), a speedup per
  round from that round's seconds at the first round's snapshots (the solvers are seeded: every round fits
  the same maps); reported as the median with its range over rounds (``points`` carry the first round).
* ``memory``: the fast solver's transport bytes (measured and the bound of
  lightcrafter.envfit.transport) at this size and at the paper's (720x480, 49 frames: synthetic
  buffers and frames, run in a subprocess for its peak RSS; R's visibility 'frame' there, since the
  49-frame aggregate mesh is R's own cost and not the solver's), with seconds per iteration of
  both solvers at that size (reference: ``--paper-ref-iterations`` on one frame).
* ``default_clip``: seconds of the fast solver and of a whole fit_envmap (pseudo video included) per clip.
* ``ground_truth``: fast fits on clips whose map is known: SH (order 2, upper hemisphere) relative
  error after yaw alignment, re-render PSNR, against the initial map and the true map.

    nice -n 10 .venv/bin/python benchmarks/envfit.py        # ~20-30 minutes on 2 busy cores
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lightcrafter import envmap, io  # noqa: E402
from lightcrafter.envfit import synthetic as es  # noqa: E402
from lightcrafter.envfit.evaluate import TrueObjective, sh_error  # noqa: E402
from lightcrafter.envfit.fit import DEFAULT_RENDER, FitSettings, fit_envmap, optimize, prepare  # noqa: E402
from lightcrafter.envfit.model import EnvParams, MapHead, log_of_map  # noqa: E402
from lightcrafter.envfit.transport import memory_bound_bytes  # noqa: E402
from lightcrafter.proxy.renderer import RenderSettings  # noqa: E402
from lightcrafter.speed import median_range  # noqa: E402

SNAPSHOTS = [0, 25, 50, 100, 200, 300, 500, 750, 1000, 1250, 1500, 1750, 2000]


def load_map(ref: str, height: int = 64, width: int = 128) -> np.ndarray:
    from lightcrafter.envfit.model import resize_map
    from lightcrafter.lights import resolve_hdri

    if ref.startswith("sky"):
        sun = float(ref.split(":")[1]) if ":" in ref else 0.0
        return es.sky_map(height, width, sun=sun)
    return resize_map(envmap.load(resolve_hdri(ref)), height, width)


def make_problem(root: Path, env: np.ndarray, width: int, height: int, frames: int, spp: int) -> tuple[Path, Path]:
    clip = es.write_synthetic_clip(root / "clip", n=frames, width=width, height=height)
    es.render_video(clip, env, root / "frames", spp=spp)
    return clip, root / "frames"


def run_solver(clip, frames_dir, settings: FitSettings, snapshots) -> tuple[list, dict, float]:
    t0 = time.perf_counter()
    pb = prepare(clip, frames_dir, settings)
    prep = time.perf_counter() - t0
    snaps = []
    c0 = time.process_time()
    res = optimize(pb, settings, snapshot=lambda it, s, p: snaps.append((it, s, p)), snapshot_at=snapshots)
    cpu = time.process_time() - c0
    return snaps, {"prepare_seconds": round(prep, 3), "solve_seconds": round(res.seconds, 3),
                   "solve_cpu_seconds_all_threads": round(cpu, 3),
                   "setup_seconds": round(res.setup_seconds, 3), "stats": res.stats,
                   "final_params": {k: v for k, v in res.params.items() if k != "log_map"}}, prep


def evaluate(snaps, ev: TrueObjective, head: MapHead, series: str) -> tuple[list, list]:
    pts, psnr = [], []
    for it, sec, p in snaps:
        env = head.baked(EnvParams.create(p["log_map"], p["yaw_rad"], p["pitch_rad"], p["exposure_ev"]))
        r = ev(env, p["log_map"])
        pts.append({"series": series, "setting": it, "seconds": round(sec, 3), "value": round(r["objective"], 4),
                    "data": round(r["data"], 4), "tv": round(r["tv"], 3), "psnr_db": round(r["psnr_db"], 3)})
        psnr.append({"series": series, "setting": it, "seconds": round(sec, 3), "value": round(r["psnr_db"], 3)})
        print(f"  {series:9s} it {it:5d}  {sec:8.2f} s  objective {r['objective']:10.3f}  PSNR {r['psnr_db']:6.2f} dB",
              flush=True)
    return pts, psnr


def seconds_to_reach(points: list, target: float) -> float | None:
    """First time a (seconds, value) curve (lower is better) reaches ``target``; log-linear in seconds."""
    pts = sorted(points, key=lambda p: p["seconds"])
    for p0, p1 in zip(pts, pts[1:]):
        if p0["value"] <= target:
            return p0["seconds"]
        if p1["value"] <= target < p0["value"]:
            f = (p0["value"] - target) / (p0["value"] - p1["value"])
            s0, s1 = max(p0["seconds"], 1e-3), max(p1["seconds"], 1e-3)
            return float(np.exp(np.log(s0) + f * (np.log(s1) - np.log(s0))))
    return pts[0]["seconds"] if pts and pts[0]["value"] <= target else None


def round_speedup(rd: dict, ref_pts: list, fast_pts: list, target: float) -> dict:
    """One round's speedup: its solvers' seconds at the first round's snapshots (same iterations, same
    objective values), the reference's final seconds over the fast solver's seconds to reach ``target``."""
    def timed(points, snaps):
        return [{**p, "seconds": sec} for p, (_, sec, _) in zip(points, snaps)]

    ref_r, fast_r = timed(ref_pts, rd["reference"][0]), timed(fast_pts, rd["fast"][0])
    t_ref, t_fast = ref_r[-1]["seconds"], seconds_to_reach(fast_r, target)
    prep_ref, prep_fast = rd["reference"][1]["prepare_seconds"], rd["fast"][1]["prepare_seconds"]
    return {"reference_seconds": round(t_ref, 3), "fast_seconds_to_reach": None if t_fast is None else round(t_fast, 3),
            "speedup": None if t_fast is None else round(t_ref / max(t_fast, 1e-9), 2),
            "speedup_with_shared_prepare": None if t_fast is None else
            round((t_ref + prep_ref) / (t_fast + prep_fast), 2)}


def paper_memory(width: int, height: int, frames: int, settings: FitSettings, iterations: int,
                 ref_iterations: int = 0) -> dict:
    """Fast solver at the paper's resolution on synthetic buffers and frames (run in a subprocess)."""
    from lightcrafter.envfit.fit import build_objective

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        t0 = time.perf_counter()
        clip = es.write_synthetic_clip(root / "clip", n=frames, width=width, height=height)
        from lightcrafter.clip import read_clip

        views, _ = read_clip(clip)
        for i, v in enumerate(views):  # a positive synthetic "video": shaded albedo + sky-ish background
            b = v.buffers
            img = np.where(b.mask[..., None] > 0.5, 0.2 + 0.6 * b.albedo * np.clip(b.normal[..., 2:3], 0.1, 1.0),
                           np.array([0.5, 0.6, 0.9], np.float32))
            io.write_rgb_exr(root / "frames" / f"{i:04d}.exr", img.astype(np.float32))
        del views
        make_s = time.perf_counter() - t0
        rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        t0 = time.perf_counter()
        s = replace(settings, iterations=iterations, checkpoint_every=0)
        render = RenderSettings(visibility="frame")
        pb = prepare(clip, root / "frames", s, render)
        prep = time.perf_counter() - t0
        t0 = time.perf_counter()
        obj = build_objective(pb, s)
        build = time.perf_counter() - t0
        rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        res = optimize(pb, s)
        per_it = (res.seconds - res.setup_seconds) / max(1, iterations)
        fitted = len(pb.video.fitted)
        transport_bytes, transport_nnz = obj.nbytes, obj.nnz
        del obj, res
        ref = {}
        if ref_iterations > 0:  # reference iterations on frame 0 only (the first builds its mesh)
            sr = replace(s, solver="reference", iterations=ref_iterations + 1, frame_stride=frames)
            pr = prepare(clip, root / "frames", sr, render)
            rr = optimize(pr, sr)
            c = rr.curve
            ref = {"reference_seconds_per_iteration": round((c[-1]["seconds"] - c[0]["seconds"]) / ref_iterations, 3),
                   "reference_iterations_timed": ref_iterations, "reference_ref_spp": sr.ref_spp}
        return {"width": width, "height": height, "frames": frames, "fitted_frames": fitted,
                "transport_pixels": s.transport_pixels, "transport_spp": s.transport_spp,
                "transport_bytes": transport_bytes, "transport_nnz": transport_nnz,
                "bound_bytes": memory_bound_bytes(fitted, s.transport_pixels, s.transport_spp, s.env_height, s.env_width),
                "video_bytes": int(pb.video.frames.nbytes),
                "peak_rss_bytes_before_prepare": rss0 * 1024, "peak_rss_bytes_after_transport": rss1 * 1024,
                "peak_rss_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
                "make_inputs_seconds": round(make_s, 2), "prepare_seconds": round(prep, 2),
                "transport_build_seconds": round(build, 2), "seconds_per_iteration": round(per_it, 5),
                "iterations_timed": iterations, "visibility": "frame", **ref}


def ground_truth(maps: list[str], args, settings: FitSettings, head: MapHead, reuse: dict) -> list:
    out = []
    for ref in maps:
        env = load_map(ref)
        if ref in reuse:
            r = reuse[ref]
        else:
            with tempfile.TemporaryDirectory() as tmp:
                clip, fd = make_problem(Path(tmp), env, args.width, args.height, args.frames, args.video_spp)
                pb = prepare(clip, fd, settings)
                res = optimize(pb, settings)
                ev = TrueObjective(pb, spp=args.eval_spp)
                r = {"fit": ev(res.env, res.params["log_map"]), "init": ev(np.exp(pb.init_log_map), pb.init_log_map),
                     "truth": ev(env), "env": res.env, "init_env": np.exp(pb.init_log_map),
                     "params": res.params, "seconds": res.seconds}
        sh_fit = sh_error(r["env"], env)
        sh_init = sh_error(r["init_env"], env)
        row = {"map": ref, "sh_aligned_relative_error": round(sh_fit["aligned_relative_error"], 4),
               "sh_relative_error": round(sh_fit["relative_error"], 4),
               "alignment_yaw_rad": round(sh_fit["alignment_yaw_rad"], 4),
               "sh_aligned_relative_error_init": round(sh_init["aligned_relative_error"], 4),
               "psnr_db_fit": round(r["fit"]["psnr_db"], 3), "psnr_db_init": round(r["init"]["psnr_db"], 3),
               "psnr_db_true_map": round(r["truth"]["psnr_db"], 3),
               "objective_fit": round(r["fit"]["objective"], 3), "objective_true_map_data_only": round(r["truth"]["data"], 3),
               "fitted_yaw_rad": round(r["params"]["yaw_rad"], 4), "fitted_pitch_rad": round(r["params"]["pitch_rad"], 4),
               "fitted_exposure_ev": round(r["params"]["exposure_ev"], 4), "fit_seconds": round(r["seconds"], 2)}
        print(f"  ground truth {ref}: {row}", flush=True)
        out.append(row)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="results/bench/envfit.json")
    ap.add_argument("--width", type=int, default=128)
    ap.add_argument("--height", type=int, default=96)
    ap.add_argument("--frames", type=int, default=17)
    ap.add_argument("--hdri", default="builtin:forest.exr", help="map of the solver comparison clip")
    ap.add_argument("--gt-maps", nargs="*", default=["sky", "builtin:sunset.exr"],
                    help="further known maps for the ground-truth check (sky[:sun] = lightcrafter.envfit.synthetic.sky_map)")
    ap.add_argument("--video-spp", type=int, default=128)
    ap.add_argument("--eval-spp", type=int, default=64)
    ap.add_argument("--iterations", type=int, default=2000)
    ap.add_argument("--threads", type=int, default=2, help="Dr.Jit threads (torch runs single-threaded)")
    ap.add_argument("--paper-width", type=int, default=720)
    ap.add_argument("--paper-height", type=int, default=480)
    ap.add_argument("--paper-frames", type=int, default=49)
    ap.add_argument("--paper-iterations", type=int, default=200, help="iterations timed at the paper's size")
    ap.add_argument("--paper-ref-iterations", type=int, default=3, help="reference iterations timed at the paper's size")
    ap.add_argument("--rounds", type=int, default=2, help="interleaved rounds of the two solvers (speedup: median "
                    "and range of the per-round speedups)")
    ap.add_argument("--skip-paper", action="store_true")
    ap.add_argument("--paper-memory-only", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()

    import drjit as dr

    from lightcrafter.proxy.mitsuba_setup import ensure_variant

    variant = ensure_variant()
    dr.set_thread_count(a.threads)
    base = FitSettings(iterations=a.iterations, threads=a.threads, checkpoint_every=0)
    if a.paper_memory_only:
        print(json.dumps(paper_memory(a.paper_width, a.paper_height, a.paper_frames, base, a.paper_iterations,
                                      a.paper_ref_iterations)))
        return
    snapshots = [s for s in SNAPSHOTS if s <= a.iterations] + ([a.iterations] if a.iterations not in SNAPSHOTS else [])
    head = MapHead(base.env_height, base.env_width)
    env_true = load_map(a.hdri)
    t_all = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        t0 = time.perf_counter()
        clip, frames_dir = make_problem(root, env_true, a.width, a.height, a.frames, a.video_spp)
        print(f"clip {a.width}x{a.height}x{a.frames} + video at {a.video_spp} spp: {time.perf_counter() - t0:.1f} s", flush=True)
        rounds = []  # per round: {solver: (snapshots, info)}, the solvers interleaved
        for k in range(a.rounds):
            rounds.append({})
            for solver in ("fast", "reference"):
                s = replace(base, solver=solver)
                print(f"round {k + 1}/{a.rounds}: {solver} solver, {a.iterations} iterations ...", flush=True)
                snaps, info, prep = run_solver(clip, frames_dir, s, snapshots)
                rounds[-1][solver] = (snaps, info)
                print(f"  prepare {prep:.1f} s, solve {info['solve_seconds']:.1f} s", flush=True)
        runs = rounds[0]
        pb_eval = prepare(clip, frames_dir, base)
        ev = TrueObjective(pb_eval, spp=a.eval_spp, lambda_tv=base.lambda_tv)
        points, psnr_points = [], []
        t_eval = time.perf_counter()
        for solver in ("reference", "fast"):
            p, q = evaluate(runs[solver][0], ev, head, solver)
            points += p
            psnr_points += q
        eval_seconds = time.perf_counter() - t_eval
        truth = ev(env_true, log_of_map(env_true))
        init_env = np.exp(pb_eval.init_log_map)
        ref_pts = [p for p in points if p["series"] == "reference"]
        fast_pts = [p for p in points if p["series"] == "fast"]
        target = ref_pts[-1]["value"]
        prep_fast = runs["fast"][1]["prepare_seconds"]
        per_round = [round_speedup(rd, ref_pts, fast_pts, target) for rd in rounds]
        speed = {  # objectives: every round; seconds here: the first round's (all rounds: per_round)
            "reference_final_objective": target, "reference_seconds_round_1": per_round[0]["reference_seconds"],
            "fast_seconds_to_reach_round_1": per_round[0]["fast_seconds_to_reach"],
            "fast_final_objective": fast_pts[-1]["value"], "fast_seconds_round_1": fast_pts[-1]["seconds"],
            "speedup": median_range([r["speedup"] for r in per_round]),
            "speedup_with_shared_prepare": median_range([r["speedup_with_shared_prepare"] for r in per_round]),
            "per_round": per_round, "rounds": a.rounds,
            "goal": 20.0,
        }
        speed["goal_met"] = bool(speed["speedup"] is not None and speed["speedup"]["median"] >= 20.0)
        t_rev = seconds_to_reach(ref_pts, fast_pts[-1]["value"])
        speed["reference_seconds_to_reach_fast_final"] = None if t_rev is None else round(t_rev, 3)
        speed["cpu_seconds_per_iteration"] = {
            k: round(runs[k][1]["solve_cpu_seconds_all_threads"] / a.iterations, 5) for k in runs}
        print(f"speedup: {speed}", flush=True)
        # whole default-size fit (pseudo video included), as the pipeline runs it
        t0 = time.perf_counter()
        man = fit_envmap(clip, frames_dir, root / "fit", base, DEFAULT_RENDER)
        whole = time.perf_counter() - t0
        default_clip = {"width": a.width, "height": a.height, "frames": a.frames, "iterations": a.iterations,
                        "fast_prepare_seconds": prep_fast, "fast_solve_seconds": runs["fast"][1]["solve_seconds"],
                        "fast_transport_build_seconds": runs["fast"][1]["setup_seconds"],
                        "fit_envmap_seconds_total": round(whole, 2), "fit_envmap_manifest_fit_seconds": man["fit"]["fit_seconds"],
                        "pseudo_psnr_db": man["pseudo_psnr_db"]["mean"]}
        st = runs["fast"][1]["stats"]
        memory = {"formula": "M <= F_s * P_s * (16 * min(4 * spp, He * We) + 4) + 4 F_s bytes (int32 column index + 3 float32 "
                             "values per (pixel, texel) entry; F_s fitted frames, P_s pixels sampled per frame)",
                  "default": {"width": a.width, "height": a.height, "frames": a.frames, "fitted_frames": len(st["fitted_frames"]),
                              "transport_bytes": st["transport_bytes"], "transport_nnz": st["transport_nnz"],
                              "bound_bytes": memory_bound_bytes(len(st["fitted_frames"]), base.transport_pixels,
                                                                base.transport_spp, base.env_height, base.env_width)}}
        reuse = {a.hdri: {"fit": None}}
        fsnap = runs["fast"][0][-1][2]
        fenv = head.baked(EnvParams.create(fsnap["log_map"], fsnap["yaw_rad"], fsnap["pitch_rad"], fsnap["exposure_ev"]))
        last_fast = fast_pts[-1]
        reuse[a.hdri] = {"fit": {"psnr_db": last_fast["psnr_db"], "objective": last_fast["value"]},
                         "init": ev(init_env, pb_eval.init_log_map), "truth": truth, "env": fenv, "init_env": init_env,
                         "params": fsnap, "seconds": runs["fast"][1]["solve_seconds"]}
    if not a.skip_paper:
        print(f"paper size {a.paper_width}x{a.paper_height}x{a.paper_frames} (subprocess) ...", flush=True)
        cmd = [sys.executable, __file__, "--paper-memory-only", "--threads", str(a.threads),
               "--paper-width", str(a.paper_width), "--paper-height", str(a.paper_height),
               "--paper-frames", str(a.paper_frames), "--paper-iterations", str(a.paper_iterations),
               "--paper-ref-iterations", str(a.paper_ref_iterations)]
        p = subprocess.run(cmd, capture_output=True, text=True)
        if p.returncode == 0:
            memory["paper"] = json.loads(p.stdout.strip().splitlines()[-1])
        else:
            memory["paper"] = f"not computed: {p.stderr.strip().splitlines()[-1] if p.stderr.strip() else p.returncode}"
        print(f"  {memory['paper']}", flush=True)
    print("ground truth ...", flush=True)
    gt = ground_truth([a.hdri] + list(a.gt_maps), a, base, head, reuse)
    result = {
        "name": "envfit", "varied": "iteration (series: solver)",
        "metric": "objective",
        "metric_definition": "sum over fitted frames, used pixels, channels of |T(R)-T(I)|, T = Reinhard, "
                             f"+ {base.lambda_tv:g} TV(log L); R at {a.eval_spp} spp",
        "higher_is_better": False,
        "machine": {"cores": os.cpu_count(), "platform": platform.platform(), "threads_used": a.threads,
                    "mitsuba_variant": variant, "load_average_at_end": list(os.getloadavg())},
        "chosen": a.iterations, "chosen_series": "fast",
        "points": points, "psnr_points": psnr_points,
        "speedup": speed, "memory": memory, "default_clip": default_clip, "ground_truth": gt,
        "true_map": {"objective_data": round(truth["data"], 4), "psnr_db": round(truth["psnr_db"], 3)},
        "solver_runs": {k: v[1] for k, v in runs.items()},
        "settings": {"fit": {k: (list(v) if isinstance(v, tuple) else v) for k, v in base.__dict__.items()},
                     "hdri": a.hdri, "video_spp": a.video_spp, "eval_spp": a.eval_spp,
                     "eval_seconds": round(eval_seconds, 2)},
        "seconds_total": round(time.perf_counter() - t_all, 1),
    }
    io.write_json(a.out, result)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
