"""Tiny end-to-end run of the whole workflow (config/ci.yaml: 3 scenes, 9 frames at 160x112, two real
clips, four dataset variants) in a scratch working directory (the session fixture e2e_run)."""

import json
import subprocess
import sys

import pytest

from workflow_util import REPO, venv_env

pytestmark = pytest.mark.slow
CI_CONFIG = str(REPO / "config" / "ci.yaml")


def snakemake(workdir, *args):
    cmd = [sys.executable, "-m", "snakemake", *args, "--cores", "2", "-d", str(workdir), "--configfile", CI_CONFIG]
    return subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=1800, env=venv_env())


def _jsonl(path):
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def test_ground_truth_counts_leave_out_unneeded_work(e2e_run):
    s = json.loads((e2e_run / "results/summary/ground_truth.json").read_text())
    # ci.yaml: 3 scenes (train, test, recon) x 3 trajectories (one per motion), 9 frames, 4 lightings;
    # train/test trajectories render their source and target lighting, recon ones the source only.
    assert s["trajectories"] == 9
    assert s["rgb_frames"] == (6 * 2 + 3 * 1) * 9
    assert s["naive_rgb_frames"] == 9 * 4 * 9
    # buffers once per trajectory; 1 frame for the static camera over the static scene
    assert s["by_motion"]["static_rotating_light"]["buffer_frames"] == 3
    assert s["buffer_frames"] == 3 + 3 * 9 + 3 * 9
    assert len(list((e2e_run / "results/gt").rglob("rgb/L*/*.exr"))) == s["rgb_frames"]


def test_phi_runs_once_per_trajectory_and_is_scored(e2e_run):
    r = json.loads((e2e_run / "results/summary/reconstruction.json").read_text())
    assert r["phi_runs"]["synthetic"] == 6 and r["phi_runs"]["naive_synthetic"] == 6  # one target per trajectory here
    assert r["clips"] == 6
    scored = [c for c in r["per_clip"].values() if "skipped" not in c]
    assert scored, r["skipped"]
    for c in scored:  # errors after Align are finite and the cameras are close to the truth
        assert c["rotation_deg"] < 5 and 0 <= c["depth_abs_rel"] < 1 and 0 < c["normal_deg"] < 90
        assert 0 <= c["ground_tilt_deg"] < 45  # every scene stands on a ground Phi sees
    assert set(r["real"]) == {"bikes_f190", "carphone_pristine_f0"}


def test_pairs_variants_and_benchmarks(e2e_run):
    res = e2e_run / "results"
    kinds = {v: {p["kind"] for p in _jsonl(res / f"datasets/{v}/pairs.jsonl")}
             for v in ("full", "no_real", "no_synthetic", "clean_buffers")}
    assert kinds["no_real"] == {"synthetic"} and kinds["clean_buffers"] == {"synthetic"}
    assert kinds["no_synthetic"] == {"real"} and kinds["full"] == {"synthetic", "real"}
    clean = _jsonl(res / "datasets/clean_buffers/pairs.jsonl")
    assert all(p["proxy"].startswith("results/proxy_gt/") for p in clean)
    matched = _jsonl(res / "datasets/no_real/pairs.jsonl")
    assert all(p["proxy"].startswith("results/proxy/") for p in matched)
    for p in matched:
        assert p["split"] == "train" and p["target_light"] != p["source_light"]
        assert (e2e_run / p["proxy"]).is_dir() and (e2e_run / p["target"]).is_dir()
    bench = _jsonl(res / "benchmarks/synthetic/pairs.jsonl")
    assert bench and all(p["split"] == "test" and "oracle_proxy" in p for p in bench)
    assert {p["clip_id"] for p in _jsonl(res / "benchmarks/real/pairs.jsonl")} == {"carphone_pristine_f0"}


def test_every_variant_is_evaluated_on_both_benchmarks(e2e_run):
    for v in ("full", "no_real", "no_synthetic", "clean_buffers"):
        for b in ("synthetic", "real"):
            m = json.loads((e2e_run / f"results/eval/{v}/{b}/metrics.json").read_text())
            assert m["num_pairs"] >= 1
            for who in ("proxy", "refined"):
                assert 0 < m["mean"][who]["psnr_db"] < 100


