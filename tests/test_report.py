"""The run report: tables with the best per column, orderings, curves, costs, and honest gaps."""

import json

import numpy as np
import pytest

from lightcrafter.report import build_report, metrics_table, ordering_checks, stage_costs, tables_markdown


def _eval(psnr_proxy, psnr_refined, lpips=None):
    return {"methods": ["proxy", "refined"], "num_pairs": 3,
            "mean": {"proxy": {"psnr_db": psnr_proxy, "ssim": 0.5, "lpips": lpips, "t_clip": None, "warp_ssim": 0.9},
                     "refined": {"psnr_db": psnr_refined, "ssim": 0.6, "lpips": lpips, "t_clip": None, "warp_ssim": 0.95}},
            "ci": {"refined": {"psnr_db": [psnr_refined - 1, psnr_refined + 1]}},
            "not_computed": {"lpips": "no LPIPS weights configured", "t_clip": "no CLIP weights configured"}, "pairs": []}


def _results(tmp_path):
    r = tmp_path / "results"
    bench = {"name": "toy_spp", "varied": "spp", "metric": "psnr_db", "higher_is_better": True,
             "machine": {"cores": 2}, "chosen": 4, "baseline": {"proxy": 20.0},
             "points": [{"setting": s, "seconds": 0.1 * s, "value": 10 + 3 * s ** 0.5} for s in (1, 4, 16)]}
    (r / "bench").mkdir(parents=True)
    (r / "bench" / "toy_spp.json").write_text(json.dumps(bench))
    (r / "bench" / "not_a_bench.json").write_text("[1, 2]")  # ignored, not a crash
    (r / "summary").mkdir()
    (r / "summary" / "ground_truth.json").write_text(json.dumps(
        {"trajectories": 3, "rgb_frames": 10, "naive_rgb_frames": 20, "buffer_frames": 4, "naive_buffer_frames": 12,
         "by_motion": {}}))
    for v, (p, q) in {"full": (20.0, 22.0), "no_real": (20.0, 21.0), "no_synthetic": (20.0, 18.0),
                      "clean_buffers": (20.0, 19.0)}.items():
        for b in ("synthetic", "real"):
            (r / "eval" / v / b).mkdir(parents=True)
            (r / "eval" / v / b / "metrics.json").write_text(json.dumps(_eval(p, q)))
    logs = tmp_path / "logs" / "benchmark" / "render_rgb"
    logs.mkdir(parents=True)
    for k in range(2):
        (logs / f"s{k}.tsv").write_text("s\th:m:s\tmax_rss\tcpu_time\n10.0\t0:00:10\t100\t18.0\n")
    return r


def test_report_tables_curves_costs_and_gaps(tmp_path):
    r = _results(tmp_path)
    index = build_report(r, tmp_path / "logs")
    html = index.read_text()
    assert (r / "report" / "toy_spp.png").stat().st_size > 1000
    assert "Table 1" in html and "Table 2" in html and "Ours (no synthetic)" in html
    assert "toy_spp" in html and "chosen: 4" in html
    # the paper's orderings are checked with the numbers: full > no_synthetic on synthetic holds (22 > 18)
    assert "full &gt; no_synthetic on synthetic" in html or "full > no_synthetic on synthetic" in html
    # gaps are named, never filled: LPIPS has no weights, and no long-form run exists
    assert "LPIPS: not computed" in html and "Long-form" in html and "not computed" in html
    # stage costs from the benchmark files: 2 jobs, 36 CPU seconds
    assert stage_costs(tmp_path / "logs")[0] == {"stage": "render_rgb", "jobs": 2, "wall_s": 20.0, "cpu_s": 36.0,
                                                 "core_hours": 0.01}


def test_best_per_column_is_marked():
    evals = {("full", "synthetic"): _eval(20.0, 22.0), ("no_real", "synthetic"): _eval(20.0, 23.0)}
    html = metrics_table(evals, [("full", "full", "refined"), ("no_real", "no_real", "refined")], ("synthetic",))
    row_best = html.split("<tr><td>no_real</td>")[1]
    assert row_best.startswith("<td class='best'>23")


