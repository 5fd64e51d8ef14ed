"""Build results/report/index.html (counts, benchmark curves, evaluation tables)."""

import argparse

import _cli


def main():
    from lightcrafter.report import build_report

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--results", required=True)
    a = ap.parse_args()
    print(build_report(a.results))


if __name__ == "__main__":
    _cli.run(main)
