"""The run report (results/report/index.html): the paper's tables on the configured data, pictures and
videos of every test clip, and what each stage cost and left out.

Sections (each shows "not computed" with the reason when its inputs are missing):

1. Table 1 (methods) and Table 2 (ablations) from results/eval/{variant}/{bench}/metrics.json, per-column
   best in bold, 95 % bootstrap intervals over clips;
2. test clips: side-by-side videos (source | proxy | refined | target) and frame strips;
3. reconstruction: Phi's errors per motion config, registration, skipped clips;
4. leave-out counts per stage (ground truth, Phi, R, datasets);
5. run time: wall seconds and CPU core-hours per rule from the rules' benchmark files (logs/benchmark),
   and the projected CPU core-hours of config/paper.yaml;
6. error against run time: every benchmark JSON (results/bench/*.json, docs/architecture.md shape) and
   the estimator's training curve, plotted with the chosen setting marked;
7. long-form relighting and scene edits, when their outputs exist; stability-test results from the
   last test run's JUnit file (results/tests/junit.xml).

Every benchmark writes ``results/bench/<name>.json`` in one shape:
``{name, varied, metric, higher_is_better, machine, chosen, points: [{setting, seconds, value[, series]}]}``.
:func:`plot_bench` draws the metric against seconds for any of them.
"""

from __future__ import annotations

import csv
import html
import json
from pathlib import Path

import numpy as np

from .io import atomic_path, read_json, write_json, write_text
from .datasets import BENCHMARKS, VARIANTS
from .evaluation import METRICS as EV_METRICS

# Label and direction of every metric: the registry (lightcrafter.evaluation.METRICS).
METRIC_LABELS = {n: (m.label, m.higher_is_better) for n, m in EV_METRICS.items()}
# Metrics without a better direction (coding artifacts): judged against the target's own value.
ARTIFACT_METRICS = tuple(n for n, m in EV_METRICS.items() if m.higher_is_better is None)
# Table columns per held-out benchmark; the tables iterate the registry (lightcrafter.datasets.BENCHMARKS), and a
# benchmark without results (e.g. mit without mit.root) has no columns.
TABLE_METRICS = {"synthetic": ("psnr_db", "ssim", "lpips", "t_clip", "warp_ssim"), "real": ("psnr_db", "ssim", "lpips"),
                 "mit": ("psnr_db", "ssim", "lpips")}
TABLE_BENCHMARKS = tuple(b for b in BENCHMARKS if b in TABLE_METRICS)
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


# ----------------------------------------------------------------------------- html helpers
def _esc(x) -> str:
    return html.escape(str(x))


def _table(rows: list[dict], keys: list[str], labels: dict | None = None) -> str:
    labels = labels or {}
    head = "".join(f"<th>{_esc(labels.get(k, k))}</th>" for k in keys)
    body = "".join("<tr>" + "".join(f"<td>{_fmt(r.get(k, ''))}</td>" for k in keys) + "</tr>" for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}" if abs(v) < 1e4 else f"{v:.3e}"
    if isinstance(v, (list, tuple)):
        return _esc(", ".join(map(str, v)))
    return _esc(v)


def _not_computed(what: str, why: str) -> str:
    return f"<p class='nc'>{_esc(what)}: not computed &mdash; {_esc(why)}</p>"


# ----------------------------------------------------------------------------- tables
def _cell(mean: dict, ci: dict, method: str, metric: str):
    """(mean, interval text) of one method and metric; the interval is a bootstrap_ci record (or a
    [low, high] pair); "n < 6" stands where there were too few clips for one."""
    v = (mean.get(method) or {}).get(metric)
    c = (ci.get(method) or {}).get(metric)
    if isinstance(c, dict):
        from .evaluation import MIN_CLIPS_FOR_INTERVAL

        c = "too few" if c.get("too_few") else (c.get("low"), c.get("high"))
        if c == "too few":
            return v, f"n < {MIN_CLIPS_FOR_INTERVAL}"
    if c and None not in c:
        return v, f"[{c[0]:.3g}, {c[1]:.3g}]"
    return v, ""


def _table_grid(evals: dict[str, dict], rows: list[tuple[str, str, str]], benches=TABLE_BENCHMARKS):
    """The cells of one table: columns (bench, metric), values[(label, bench, metric)] = (mean, ci), best per column."""
    cols = [(b, m) for b in benches for m in TABLE_METRICS[b] if b in {k[0] for k in _bench_keys(evals)}]
    values = {}
    for label, variant, method in rows:
        for b, m in cols:
            e = evals.get((variant, b))
            values[(label, b, m)] = (None, None) if e is None else _cell(e.get("mean", {}), e.get("ci", {}), method, m)
    best = {}
    for b, m in cols:
        higher = METRIC_LABELS[m][1]
        vals = [values[(lbl, b, m)][0] for lbl, _, _ in rows if values[(lbl, b, m)][0] is not None]
        if vals:
            best[(b, m)] = max(vals) if higher else min(vals)
    return cols, values, best


