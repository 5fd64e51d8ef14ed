"""Labels, orderings of rows and columns, the page style and small HTML helpers of the report."""

from __future__ import annotations

import html

from ..datasets import BENCHMARKS, ONE_FRAME_BENCHMARKS, VARIANTS
from ..evaluation import METRICS as EV_METRICS


# Label and direction of every metric: the registry (lightcrafter.evaluation.METRICS).
METRIC_LABELS = {n: (m.label, m.higher_is_better) for n, m in EV_METRICS.items()}


# Metrics without a better direction (coding artifacts): judged against the target's own value.
ARTIFACT_METRICS = tuple(n for n, m in EV_METRICS.items() if m.higher_is_better is None)


# Table columns per held-out benchmark, from the registries (lightcrafter.datasets.BENCHMARKS,
# lightcrafter.evaluation.METRICS): every metric with a better direction (the coding-artifact metrics have their own
# section), but a temporal one on a one-frame benchmark; a benchmark without results (e.g. mit without mit.root) has
# no columns.
TABLE_METRICS = {b: tuple(n for n, m in EV_METRICS.items() if m.higher_is_better is not None
                          and not (m.temporal and b in ONE_FRAME_BENCHMARKS)) for b in BENCHMARKS}


TABLE_BENCHMARKS = tuple(BENCHMARKS)


METHOD_LABELS = {"proxy": "PBR proxy (Phi buffers)", "oracle_proxy": "PBR proxy (ground-truth buffers)",
                 "refined": "Refined (LightCrafter)", "regressor": "One-step regressor (same network)",
                 "affine_colour": "Affine colour fit of the proxy"}


# Row labels and order of Table 2: the dataset-variant registry (lightcrafter.datasets.VARIANTS).
VARIANT_LABELS = {name: v.label or name for name, v in VARIANTS.items()}


CSS = """body{font-family:system-ui,sans-serif;margin:2em auto;max-width:1250px;color:#222;line-height:1.4}
h1{margin-bottom:0}h2{border-bottom:2px solid #ddd;padding-bottom:.2em;margin-top:2em}
table{border-collapse:collapse;margin:.6em 0;font-size:.92em}td,th{border:1px solid #ccc;padding:.25em .6em;text-align:right}
th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}.ci{color:#777;font-size:.8em}
.best{font-weight:bold;background:#e8f5e9}.nc{color:#a33}.note{color:#555;font-size:.9em}
.grid{display:flex;flex-wrap:wrap;gap:14px}.card{border:1px solid #ddd;padding:8px;border-radius:6px}
img.strip{max-width:100%;image-rendering:pixelated}video{max-width:100%;image-rendering:pixelated}
nav a{margin-right:1em}code{background:#f5f5f5;padding:0 .2em}"""


# ----------------------------------------------------------------------------- html helpers
def _esc(x) -> str:
    return html.escape(str(x))


def _table(rows: list[dict], keys: list[str], labels: dict | None = None) -> str:
    labels = labels or {}
    head = "".join(f"<th>{_esc(labels.get(k, k))}</th>" for k in keys)
    body = "".join("<tr>" + "".join(f"<td>{_fmt(r.get(k, ''))}</td>" for k in keys) + "</tr>" for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _fmt(v) -> str:
    if v is None:  # no value (e.g. no limit configured): an empty cell, as for a missing key
        return ""
    if isinstance(v, float):
        return f"{v:.4g}" if abs(v) < 1e4 else f"{v:.3e}"
    if isinstance(v, (list, tuple)):
        return _esc(", ".join(map(str, v)))
    return _esc(v)


def _not_computed(what: str, why: str) -> str:
    return f"<p class='nc'>{_esc(what)}: not computed &mdash; {_esc(why)}</p>"
