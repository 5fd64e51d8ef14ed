"""Cost of building the job graph at paper scale: dry-run seconds and peak memory against scene count.

For each scene count N, runs in a fresh empty working directory

    snakemake -n --configfile config/paper.yaml <N scenes> --quiet rules -d <empty dir>

(the paper config with ``scenes.count`` set to N through a small extra config file; the default
target, i.e. the whole pipeline; the paper config's data folders are stand-ins in their real layouts,
tests/paper_site.py, since the workflow checks them at start-up) and records the wall seconds of the Snakemake process, its peak
resident memory (``ru_maxrss`` from wait4 on that process, MB = 1e6 bytes), its CPU seconds and
the planned job count. Writes

    results/bench/dag_scale.json   (shape of docs/architecture.md; metric peak_rss_mb, lower is better)

``chosen`` is the paper's own scene count (config/paper.yaml). The head node that runs Snakemake
for a SLURM run must hold this graph in memory for the whole run; the JSON shows how that grows.

    .venv/bin/python benchmarks/dag_scale.py                      # 50/100/200/400 scenes
    .venv/bin/python benchmarks/dag_scale.py --scenes 50 100 --repeats 2
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))

from lightcrafter import io  # noqa: E402
from lightcrafter.config import raw_config, validate  # noqa: E402
from paper_site import make_site  # noqa: E402
from workflow_util import job_counts  # noqa: E402


def dry_run(scenes: int, configfile: Path) -> dict:
    """One dry run of the default target with ``scenes`` scenes: seconds, peak RSS MB, job counts."""
    with tempfile.TemporaryDirectory(prefix="lc_dag_") as tmp:
        extra = Path(tmp) / "scenes.yaml"
        extra.write_text(yaml.safe_dump({"scenes": {"count": scenes}}))
        workdir = Path(tmp) / "work"
        workdir.mkdir()
        cmd = [sys.executable, "-m", "snakemake", "-n", "--configfile", str(configfile), str(extra),
               "--quiet", "rules", "-d", str(workdir)]
        env = dict(os.environ, PATH=str(Path(sys.executable).parent) + os.pathsep + os.environ.get("PATH", ""))
        out_path = Path(tmp) / "out.txt"
        with open(out_path, "w") as out:
            t0 = time.perf_counter()
            proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=out, stderr=subprocess.STDOUT)
            _, status, usage = os.wait4(proc.pid, 0)
            seconds = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)
        text = out_path.read_text()
        if proc.returncode != 0:
            raise SystemExit(f"dry run with {scenes} scenes failed ({proc.returncode}):\n{text[-3000:]}")
    counts = job_counts(text)
    return {"seconds": seconds, "cpu_seconds": usage.ru_utime + usage.ru_stime,
            "peak_rss_mb": usage.ru_maxrss * 1024 / 1e6, "jobs": sum(counts.values()), "counts": counts}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", type=int, nargs="+", default=[50, 100, 200, 400])
    ap.add_argument("--repeats", type=int, default=1, help="runs per setting; the fastest is kept (machine noise)")
    ap.add_argument("--configfile", type=Path, default=REPO / "config" / "paper.yaml")
    ap.add_argument("--out", type=Path, default=REPO / "results" / "bench" / "dag_scale.json")
    args = ap.parse_args(argv)

    paper_scenes = validate(raw_config([args.configfile]))["scenes"]["count"]
    site_dir = tempfile.TemporaryDirectory(prefix="lc_site_")
    configfile = args.configfile
    if args.configfile.resolve() == (REPO / "config" / "paper.yaml").resolve():
        configfile = Path(make_site(Path(site_dir.name))["site"])
    points = []
    for n in args.scenes:
        runs = [dry_run(n, configfile) for _ in range(args.repeats)]
        best = min(runs, key=lambda r: r["seconds"])
        points.append({"setting": n, "seconds": round(best["seconds"], 2), "value": round(best["peak_rss_mb"], 1),
                       "jobs": best["jobs"], "cpu_seconds": round(best["cpu_seconds"], 2),
                       "all_seconds": [round(r["seconds"], 2) for r in runs],
                       "counts": best["counts"]})
        print(f"{n:5d} scenes: {best['jobs']:6d} jobs, {best['seconds']:6.1f} s wall, {best['cpu_seconds']:6.1f} s CPU, "
              f"peak RSS {best['peak_rss_mb']:7.1f} MB",
              flush=True)
    try:
        load = os.getloadavg()
    except OSError:
        load = None
    result = {
        "name": "dag_scale",
        "varied": "scenes",
        "metric": "peak_rss_mb",
        "higher_is_better": False,
        "machine": {"cores": os.cpu_count(), "platform": platform.platform(), "load_avg_at_end": load},
        "chosen": paper_scenes,
        "points": points,
        "command": "snakemake -n --configfile <config> <scenes.count=N> --quiet rules -d <empty dir>",
        "configfile": str(args.configfile.relative_to(REPO) if args.configfile.is_relative_to(REPO) else args.configfile),
        "seconds_are": "wall seconds of the Snakemake process (parse, DAG build, dry-run report); fastest of repeats; "
                       "cpu_seconds: its user + system CPU time (less sensitive to other load on the machine)",
        "value_is": "peak resident set size of the Snakemake process, MB (1e6 bytes), from wait4 ru_maxrss",
    }
    io.write_json(args.out, result)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