def _is_best(best: dict, b: str, m: str, v: float) -> bool:
    return best.get((b, m)) is not None and bool(np.isclose(v, best[(b, m)]))


def metrics_table(evals: dict[str, dict], rows: list[tuple[str, str, str]], benches=TABLE_BENCHMARKS) -> str:
    """One table: rows (label, variant, method); columns per benchmark and metric; best per column bold."""
    cols, values, best = _table_grid(evals, rows, benches)
    if not cols:
        return _not_computed("table", "no evaluation results")
    head1 = "<tr><th rowspan=2>method</th>" + "".join(
        f"<th colspan={sum(1 for c in cols if c[0] == b)}>{_esc(b)}</th>" for b in dict.fromkeys(c[0] for c in cols)) + "</tr>"
    head2 = "<tr>" + "".join(f"<th>{METRIC_LABELS[m][0]} {'&uarr;' if METRIC_LABELS[m][1] else '&darr;'}</th>"
                             for _, m in cols) + "</tr>"
    body = ""
    for label, _, _ in rows:
        body += f"<tr><td>{_esc(label)}</td>"
        for b, m in cols:
            v, c = values[(label, b, m)]
            if v is None:
                body += "<td class='nc'>&ndash;</td>"
                continue
            cls = " class='best'" if _is_best(best, b, m, v) else ""
            ci = f"<br><span class='ci'>{_esc(c)}</span>" if c else ""
            body += f"<td{cls}>{v:.4g}{ci}</td>"
        body += "</tr>"
    return f"<table>{head1}{head2}{body}</table>"


def metrics_table_markdown(evals: dict[str, dict], rows: list[tuple[str, str, str]],
                           benches=TABLE_BENCHMARKS) -> str:
    """The same table as :func:`metrics_table` in Markdown (best per column in bold, interval in brackets)."""
    cols, values, best = _table_grid(evals, rows, benches)
    if not cols:
        return "_not computed: no evaluation results_\n"
    arrows = {True: "↑", False: "↓"}
    head = "| method | " + " | ".join(f"{b} {METRIC_LABELS[m][0]} {arrows[METRIC_LABELS[m][1]]}" for b, m in cols) + " |"
    lines = [head, "| --- |" + " ---: |" * len(cols)]
    for label, _, _ in rows:
        cells = []
        for b, m in cols:
            v, c = values[(label, b, m)]
            if v is None:
                cells.append("–")
                continue
            txt = f"**{v:.4g}**" if _is_best(best, b, m, v) else f"{v:.4g}"
            cells.append(txt + (f" {c}" if c else ""))
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


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


def not_computed_notes(evals: dict) -> str:
    notes = _not_computed_metrics(evals)
    if not notes:
        return ""
    return "".join(f"<p class='note'>{_esc(METRIC_LABELS.get(k, (k,))[0])}: not computed &mdash; {_esc(w)}</p>"
                   for k, w in sorted(notes.items()))


def artifacts_section(evals: dict) -> str:
    """Blockiness and 4-frame jump of every method next to the target's own (1 = no grid / no jump), for
    the first variant on each held-out benchmark."""
    v0 = _first_variant(evals)
    rows = []
    for (v, b), e in sorted(evals.items()):
        if v != v0:
            continue
        mean = e.get("mean", {})
        for m in [*e.get("methods", []), "target"]:
            vals = {k: (mean.get(m) or {}).get(k) for k in ARTIFACT_METRICS}
            if any(x is not None for x in vals.values()):
                rows.append({"benchmark": b, "method": METHOD_LABELS.get(m, m), **vals})
    if not rows:
        return _not_computed("Coding artifacts", "no blockiness / jump values in the evaluations")
    return ("<h3>Coding artifacts (no reference; 1 = none)</h3><p class='note'>Blockiness: luma gradient across "
            "the 8 / 16 px grid lines over elsewhere; 4-frame jump: frame change across the autoencoder's 4-frame "
            f"blocks over elsewhere. Variant <code>{_esc(v0)}</code>; compare each method with the target.</p>"
            + _table(rows, ["benchmark", "method", *ARTIFACT_METRICS],
                     {k: METRIC_LABELS[k][0] for k in ARTIFACT_METRICS}))


# ----------------------------------------------------------------------------- run time
# Benchmark folders that hold several rules' files: (folder, file-name prefix) -> rule (first match wins).
_SHARED_BENCHMARK_FOLDERS = [
    ("recon", "synthetic_", "reconstruct_synthetic"), ("recon", "align_", "align_synthetic"),
    ("recon", "real_", "reconstruct_real"), ("recon", "train_gbuffer_estimator", "train_gbuffer_estimator"),
    ("recon", "summarize_", "summarize_reconstruction"),
    ("refiner", "train_", "train_refiner"), ("refiner", "infer_", "infer_refiner"),
    ("refiner", "evaluate_", "evaluate_refiner"),
    ("envfit", "mit_", "relight_mit"), ("envfit", "", "fit_envmap"), ("ingest", "", "ingest_video"),
]


