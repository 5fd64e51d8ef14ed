#!/usr/bin/env python
"""Align(S~, S_gt): write the reconstruction of a synthetic clip in the ground-truth world frame.

  align_clip.py --est results/recon/synthetic/s0000_t0 --gt results/gt/s0000/t0 --out results/aligned/s0000/t0

A skipped reconstruction gives a skipped aligned clip.
"""

import argparse

import _cli  # puts the repository on sys.path; run() is the one error path

from lightcrafter import io


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--est", required=True)
    ap.add_argument("--gt", required=True)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    from lightcrafter.clip import is_skipped, write_skipped
    from lightcrafter.recon.align import align_clip

    reason = is_skipped(a.est)
    if reason:
        write_skipped(a.out, reason)
        print(f"align_clip: {a.est} was skipped; left out")
        return 0
    m = align_clip(a.est, a.gt, a.out)
    print(f"align_clip: scale {m['align']['scale']:.4f}, depth scale {m['align']['depth_scale']:.4f} -> {a.out}")
    return 0


if __name__ == "__main__":
    _cli.run(main, "align_clip", (io.DataError,))
