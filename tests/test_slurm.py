"""The rehearsal of the paper's run through the shipped SLURM profile on a real one-node SLURM cluster
(tests/slurm_cluster.py).

config/rehearsal.yaml (the paper config with only size keys shrunk; tests/test_rehearsal.py) runs, with
a stand-in site (tests/paper_site.py: a nested Objaverse-layout asset folder with one truncated GLB, a
PolyHaven HDRI, an ambientCG texture set, a DL3DV-layout folder of video frames, a MIT
Multi-Illumination scene) and the paper stack's tools as format stand-ins (tests/standin_tools.py:
MegaSAM's npz, DiffusionRenderer's JPEG passes, DiffusionLight's EXR; not reconstructions), to every
dataset variant and benchmark and the refiner's training (its tiny preset), with
``--workflow-profile profiles/slurm``. MegaSAM's stand-in fails on one synthetic clip and hangs on one
DL3DV clip (stopped by its timeout); a render job is cancelled with scancel once it has written some
frames. Overrides, each because of the single test node only:

* ``--cores N`` with N = node CPUs / 2: caps threads (8 in the profile) and group width so that the
  node runs two jobs at once;
* ``--resources mem_mb=M`` with M = node memory / 2 - 100 MB: caps per-job memory (16-128 GB in the
  profile) to half the node, for the same two jobs at once;
* ``--slurm-status-command squeue``: the test cluster has no accounting database for sacct;
* ``--slurm-init-seconds-before-status-checks 5``: first status check after 5 s, not 40 s.

Checked: every planned rule ran under SLURM (SLURM's own job records and the job-completion log, and
Snakemake's "submitted with SLURM jobid" lines), each on its partition with a GPU only for GPU rules;
the failing and the hanging clip were left out with one-line reasons and counted; the cancelled render
was retried and rendered only the frames it had not finished; the paper stack's clips are on the video's
grid with their tools' work removed; scene specs and the asset manifest equal a local run's byte for
byte. Where SLURM cannot start the test skips with the reason.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml

from paper_site import make_site, standin_commands
from slurm_cluster import LocalSlurm, SlurmUnavailable
from workflow_util import REPO, job_counts, venv_env

pytestmark = pytest.mark.slow
PROFILE = REPO / "profiles" / "slurm"
TARGETS = ["pairs", "results/refiner/full/model.pt"]
COMPARED = ["results/assets/manifest.json"]
FAILING_CLIP = "s0000_t2"                      # MegaSAM's stand-in exits 3 on this synthetic clip
DL3DV_SCENES = 3
NUM_FRAMES = 5                                 # config/rehearsal.yaml scenes.num_frames
TIMEOUTS = {"megasam": 20, "diffusion_renderer": 60, "diffusion_light": 60}
JOBS_AT_ONCE = 2  # the test node runs this many jobs side by side
MEM_MARGIN_MB = 100


def threads_cap(cluster: LocalSlurm) -> int:
    return max(1, cluster.cpus // JOBS_AT_ONCE)


def single_node_overrides(cluster: LocalSlurm) -> list[str]:
    return [
        "--cores", str(threads_cap(cluster)),
        "--resources", f"mem_mb={cluster.mem_mb // JOBS_AT_ONCE - MEM_MARGIN_MB}",
        "--slurm-status-command", "squeue",
        "--slurm-init-seconds-before-status-checks", "5",
    ]


def snakemake_cmd(workdir, site_file, *args):
    # --configfile last: it takes several values, so targets after it would be read as config files
    return [sys.executable, "-m", "snakemake", "-d", str(workdir), *args, "--configfile", site_file]


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    c = LocalSlurm(tmp_path_factory.mktemp("slurm"))
    try:
        c.start()
    except SlurmUnavailable as exc:
        print(f"SKIP: SLURM unavailable: {exc}")
        pytest.skip(f"SLURM unavailable: {exc}")
    print(f"SLURM: apt install {c.install_seconds:.1f} s, daemons up in {c.start_seconds:.1f} s, "
          f"node {c.node}: {c.cpus} CPUs, {c.mem_mb} MB, state in {c.root}")
    yield c
    c.stop()


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    s = make_site(tmp_path_factory.mktemp("rehearsal-site"), dl3dv_scenes=DL3DV_SCENES, mit_scenes=1, content=True,
                  extends=REPO / "config" / "rehearsal.yaml")
    cfg = yaml.safe_load(Path(s["site"]).read_text())
    cfg["recon"]["paper_stack"].update({"commands": standin_commands(sys.executable), "timeouts": TIMEOUTS})
    Path(s["site"]).write_text(yaml.safe_dump(cfg, sort_keys=False))
    return s


def planned_jobs(site_file, *extra) -> tuple[dict[str, int], str]:
    """({rule: job count}, dry-run text) of the targets in an empty working directory."""
    import tempfile

    res = subprocess.run(snakemake_cmd(tempfile.mkdtemp(prefix="dag-"), site_file, *TARGETS, "-n", *extra),
                         cwd=REPO, env=venv_env(), capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    return job_counts(res.stdout), res.stdout


def _kill_renders_midway(workdir: Path, stop: threading.Event, killed: list):
    """Once some render_rgb frame folder has some but not all of its frames, cancel (scancel) every
    running SLURM job that renders RGB (a group job's comment names its rules, not its wildcards, so
    the job writing that folder is among them); records the partial folders and their frame counts."""
    gt = workdir / "results" / "gt"
    while not stop.is_set() and not killed:
        partial = {}
        for d in gt.glob("*/*/rgb/L*"):
            n = len(list(d.glob("[0-9]*.exr")))
            if d.is_dir() and n >= 1 and not d.with_suffix(".json").exists():
                partial[d] = n
        if partial:
            q = subprocess.run(["squeue", "-h", "-t", "RUNNING", "-o", "%i|%k"], capture_output=True, text=True)
            jobs = [ln.split("|")[0].strip() for ln in q.stdout.splitlines() if "render_rgb" in ln.split("|")[-1]]
            if jobs:
                subprocess.run(["scancel", *jobs], capture_output=True)
                killed.append({"jobs": jobs, "partial": {str(d.relative_to(workdir)): n for d, n in partial.items()}})
                return
        time.sleep(0.05)


@pytest.fixture(scope="module")
def runs(cluster, site, tmp_path_factory):
    """The rehearsal on SLURM and, at the same time, a local run of its scene specs and asset manifest."""
    slurm_dir, local_dir = tmp_path_factory.mktemp("on-slurm"), tmp_path_factory.mktemp("local")
    _, plan = planned_jobs(site["site"])
    hung = sorted(set(re.findall(r"results/recon/real/([0-9a-f]{64}_c\d+)/buffers.json", plan)))[0]
    env = dict(venv_env(), STANDIN_FAIL=FAILING_CLIP, STANDIN_HANG=hung)
    local_log = open(local_dir / "local-run.log", "w")
    local = subprocess.Popen(snakemake_cmd(local_dir, site["site"], "--cores", "1", "scene_specs", *COMPARED),
                             cwd=REPO, env=env, stdout=local_log, stderr=subprocess.STDOUT)
    stop, killed = threading.Event(), []
    killer = threading.Thread(target=_kill_renders_midway, args=(slurm_dir, stop, killed), daemon=True)
    killer.start()
    t0 = time.perf_counter()
    cmd = snakemake_cmd(slurm_dir, site["site"], "--workflow-profile", str(PROFILE), *single_node_overrides(cluster), *TARGETS)
    res = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=2400)
    seconds = time.perf_counter() - t0
    stop.set()
    local.wait(timeout=600)
    local_log.close()
    assert res.returncode == 0, f"SLURM run failed:\n{res.stderr[-5000:]}\n{cluster.controller_log()[-3000:]}"
    assert local.returncode == 0, f"local run failed:\n{(local_dir / 'local-run.log').read_text()[-4000:]}"
    records = cluster.job_records()
    print(f"rehearsal on the test cluster: {seconds:.1f} s wall, {len(records)} SLURM jobs, "
          f"{len(re.findall('Finished job', res.stderr))} Snakemake jobs finished; cancelled: {killed}")
    return {"slurm_dir": slurm_dir, "local_dir": local_dir, "log": res.stderr, "records": records,
            "jobcomp": cluster.jobs(), "seconds": seconds, "killed": killed, "hung": hung}


def profile() -> dict:
    return yaml.safe_load((PROFILE / "config.yaml").read_text())


def rule_of(record: dict) -> str:
    """Rule or group name from the plugin's job comment: 'rule_<rule>[_wildcards_<values>]' for
    a rule's job, 'rule_<group>_<member rules>' for a group job (returns the group)."""
    m = re.match(r"rule_(.+?)(?:_wildcards_.*)?$", record.get("Comment", ""))
    assert m, f"SLURM job {record.get('JobId')} has no Snakemake comment: {record}"
    name = m.group(1)
    for group in sorted(profile().get("group-components", {}), key=len, reverse=True):  # proxy_gt before proxy
        if name.startswith(group + "_"):
            return group
    return name


