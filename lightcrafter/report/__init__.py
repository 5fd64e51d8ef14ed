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

Modules: common (labels, style, HTML helpers), data (reading results), tables, costs, media,
plots, sections; :func:`build_report` here assembles the page.
"""

from __future__ import annotations

from pathlib import Path

from ..io import read_json, write_json, write_text
from .common import (ARTIFACT_METRICS, CSS, METHOD_LABELS, METRIC_LABELS, TABLE_BENCHMARKS,  # noqa: F401 (re-exported)
                     TABLE_METRICS, VARIANT_LABELS, _esc, _fmt, _not_computed, _table)
from .costs import stage_costs
from .data import _variants, load_evals
from .media import _img_tag, _video_tag, side_by_side_video  # noqa: F401 (re-exported)
from .plots import plot_bench
from .sections import (_budget_section, _clips_section, _edits_section, _leave_out_section, _longform_section,
                       _stability_section)
from .tables import (ORDERINGS, _ordering_checks, _selection_section, _table1_rows,  # noqa: F401 (re-exported)
                     artifacts_section, metrics_table, metrics_table_markdown, not_computed_notes, ordering_checks,
                     tables_markdown)


def _pseudo_input_scores(results: Path, clip: str) -> dict:
    """The envmap fit's pseudo-input PSNR against the video (dB) and fitted camera gamma of a real clip."""
    fit = results / "envfit" / clip / "fit.json"
    try:
        m = read_json(fit)
    except Exception:  # noqa: BLE001 - a clip not fitted (yet): no scores
        return {}
    psnr = m.get("pseudo_psnr_db") or {}
    return {"pseudo_input_psnr_db": psnr.get("mean"),
            "camera_gamma": ((m.get("fit") or {}).get("response") or {}).get("gamma")}


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
                "normal_deg", "ground_tilt_deg_median", "albedo_psnr_db", "albedo_psnr_db_colour_fit", "roughness_mae",
                "metallic_mae", "mask_iou"]
        parts.append(_table([{"motion": m, **v} for m, v in r.get("by_motion", {}).items()], keys))
        parts.append(f"<p>Moving-camera frames registered (skipped clips count as unregistered): "
                     f"{_fmt(r.get('moving_camera_frames_registered_incl_skipped'))}; Phi seconds per frame: "
                     f"{_fmt(r.get('seconds_per_frame'))}.</p>")
        if r.get("skipped"):
            parts.append("<p>Left out by Phi:</p>" + _table([{"clip": k, "reason": v} for k, v in r["skipped"].items()],
                                                             ["clip", "reason"]))
        if r.get("real"):
            parts.append("<p>Real clips (pseudo-input: R under the fitted map, and the fitted camera curve where "
                         "<code>envfit.fit_response</code> is on, against the video, display PSNR):</p>"
                         + _table([{"clip": k, **v, **_pseudo_input_scores(results, k)} for k, v in r["real"].items()],
                                  ["clip", "camera_method", "registered", "frames", "camera_static", "seconds",
                                   "pseudo_input_psnr_db", "camera_gamma", "skipped"]))
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
