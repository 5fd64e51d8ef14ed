"""Dry-run DAG tests: job counts per rule, and that a target pulls in only what it needs.

Each dry run uses a fresh, empty working directory (``snakemake -d``), so a developer's own
results/ never changes the counts.
"""

import time

import pytest
import yaml

from lightcrafter import scenes
from workflow_util import REPO, dry_run, dry_run_outputs, job_counts, venv_env

def _plans(cfg):
    s = cfg["scenes"]
    return [scenes.plan_scene(s, cfg["seed"], i) for i in range(s["count"])]


def _rendered(cfg, plans):
    """Plans of the scenes a run renders: the recon split only when it trains Phi's estimator."""
    trains = scenes.renders_recon_split(cfg)
    return [p for p in plans if trains or p["split"] != "recon"]


def expected_gt_counts(cfg):
    plans = _rendered(cfg, _plans(cfg))
    trajs = [t for p in plans for t in p["trajectories"]]
    return {
        "generate_assets": 1 if cfg["assets"]["source"] == "procedural" else 0,
        "curate_assets": 1,
        "curate_assets_shard": cfg["assets"]["curation_jobs"],
        "sample_scene": len(plans),
        "render_buffers": len(trajs),
        "render_rgb": sum(len(t["render_lights"]) for t in trajs),
    }


def test_default_config_ground_truth_counts(default_config):
    res = dry_run("ground_truth")
    assert res.returncode == 0, res.stderr
    counts = job_counts(res.stdout)
    exp = expected_gt_counts(default_config)
    assert {k: counts.get(k, 0) for k in exp} == exp
    # The default: 8 scenes x 3 trajectories; the 6 train/test scenes' trajectories use 2 of 4 lightings; the 2
    # recon scenes (the estimator's training data) are not rendered: the default ships the estimator's weights.
    assert default_config["recon"]["estimator"]["weights"] == "shipped"
    assert counts["render_buffers"] == 6 * 3 and counts["render_rgb"] == 6 * 3 * 2
    # Nothing beyond ground truth is pulled in by this target.
    assert set(counts) == set(exp) | {"ground_truth", "summarize_ground_truth"}


def test_paper_config_counts_and_dag_build_time(paper_config, paper_site):
    t0 = time.perf_counter()
    res = dry_run("ground_truth", configfile=paper_site["site"])
    seconds = time.perf_counter() - t0
    assert res.returncode == 0, res.stderr
    counts = job_counts(res.stdout)
    # the paper stack trains nothing: the 40 recon-split scenes are not rendered
    assert counts["sample_scene"] == 360
    assert counts["render_buffers"] == 360 * 3
    # train/test: 1 source + 3 targets = every lighting
    assert counts["render_rgb"] == 360 * 3 * 4
    print(f"paper-config dry run: {sum(counts.values())} jobs in {seconds:.1f} s")


def _split_counts(cfg):
    plans = _plans(cfg)
    by = {sp: [p for p in plans if p["split"] == sp] for sp in ("train", "test", "recon")}
    trajs = {sp: [t for p in ps for t in p["trajectories"]] for sp, ps in by.items()}
    return by, trajs


@pytest.mark.parametrize("paper", [False, True])
def test_clean_buffers_training_needs_no_reconstruction(default_config, paper_config, paper_site, paper):
    cfg = paper_config if paper else default_config
    res = dry_run("results/refiner/clean_buffers/model.pt", configfile=paper_site["site"] if paper else None)
    assert res.returncode == 0, res.stderr[-2000:]
    counts = job_counts(res.stdout)
    by, trajs = _split_counts(cfg)
    targets = sum(len(t["target_lights"]) for t in trajs["train"])
    expected = {"generate_assets": 1, "curate_assets": 1, "curate_assets_shard": cfg["assets"]["curation_jobs"],
                "sample_scene": len(by["train"]),
                "render_buffers": len(trajs["train"]), "render_rgb": targets, "render_proxy_gt": targets,
                "dataset": 1, "train_refiner": 1}
    if cfg["assets"]["source"] == "folder":  # the paper's Objaverse folder: nothing is generated
        del expected["generate_assets"]
    if cfg["refiner"]["model"]["kind"] == "paper":  # the checkpoint's T5 encodes the empty prompt once
        expected["encode_empty_prompt"] = 1
    assert counts == expected