def _rule_of_benchmark(rel: Path) -> str:
    if len(rel.parts) == 1:
        return rel.stem
    folder, name = rel.parts[0], rel.name
    for f, prefix, rule in _SHARED_BENCHMARK_FOLDERS:
        if f == folder and name.startswith(prefix):
            return rule
    return folder


def stage_costs(logs: Path) -> list[dict]:
    """Per rule: jobs, wall seconds, CPU seconds (Snakemake benchmark TSVs: s, cpu_time columns)."""
    rules: dict[str, dict] = {}
    for f in sorted(logs.glob("benchmark/**/*.tsv")):
        rule = _rule_of_benchmark(f.relative_to(logs / "benchmark"))
        try:
            rows = list(csv.DictReader(f.open(), delimiter="\t"))
        except OSError:
            continue
        if not rows:
            continue
        r = rows[-1]
        d = rules.setdefault(rule, {"stage": rule, "jobs": 0, "wall_s": 0.0, "cpu_s": 0.0})
        d["jobs"] += 1
        d["wall_s"] += float(r.get("s") or 0)
        d["cpu_s"] += float(r.get("cpu_time") or 0)
    for d in rules.values():
        d["core_hours"] = d["cpu_s"] / 3600
        d["wall_s"] = round(d["wall_s"], 1)
        d["cpu_s"] = round(d["cpu_s"], 1)
    return sorted(rules.values(), key=lambda d: -d["cpu_s"])


# ----------------------------------------------------------------------------- media
def _video_tag(path: Path, rel_to: Path) -> str:
    return (f"<video controls loop muted playsinline src='{_esc(_rel(path, rel_to))}'></video>" if path.is_file()
            else "")


def _img_tag(path: Path, rel_to: Path, cls="strip") -> str:
    return f"<img class='{cls}' src='{_esc(_rel(path, rel_to))}'>" if path.is_file() else ""


def _rel(path: Path, base: Path) -> str:
    """The page's link to ``path`` from the report folder ``base``. Media outside the folder are copied
    into ``base/media/`` (under their path relative to the results folder), so the report folder is
    self-contained: it can be copied or shared without the run's results."""
    import os
    import shutil

    path, base = Path(path).resolve(), Path(base).resolve()
    if base not in path.parents:
        try:
            rel = path.relative_to(base.parent)
        except ValueError:
            rel = Path(path.name)
        dest = base / "media" / rel
        if not dest.is_file() or dest.stat().st_mtime < path.stat().st_mtime or dest.stat().st_size != path.stat().st_size:
            dest.parent.mkdir(parents=True, exist_ok=True)
            tmp = dest.with_name(f".{dest.name}.tmp")
            shutil.copy2(path, tmp)
            os.replace(tmp, dest)
        path = dest
    return os.path.relpath(path, base)


def side_by_side_video(folders: list[Path], out: Path, fps: float = 12.0, scale: int = 2) -> Path | None:
    """An mp4 of the frame folders side by side (linear EXR frames -> display), each upscaled ``scale`` x."""
    from .io import linear_to_display, read_rgb_exr, to_uint8, write_video

    folders = [f for f in folders if f is not None and (f / "0000.exr").is_file()]
    if not folders:
        return None
    n = min(sum(1 for _ in f.glob("*.exr")) for f in folders)
    frames = []
    for i in range(n):
        row = [to_uint8(linear_to_display(read_rgb_exr(f / f"{i:04d}.exr"))) for f in folders]
        h = min(r.shape[0] for r in row)
        row = [np.repeat(np.repeat(r[:h], scale, 0), scale, 1) for r in row]
        frames.append(np.concatenate([np.pad(r, ((0, 0), (0, 4), (0, 0)), constant_values=255) for r in row], 1))
    write_video(out, np.stack(frames), fps=fps)
    return out


# ----------------------------------------------------------------------------- report
def _variants(evals: dict) -> list[str]:
    return [v for v in VARIANTS if any(k[0] == v for k in evals)]


def _first_variant(evals: dict) -> str | None:
    return next(iter(_variants(evals)), None)


def _table1_rows(evals: dict, v0: str) -> list[tuple[str, str, str]]:
    methods = []
    for (v, _b), e in evals.items():
        if v == v0:
            methods += [m for m in e.get("methods", []) if m not in methods]
    return [(METHOD_LABELS.get(m, m), v0, m) for m in methods]


