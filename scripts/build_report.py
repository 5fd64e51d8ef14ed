"""Build results/report/index.html: the paper's tables, clips, reconstruction errors, leave-out counts,
per-stage run time (and the projected cost of a larger config), benchmark curves, long-form, edits.

  build_report.py --results results [--logs logs] [--config-json @run.json --project @paper.json]
"""

import argparse

import _cli


def main():
    from lightcrafter.report import build_report, stage_costs

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", required=True)
    ap.add_argument("--logs", default=None, help="Snakemake log folder with benchmark/ (default: RESULTS/../logs)")
    ap.add_argument("--config-json", default=None, help="this run's config, JSON or @file (for the cost projection)")
    ap.add_argument("--project", default=None, help="the effective config whose CPU cost to project, JSON or @file "
                    "(the workflow passes config/paper.yaml's), or a config YAML file")
    a = ap.parse_args()
    projection = None
    if a.config_json and a.project:
        from pathlib import Path

        from lightcrafter.config import raw_config, validate
        from lightcrafter.costs import project

        target = (validate(raw_config([a.project]), a.project) if a.project.endswith((".yaml", ".yml"))
                  else _cli.json_arg(a.project))
        logs = Path(a.logs) if a.logs else Path(a.results).parent / "logs"
        projection = project(stage_costs(logs), _cli.json_arg(a.config_json), target)
    print(build_report(a.results, a.logs, projection))


if __name__ == "__main__":
    _cli.run(main)