def test_report_shows_tables_clips_and_curves(e2e_run):
    html = (e2e_run / "results/report/index.html").read_text()
    for text in ("Table 1", "Table 2", "Ours (no real)", "Reconstruction stack", "Work left out", "Run time per stage",
                 "Projected cost of config/paper.yaml", "gbuffer_estimator", "Long-form", "Scene edits"):
        assert text in html, text
    assert "<video" in html and "<img" in html


def test_report_loads_in_a_real_browser(e2e_run):
    """Every strip, plot and side-by-side video of the run's report loads and decodes in headless Chromium."""
    from lightcrafter.report_check import check_report, find_browser

    if find_browser() is None:
        pytest.skip("no Chromium on this machine (`bash scripts/setup.sh --test` installs it)")
    v = check_report(e2e_run / "results/report/index.html")
    assert v["title"] == "LightCrafter run report" and v["text_chars"] > 2000
    assert v["images"] >= 4 and v["broken_images"] == [], v
    assert v["videos"] >= 2 and v["broken_videos"] == [], v
    assert all(w > 0 and h > 0 for w, h in v["video_sizes"])


def test_rerun_has_nothing_to_do(e2e_run):
    res = snakemake(e2e_run, "-n", "--quiet", "rules")
    assert res.returncode == 0
    assert "Nothing to be done" in res.stdout + res.stderr


def test_killed_render_resumes_where_it_stopped(e2e_run, tmp_path):
    """Lose a frame and the manifest (what a kill leaves): only that job reruns, one frame rendered."""
    import shutil

    wd = tmp_path / "copy"
    shutil.copytree(e2e_run, wd, symlinks=True)
    manifest = sorted((wd / "results/gt").rglob("rgb/L*.json"))[0]
    frames_dir = manifest.with_suffix("")
    victim = sorted(frames_dir.glob("*.exr"))[2]
    others = {p: p.stat().st_mtime_ns for p in frames_dir.glob("*.exr") if p != victim}
    victim.unlink()
    manifest.unlink()
    res = snakemake(wd, "ground_truth")
    assert res.returncode == 0, res.stderr[-3000:]
    assert victim.exists() and manifest.exists()
    assert all(p.stat().st_mtime_ns == t for p, t in others.items()), "complete frames must not be re-rendered"


def test_scene_specs_are_reproducible(e2e_run, tmp_path):
    """Same config and seed: byte-identical scene specs and asset manifest in a second workdir."""
    res = snakemake(tmp_path, "scene_specs")
    assert res.returncode == 0, res.stderr[-3000:]
    specs = sorted((e2e_run / "results/scenes").glob("*/scene.json"))
    assert len(specs) == 3
    for spec in specs:
        assert (tmp_path / "results/scenes" / spec.parent.name / "scene.json").read_bytes() == spec.read_bytes()
    assert (tmp_path / "results/assets/manifest.json").read_bytes() == \
        (e2e_run / "results/assets/manifest.json").read_bytes()