def build_report(results_dir: str | Path = "results", logs_dir: str | Path | None = None,
                 projection: dict | None = None) -> Path:
    """Write ``results/report/index.html`` from whatever the run and the benchmarks produced."""
    results = Path(results_dir)
    logs = Path(logs_dir) if logs_dir else results.parent / "logs"
    out_dir = results / "report"
    out_dir.mkdir(parents=True, exist_ok=True)
    evals = load_evals(results)
    orderings = ordering_checks(evals)
    nav = ["tables", "clips", "reconstruction", "leave-out", "runtime", "curves", "longform", "edits", "stability"]
    parts = ["<!doctype html><html><head><meta charset='utf-8'><title>LightCrafter run report</title>",
             f"<style>{CSS}</style></head><body><h1>LightCrafter run report</h1>",
             "<p class='note'>Every number on this page was computed by this run on this machine; a missing input "
             "is shown as not computed, with the reason.</p>",
             "<nav>" + "".join(f"<a href='#{n}'>{n}</a>" for n in nav) + "</nav>"]

    # 1. tables ------------------------------------------------------------------------------
    parts.append("<h2 id='tables'>Table 1: methods (trained on the full data)</h2>")
    full = _variants(evals)
    if full:
        v0 = full[0]
        rows = _table1_rows(evals, v0)
        parts.append(f"<p class='note'>Variant <code>{_esc(v0)}</code>; mean over held-out clips (frame-wise metrics on "
                     "display values, averaged per clip), 95 % bootstrap interval over clips below each value. "
                     "Synthetic: target-light Cycles video; real: relit back to the fitted source light and compared "
                     "with the input video (the paper's DL3DV protocol 1).</p>")
        parts.append(metrics_table(evals, rows))
        parts.append("<h2>Table 2: ablations of the training data</h2>")
        parts.append(metrics_table(evals, [(VARIANT_LABELS.get(v, v), v, "refined") for v in full]))
        parts.append(not_computed_notes(evals))
        parts.append(artifacts_section(evals))
        parts.append(_ordering_checks(orderings))
        parts.append(_selection_section(evals))
    else:
        parts.append(_not_computed("Tables 1 and 2", "no results/eval/*/*/metrics.json (run `snakemake` to the end)"))

    # 2. clips ---------------------------------------------------------------------------------
    parts.append("<h2 id='clips'>Test clips: source | proxy | refined | target</h2>")
    parts.append(_clips_section(results, out_dir, evals))

    # 3. reconstruction -------------------------------------------------------------------------
    parts.append("<h2 id='reconstruction'>Reconstruction stack &Phi; (after Align, per motion config)</h2>")
    rec = results / "summary" / "reconstruction.json"
    if rec.is_file():
        r = read_json(rec)
        keys = ["motion", "clips", "rotation_deg_median", "translation_m", "registered_fraction", "depth_abs_rel",
                "normal_deg", "albedo_psnr_db", "roughness_mae", "metallic_mae", "mask_iou"]
        parts.append(_table([{"motion": m, **v} for m, v in r.get("by_motion", {}).items()], keys))
        parts.append(f"<p>Moving-camera frames registered (skipped clips count as unregistered): "
                     f"{_fmt(r.get('moving_camera_frames_registered_incl_skipped'))}; Phi seconds per frame: "
                     f"{_fmt(r.get('seconds_per_frame'))}.</p>")
        if r.get("skipped"):
            parts.append("<p>Left out by Phi:</p>" + _table([{"clip": k, "reason": v} for k, v in r["skipped"].items()],
                                                             ["clip", "reason"]))
        if r.get("real"):
            parts.append("<p>Real clips:</p>" + _table([{"clip": k, **v} for k, v in r["real"].items()],
                                                       ["clip", "camera_method", "registered", "frames", "camera_static",
                                                        "seconds", "skipped"]))
    else:
        parts.append(_not_computed("reconstruction summary", f"{rec} missing"))
    parts.append(_budget_section(results))

    # 4. leave-out counts ---------------------------------------------------------------------
    parts.append("<h2 id='leave-out'>Work left out (what a scene does not need)</h2>")
    parts.append(_leave_out_section(results))

    # 5. run time -------------------------------------------------------------------------------
    parts.append("<h2 id='runtime'>Run time per stage</h2>")
    costs = stage_costs(logs)
    if costs:
        total = sum(c["cpu_s"] for c in costs)
        parts.append(_table(costs, ["stage", "jobs", "wall_s", "cpu_s", "core_hours"],
                            {"wall_s": "wall s (sum over jobs)", "cpu_s": "CPU s", "core_hours": "core-hours"}))
        parts.append(f"<p>Total CPU: {total / 3600:.3f} core-hours.</p>")
    else:
        parts.append(_not_computed("stage costs", f"no Snakemake benchmark files under {logs}/benchmark"))
    proj = projection or (read_json(results / "summary" / "paper_projection.json")
                          if (results / "summary" / "paper_projection.json").is_file() else None)
    if proj:
        parts.append("<h3>Projected cost of config/paper.yaml</h3>")
        parts.append(f"<p class='note'>{_esc(proj.get('method', ''))}</p>")
        parts.append(_table(proj.get("stages", []), ["stage", "jobs", "unit", "units", "core_hours", "note"]))
        parts.append(f"<p>Projected CPU total: {_fmt(proj.get('total_core_hours'))} core-hours.</p>")

    # 6. curves --------------------------------------------------------------------------------
    parts.append("<h2 id='curves'>Error against run time</h2>")
    benches = sorted((results / "bench").glob("*.json"))
    curve = results / "recon" / "estimator" / "curve.json"
    if curve.is_file():
        benches.append(curve)
    shown = 0
    for b in benches:
        try:
            bench = read_json(b)
        except Exception:  # noqa: BLE001
            continue
        if not isinstance(bench, dict) or "points" not in bench or "metric" not in bench or "table" in bench:
            continue  # (a benchmark with a table, e.g. Phi's error budget, has its own section)
        png = out_dir / f"{bench['name']}.png"
        plot_bench(bench, png)
        m = bench.get("machine", {})
        parts.append(f"<div class='card'><h3>{_esc(bench['name'])}</h3><p class='note'>varied: {_esc(bench['varied'])}; "
                     f"metric: {_esc(bench['metric'])} ({'higher' if bench.get('higher_is_better') else 'lower'} is "
                     f"better); chosen: {_esc(bench.get('chosen'))}; machine: {_esc(m.get('cores'))} cores</p>"
                     f"<img src='{png.name}'>")
        keys = ["series", "setting", "seconds", "value"] if any("series" in p for p in bench["points"]) else \
            ["setting", "seconds", "value"]
        parts.append(f"<details><summary>points</summary>{_table(bench['points'], keys)}</details></div>")
        shown += 1
    if not shown:
        parts.append(_not_computed("benchmark curves", "no results/bench/*.json; run `make bench`"))

    # 7. long form, edits, stability ---------------------------------------------------------------
    parts.append("<h2 id='longform'>Long-form relighting: fused tiling vs independent chunks</h2>")
    parts.append(_longform_section(results, out_dir))
    parts.append("<h2 id='edits'>Scene edits (same renderer, same refiner)</h2>")
    parts.append(_edits_section(results, out_dir))
    parts.append("<h2 id='stability'>Numerical stability and bad-input tests</h2>")
    parts.append(_stability_section(results))
    parts.append("</body></html>")
    if evals:
        write_text(out_dir / "tables.md", tables_markdown(evals, orderings))
        write_json(out_dir / "orderings.json", orderings)
    index = out_dir / "index.html"
    write_text(index, "\n".join(p for p in parts if p))
    return index


