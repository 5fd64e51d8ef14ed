"""The run report: every benchmark JSON becomes a curve with its chosen setting, plus the tables."""

import json

from lightcrafter.report import build_report


def test_report_plots_every_benchmark_and_lists_counts(tmp_path):
    bench = {"name": "toy_spp", "varied": "spp", "metric": "psnr_db", "higher_is_better": True,
             "machine": {"cores": 2}, "chosen": 4, "baseline": {"proxy_psnr_db": 20.0},
             "points": [{"setting": s, "seconds": 0.1 * s, "value": 10 + 3 * s ** 0.5} for s in (1, 4, 16)]}
    (tmp_path / "bench").mkdir()
    (tmp_path / "bench" / "toy_spp.json").write_text(json.dumps(bench))
    (tmp_path / "bench" / "not_a_bench.json").write_text("[1, 2]")  # ignored, not a crash
    (tmp_path / "summary").mkdir()
    (tmp_path / "summary" / "ground_truth.json").write_text(json.dumps(
        {"trajectories": 3, "rgb_frames": 10, "naive_rgb_frames": 20, "by_motion": {"orbit_static": {
            "trajectories": 3, "buffer_frames": 5, "rgb_frames": 10}}}))
    index = build_report(tmp_path)
    html = index.read_text()
    assert (tmp_path / "report" / "toy_spp.png").stat().st_size > 1000
    assert "toy_spp" in html and "chosen: 4" in html
    assert "naive_rgb_frames" in html and "orbit_static" in html
    assert html.count("<img") == 1
