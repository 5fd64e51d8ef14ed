"""Run every benchmark (each writes results/bench/<name>.json), then build the report.

    make bench            # all of them
    make bench ONLY=cycles_spp,proxy_spp

Benchmarks that need pipeline outputs (proxy_vs_cycles reads results/gt, refiner_clean_buffers
the clean_buffers pairs) first bring the default pipeline up to them via Snakemake.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ORDER = ["cycles_spp", "cycles_device", "proxy_spp", "proxy_vs_cycles", "envfit", "recon_error", "phi_budget", "refiner",
         "refiner_clean_buffers", "dag_scale", "storage"]
# Benchmarks that read the default run's outputs, and the Snakemake target they need.
NEEDS_PIPELINE = {"proxy_vs_cycles": "ground_truth",
                  "refiner_clean_buffers": "results/datasets/clean_buffers/pairs.jsonl",
                  "storage": "pairs", "phi_budget": "all"}


def main() -> int:
    sys.path.insert(0, str(REPO))
    only = [s for s in os.environ.get("ONLY", "").split(",") if s]
    names = [n for n in ORDER if (REPO / "benchmarks" / f"{n}.py").is_file() and (not only or n in only)]
    failed = []
    for name in names:
        if name in NEEDS_PIPELINE:
            subprocess.run([sys.executable, "-m", "snakemake", NEEDS_PIPELINE[name]], cwd=REPO, check=True)
        t0 = time.perf_counter()
        print(f"== benchmark {name}", flush=True)
        res = subprocess.run([sys.executable, str(REPO / "benchmarks" / f"{name}.py")], cwd=REPO)
        print(f"== {name}: exit {res.returncode} after {time.perf_counter() - t0:.0f} s", flush=True)
        if res.returncode:
            failed.append(name)
    from lightcrafter.report import build_report

    print(f"report: {build_report(REPO / 'results')}")
    if failed:
        print(f"failed: {failed}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
