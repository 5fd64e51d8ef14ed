"""The shipped SLURM profile on a real one-node SLURM cluster (tests/slurm_cluster.py).

The tiny config (config/ci.yaml over config/config.yaml) runs through the executor plugin with
``--workflow-profile profiles/slurm`` up to the clean_buffers pairs and the refiner's training, so
CPU, Blender, Mitsuba, group, job-array and GPU jobs all go through sbatch. Overrides, each
because of the single test node only:

* ``--cores N`` with N = node CPUs / 2: caps threads (8 in the profile) and group width so that
  the node runs two jobs at once (on a 2-CPU machine N = 1; with N = 2 every render job took the
  whole node: 525 s instead of 380 s for the SLURM run on this 2-CPU machine under the same load);
* ``--resources mem_mb=M`` with M = node memory / 2 - 100 MB: caps per-job memory (16-128 GB in
  the profile) to half the node, for the same two jobs at once (the margin: the plugin adds a few
  MB to an array job's --mem for its task payload, and 2 x 12053 MB did not fit a 24105 MB node);
* ``--slurm-status-command squeue``: the test cluster has no accounting database for sacct;
* ``--slurm-init-seconds-before-status-checks 5``: first status check after 5 s, not 40 s.

Checked: jobs really ran under SLURM (SLURM's own job records and the job-completion log, and
Snakemake's "submitted with SLURM jobid" lines), each rule on its partition with a GPU only for
GPU rules, and the outputs equal those of a local run of the same config: byte-identical scene
specs, asset manifest and clean_buffers pairs.jsonl. Where SLURM cannot start the test skips
with the reason.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
import time

import pytest
import yaml

from slurm_cluster import LocalSlurm, SlurmUnavailable
from workflow_util import REPO, job_counts, venv_env

pytestmark = pytest.mark.slow
CI_CONFIG = str(REPO / "config" / "ci.yaml")
PROFILE = REPO / "profiles" / "slurm"
TARGETS = ["results/datasets/clean_buffers/pairs.jsonl", "results/refiner/clean_buffers/model.pt", "scene_specs"]
COMPARED = ["results/assets/manifest.json", "results/datasets/clean_buffers/pairs.jsonl"]


def snakemake_cmd(workdir, *args):
    return [sys.executable, "-m", "snakemake", "-d", str(workdir), "--configfile", CI_CONFIG, *args]


JOBS_AT_ONCE = 2  # the test node runs this many jobs side by side
ARRAY_MEM_MARGIN_MB = 100  # room for the plugin's per-array memory addition (apply_mem_fudge)


def threads_cap(cluster: LocalSlurm) -> int:
    return max(1, cluster.cpus // JOBS_AT_ONCE)


def single_node_overrides(cluster: LocalSlurm) -> list[str]:
    return [
        "--cores", str(threads_cap(cluster)),
        "--resources", f"mem_mb={cluster.mem_mb // JOBS_AT_ONCE - ARRAY_MEM_MARGIN_MB}",
        "--slurm-status-command", "squeue",
        "--slurm-init-seconds-before-status-checks", "5",
    ]


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
def runs(cluster, tmp_path_factory):
    """The SLURM run and, at the same time, a local run of the same config (to compare)."""
    slurm_dir, local_dir = tmp_path_factory.mktemp("on-slurm"), tmp_path_factory.mktemp("local")
    env = venv_env()
    t0 = time.perf_counter()
    # Local reference (default profile, 2 cores), concurrently: the SLURM run mostly waits.
    local_log = open(local_dir / "local-run.log", "w")
    local = subprocess.Popen(snakemake_cmd(local_dir, "--cores", "2", "scene_specs", COMPARED[1]),
                             cwd=REPO, env=env, stdout=local_log, stderr=subprocess.STDOUT)
    cmd = snakemake_cmd(slurm_dir, "--workflow-profile", str(PROFILE), *single_node_overrides(cluster), *TARGETS)
    res = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=1500)
    slurm_seconds = time.perf_counter() - t0
    local.wait(timeout=1500)
    local_log.close()
    wall = time.perf_counter() - t0
    assert res.returncode == 0, f"SLURM run failed:\n{res.stderr[-5000:]}\n{cluster.controller_log()[-3000:]}"
    assert local.returncode == 0, f"local run failed:\n{(local_dir / 'local-run.log').read_text()[-4000:]}"
    records = cluster.job_records()
    print(f"SLURM run: {slurm_seconds:.1f} s for {len(records)} SLURM jobs; local + SLURM wall {wall:.1f} s")
    return {"slurm_dir": slurm_dir, "local_dir": local_dir, "log": res.stderr, "records": records,
            "jobcomp": cluster.jobs(), "seconds": slurm_seconds}


def planned_jobs() -> dict[str, int]:
    """{rule: job count} of the targets, from a dry run with the same profile (empty workdir)."""
    import tempfile

    cmd = snakemake_cmd(tempfile.mkdtemp(prefix="dag-"), "-n", "--quiet", "rules",
                        "--workflow-profile", str(PROFILE), *TARGETS)
    res = subprocess.run(cmd, cwd=REPO, env=venv_env(), capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    return job_counts(res.stdout)


def profile() -> dict:
    return yaml.safe_load((PROFILE / "config.yaml").read_text())


def rule_of(record: dict) -> str:
    """Rule or group name from the plugin's job comment: 'rule_<rule>[_wildcards_<values>]' for
    a rule's job, 'rule_<group>_<member rules>' for a group job (returns the group)."""
    m = re.match(r"rule_(.+?)(?:_wildcards_.*)?$", record.get("Comment", ""))
    assert m, f"SLURM job {record.get('JobId')} has no Snakemake comment: {record}"
    name = m.group(1)
    for group in profile().get("group-components", {}):
        if name.startswith(group + "_"):
            return group
    return name