def test_the_default_holds_out_clips_for_intervals_and_real_test_clips_from_four_videos(default_config):
    """The default run: at least 8 synthetic test pairs (and MIN_CLIPS_FOR_INTERVAL) and >= 4 real test clips,
    each from its own video, none of which trains; checked on disk as a run starts (the OpenCV sample videos
    that scripts/setup.sh installs are found)."""
    from lightcrafter.evaluation import MIN_CLIPS_FOR_INTERVAL
    from lightcrafter.ingest import real_clips

    by, trajs = _split_counts(default_config)
    assert sum(len(t["target_lights"]) for t in trajs["test"]) >= max(8, MIN_CLIPS_FOR_INTERVAL)
    assert len(by["test"]) >= 3  # the synthetic test clips come from several scenes, not one scene's trajectories
    real = real_clips(default_config["real"]).values()
    test_videos = [c["video"] for c in real if c["split"] == "test"]
    assert len(test_videos) >= 4 and len(set(test_videos)) == len(test_videos)
    assert not set(test_videos) & {c["video"] for c in real if c["split"] == "train"}


def test_no_real_schedules_no_real_video_job(default_config):
    counts = job_counts(dry_run("results/refiner/no_real/model.pt").stdout)
    by, trajs = _split_counts(default_config)
    for rule in ("ingest_video", "reconstruct_real", "fit_envmap", "render_pseudo_input", "render_proxy_gt"):
        assert rule not in counts, rule
    # Phi once per train trajectory (on its source video), not once per target light
    assert counts["reconstruct_synthetic"] == counts["align_synthetic"] == len(trajs["train"])
    assert counts["render_proxy"] == sum(len(t["target_lights"]) for t in trajs["train"])
    trains = default_config["recon"]["estimator"]["weights"] == "train"
    assert counts.get("train_gbuffer_estimator", 0) == int(trains)


def test_shipped_estimator_weights_leave_out_training_and_the_recon_split(default_config, tmp_path):
    """recon.estimator.weights: shipped (the default): no estimator training job and no render of a
    recon-split scene; with train, both are back."""
    by, trajs = _split_counts(default_config)
    counts = {}
    for w in ("shipped", "train"):
        cfg = tmp_path / f"{w}.yaml"
        cfg.write_text(yaml.safe_dump({"extends": str(REPO / "config" / "config.yaml"),
                                       "recon": {"estimator": {"weights": w}}}))
        counts[w] = job_counts(dry_run("all", configfile=str(cfg)).stdout)
    assert "train_gbuffer_estimator" not in counts["shipped"] and counts["train"]["train_gbuffer_estimator"] == 1
    assert counts["train"]["render_buffers"] - counts["shipped"]["render_buffers"] == len(trajs["recon"])
    assert counts["train"]["sample_scene"] - counts["shipped"]["sample_scene"] == len(by["recon"])


def test_recon_lightings_train_the_estimator_on_every_video_of_a_recon_trajectory(default_config, tmp_path):
    """scenes.recon_lightings: 3 renders each recon trajectory under 3 lights, and the estimator's job pairs
    each of those videos with the trajectory's buffers (the clip repeats), nothing else changes."""
    by, trajs = _split_counts(default_config)
    runs = {}
    for n in (1, 3):
        cfg = tmp_path / f"{n}.yaml"
        cfg.write_text(yaml.safe_dump({"extends": str(REPO / "config" / "config.yaml"),
                                       "scenes": {"recon_lightings": n}, "recon": {"estimator": {"weights": "train"}}}))
        res = dry_run("results/recon/estimator/model.pt", configfile=str(cfg), extra=("-p",), quiet=False)
        assert res.returncode == 0, res.stderr
        cmd = next(line for line in res.stdout.splitlines() if "train_estimator.py" in line and "--clips" in line)
        clips = cmd.split("--clips")[1].split("--videos")[0].split()
        videos = cmd.split("--videos")[1].split("--config-json")[0].split()
        runs[n] = (job_counts(res.stdout), clips, videos)
    (one, clips1, videos1), (three, clips3, videos3) = runs[1], runs[3]
    assert len(clips1) == len(videos1) == len(trajs["recon"])
    assert len(clips3) == len(videos3) == 3 * len(trajs["recon"]) and len(set(videos3)) == len(videos3)
    for clip, video in zip(clips3, videos3):  # a video's buffers are its own trajectory's
        assert clip.removesuffix("buffers.json") == video.split("rgb/")[0]
    assert sorted(set(clips3)) == sorted(clips1) and set(videos1) <= set(videos3)
    assert three["render_rgb"] - one["render_rgb"] == 2 * len(trajs["recon"])
    assert {k: v for k, v in three.items() if k != "render_rgb"} == {k: v for k, v in one.items() if k != "render_rgb"}


