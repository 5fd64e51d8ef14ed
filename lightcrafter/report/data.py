"""Reading the run's evaluation results for the report."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..datasets import VARIANTS
from ..io import read_json


def _bench_keys(evals):
    return {(b, v) for (v, b) in evals}


def load_evals(results: Path) -> dict[tuple[str, str], dict]:
    out = {}
    for f in sorted(results.glob("eval/*/*/metrics.json")):
        try:
            out[(f.parent.parent.name, f.parent.name)] = read_json(f)
        except Exception:  # noqa: BLE001 - a broken file shows as missing, the report still builds
            continue
    return out


def _not_computed_metrics(evals: dict) -> dict[str, str]:
    """metric -> why it was not computed, over every evaluation."""
    return {k: why for e in evals.values() for k, why in (e.get("not_computed") or {}).items()}


# ----------------------------------------------------------------------------- report
def _variants(evals: dict) -> list[str]:
    return [v for v in VARIANTS if any(k[0] == v for k in evals)]


def _first_variant(evals: dict) -> str | None:
    return next(iter(_variants(evals)), None)


def _per_clip(evals: dict, variant: str, bench: str, method: str, metric: str) -> dict[str, float]:
    e = evals.get((variant, bench)) or {}
    out = {}
    for p in e.get("pairs") or []:
        v = p[method].get(metric) if isinstance(p.get(method), dict) else None
        if p.get("pair_id") is not None and v is not None and np.isfinite(v):
            out[str(p["pair_id"])] = float(v)
    return out