def _budget_section(results: Path) -> str:
    """Phi's error budget (benchmarks/phi_budget.py): the proxy's dB per buffer component."""
    f = results / "bench" / "phi_budget.json"
    head = "<h3>Error budget of &Phi; (where the proxy's decibels go)</h3>"
    if not f.is_file():
        return head + _not_computed("error budget", f"{f} missing; run `.venv/bin/python benchmarks/phi_budget.py`")
    b = read_json(f)
    rows = [{"row": k, **v} for k, v in b["table"].items() if "psnr_db" in v]
    missing = [f"{k}: {v['not_computed']}" for k, v in b["table"].items() if "not_computed" in v]
    return (head + f"<p class='note'>R on the {b['split']} pairs ({b['pairs']}) from ground-truth buffers with one "
            "component taken from &Phi; (gt+phi:&hellip;), from &Phi;'s buffers with one taken from ground truth "
            "(phi+gt:&hellip;), and R's own error: the per-frame shadow mesh &Phi;'s clips get (oracle@frame), its "
            "sampling noise (oracle_vs_16x: the oracle against 16x its samples) and a denoised oracle "
            "(oracle+oidn). PSNR / SSIM on display values against the Cycles target.</p>"
            + _table(rows, ["row", "psnr_db", "ssim", "vs_oracle_db", "vs_phi_db"],
                     {"psnr_db": "PSNR dB", "vs_oracle_db": "dB vs oracle", "vs_phi_db": "dB vs Phi"})
            + "".join(f"<p class='note'>{_esc(m)}</p>" for m in missing))


def _selection_section(evals: dict) -> str:
    """What validation chose for each variant's refiner (from its evaluation's inference record)."""
    rows = []
    for v in sorted({k[0] for k in evals}):
        e = next(evals[k] for k in evals if k[0] == v)
        sel = (e.get("inference") or {}).get("selection") or {}
        ch = sel.get("chosen")
        if not ch:
            rows.append({"variant": v, "note": sel.get("note", "no selection recorded")})
            continue
        rows.append({"variant": v, "step": ch.get("step"), "strength": ch.get("strength"),
                     "guidance": ch.get("guidance_scale"), "residual": ch.get("residual_scale", 1.0),
                     "val_refined_db": ch.get("value") if ch.get("metric") == "psnr_db" else None,
                     "val_proxy_db": (sel.get("val_proxy") or {}).get("psnr_db"), "note": sel.get("note")})
    if not rows:
        return ""
    return ("<h3>Refiner settings chosen on validation scenes (never test)</h3><p class='note'>residual 0 = the "
            "learned latent map of the proxy alone (the transformer's correction did not help on validation); "
            "1 = the full refiner.</p>" + _table(rows, ["variant", "step", "strength", "guidance", "residual",
                                                         "val_refined_db", "val_proxy_db", "note"]))