def test_browser_check_finds_broken_images_and_videos(tmp_path):
    """The browser check must fail a page whose image is missing or whose mp4 does not decode."""
    import numpy as np
    import pytest

    from lightcrafter.io import write_video
    from lightcrafter.report_check import check_report, find_browser

    if find_browser() is None:
        pytest.skip("no Chromium on this machine (`bash scripts/setup.sh --test` installs it)")
    from PIL import Image

    Image.fromarray(np.full((8, 8, 3), 200, np.uint8)).save(tmp_path / "ok.png")
    write_video(tmp_path / "ok.mp4", np.random.default_rng(0).integers(0, 255, (6, 64, 96, 3), dtype=np.uint8),
                fps=6)
    (tmp_path / "bad.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(500))
    (tmp_path / "index.html").write_text(
        "<!doctype html><html><head><title>t</title></head><body><p>x</p><img src='ok.png'><img src='gone.png'>"
        "<video src='ok.mp4' muted></video><video src='bad.mp4' muted></video></body></html>")
    v = check_report(tmp_path / "index.html")
    assert v["images"] == 2 and v["broken_images"] == ["gone.png"], v
    assert v["videos"] == 2 and v["broken_videos"] == ["bad.mp4"], v
    assert v["video_sizes"][0] == [96, 64]
    assert not list(tmp_path.glob(".check_*"))  # the harness is removed


def test_stage_costs_split_folders_shared_by_several_rules(tmp_path):
    """recon/ holds Phi, Align and the estimator; refiner/ training, inference and evaluation: each its own stage."""
    b = tmp_path / "logs" / "benchmark"
    row = "s\th:m:s\tmax_rss\tcpu_time\n{0}\t0:00:01\t1\t{0}\n"
    for rel, sec in [("recon/synthetic_s0000_t0.tsv", 5), ("recon/synthetic_s0000_t1.tsv", 7),
                     ("recon/align_s0000_t0.tsv", 1), ("recon/real_bikes_f32.tsv", 3),
                     ("recon/train_gbuffer_estimator.tsv", 20), ("refiner/train_full.tsv", 100),
                     ("refiner/infer_full_real.tsv", 9), ("envfit/bikes_f32.tsv", 30), ("render_rgb/s0_t0_L1.tsv", 4)]:
        (b / rel).parent.mkdir(parents=True, exist_ok=True)
        (b / rel).write_text(row.format(sec))
    got = {c["stage"]: (c["jobs"], c["cpu_s"]) for c in stage_costs(tmp_path / "logs")}
    assert got == {"reconstruct_synthetic": (2, 12.0), "align_synthetic": (1, 1.0), "reconstruct_real": (1, 3.0),
                   "train_gbuffer_estimator": (1, 20.0), "train_refiner": (1, 100.0), "infer_refiner": (1, 9.0),
                   "fit_envmap": (1, 30.0), "render_rgb": (1, 4.0)}


def _eval_pairs(per_clip: dict[str, dict[str, float]]):
    """An evaluation with per-clip PSNR for each method (clip id -> method -> dB)."""
    methods = sorted({m for v in per_clip.values() for m in v})
    pairs = [{"pair_id": k, **{m: {"psnr_db": v[m]} for m in v}} for k, v in sorted(per_clip.items())]
    mean = {m: {"psnr_db": float(np.mean([v[m] for v in per_clip.values()]))} for m in methods}
    return {"methods": methods, "num_pairs": len(pairs), "mean": mean, "ci": {}, "pairs": pairs}


def test_orderings_carry_paired_intervals_and_honest_verdicts(tmp_path):
    """An ordering holds only when the paired interval over the same clips lies above 0; a difference
    whose clips disagree in sign is inconclusive however large its mean; a missing side is not computed."""
    clips = [f"c{k}" for k in range(6)]
    evals = {
        # refined beats the proxy by 1 dB +- 0.1 on every clip: holds
        ("full", "synthetic"): _eval_pairs({c: {"proxy": 10.0 + k, "refined": 11.0 + k + 0.1 * (-1) ** k}
                                            for k, c in enumerate(clips)}),
        # full is 2 dB better than no_synthetic on half the clips and 1 dB worse on the others: inconclusive
        ("no_synthetic", "synthetic"): _eval_pairs({c: {"refined": 11.0 + k + (-2.0 if k % 2 else 1.0)}
                                                    for k, c in enumerate(clips)}),
        # the clean-buffer model wins on every real clip: reversed
        ("no_real", "real"): _eval_pairs({c: {"refined": 12.0 + k} for k, c in enumerate(clips)}),
        ("clean_buffers", "real"): _eval_pairs({c: {"refined": 13.0 + k} for k, c in enumerate(clips)}),
    }
    checks = {r["ordering"]: r for r in ordering_checks(evals)}
    assert checks["refined > proxy on synthetic (full)"]["verdict"] == "holds"
    assert 0.9 < checks["refined > proxy on synthetic (full)"]["diff_low"]
    assert checks["full > no_synthetic on synthetic"]["verdict"] == "inconclusive"
    assert checks["artifact-matched (no_real) > clean_buffers on real"]["verdict"] == "reversed"
    assert checks["artifact-matched (no_real) > clean_buffers on real"]["diff_mean"] == pytest.approx(-1.0)
    assert checks["full > no_real on real"]["verdict"] == "not computed"  # no full/real evaluation
    md = tables_markdown(evals)
    assert "| refined > proxy on synthetic (full) | 13.50 | 12.50 | +1.00 [" in md
    assert "Table 2" in md and "**" in md  # the best per column is bold
    # five clips are below the documented minimum: the mean is shown, no interval and no verdict
    few = {k: _eval_pairs({c: v for c, v in zip(clips[:5], [{"proxy": 10.0 + i, "refined": 12.0 + i}
                                                          for i in range(5)])}) for k in [("full", "synthetic")]}
    rec = next(r for r in ordering_checks(few) if r["ordering"] == "refined > proxy on synthetic (full)")
    assert rec["verdict"] == "too few clips for an interval (5 < 6)" and rec["diff_low"] is None
    assert rec["diff_mean"] == pytest.approx(2.0) and rec["clips"] == 5


def test_report_writes_tables_markdown_and_orderings(tmp_path):
    r = _results(tmp_path)
    build_report(r, tmp_path / "logs")
    md = (r / "report" / "tables.md").read_text()
    assert "Table 1" in md and "Ours (no synthetic)" in md
    # the fixture has no per-clip values: no verdict rests on the means alone
    orderings = json.loads((r / "report" / "orderings.json").read_text())
    assert {o["verdict"] for o in orderings} <= {"no clips scored by both sides", "not computed"}
    assert next(o for o in orderings if o["ordering"].startswith("full > no_synthetic"))["verdict"] == \
        "no clips scored by both sides"


def test_tables_follow_the_registries_mit_results_reach_them():
    """Rows come from the dataset-variant registry and columns from the held-out registry: a variant or the
    MIT benchmark with results appears without a change to the report."""
    from lightcrafter import datasets as ds
    from lightcrafter.report import VARIANT_LABELS, metrics_table_markdown

    assert list(VARIANT_LABELS) == list(ds.VARIANTS)
    evals = {("full", "synthetic"): {"mean": {"refined": {"psnr_db": 20.0}}, "ci": {}},
             ("full", "mit"): {"mean": {"refined": {"psnr_db": 17.5, "ssim": 0.6}}, "ci": {}}}
    text = metrics_table_markdown(evals, [("Ours (full)", "full", "refined")])
    assert "mit PSNR" in text and "17.5" in text and "synthetic PSNR" in text
    assert "real PSNR" not in text  # no real results: no columns
    # columns: every metric of the registry with a better direction; no temporal one for one-frame pairs (MIT)
    from lightcrafter.evaluation import METRICS
    from lightcrafter.report.common import TABLE_METRICS

    ranked = [n for n, m in METRICS.items() if m.higher_is_better is not None]
    assert list(TABLE_METRICS["synthetic"]) == list(TABLE_METRICS["real"]) == ranked
    assert list(TABLE_METRICS["mit"]) == [n for n in ranked if not METRICS[n].temporal]
    evals[("full", "real")] = {"mean": {"refined": {"psnr_db": 21.0, "warp_ssim": 0.961}}, "ci": {}}
    text = metrics_table_markdown(evals, [("Ours (full)", "full", "refined")])
    assert "real Warp-SSIM" in text and "0.961" in text and "mit Warp-SSIM" not in text


def test_report_folder_is_self_contained(tmp_path):
    """Media from elsewhere in the results are copied under report/media/; every link stays inside the
    folder, so a copy of the folder alone shows them."""
    import re
    import shutil

    from lightcrafter.report import _img_tag, _video_tag

    results = tmp_path / "results"
    strip = results / "refined" / "full" / "synthetic" / "p0" / "strip.png"
    strip.parent.mkdir(parents=True)
    strip.write_bytes(b"\x89PNG fake")
    video = results / "gt" / "s0" / "t0" / "rgb" / "L0.mp4"
    video.parent.mkdir(parents=True)
    video.write_bytes(b"fake mp4")
    out = results / "report"
    out.mkdir()
    inside = out / "toy.png"
    inside.write_bytes(b"\x89PNG here")
    html = _img_tag(strip, out) + _video_tag(video, out) + _img_tag(inside, out)
    links = re.findall(r"src='([^']+)'", html)
    assert links == ["media/refined/full/synthetic/p0/strip.png", "media/gt/s0/t0/rgb/L0.mp4", "toy.png"]
    copy = shutil.copytree(out, tmp_path / "shared_report")
    assert all((copy / link).read_bytes() == src.read_bytes() for link, src in zip(links, (strip, video, inside)))
    strip.write_bytes(b"\x89PNG newer, longer")  # a rerun's newer media replace the copies
    _img_tag(strip, out)
    assert (out / links[0]).read_bytes() == strip.read_bytes()


def test_artifacts_section_puts_each_method_beside_the_target():
    from lightcrafter.report import artifacts_section

    evals = {("full", "synthetic"): {"methods": ["proxy", "refined"], "mean": {
        "proxy": {"blockiness_8": 1.01, "blockiness_16": 1.0, "jump_4": 1.1},
        "refined": {"blockiness_8": 2.4, "blockiness_16": 2.9, "jump_4": 3.2},
        "target": {"blockiness_8": 1.02, "blockiness_16": 1.01, "jump_4": 1.05}}}}
    html = artifacts_section(evals)
    assert "Refined (LightCrafter)" in html and "target" in html and "2.4" in html and "3.2" in html
    assert "not computed" in artifacts_section({("full", "synthetic"): {"methods": ["proxy"], "mean": {}}})


def test_real_clips_show_their_pseudo_input_score_and_camera_curve(tmp_path):
    r = _results(tmp_path)
    (r / "summary" / "reconstruction.json").write_text(json.dumps(
        {"by_motion": {}, "real": {"clipA": {"camera_method": "sfm", "registered": 13, "frames": 13},
                                   "clipB": {"camera_method": "static", "registered": 13, "frames": 13}}}))
    (r / "envfit" / "clipA").mkdir(parents=True)
    (r / "envfit" / "clipA" / "fit.json").write_text(json.dumps(
        {"pseudo_psnr_db": {"mean": 19.25, "per_frame": [19.25]}, "fit": {"response": {"gamma": 1.6}}}))
    html = build_report(r, tmp_path / "logs").read_text()
    row_a = html.split("<td>clipA</td>")[1].split("</tr>")[0]
    row_b = html.split("<td>clipB</td>")[1].split("</tr>")[0]
    assert "<td>19.25</td>" in row_a and "<td>1.6</td>" in row_a
    assert "19.25" not in row_b  # a clip not fitted shows no score


def test_cost_projection_says_when_the_measured_renders_used_other_oidn_networks(default_config, paper_config):
    """The default renders target-only videos with OIDN's balanced network, the paper config every video with the
    high one: render_rgb's projected core-hours rest on a cheaper rate, and the projection says so."""
    from lightcrafter.costs import denoiser_networks, project

    measured = [{"stage": "render_rgb", "cpu_s": 700.0}]
    assert denoiser_networks(default_config) == ("high", "balanced")
    assert denoiser_networks(paper_config) == ("high", "high")
    row = next(r for r in project(measured, default_config, paper_config)["stages"] if r["stage"] == "render_rgb")
    assert row["core_hours"] > 0
    assert "OIDN networks differ (this run: high, balanced, projected: high, high)" in row["note"]
    same = next(r for r in project(measured, default_config, default_config)["stages"] if r["stage"] == "render_rgb")
    assert "OIDN" not in same["note"]


def test_selection_section_says_what_validation_refused():
    """The report's selection table gives each variant's choice with its correction blur, its block-grid, 4-frame
    jump and Warp-SSIM ratios and how many candidates were within the limits; a variant without selection says
    why."""
    from lightcrafter.report import _selection_section

    chosen = {"step": 25, "strength": 0.1, "guidance_scale": 1.0, "residual_scale": 0.0, "metric": "psnr_db",
              "value": 20.49, "block_ratio": 1.0016, "warp_ssim_ratio": 1.0046, "jump_ratio": 0.9961,
              "correction_blur_px": 4.0, "correction_blur_frames": 1.0}
    evals = {("full", "synthetic"): {"inference": {"selection": {"chosen": chosen, "candidates": 3,
                                                                 "admissible_candidates": 1,
                                                                 "val_proxy": {"psnr_db": 20.81}}}},
             ("no_real", "synthetic"): {"inference": {"selection": {"chosen": None, "note": "selection off"}}}}
    html = _selection_section(evals)
    assert "<td>1 of 3</td>" in html and "<td>1.005</td>" in html and "<td>1.002</td>" in html
    assert "<td>0.9961</td>" in html and "<td>4 px, 1 frame</td>" in html
    assert "<td>selection off</td>" in html and "None" not in html
