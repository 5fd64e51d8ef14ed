#!/usr/bin/env python
"""Write a G-buffer estimator weights file that averages chosen networks, to try an ensemble before shipping it.

  estimator_ensemble.py --out ../mine.pt shipped:0 shipped:1 ../estimator_run/results/recon/estimator/model.pt

A member is ``shipped`` (every member of the shipped file), ``shipped:N`` (the shipped file's member N, from 0, in
the order of ``members`` in lightcrafter/recon/weights/gbuffer_estimator.json) or a weights file (a network the
``train_gbuffer_estimator`` rule wrote, or an ensemble file: each of its members). The output is what
:func:`lightcrafter.recon.estimator.save_ensemble` writes; point ``recon.estimator.weights`` at it, e.g. in a
config for ``benchmarks/phi_budget.py --config`` or as ``benchmarks/estimator_weights.py --weights mine=PATH``
(docs/phi.md, "A fourth and a fifth member"). The shipped weights are not touched: ``scripts/ship_estimator.py
--add-member`` ships a member with its provenance.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import _cli

from lightcrafter.io import DataError


def member_states(spec: str) -> list[dict]:
    """The saved networks (dicts with ``state`` and ``config``) one member spec names; a bad spec, a missing or
    unreadable file, or a shipped index out of range is a DataError of one line."""
    from lightcrafter.recon import estimator as est
    from lightcrafter.recon.weights import SHIPPED_WEIGHTS

    name, sep, index = spec.partition(":")
    path = SHIPPED_WEIGHTS if name == "shipped" else Path(spec)
    states = est.saved_members(path)  # one line for a missing, corrupt or mismatched file
    if name != "shipped" or not sep:
        return states
    if not index.isdigit() or int(index) >= len(states):
        raise DataError(f"member {spec!r}: the shipped file {path} has {len(states)} member(s), numbered 0 to "
                        f"{len(states) - 1}; name one of them as shipped:N")
    return [states[int(index)]]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True, help="the ensemble weights file to write")
    ap.add_argument("members", nargs="+", help="shipped | shipped:N | a weights file")
    a = ap.parse_args(argv)
    from lightcrafter.recon import estimator as est

    states = [s for spec in a.members for s in member_states(spec)]
    a.out.parent.mkdir(parents=True, exist_ok=True)
    est.save_ensemble(states, a.out)
    n = len(est.load(a.out).members)
    print(f"wrote {a.out}: {n} member(s) from {' '.join(a.members)}; use it with recon.estimator.weights: {a.out}")
    return 0


if __name__ == "__main__":
    _cli.run(main, "estimator_ensemble")