def test_estimator_weights_benchmark_scores_each_weights_file_on_train_and_test_scenes(e2e_run, tmp_path):
    """benchmarks/estimator_weights.py on the run's ground truth: the shipped weights and the run's own
    (trained 60 steps on its recon split) each get every error on both splits; a bad git revision is one line."""
    import importlib.util
    import math

    from lightcrafter.io import DataError

    spec = importlib.util.spec_from_file_location("estimator_weights", REPO / "benchmarks" / "estimator_weights.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    own = e2e_run / "results/recon/estimator/model.pt"
    out = tmp_path / "ew.json"
    assert bench.main(["--results", str(e2e_run / "results"), "--weights", "shipped=shipped", f"own={own}",
                       "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["frames"]["train"] > 0 and res["frames"]["test"] > 0
    got = {(p["setting"], p["series"]): p["value"] for p in res["points"]}
    assert set(got) == {(w, f"{s}_{e}") for w in ("shipped", "own") for s in ("train", "test") for e in bench.ERRORS}
    assert all(math.isfinite(v) for v in got.values())
    assert got[("shipped", "test_normal_deg")] != got[("own", "test_normal_deg")]
    with pytest.raises(DataError, match="name a commit that shipped weights"):
        bench.main(["--results", str(e2e_run / "results"), "--weights", "old=git:no-such-rev", "--out", str(out)])


def test_ship_estimator_ships_a_run_then_adds_it_as_an_ensemble_member(e2e_run, tmp_path, monkeypatch):
    """scripts/ship_estimator.py on the run's estimator (into a scratch weights folder): it ships one network with
    its provenance and check set; --add-member makes the file an ensemble of two whose provenance lists both
    records and whose recorded errors the loaded ensemble reproduces; --add-member with nothing shipped is one
    line."""
    import importlib.util

    import lightcrafter.recon.weights as W
    from lightcrafter.io import DataError
    from lightcrafter.recon import estimator as est

    monkeypatch.setattr(W, "SHIPPED_WEIGHTS", tmp_path / "w" / "gbuffer_estimator.pt")
    monkeypatch.setattr(W, "SHIPPED_PROVENANCE", tmp_path / "w" / "gbuffer_estimator.json")
    monkeypatch.syspath_prepend(str(REPO / "scripts"))
    spec = importlib.util.spec_from_file_location("ship_estimator", REPO / "scripts" / "ship_estimator.py")
    ship = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ship)
    args = ["--results", str(e2e_run / "results"), "--config", str(REPO / "config" / "ci.yaml"), "--check-frames", "2"]
    with pytest.raises(DataError, match="no shipped weights to add a member to"):
        ship.main(args + ["--add-member"])
    assert ship.main(args) == 0
    one = json.loads(W.SHIPPED_PROVENANCE.read_text())
    assert "members" not in one and one["config_file"] == "ci.yaml" and len(one["data"]["check_frames"]) == 2
    assert isinstance(est.load(W.SHIPPED_WEIGHTS), est.GBufferNet)
    assert ship.main(args + ["--add-member"]) == 0
    two = json.loads(W.SHIPPED_PROVENANCE.read_text())
    assert len(two["members"]) == 2 and two["members"][0]["commit"] == one["commit"]
    assert all("sha256" not in r and r["curve"] for r in two["members"])
    ens = est.load(W.SHIPPED_WEIGHTS)
    assert isinstance(ens, est.EstimatorEnsemble) and len(ens.members) == 2
    assert two["parameters"] == 2 * one["parameters"]
    errors = est.check_set_errors(ens, W.check_set_path())
    for k, v in two["check_set_errors"].items():  # two copies of one network: its own errors, reproduced
        assert errors[k] == pytest.approx(v, rel=1e-4, abs=1e-5) and v == pytest.approx(one["check_set_errors"][k],
                                                                                         rel=1e-4, abs=1e-5), k


def test_envfit_response_benchmark_scores_real_clips_and_a_synthetic_control(e2e_run, tmp_path):
    """benchmarks/envfit_response.py on the run: each real clip and each train split's synthetic clip get the
    pseudo-input's PSNR without and with the fitted camera curve; the curve never makes the fitted frames worse."""
    import importlib.util
    import math

    spec = importlib.util.spec_from_file_location("envfit_response", REPO / "benchmarks" / "envfit_response.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    out = tmp_path / "er.json"
    assert bench.main(["--results", str(e2e_run / "results"), "--config", CI_CONFIG, "--split", "train",
                       "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    groups = {(g, s) for g in res["summary"] for s in ("off", "on")}
    assert {(p["series"], p["setting"]) for p in res["points"]} == groups
    assert res["chosen"] == "on"  # the default (config/ci.yaml extends it) fits the curve
    kinds = {r["kind"] for r in res["clips"]}
    assert kinds == {"real", "synthetic control"}
    real = {r["clip"]: r for r in res["clips"] if r["kind"] == "real"}
    fits = {p.parent.name for p in (e2e_run / "results" / "envfit").glob("*/fit.json")
            if "skipped" not in json.loads(p.read_text())}
    assert set(real) == fits
    for r in res["clips"]:
        assert math.isfinite(r["psnr_db_without"]) and math.isfinite(r["psnr_db_with"])
        assert 0.5 <= r["gamma"] <= 3.0
    for clip, r in real.items():  # the run's own pseudo-input is the benchmark's "with"
        fit = json.loads((e2e_run / "results" / "envfit" / clip / "fit.json").read_text())
        assert fit["pseudo_psnr_db"]["mean"] == pytest.approx(r["psnr_db_with"], abs=0.01)