def test_every_job_ran_under_slurm(runs, site):
    planned, _ = planned_jobs(site["site"], "--quiet", "rules")
    groups = profile().get("groups", {})
    records = runs["records"]
    states = [r["JobState"] for r in records]
    (k,) = runs["killed"]
    cancelled = states.count("CANCELLED")
    assert 1 <= cancelled <= len(k["jobs"]) and states.count("COMPLETED") == len(states) - cancelled, states
    # The job-completion log agrees, and Snakemake's own log names a SLURM job id for every submission.
    assert len(runs["jobcomp"]) == len(records)
    assert len(re.findall(r"submitted with SLURM jobid (\d+)", runs["log"])) == len(records)
    ran = {rule_of(r) for r in records}
    assert ran == {groups.get(r, r) for r in planned if r != "pairs"}, (ran, planned)
    # batching: fewer submissions than jobs
    assert len(records) - cancelled < sum(n for r, n in planned.items() if r != "pairs")
    for rule in ("curate_assets_shard", "render_rgb", "reconstruct_synthetic", "reconstruct_real", "fit_envmap",
                 "relight_mit", "ingest_video", "train_refiner"):
        assert planned.get(rule), rule
    print(f"{len(records)} SLURM jobs ({cancelled} cancelled) for {sum(planned.values())} Snakemake jobs: {planned}")


