#!/usr/bin/env python
"""Write a pair manifest: a variant's training set or a held-out benchmark (thin entry point over
lightcrafter.datasets).

  build_dataset.py --variant no_real --specs @specs.json --output PAIRS        (what the workflow runs)
  build_dataset.py --variant no_real --plans-json '{"s0000": {...}}' --real-json '{}' --output PAIRS
  build_dataset.py --benchmark synthetic --plans-json @plans.json --real-json @real.json --output PAIRS

Writes PAIRS (pairs.jsonl) and summary.json beside it (pair counts by kind, pairs left out because
their clip could not be reconstructed, with the reason). ``--specs`` gives the pair specs themselves
(lightcrafter.datasets.variant_specs / benchmark_specs, computed by the workflow: a job carries only the
clips it reads); ``@file`` reads JSON from a file. The
output root (e.g. results) is taken from PAIRS (its part before datasets/ or benchmarks/).
"""

import argparse
import sys
from pathlib import Path

import _cli  # puts the repository on sys.path; run() is the one error path

from lightcrafter import datasets
from lightcrafter.io import DataError, write_json, write_jsonl
from lightcrafter.layout import Layout, root_of


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    what = ap.add_mutually_exclusive_group(required=True)
    what.add_argument("--variant", choices=sorted(datasets.VARIANTS))
    what.add_argument("--benchmark", choices=datasets.BENCHMARKS)
    ap.add_argument("--specs", default=None, help="JSON or @path: the pair specs (instead of plans and clips)")
    ap.add_argument("--plans-json", default="{}", help="JSON {scene_id: scene_plan} or @path")
    ap.add_argument("--real-json", default="{}", help="JSON {clip_id: {split, video, ...}} or @path")
    ap.add_argument("--mit-json", default="{}", help="JSON {pair_id: {...}} of the MIT benchmark or @path")
    ap.add_argument("--output", required=True)
    a = ap.parse_args()
    out = Path(a.output)
    layout = Layout(root_of(out, "datasets" if a.variant else "benchmarks").as_posix())
    if a.specs is not None:
        specs = _cli.json_arg(a.specs)
    elif a.variant:
        specs = datasets.variant_specs(a.variant, layout, _cli.json_arg(a.plans_json), _cli.json_arg(a.real_json))
    else:
        specs = datasets.benchmark_specs(a.benchmark, layout, _cli.json_arg(a.plans_json),
                                         _cli.json_arg(a.real_json), _cli.json_arg(a.mit_json))
    records, summary = datasets.build_records(specs, ".", a.variant)
    if not records:
        print(f"build_dataset: {a.variant or a.benchmark}: no pairs (all {len(summary['skipped'])} left out or none "
              "configured); check results/*/summary.json and the config's splits", file=sys.stderr)
        return 1
    write_json(out.parent / "summary.json", {"name": a.variant or a.benchmark, **summary})
    write_jsonl(out, records)
    print(f"build_dataset: {a.variant or a.benchmark}: {len(records)} pairs {summary['by_kind']}, "
          f"{len(summary['skipped'])} left out -> {out}")
    return 0


if __name__ == "__main__":
    _cli.run(main, "build_dataset", (DataError,))
