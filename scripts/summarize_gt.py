"""Write results/summary/ground_truth.json: rendered frame counts vs a naive renderer's."""

import argparse

import _cli


def main():
    from lightcrafter.io import read_json, write_json
    from lightcrafter.summary import ground_truth_summary

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--gt-root", required=True)
    ap.add_argument("--specs", nargs="+", required=True)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    summary = ground_truth_summary(a.gt_root, [read_json(p) for p in a.specs])
    write_json(a.out, summary)
    print(summary)


if __name__ == "__main__":
    _cli.run(main)