def test_partitions_threads_and_gpus_follow_the_profile(runs, cluster):
    prof = profile()
    res = prof["set-resources"]
    for rec in runs["records"]:
        name = rule_of(rec)
        rule_res = res.get(name, {})
        if name in prof.get("group-components", {}):  # a group: its member rules' settings
            rule_res = next(res[r] for r, g in prof["groups"].items() if g == name)
        assert rec["Partition"] == rule_res.get("slurm_partition", "cpu"), (name, rec["Partition"])
        gpu_request = rec.get("TresPerJob", "") + rec.get("TresPerNode", "")
        if rule_res.get("gpu"):
            assert "gpu" in gpu_request, (name, rec)
        else:
            assert "gpu" not in gpu_request, f"CPU rule {name} asked for a GPU: {rec}"
        threads = prof.get("set-threads", {}).get(name)
        if threads:  # capped to the node by --cores
            assert int(rec["NumCPUs"]) == min(threads, threads_cap(cluster)), (name, rec["NumCPUs"])
        if name in res:  # the runtime expression of attempt 1 became the SLURM time limit
            assert minutes(rec["TimeLimit"]) == eval(str(rule_res["runtime"]), {"attempt": 1, "min": min}), (name, rec["TimeLimit"])


def minutes(limit: str) -> int:
    """SLURM time limit '[D-]HH:MM:SS' in minutes."""
    days, _, hms = limit.rpartition("-")
    h, m, s = (int(x) for x in hms.split(":"))
    return int(days or 0) * 1440 + h * 60 + m + (s > 0)


