"""Dry-run DAG tests: job counts per rule, and that a target pulls in only what it needs.

Each dry run uses a fresh, empty working directory (``snakemake -d``), so a developer's own
results/ never changes the counts.
"""

import time

import pytest
import yaml

from lightcrafter import scenes
from workflow_util import REPO, dry_run, dry_run_outputs, job_counts, venv_env

def expected_gt_counts(cfg):
    s = cfg["scenes"]
    plans = [scenes.plan_scene(s, cfg["seed"], i) for i in range(s["count"])]
    trajs = [t for p in plans for t in p["trajectories"]]
    return {
        "generate_assets": 1 if cfg["assets"]["source"] == "procedural" else 0,
        "curate_assets": 1,
        "sample_scene": s["count"],
        "render_buffers": len(trajs),
        "render_rgb": sum(len(t["render_lights"]) for t in trajs),
    }


def test_default_config_ground_truth_counts(default_config):
    res = dry_run("ground_truth")
    assert res.returncode == 0, res.stderr
    counts = job_counts(res.stdout)
    exp = expected_gt_counts(default_config)
    assert {k: counts.get(k, 0) for k in exp} == exp
    # The default: 4 scenes x 3 trajectories, each using 2 of 4 lightings.
    assert counts["render_buffers"] == 12 and counts["render_rgb"] == 24
    # Nothing beyond ground truth is pulled in by this target.
    assert set(counts) == set(exp) | {"ground_truth", "summarize_ground_truth"}


def test_paper_config_counts_and_dag_build_time(paper_config):
    t0 = time.perf_counter()
    res = dry_run("ground_truth", configfile="config/paper.yaml")
    seconds = time.perf_counter() - t0
    assert res.returncode == 0, res.stderr
    counts = job_counts(res.stdout)
    assert counts["sample_scene"] == 400
    assert counts["render_buffers"] == 400 * 3
    assert counts["render_rgb"] == 400 * 3 * 4  # 1 source + 3 targets: every lighting is used
    print(f"paper-config dry run: {sum(counts.values())} jobs in {seconds:.1f} s")


def refiner_expected_counts(cfg):
    """The clean_buffers evaluation needs train/test scenes only, and only target lightings."""
    s = cfg["scenes"]
    plans = [scenes.plan_scene(s, cfg["seed"], i) for i in range(s["count"])]
    used = [p for p in plans if p["split"] in ("train", "test")]
    trajs = [t for p in used for t in p["trajectories"]]
    targets = sum(len(t["target_lights"]) for t in trajs)
    return {"generate_assets": 1, "curate_assets": 1, "sample_scene": len(used), "render_buffers": len(trajs),
            "render_rgb": targets, "render_proxy_gt": targets, "dataset_clean_buffers": 1, "train_refiner": 1,
            "infer_refiner": 1, "evaluate_refiner": 1}


@pytest.mark.parametrize("configfile", [None, "config/paper.yaml"])
def test_clean_buffers_evaluation_pulls_only_what_it_needs(default_config, paper_config, configfile):
    cfg = paper_config if configfile else default_config
    res = dry_run("results/eval/clean_buffers/metrics.json", configfile=configfile)
    assert res.returncode == 0, res.stderr[-2000:]
    counts = job_counts(res.stdout)
    exp = refiner_expected_counts(cfg)
    assert counts == exp
    # Source-lighting radiance and recon-split scenes are not needed by this target.
    all_rgb = sum(len(t["render_lights"]) for i in range(cfg["scenes"]["count"])
                  for t in scenes.plan_scene(cfg["scenes"], cfg["seed"], i)["trajectories"])
    assert counts["render_rgb"] < all_rgb


@pytest.mark.parametrize("variant", ["full", "no_real", "no_synthetic"])
def test_variants_without_data_stages_cannot_be_requested(variant):
    res = dry_run(f"results/eval/{variant}/metrics.json")
    assert res.returncode != 0
    out = res.stdout + res.stderr
    assert "MissingRuleException" in out and f"results/eval/{variant}/metrics.json" in out, out[-1500:]


def test_single_rgb_target_pulls_only_its_chain(default_config):
    plan = scenes.plan_scene(default_config["scenes"], 0, 0)
    t = plan["trajectories"][0]
    target = f"results/gt/s0000/{t['id']}/rgb/{t['source_light']}.json"
    counts = job_counts(dry_run(target).stdout)
    assert counts == {"generate_assets": 1, "curate_assets": 1, "sample_scene": 1, "render_rgb": 1}


def test_unused_lighting_is_not_a_target(default_config):
    plan = scenes.plan_scene(default_config["scenes"], 0, 0)
    t = plan["trajectories"][0]
    unused = sorted(set(plan["lighting_ids"]) - set(t["render_lights"]))
    text = dry_run_outputs("ground_truth")
    assert f"results/gt/s0000/{t['id']}/rgb/{t['source_light']}.json" in text
    for light in unused:
        assert f"results/gt/s0000/{t['id']}/rgb/{light}.json" not in text


@pytest.mark.parametrize("change, key", [
    ({"scenes": {"widht": 96}}, "unknown key 'scenes.widht'"),
    ({"scenes": {"num_frames": 0}}, "key 'scenes.num_frames'"),
    ({"scenes": {"width": -96}}, "key 'scenes.width'"),
    ({"scenes": {"objects_per_scene": 20}}, "key 'scenes.layout_radius_m'"),
])
def test_bad_config_stops_with_one_line_naming_the_key(tmp_path, change, key):
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(change))
    res = dry_run("ground_truth", configfile=str(bad))
    assert res.returncode != 0
    lines = [l for l in (res.stderr + res.stdout).splitlines() if "ConfigError" in l]
    assert len(lines) == 1 and key in lines[0], res.stderr[-1500:]


def test_lint_is_clean():
    import subprocess
    import sys

    res = subprocess.run([sys.executable, "-m", "snakemake", "--lint"], cwd=REPO, capture_output=True, text=True,
                         timeout=300, env=venv_env())
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