def test_no_synthetic_trains_without_synthetic_pairs(default_config):
    counts = job_counts(dry_run("results/refiner/no_synthetic/model.pt").stdout)
    by, trajs = _split_counts(default_config)
    for rule in ("reconstruct_synthetic", "align_synthetic", "render_proxy", "render_proxy_gt"):
        assert rule not in counts, rule
    # only the recon split's source videos and buffers when the estimator is trained here (Phi runs on real
    # clips), nothing synthetic with shipped weights
    n = len(trajs["recon"]) if default_config["recon"]["estimator"]["weights"] == "train" else 0
    assert counts.get("render_rgb", 0) == n and counts.get("render_buffers", 0) == n
    from lightcrafter.ingest import real_clips

    n_train_real = sum(c["split"] == "train" for c in real_clips(default_config["real"]).values())
    assert counts["ingest_video"] == counts["reconstruct_real"] == counts["fit_envmap"] == n_train_real


def test_no_synthetic_evaluation_renders_only_the_test_scenes(default_config):
    """Its synthetic benchmark needs the test scenes (and the recon split for the estimator), never train scenes."""
    counts = job_counts(dry_run("results/eval/no_synthetic/synthetic/metrics.json").stdout)
    by, trajs = _split_counts(default_config)
    assert counts["reconstruct_synthetic"] == len(trajs["test"])
    trains = default_config["recon"]["estimator"]["weights"] == "train"
    assert counts["sample_scene"] == len(by["test"]) + trains * len(by["recon"])
    assert counts["render_rgb"] == sum(len(t["render_lights"]) for t in trajs["test"]) + trains * len(trajs["recon"])


def test_ablations_target_trains_and_scores_every_variant(default_config):
    counts = job_counts(dry_run("ablations").stdout)
    assert counts["train_refiner"] == 4 and counts["dataset"] == 4
    assert counts["infer_refiner"] == counts["evaluate_refiner"] == 4 * 2  # synthetic and real benchmarks
    assert counts["benchmark_pairs"] == 2


def test_mit_benchmark_plans_its_jobs_from_the_folder(tmp_path):
    """mit.root set: one-frame clips per scene and direction, Phi on the source images only, one relighting
    fit per (scene, target direction); none of it without mit.root."""
    import yaml
    from test_ingest import _mit_fixture

    root = _mit_fixture(tmp_path / "mit")
    cfg = tmp_path / "mit.yaml"
    cfg.write_text(yaml.safe_dump({"extends": str(REPO / "config" / "config.yaml"),
                                   "mit": {"root": str(root), "target_dirs": [1, 2]}}))
    res = dry_run("results/benchmarks/mit/pairs.jsonl", configfile=str(cfg))
    assert res.returncode == 0, res.stderr[-2000:]
    counts = job_counts(res.stdout)
    assert counts["ingest_video"] == 6 and counts["reconstruct_real"] == 2 and counts["relight_mit"] == 4
    assert "reconstruct_synthetic" not in counts and counts["benchmark_pairs"] == 1
    assert "relight_mit" not in job_counts(dry_run("all").stdout)


@pytest.mark.parametrize("variant", ["synthetic", "clean", "full_real"])
def test_unknown_variants_cannot_be_requested(variant):
    res = dry_run(f"results/eval/{variant}/synthetic/metrics.json")
    assert res.returncode != 0
    out = res.stdout + res.stderr
    assert "MissingRuleException" in out, out[-1500:]


def test_single_rgb_target_pulls_only_its_chain(default_config):
    plan = scenes.plan_scene(default_config["scenes"], 0, 0)
    t = plan["trajectories"][0]
    target = f"results/gt/s0000/{t['id']}/rgb/{t['source_light']}.json"
    counts = job_counts(dry_run(target).stdout)
    assert counts == {"generate_assets": 1, "curate_assets": 1, "curate_assets_shard": default_config["assets"]["curation_jobs"],
                      "sample_scene": 1, "render_rgb": 1}


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
    bad.write_text(yaml.safe_dump({"extends": str(REPO / "config" / "config.yaml"), **change}))
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


def test_make_bench_runs_or_names_every_benchmark():
    """Each benchmarks/*.py is either run by `make bench` (run_all.ORDER) or listed with the reason it is
    not (run_all.NOT_IN_BENCH), never both, never silently left out."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("run_all", REPO / "benchmarks" / "run_all.py")
    run_all = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(run_all)
    present = {p.stem for p in (REPO / "benchmarks").glob("*.py")} - {"run_all"}
    assert not set(run_all.ORDER) & set(run_all.NOT_IN_BENCH)
    assert present == set(run_all.ORDER) | set(run_all.NOT_IN_BENCH), present ^ (set(run_all.ORDER) | set(run_all.NOT_IN_BENCH))
    assert all(why.strip() for why in run_all.NOT_IN_BENCH.values())
    assert set(run_all.NEEDS_PIPELINE) <= set(run_all.ORDER)
