"""Speed ratios and timings measured by interleaved repeats (A, B, A, B, ...), summarised in one shape.

A ratio of two timings taken minutes apart on a shared machine mixes the machine's drift into it; the
benchmarks (``benchmarks/*.py``) time the arms in alternation and report each figure as the median over
repeats with its range: ``{"median", "min", "max", "n"}`` (:func:`median_range`).
"""

from __future__ import annotations

import statistics


def median_range(values, digits: int = 3) -> dict | None:
    """``{"median", "min", "max", "n"}`` of the values that are not None, rounded to ``digits``; None when there
    are none."""
    v = [float(x) for x in values if x is not None]
    if not v:
        return None
    return {"median": round(statistics.median(v), digits), "min": round(min(v), digits),
            "max": round(max(v), digits), "n": len(v)}


def ratio_median_range(first, second, digits: int = 3) -> dict | None:
    """:func:`median_range` of first[i] / second[i] over interleaved pairs (the same repeat of each arm)."""
    if len(first) != len(second):
        raise ValueError(f"ratio of {len(first)} and {len(second)} timings: the arms must be paired")
    return median_range([a / b for a, b in zip(first, second)], digits)
