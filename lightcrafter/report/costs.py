"""Stage costs from the rules' benchmark files (logs/benchmark)."""

from __future__ import annotations

import csv
from pathlib import Path


# ----------------------------------------------------------------------------- run time
# Benchmark folders that hold several rules' files: (folder, file-name prefix) -> rule (first match wins).
_SHARED_BENCHMARK_FOLDERS = [
    ("recon", "synthetic_", "reconstruct_synthetic"), ("recon", "align_", "align_synthetic"),
    ("recon", "real_", "reconstruct_real"), ("recon", "train_gbuffer_estimator", "train_gbuffer_estimator"),
    ("recon", "summarize_", "summarize_reconstruction"),
    ("refiner", "train_", "train_refiner"), ("refiner", "infer_", "infer_refiner"),
    ("refiner", "evaluate_", "evaluate_refiner"),
    ("envfit", "mit_", "relight_mit"), ("envfit", "", "fit_envmap"), ("ingest", "", "ingest_video"),
]


def _rule_of_benchmark(rel: Path) -> str:
    if len(rel.parts) == 1:
        return rel.stem
    folder, name = rel.parts[0], rel.name
    for f, prefix, rule in _SHARED_BENCHMARK_FOLDERS:
        if f == folder and name.startswith(prefix):
            return rule
    return folder


def stage_costs(logs: Path) -> list[dict]:
    """Per rule: jobs, wall seconds, CPU seconds (Snakemake benchmark TSVs: s, cpu_time columns)."""
    rules: dict[str, dict] = {}
    for f in sorted(logs.glob("benchmark/**/*.tsv")):
        rule = _rule_of_benchmark(f.relative_to(logs / "benchmark"))
        try:
            rows = list(csv.DictReader(f.open(), delimiter="\t"))
        except OSError:
            continue
        if not rows:
            continue
        r = rows[-1]
        d = rules.setdefault(rule, {"stage": rule, "jobs": 0, "wall_s": 0.0, "cpu_s": 0.0})
        d["jobs"] += 1
        d["wall_s"] += float(r.get("s") or 0)
        d["cpu_s"] += float(r.get("cpu_time") or 0)
    for d in rules.values():
        d["core_hours"] = d["cpu_s"] / 3600
        d["wall_s"] = round(d["wall_s"], 1)
        d["cpu_s"] = round(d["cpu_s"], 1)
    return sorted(rules.values(), key=lambda d: -d["cpu_s"])
