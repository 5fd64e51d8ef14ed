"""Error-against-run-time plots of the benchmark JSONs (one shape, see lightcrafter.report)."""

from __future__ import annotations

from pathlib import Path

from ..io import atomic_path


# ----------------------------------------------------------------------------- plots
def plot_bench(bench: dict, png_path: str | Path) -> None:
    """Metric against seconds (log x), one line per series, the chosen setting circled in red."""
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pts = [p for p in bench["points"] if p.get("seconds") is not None and p.get("value") is not None]
    fig, ax = plt.subplots(figsize=(5.4, 3.6), dpi=110)
    series: dict[str, list] = {}
    for p in pts:
        series.setdefault(str(p.get("series", bench["name"])), []).append(p)
    for label, ps in series.items():
        ax.plot([p["seconds"] for p in ps], [p["value"] for p in ps], "o-", label=label, ms=4)
        for p in ps:
            ax.annotate(str(p["setting"]), (p["seconds"], p["value"]), textcoords="offset points", xytext=(3, 3),
                        fontsize=6)
            chosen_series = bench.get("chosen_series", label)
            if str(p["setting"]) == str(bench.get("chosen")) and str(p.get("series", label)) == str(chosen_series):
                ax.plot(p["seconds"], p["value"], "o", ms=13, mfc="none", mec="red")
    if pts and min(p["seconds"] for p in pts) > 0:
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.xaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
    ax.set_xlabel("seconds")
    ax.set_ylabel(bench["metric"])
    for key, value in (bench.get("baseline") or {}).items():
        if isinstance(value, (int, float)):
            ax.axhline(value, color="grey", ls="--", lw=1, label=key)
    ax.set_title(f"{bench['name']} (varied: {bench['varied']})\nchosen: {bench.get('chosen')} (red circle)", fontsize=8)
    if len(series) > 1 or bench.get("baseline"):
        ax.legend(fontsize=6)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    with atomic_path(png_path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