def test_every_job_ran_under_slurm(runs):
    planned = planned_jobs()
    prof = profile()
    groups = prof.get("groups", {})
    per_group = prof.get("group-components", {})
    # A group of k jobs with n components per submission is ceil(k / n) SLURM jobs.
    grouped: dict[str, int] = {}
    expected = 0
    for rule, n in planned.items():
        if rule in groups:
            grouped[groups[rule]] = grouped.get(groups[rule], 0) + n
        else:
            expected += n
    expected += sum(math.ceil(n / per_group.get(g, 1)) for g, n in grouped.items())
    # Target rules without an action run in the Snakemake process, not on SLURM.
    expected -= sum(planned.get(r, 0) for r in ("scene_specs",))

    records = runs["records"]
    assert len(records) == expected, (planned, [rule_of(r) for r in records])
    assert all(r["JobState"] == "COMPLETED" for r in records), [(r["JobId"], r["JobState"]) for r in records]
    # The job-completion log agrees: every SLURM job finished, with exit code 0.
    assert len(runs["jobcomp"]) == expected
    assert all(r["JobState"] == "COMPLETED" and r["ExitCode"] == "0:0" for r in runs["jobcomp"])
    # Snakemake's own log names a SLURM job id for every submission.
    submitted = re.findall(r"submitted with SLURM jobid (\d+)", runs["log"])
    array_submits = re.findall(r"SLURM job ID (\d+)\. The individual task IDs are (\d+)-(\d+)", runs["log"])
    n_tasks = len(submitted) + sum(int(b) - int(a) + 1 for _, a, b in array_submits)
    assert n_tasks == expected, runs["log"][-3000:]
    ran = {rule_of(r) for r in records}
    assert ran == {groups.get(r, r) for r in planned if r != "scene_specs"}
    print(f"{expected} SLURM jobs for {sum(planned.values())} Snakemake jobs: {planned}")


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
            assert minutes(rec["TimeLimit"]) == eval(str(rule_res["runtime"]), {"attempt": 1}), (name, rec["TimeLimit"])


def minutes(limit: str) -> int:
    """SLURM time limit '[D-]HH:MM:SS' in minutes."""
    days, _, hms = limit.rpartition("-")
    h, m, s = (int(x) for x in hms.split(":"))
    return int(days or 0) * 1440 + h * 60 + m + (s > 0)


def test_outputs_equal_a_local_run(runs):
    slurm_dir, local_dir = runs["slurm_dir"], runs["local_dir"]
    specs = sorted((local_dir / "results/scenes").glob("*/scene.json"))
    assert len(specs) == 3  # ci.yaml: 3 scenes (train, test, recon)
    for spec in specs:
        other = slurm_dir / spec.relative_to(local_dir)
        assert other.read_bytes() == spec.read_bytes(), spec.relative_to(local_dir)
    for rel in COMPARED:
        assert (slurm_dir / rel).read_bytes() == (local_dir / rel).read_bytes(), rel
    pairs = (slurm_dir / COMPARED[1]).read_text().splitlines()
    assert len(pairs) == 3  # the train scene's 3 trajectories, one target lighting each
    for p in map(json.loads, pairs):
        assert len(list((slurm_dir / p["proxy"]).glob("*.exr"))) == p["num_frames"]
    # The GPU rule ran too: the refiner trained on those pairs.
    assert (slurm_dir / "results/refiner/clean_buffers/model.pt").stat().st_size > 0
    assert "train_refiner: 30 steps" in (slurm_dir / "logs/refiner/train_clean_buffers.log").read_text()