def test_outputs_equal_a_local_run(runs):
    slurm_dir, local_dir = runs["slurm_dir"], runs["local_dir"]
    specs = sorted((local_dir / "results/scenes").glob("*/scene.json"))
    assert len(specs) == 2  # rehearsal: 2 scenes (train, test)
    for spec in specs:
        assert (slurm_dir / spec.relative_to(local_dir)).read_bytes() == spec.read_bytes(), spec.relative_to(local_dir)
    for rel in COMPARED:
        assert (slurm_dir / rel).read_bytes() == (local_dir / rel).read_bytes(), rel
    m = json.loads((slurm_dir / COMPARED[0]).read_text())
    assert len(m["accepted"]) == 5 and [r["reason"][:10] for r in m["rejected"]] == ["unreadable"]


def test_failing_and_hanging_tools_leave_their_clips_out_counted_and_a_killed_render_resumes(runs):
    wd = runs["slurm_dir"]
    # the cancelled render was retried and resumed: the retry rendered only the frames left undone
    (k,) = runs["killed"]
    for folder, n_done in k["partial"].items():
        scene, traj, _, light = Path(folder).parts[-4:]
        done = re.search(r"rendered (\d+) RGB frame", (wd / "logs" / "render_rgb" / f"{scene}_{traj}_{light}.log").read_text())
        assert done and int(done.group(1)) <= NUM_FRAMES - n_done, (folder, n_done, done and done.group(0))
        assert json.loads((wd / folder).with_suffix(".json").read_text())["num_frames"] == NUM_FRAMES
    # products: every training variant and benchmark, the refiner
    for v in ("full", "no_real", "no_synthetic", "clean_buffers"):
        assert (wd / "results" / "datasets" / v / "pairs.jsonl").read_text().strip(), v
    for b in ("synthetic", "real", "mit"):
        assert (wd / "results" / "benchmarks" / b / "pairs.jsonl").read_text().strip(), b
    assert (wd / "results" / "refiner" / "full" / "model.pt").stat().st_size > 0
    # the paper stack's clips: on the video's grid, the tools' work removed, MIT's one frame on the static path
    recon = wd / "results" / "recon"
    ok = [json.loads(p.read_text()) for p in recon.glob("*/*/buffers.json")]
    ok = [m for m in ok if "skipped" not in m]
    assert ok and all((m["width"], m["height"]) == (96, 64) for m in ok)
    assert not list(recon.glob("*/*/.work")) and not list(recon.glob("*/*/tool_grid"))
    mit = json.loads((recon / "real" / "mit_everett_kitchen0_d0" / "buffers.json").read_text())
    assert mit["camera_static"] and mit["num_frames"] == 1
    # the failing and the hanging clip: left out with a one-line reason naming the tool and its log, counted
    summary = json.loads((wd / "results" / "datasets" / "full" / "summary.json").read_text())
    reasons = {s["pair_id"]: s["reason"] for s in summary["skipped"]}
    fail = next(r for p, r in reasons.items() if p.startswith(FAILING_CLIP))
    hang = reasons[f"real_{runs['hung']}"]
    assert "megasam command failed (exit 3)" in fail and "megasam command timed out after 20 s" in hang
    for reason in (fail, hang):
        log_path = wd / reason.rsplit("see ", 1)[1]
        assert "\n" not in reason and log_path.is_file() and "tool_logs" in log_path.parts, reason
    assert summary["pairs"] == len((wd / "results" / "datasets" / "full" / "pairs.jsonl").read_text().splitlines())
    print(f"full: {summary['pairs']} pairs, {len(summary['skipped'])} left out: {sorted(reasons)}")