# The paper's orderings: (name, (variant, bench, method) on the left, the same on the right); PSNR.
ORDERINGS = [
    ("refined > proxy on synthetic (full)", ("full", "synthetic", "refined"), ("full", "synthetic", "proxy")),
    ("full > no_real on real", ("full", "real", "refined"), ("no_real", "real", "refined")),
    ("full > no_synthetic on synthetic", ("full", "synthetic", "refined"), ("no_synthetic", "synthetic", "refined")),
    ("artifact-matched (no_real) > clean_buffers on real", ("no_real", "real", "refined"),
     ("clean_buffers", "real", "refined")),
    ("artifact-matched (no_real) > clean_buffers on synthetic", ("no_real", "synthetic", "refined"),
     ("clean_buffers", "synthetic", "refined")),
]


def _per_clip(evals: dict, variant: str, bench: str, method: str, metric: str) -> dict[str, float]:
    e = evals.get((variant, bench)) or {}
    out = {}
    for p in e.get("pairs") or []:
        v = p[method].get(metric) if isinstance(p.get(method), dict) else None
        if p.get("pair_id") is not None and v is not None and np.isfinite(v):
            out[str(p["pair_id"])] = float(v)
    return out


def ordering_checks(evals: dict, metric: str = "psnr_db") -> list[dict]:
    """Each of the paper's orderings on this run: both means, and the paired difference over the clips both
    sides scored (95 % paired bootstrap interval, :func:`lightcrafter.evaluation.paired_bootstrap_ci`).

    ``verdict``: "holds" when the interval lies above 0, "reversed" when below 0, "inconclusive" when it
    spans 0, "too few clips for an interval (n < 6)" below :data:`lightcrafter.evaluation.MIN_CLIPS_FOR_INTERVAL`
    paired clips (no verdict from the means), and "not computed" when a side is missing."""
    from .evaluation import paired_bootstrap_ci

    out = []
    for name, left, right in ORDERINGS:
        rec = {"ordering": name, "metric": metric, "left": "/".join(left), "right": "/".join(right)}
        la, ra = (evals.get(left[:2]) or {}).get("mean", {}), (evals.get(right[:2]) or {}).get("mean", {})
        lm, rm = (la.get(left[2]) or {}).get(metric), (ra.get(right[2]) or {}).get(metric)
        if lm is None or rm is None:
            out.append({**rec, "verdict": "not computed"})
            continue
        rec.update(left_mean=lm, right_mean=rm)
        lc, rc = _per_clip(evals, *left, metric), _per_clip(evals, *right, metric)
        ids = sorted(set(lc) & set(rc))
        if ids:
            ci = paired_bootstrap_ci([lc[i] for i in ids], [rc[i] for i in ids])
            rec.update(diff_mean=ci["mean"], diff_low=ci["low"], diff_high=ci["high"], clips=len(ids))
            if ci["too_few"]:
                rec["verdict"] = ci["too_few"]
            else:
                rec["verdict"] = "holds" if ci["low"] > 0 else "reversed" if ci["high"] < 0 else "inconclusive"
        else:
            rec.update(diff_mean=lm - rm, clips=0)
            rec["verdict"] = "no clips scored by both sides"
        out.append(rec)
    return out


def _ordering_checks(orderings: list[dict]) -> str:
    """Which of the paper's orderings hold on this run (with the numbers), from :func:`ordering_checks`."""
    rows = [{"ordering (PSNR)": r["ordering"], "left dB": r.get("left_mean"), "right dB": r.get("right_mean"),
             "difference dB [95 % CI]": _diff_text(r), "paired clips": r.get("clips"), "verdict": r["verdict"]}
            for r in orderings]
    return ("<h3>The paper's orderings on this run</h3><p class='note'>difference = left − right over the clips "
            "both sides scored, 95 % paired bootstrap interval; holds / reversed when the interval excludes 0, "
            "inconclusive when it spans 0.</p>"
            + _table(rows, ["ordering (PSNR)", "left dB", "right dB", "difference dB [95 % CI]", "paired clips",
                            "verdict"]))


def _diff_text(r: dict) -> str:
    if r.get("diff_mean") is None:
        return ""
    if r.get("diff_low") is None:
        return f"{r['diff_mean']:+.2f}"
    return f"{r['diff_mean']:+.2f} [{r['diff_low']:+.2f}, {r['diff_high']:+.2f}]"


