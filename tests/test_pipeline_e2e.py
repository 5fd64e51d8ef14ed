"""Tiny end-to-end run of the workflow (config/ci.yaml) in a scratch working directory."""

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


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    wd = tmp_path_factory.mktemp("e2e")
    res = snakemake(wd)  # the default target: everything, from assets to the report
    assert res.returncode == 0, res.stderr[-4000:]
    return wd


def test_ground_truth_counts_leave_out_unneeded_work(run_dir):
    s = json.loads((run_dir / "results/summary/ground_truth.json").read_text())
    # ci.yaml: 2 scenes x 3 trajectories (one per motion), 5 frames, 4 lightings, 1 target each.
    assert s["trajectories"] == 6
    assert s["rgb_frames"] == 6 * 2 * 5  # only the source and the target lighting
    assert s["naive_rgb_frames"] == 6 * 4 * 5
    # Buffers once per trajectory; 1 frame for the static camera over the static scene.
    assert s["by_motion"]["static_rotating_light"]["buffer_frames"] == 2
    assert s["by_motion"]["orbit_static"]["buffer_frames"] == 2 * 5
    assert s["buffer_frames"] == 2 + 2 * 5 + 2 * 5
    exrs = list((run_dir / "results/gt").rglob("rgb/L*/*.exr"))
    assert len(exrs) == s["rgb_frames"]


def test_rerun_has_nothing_to_do(run_dir):
    res = snakemake(run_dir, "-n", "--quiet", "rules")
    assert res.returncode == 0
    assert "Nothing to be done" in res.stdout + res.stderr


def test_killed_render_resumes_where_it_stopped(run_dir):
    """Lose a frame and the manifest (what a kill leaves): only that job reruns, one frame rendered."""
    manifest = sorted((run_dir / "results/gt").rglob("rgb/L*.json"))[0]
    frames_dir = manifest.with_suffix("")
    victim = sorted(frames_dir.glob("*.exr"))[2]
    others = {p: p.stat().st_mtime_ns for p in frames_dir.glob("*.exr") if p != victim}
    victim.unlink()
    manifest.unlink()
    res = snakemake(run_dir, "ground_truth")
    assert res.returncode == 0, res.stderr[-3000:]
    assert victim.exists() and manifest.exists()
    assert all(p.stat().st_mtime_ns == t for p, t in others.items()), "complete frames must not be re-rendered"


def test_scene_specs_are_reproducible(run_dir, tmp_path):
    """Same config and seed: byte-identical scene specs and asset manifest in a second workdir."""
    res = snakemake(tmp_path, "scene_specs")
    assert res.returncode == 0, res.stderr[-3000:]
    specs = sorted((run_dir / "results/scenes").glob("*/scene.json"))
    assert len(specs) == 2
    for spec in specs:
        again = tmp_path / "results/scenes" / spec.parent.name / "scene.json"
        assert again.read_bytes() == spec.read_bytes()
    a = json.loads((run_dir / "results/assets/manifest.json").read_text())
    b = json.loads((tmp_path / "results/assets/manifest.json").read_text())
    assert [x["sha256"] for x in a["accepted"]] == [x["sha256"] for x in b["accepted"]]
    assert a["rejected"] == b["rejected"] or [r["reason"] for r in a["rejected"]] == [r["reason"] for r in b["rejected"]]


def test_clean_buffers_pairs_and_evaluation(run_dir):
    pairs = [json.loads(l) for l in (run_dir / "results/datasets/clean_buffers/pairs.jsonl").read_text().splitlines()]
    # ci.yaml: 1 train + 1 test scene, 3 trajectories each, 1 target lighting each.
    assert len(pairs) == 6
    assert {p["split"] for p in pairs} == {"train", "test"}
    for p in pairs:
        assert p["target_light"] != p["source_light"]
        assert (run_dir / p["proxy"]).exists() and (run_dir / p["target"]).exists()
    metrics = json.loads((run_dir / "results/eval/clean_buffers/metrics.json").read_text())
    assert metrics["num_pairs"] == 3
    for who in ("proxy", "refined"):
        assert 0 < metrics["mean"][who]["psnr_db"] < 100
    assert (run_dir / "results/report/index.html").read_text().count("clean_buffers") >= 1


def test_pairs_are_reproducible(run_dir, tmp_path):
    res = snakemake(tmp_path, "results/datasets/clean_buffers/pairs.jsonl")
    assert res.returncode == 0, res.stderr[-3000:]
    a = (run_dir / "results/datasets/clean_buffers/pairs.jsonl").read_text()
    assert (tmp_path / "results/datasets/clean_buffers/pairs.jsonl").read_text() == a
    # The proxies themselves: Mitsuba with a fixed seed renders the same frames.
    import numpy as np

    from lightcrafter.io import read_rgb_exr

    first = json.loads(a.splitlines()[0])
    proxy_frames = sorted((run_dir / first["proxy"]).glob("*.exr"))
    assert len(proxy_frames) == first["num_frames"]
    for f in proxy_frames:
        np.testing.assert_allclose(read_rgb_exr(tmp_path / first["proxy"] / f.name), read_rgb_exr(f), atol=1e-6)
