#!/usr/bin/env python
"""Write results/datasets/{variant}/pairs.jsonl. Thin entry point over lightcrafter.datasets.

  build_dataset.py --variant clean_buffers --plans-json '{"s0000": {...}}' --output PAIRS
  (--plans-json @file.json reads the plans from a file)
"""

import argparse
import json
import sys
from pathlib import Path

import _cli  # noqa: F401  (puts the repository on sys.path)

from lightcrafter.datasets import build_clean_buffers_records
from lightcrafter.io import DataError, write_jsonl

BUILDERS = {"clean_buffers": build_clean_buffers_records}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--variant", required=True, choices=sorted(BUILDERS))
    ap.add_argument("--out-root", default=None,
                    help="workflow output folder holding gt/ and proxy_gt/ (default: OUTPUT/../../..)")
    ap.add_argument("--plans-json", required=True, help="JSON {scene_id: scene_plan} or @path")
    ap.add_argument("--output", required=True)
    a = ap.parse_args()
    out_root = a.out_root or Path(a.output).parents[2].as_posix()  # {out}/datasets/{variant}/pairs.jsonl
    text = Path(a.plans_json[1:]).read_text() if a.plans_json.startswith("@") else a.plans_json
    try:
        records = BUILDERS[a.variant](out_root, json.loads(text))
    except DataError as exc:
        print(f"build_dataset: {exc}", file=sys.stderr)
        return 1
    write_jsonl(a.output, records)
    splits = {s: sum(r["split"] == s for r in records) for s in ("train", "test")}
    print(f"build_dataset: {a.variant}: {len(records)} pairs {splits} -> {a.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
