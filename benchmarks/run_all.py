"""Run every benchmark (each writes results/bench/<name>.json), then build the report.

    make bench            # all of them
    make bench ONLY=cycles_spp,proxy_spp

Benchmarks that need pipeline outputs (proxy_vs_cycles reads results/gt, refiner_clean_buffers
the clean_buffers pairs) first bring the default pipeline up to them via Snakemake. At the end it
lists every benchmark it ran with its exit status and wall seconds (the pipeline catch-up counted
apart) and writes the list to results/bench/run_all.json.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ORDER = ["cycles_spp", "cycles_device", "proxy_spp", "proxy_vs_cycles", "envfit", "envfit_response", "recon_error",
         "sfm_settings", "estimator_weights", "phi_budget", "refiner", "refiner_clean_buffers", "refiner_scale",
         "dag_scale", "storage", "job_threads"]
# Benchmarks make bench does not run, and why (it lists them; tests/test_workflow_dag.py checks that every
# benchmarks/*.py is in ORDER or here).
NOT_IN_BENCH = {
    "proxy_device": "its point is cuda_ad_rgb against llvm_ad_rgb: run by scripts/gpu_check.sh on a GPU node",
    "refiner_step": "the paper preset's step at 5B size needs a >= 120 GB GPU: run by scripts/gpu_check.sh",
    "refiner_small_scale": "several seeds and data sizes on a chosen pairs manifest (hours on 2 cores): run by hand",
    "evaluation_cost": "the metrics' run time, quoted in lightcrafter/evaluation.py: run by hand when a metric changes",
}
# Benchmarks that read the default run's outputs, and the Snakemake target they need.
NEEDS_PIPELINE = {"proxy_vs_cycles": "ground_truth",
                  "refiner_clean_buffers": "results/datasets/clean_buffers/pairs.jsonl",
                  "refiner_scale": "results/datasets/full/pairs.jsonl", "storage": "pairs", "phi_budget": "all",
                  "envfit_response": "all", "job_threads": "all",
                  "sfm_settings": "ground_truth", "estimator_weights": "ground_truth"}


def main() -> int:
    sys.path.insert(0, str(REPO))
    only = [s for s in os.environ.get("ONLY", "").split(",") if s]
    names = [n for n in ORDER if (REPO / "benchmarks" / f"{n}.py").is_file() and (not only or n in only)]
    for n in only:
        if n not in ORDER:
            print(f"ONLY={n}: " + (f"not run by make bench ({NOT_IN_BENCH[n]})" if n in NOT_IN_BENCH
                                   else f"no such benchmark; use one of {', '.join(ORDER)}"), file=sys.stderr)
    failed, ran = [], []
    for name in names:
        t_pipe = 0.0
        if name in NEEDS_PIPELINE:
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "snakemake", NEEDS_PIPELINE[name]], cwd=REPO, check=True)
            t_pipe = time.perf_counter() - t0
        t0 = time.perf_counter()
        print(f"== benchmark {name}", flush=True)
        res = subprocess.run([sys.executable, str(REPO / "benchmarks" / f"{name}.py")], cwd=REPO)
        sec = time.perf_counter() - t0
        print(f"== {name}: exit {res.returncode} after {sec:.0f} s", flush=True)
        ran.append({"benchmark": name, "exit": res.returncode, "seconds": round(sec, 1),
                    "pipeline_target": NEEDS_PIPELINE.get(name), "pipeline_seconds": round(t_pipe, 1)})
        if res.returncode:
            failed.append(name)
    print(f"{'benchmark':24s} {'exit':>4s} {'seconds':>8s} {'pipeline s':>10s}")
    for r in ran:
        print(f"{r['benchmark']:24s} {r['exit']:4d} {r['seconds']:8.0f} {r['pipeline_seconds']:10.0f}")
    for name, why in NOT_IN_BENCH.items():
        print(f"{name:24s} not run: {why}")
    from lightcrafter.io import write_json

    write_json(REPO / "results" / "bench" / "run_all.json",
               {"benchmarks": ran, "not_run": NOT_IN_BENCH, "cores": os.cpu_count()})
    from lightcrafter.report import build_report

    print(f"report: {build_report(REPO / 'results')}")
    if failed:
        print(f"failed: {failed}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
