"""The run report: cost/quality curves of every benchmark, ground-truth counts, evaluation tables.

Every benchmark writes ``results/bench/<name>.json`` in one shape (docs/architecture.md):
``{name, varied, metric, higher_is_better, machine, chosen, points: [{setting, seconds, value}]}``.
:func:`plot_bench` draws error (or quality) against run time for any of them and marks the chosen
default; :func:`build_report` collects everything into ``results/report/index.html``.
"""

from __future__ import annotations

import html
import json
from pathlib import Path

from .io import atomic_path, read_json, write_text


def plot_bench(bench: dict, png_path: str | Path) -> None:
    """Metric against seconds (log x), one point per setting, the chosen setting circled."""
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pts = [p for p in bench["points"] if p.get("seconds") is not None and p.get("value") is not None]
    fig, ax = plt.subplots(figsize=(5, 3.4), dpi=110)
    series = {}
    for p in pts:
        series.setdefault(p.get("series", bench["name"]), []).append(p)
    for label, ps in series.items():
        ax.plot([p["seconds"] for p in ps], [p["value"] for p in ps], "o-", label=label)
        for p in ps:
            ax.annotate(str(p["setting"]), (p["seconds"], p["value"]), textcoords="offset points", xytext=(4, 4),
                        fontsize=7)
            if p["setting"] == bench.get("chosen") and p.get("series", label) == bench.get("chosen_series", label):
                ax.plot(p["seconds"], p["value"], "o", ms=13, mfc="none", mec="red")
    if pts and min(p["seconds"] for p in pts) > 0:
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.xaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
    ax.set_xlabel("seconds")
    ax.set_ylabel(bench["metric"])
    for key, value in bench.get("baseline", {}).items():
        if key.endswith(bench["metric"]) and isinstance(value, (int, float)):
            ax.axhline(value, color="grey", ls="--", lw=1, label=key.removesuffix("_" + bench["metric"]))
    ax.set_title(f"{bench['name']}\nvaried: {bench['varied']}; chosen: {bench.get('chosen')}", fontsize=8)
    if len(series) > 1 or bench.get("baseline"):
        ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    with atomic_path(png_path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


def _table(rows: list[dict], keys: list[str]) -> str:
    head = "".join(f"<th>{html.escape(k)}</th>" for k in keys)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(r.get(k, '')))}</td>" for k in keys) + "</tr>" for r in rows)
    return f"<table border=1 cellpadding=3><tr>{head}</tr>{body}</table>"


def build_report(results_dir: str | Path = "results") -> Path:
    """Write ``results/report/index.html`` from whatever the run and the benchmarks produced."""
    results = Path(results_dir)
    out_dir = results / "report"
    parts = ["<html><head><meta charset='utf-8'><title>LightCrafter run report</title></head><body>",
             "<h1>LightCrafter run report</h1>"]
    summary = results / "summary" / "ground_truth.json"
    if summary.is_file():
        s = read_json(summary)
        parts.append("<h2>Ground truth: rendered vs naive frame counts</h2>")
        parts.append(_table([{k: s[k] for k in s if k != "by_motion"}], [k for k in s if k != "by_motion"]))
        parts.append(_table([{"motion": m, **v} for m, v in s["by_motion"].items()],
                            ["motion", "trajectories", "buffer_frames", "rgb_frames"]))
    benches = sorted((results / "bench").glob("*.json"))
    if benches:
        parts.append("<h2>Error against run time</h2>")
    for b in benches:
        bench = read_json(b)
        if not isinstance(bench, dict) or "points" not in bench:
            continue
        png = out_dir / f"{bench['name']}.png"
        plot_bench(bench, png)
        m = bench.get("machine", {})
        parts.append(f"<h3>{html.escape(bench['name'])}</h3><p>varied: {html.escape(str(bench['varied']))}; "
                     f"metric: {html.escape(bench['metric'])} ({'higher' if bench.get('higher_is_better') else 'lower'}"
                     f" is better); chosen: {html.escape(str(bench.get('chosen')))}; machine: {m.get('cores')} cores</p>")
        parts.append(f"<img src='{png.name}'>")
        keys = ["series", "setting", "seconds", "value"] if any("series" in p for p in bench["points"]) else \
            ["setting", "seconds", "value"]
        parts.append(_table(bench["points"], keys))
    evals = sorted((results / "eval").glob("*/metrics.json"))
    if evals:
        parts.append("<h2>Evaluation</h2>")
        for e in evals:
            parts.append(f"<h3>{html.escape(e.parent.name)}</h3><pre>{html.escape(json.dumps(read_json(e), indent=1))}</pre>")
    parts.append("</body></html>")
    index = out_dir / "index.html"
    write_text(index, "\n".join(parts))
    return index