def tables_markdown(evals: dict, orderings: list[dict] | None = None) -> str:
    """Table 1, Table 2 and the orderings (:func:`ordering_checks`, computed here unless given) in Markdown
    (``results/report/tables.md``), for a README or a note."""
    v0 = _first_variant(evals)
    if v0 is None:
        return "_Tables 1 and 2: not computed (no results/eval/*/*/metrics.json)_\n"
    n = {b: (evals.get((v0, b)) or {}).get("num_pairs") for b in ("synthetic", "real")}
    parts = [f"Table 1: methods (variant `{v0}`; {n['synthetic']} synthetic and {n['real']} real test clips; "
             "mean [95 % bootstrap interval over clips])\n", metrics_table_markdown(evals, _table1_rows(evals, v0)),
             "\nTable 2: ablations of the training data\n",
             metrics_table_markdown(evals, [(VARIANT_LABELS.get(v, v), v, "refined") for v in _variants(evals)]),
             "\nThe paper's orderings (PSNR; left − right over the same clips, 95 % paired bootstrap interval)\n",
             "| ordering | left dB | right dB | difference dB | clips | verdict |", "| --- | ---: | ---: | ---: | ---: | --- |"]
    for r in orderings if orderings is not None else ordering_checks(evals):
        lm, rm = r.get("left_mean"), r.get("right_mean")
        parts.append(f"| {r['ordering']} | {'' if lm is None else f'{lm:.2f}'} | {'' if rm is None else f'{rm:.2f}'} | "
                     f"{_diff_text(r)} | {r.get('clips', '')} | {r['verdict']} |")
    parts += [f"\n{METRIC_LABELS.get(k, (k,))[0]}: not computed ({w})."
              for k, w in sorted(_not_computed_metrics(evals).items())]
    return "\n".join(parts) + "\n"


def _clips_section(results: Path, out_dir: Path, evals: dict) -> str:
    parts = []
    variant = _first_variant(evals)
    if variant is None:
        return _not_computed("clip gallery", "no refined clips")
    for bench in ("synthetic", "real"):
        e = evals.get((variant, bench))
        man = results / "refined" / variant / bench / "manifest.json"
        if e is None or not man.is_file():
            continue
        pairs_file = results / "benchmarks" / bench / "pairs.jsonl"
        records = {}
        if pairs_file.is_file():
            for line in pairs_file.read_text().splitlines():
                if line.strip():
                    r = json.loads(line)
                    records[r["pair_id"]] = r
        refined = {p["pair_id"]: p for p in read_json(man).get("pairs", [])}
        scores = {r["pair_id"]: r for r in e.get("pairs", [])}
        parts.append(f"<h3>{_esc(bench)} benchmark (variant {_esc(variant)})</h3><div class='grid'>")
        root = results.parent
        for pid, ref in sorted(refined.items()):
            rec = records.get(pid, {})
            folders = [root / rec["source"] if rec.get("source") else None, root / rec["proxy"] if rec.get("proxy") else None,
                       Path(ref["frames"]) if Path(ref["frames"]).is_absolute() else root / ref["frames"],
                       root / rec["target"] if rec.get("target") else None]
            vid = side_by_side_video(folders, out_dir / "clips" / f"{bench}_{pid}.mp4")
            strip = results / "refined" / variant / bench / f"{pid}_strip.png"
            s = scores.get(pid, {})
            line = " &middot; ".join(f"{m}: {s[m]['psnr_db']:.2f} dB" for m in ("proxy", "refined", "oracle_proxy")
                                     if isinstance(s.get(m), dict) and s[m].get("psnr_db") is not None)
            parts.append(f"<div class='card'><b>{_esc(pid)}</b> <span class='note'>{line}</span><br>"
                         f"{_video_tag(vid, out_dir) if vid else ''}<br>{_img_tag(strip, out_dir)}</div>")
        parts.append("</div>")
    return "".join(parts) or _not_computed("clip gallery", "no refined clips")


