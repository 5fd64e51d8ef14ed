"""Build results/report/index.html: the paper's tables, clips, reconstruction errors, leave-out counts,
per-stage run time (and the projected cost of a larger config), benchmark curves, long-form, edits.

  build_report.py --results results [--logs logs] [--config-json '{...}' --project config/paper.yaml]
"""

import argparse
import json

import _cli


def main():
    from lightcrafter.report import build_report, stage_costs

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", required=True)
    ap.add_argument("--logs", default=None, help="Snakemake log folder with benchmark/ (default: RESULTS/../logs)")
    ap.add_argument("--config-json", default=None, help="this run's config (for the cost projection)")
    ap.add_argument("--project", default=None, help="config YAML whose CPU cost to project (e.g. config/paper.yaml)")
    a = ap.parse_args()
    projection = None
    if a.config_json and a.project:
        from pathlib import Path

        import yaml

        from lightcrafter.costs import project

        logs = Path(a.logs) if a.logs else Path(a.results).parent / "logs"
        projection = project(stage_costs(logs), json.loads(a.config_json), yaml.safe_load(Path(a.project).read_text()))
    print(build_report(a.results, a.logs, projection))


if __name__ == "__main__":
    _cli.run(main)
