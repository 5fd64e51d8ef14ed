"""The report's other sections: Phi's error budget, test clips, leave-out counts, long-form, edits, stability."""

from __future__ import annotations

import json
from pathlib import Path

from ..io import read_json
from .common import _esc, _not_computed, _table
from .data import _first_variant
from .media import _img_tag, _video_tag, side_by_side_video


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