def _leave_out_section(results: Path) -> str:
    parts = []
    gt = results / "summary" / "ground_truth.json"
    if gt.is_file():
        s = read_json(gt)
        parts.append("<h3>Ground truth (Cycles)</h3>" + _table(
            [{"what": "radiance frames", "rendered": s.get("rgb_frames"), "naive": s.get("naive_rgb_frames")},
             {"what": "buffer frames", "rendered": s.get("buffer_frames"), "naive": s.get("naive_buffer_frames")}],
            ["what", "rendered", "naive"]))
        parts.append("<p class='note'>Naive: every lighting rendered for every frame; buffers rendered with each "
                     "radiance render. Left out: lightings no pair uses, buffers re-rendered per lighting, per-frame "
                     "buffers of a static camera over a static scene.</p>")
    rec = results / "summary" / "reconstruction.json"
    if rec.is_file():
        r = read_json(rec)
        pr = r.get("phi_runs", {})
        parts.append("<h3>Reconstruction stack</h3>" + _table(
            [{"what": "Phi runs (synthetic)", "done": pr.get("synthetic"), "naive": pr.get("naive_synthetic"),
              "note": pr.get("note")}], ["what", "done", "naive", "note"]))
    rows = []
    for man in sorted(results.glob("proxy*/*/*/*.json")) + sorted(results.glob("envfit/*/pseudo.json")):
        try:
            m = read_json(man)
        except Exception:  # noqa: BLE001
            continue
        st = m.get("stats") if isinstance(m, dict) else None
        if st:
            rows.append({"proxy": str(man.relative_to(results)).removesuffix(".json"), "frames": st.get("frames"),
                         "mesh_builds": st.get("mesh_builds"), "visibility_builds": st.get("visibility_builds"),
                         "local_light_rays": st.get("local_light_rays")})
    if rows:
        frames = sum(r["frames"] or 0 for r in rows)
        builds = sum(r["mesh_builds"] or 0 for r in rows)
        parts.append(f"<h3>Forward renderer R</h3><p>{len(rows)} clips, {frames} frames rendered, {builds} per-frame "
                     f"meshes built (a static camera over a static scene builds one for all its frames); local-light "
                     f"shadow rays only where a lighting has local lights.</p>")
        parts.append(f"<details><summary>per clip</summary>{_table(rows, list(rows[0]))}</details>")
    ds = []
    for s in sorted(results.glob("datasets/*/summary.json")) + sorted(results.glob("benchmarks/*/summary.json")):
        d = read_json(s)
        ds.append({"set": f"{s.parent.parent.name}/{s.parent.name}", "pairs": d.get("pairs"),
                   "synthetic": d.get("by_kind", {}).get("synthetic"), "real": d.get("by_kind", {}).get("real"),
                   "left out": len(d.get("skipped", [])),
                   "why": "; ".join(sorted({x["reason"][:90] for x in d.get("skipped", [])}))})
    if ds:
        parts.append("<h3>Pair sets</h3>" + _table(ds, ["set", "pairs", "synthetic", "real", "left out", "why"]))
    return "".join(parts) or _not_computed("leave-out counts", "no summaries")


def _longform_section(results: Path, out_dir: Path) -> str:
    f = results / "longform" / "metrics.json"
    if not f.is_file():
        return _not_computed("long-form check", f"{f} missing (target `longform`)")
    m = read_json(f)
    parts = [_table([{"mode": k, **v} for k, v in m.get("summary", {}).items()],
                    ["mode", "warp_ssim", "temporal_diff_boundary", "temporal_diff_interior", "boundary_over_interior",
                     "psnr_db"])]
    png = results / "longform" / "curves.png"
    if png.is_file():
        parts.append(_img_tag(png, out_dir, cls=""))
    vid = results / "longform" / "side_by_side.mp4"
    parts.append(_video_tag(vid, out_dir))
    parts.append(f"<p class='note'>{_esc(m.get('note', ''))}</p>")
    return "".join(parts)


def _edits_section(results: Path, out_dir: Path) -> str:
    parts = []
    for kind in ("light", "material", "object"):
        d = results / "edits" / kind
        if not (d / "edit.json").is_file():
            continue
        e = read_json(d / "edit.json")
        parts.append(f"<div class='card'><h3>{_esc(kind)}</h3><p class='note'>{_esc(json.dumps(e)[:300])}</p>"
                     f"{_img_tag(d / 'strip.png', out_dir)}<br>{_video_tag(d / 'side_by_side.mp4', out_dir)}</div>")
    return ("<div class='grid'>" + "".join(parts) + "</div>") if parts else \
        _not_computed("scene edits", "no results/edits/*/edit.json (target `edits`)")


def _stability_section(results: Path) -> str:
    f = results / "tests" / "junit.xml"
    if not f.is_file():
        return _not_computed("stability tests", f"{f} missing (`make test` writes it)")
    import xml.etree.ElementTree as ET

    rows = []
    for tc in ET.parse(f).getroot().iter("testcase"):
        name = tc.get("name", "")
        cls = tc.get("classname", "")
        if not any(k in (name + cls).lower() for k in ("stab", "extreme", "nan", "sun", "bad", "black", "saturat",
                                                        "degenerate", "corrupt", "one_line", "furnace")):
            continue
        outcome = "failed" if tc.find("failure") is not None or tc.find("error") is not None else (
            "skipped" if tc.find("skipped") is not None else "passed")
        rows.append({"test": f"{cls.split('.')[-1]}::{name}", "outcome": outcome, "seconds": float(tc.get("time", 0))})
    if not rows:
        return _not_computed("stability tests", "none found in the JUnit file")
    passed = sum(r["outcome"] == "passed" for r in rows)
    return f"<p>{passed}/{len(rows)} passed.</p>" + _table(rows, ["test", "outcome", "seconds"])
