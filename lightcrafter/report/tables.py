"""Tables 1 and 2, the coding-artifact table, the paper's orderings and the refiner selection."""

from __future__ import annotations

import numpy as np

from .common import (ARTIFACT_METRICS, METHOD_LABELS, METRIC_LABELS, TABLE_BENCHMARKS, TABLE_METRICS,
                     VARIANT_LABELS, _esc, _not_computed, _table)
from .data import _bench_keys, _first_variant, _not_computed_metrics, _per_clip, _variants


# ----------------------------------------------------------------------------- tables
def _cell(mean: dict, ci: dict, method: str, metric: str):
    """(mean, interval text) of one method and metric; the interval is a bootstrap_ci record (or a
    [low, high] pair); "n < 6" stands where there were too few clips for one."""
    v = (mean.get(method) or {}).get(metric)
    c = (ci.get(method) or {}).get(metric)
    if isinstance(c, dict):
        from ..evaluation import MIN_CLIPS_FOR_INTERVAL

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


def _table1_rows(evals: dict, v0: str) -> list[tuple[str, str, str]]:
    methods = []
    for (v, _b), e in evals.items():
        if v == v0:
            methods += [m for m in e.get("methods", []) if m not in methods]
    return [(METHOD_LABELS.get(m, m), v0, m) for m in methods]


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
                     "blur": _blur_cell(ch.get("correction_blur_px", 0.0), ch.get("correction_blur_frames", 0.0)),
                     "val_refined_db": ch.get("value") if ch.get("metric") == "psnr_db" else None,
                     "val_proxy_db": (sel.get("val_proxy") or {}).get("psnr_db"),
                     "val_block_ratio": ch.get("block_ratio"), "val_jump_ratio": ch.get("jump_ratio"),
                     "val_warp_ssim_ratio": ch.get("warp_ssim_ratio"),
                     "admissible": _admissible_count(sel), "note": sel.get("note")})
    if not rows:
        return ""
    return ("<h3>Refiner settings chosen on validation scenes (never test)</h3><p class='note'>residual 1 = the "
            "full refiner; residual 0 = the learned anchor of the proxy alone (a colour map and a small kernel, "
            "refiner.model.anchor_space), chosen when the transformer's correction scored lower on validation or "
            "every candidate with it was refused; a residual in between adds the transformer's correction at that "
            "weight (refiner.select.residual_scales); blur: the Gaussian on the transformer's correction, in "
            "pixels and in frames (refiner.select.correction_blurs_px, correction_blurs_frames; 0 = none). "
            "Admissible: candidates within refiner.select.max_block_ratio, the block grid over the proxy's, "
            "refiner.select.max_jump_ratio, the 4-frame jump over the target's, and "
            "refiner.select.min_warp_ssim_ratio, the Warp-SSIM over the proxy's.</p>"
            + _table(rows, ["variant", "step", "strength", "guidance", "residual", "blur", "val_refined_db",
                            "val_proxy_db", "val_block_ratio", "val_jump_ratio", "val_warp_ssim_ratio", "admissible",
                            "note"],
                     labels={"val_refined_db": "validation dB", "val_proxy_db": "proxy dB",
                             "val_block_ratio": "block grid ratio", "val_jump_ratio": "4-frame jump ratio",
                             "val_warp_ssim_ratio": "Warp-SSIM ratio"}))


def _blur_cell(px: float, frames: float) -> str:
    """The correction's blur as the selection table shows it: '0', '4 px', '4 px, 1 frame(s)'."""
    parts = ([f"{px:g} px"] if px else []) + ([f"{frames:g} frame" + ("" if frames == 1 else "s")] if frames else [])
    return ", ".join(parts) or "0"


def _admissible_count(sel: dict) -> str | None:
    """'k of n' candidates within the selection's limits (None when the record has no count)."""
    if sel.get("admissible_candidates") is None or not sel.get("candidates"):
        return None
    return f"{sel['admissible_candidates']} of {sel['candidates']}"


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


def ordering_checks(evals: dict, metric: str = "psnr_db") -> list[dict]:
    """Each of the paper's orderings on this run: both means, and the paired difference over the clips both
    sides scored (95 % paired bootstrap interval, :func:`lightcrafter.evaluation.paired_bootstrap_ci`).

    ``verdict``: "holds" when the interval lies above 0, "reversed" when below 0, "inconclusive" when it
    spans 0, "too few clips for an interval (n < 6)" below :data:`lightcrafter.evaluation.MIN_CLIPS_FOR_INTERVAL`
    paired clips (no verdict from the means), and "not computed" when a side is missing."""
    from ..evaluation import paired_bootstrap_ci

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
