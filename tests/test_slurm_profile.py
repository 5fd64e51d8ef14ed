"""The SLURM profile (profiles/slurm/config.yaml) without a cluster: names, classes, retries.

Fast checks that keep the profile valid while the workflow grows: every rule it names exists
(``snakemake --list-rules``), every rule that runs a job has a line, GPU requests go only to GPU
rules and only the way plugin 2.6 accepts them, and runtimes grow with each retry when Snakemake
itself evaluates them. The real cluster run is tests/test_slurm.py.
"""

from __future__ import annotations

import io
import re
import subprocess
import sys

import pytest
import yaml

from workflow_util import REPO, venv_env

PROFILE = REPO / "profiles" / "slurm" / "config.yaml"
ACTIONS = ("shell", "run", "script", "notebook", "wrapper", "cwl", "template_engine")
GPU_KEYS = ("gpu", "gpu_model", "gres", "cpus_per_gpu", "tasks_per_gpu")


def profile() -> dict:
    return yaml.safe_load(PROFILE.read_text())


@pytest.fixture(scope="module")
def workflow_rules() -> set[str]:
    res = subprocess.run([sys.executable, "-m", "snakemake", "--list-rules"], cwd=REPO, capture_output=True,
                         text=True, timeout=120, env=venv_env())
    assert res.returncode == 0, res.stderr[-2000:]
    return {line.strip() for line in res.stdout.splitlines() if re.fullmatch(r"\w+", line.strip())}


def rule_blocks() -> dict[str, str]:
    """{rule name: its source block} from the Snakefile and workflow/rules/*.smk."""
    blocks = {}
    for f in [REPO / "Snakefile", *sorted((REPO / "workflow" / "rules").glob("*.smk"))]:
        text = f.read_text()
        for m in re.finditer(r"^rule (\w+):\n((?:[ \t]+.*\n|\n)*)", text, flags=re.M):
            blocks[m.group(1)] = m.group(2)
    return blocks


def job_rules(blocks: dict[str, str]) -> set[str]:
    """Rules that run something (target-only rules such as `all` never reach SLURM)."""
    return {
        name for name, body in blocks.items()
        if any(re.search(rf"^\s+{a}:", body, flags=re.M) for a in ACTIONS)
        and not re.search(r"^\s+localrule:\s*True", body, flags=re.M)
    }


def named_rules(prof: dict) -> dict[str, set[str]]:
    arrays = prof.get("slurm-array-jobs") or ""
    return {
        "set-resources": set(prof.get("set-resources", {})),
        "set-threads": set(prof.get("set-threads", {})),
        "groups": set(prof.get("groups", {})),
        "slurm-array-jobs": {r.strip() for r in re.split(r"[,;]", arrays) if r.strip() and r.strip() != "all"},
    }


def test_every_rule_named_in_the_profile_exists(workflow_rules):
    for key, names in named_rules(profile()).items():
        unknown = names - workflow_rules
        assert not unknown, f"profiles/slurm/config.yaml {key} names rules that do not exist: {sorted(unknown)}"


def test_rule_parser_sees_every_rule(workflow_rules):
    assert set(rule_blocks()) == workflow_rules


def test_every_job_rule_has_a_profile_line(workflow_rules):
    missing = job_rules(rule_blocks()) - set(profile()["set-resources"])
    assert not missing, (
        f"rules without a line in profiles/slurm/config.yaml set-resources: {sorted(missing)}; add "
        "`NAME: {slurm_partition: cpu, mem_mb: M, runtime: \"T*attempt\"}` (GPU rules: slurm_partition: gpu, gpu: 1)"
    )


def test_gpus_only_for_gpu_rules_and_the_way_the_plugin_accepts():
    from snakemake_executor_plugin_slurm.validation import get_forbidden_slurm_options

    prof = profile()
    assert not set(GPU_KEYS) & set(prof.get("default-resources", {})), "a default GPU would reach CPU rules"
    forbidden = get_forbidden_slurm_options()
    gpu_rules = set()
    for rule, res in prof["set-resources"].items():
        extra = str(res.get("slurm_extra", ""))
        bad = [name for pattern, name in forbidden.items() if re.search(pattern, extra)]
        assert not bad, f"{rule}: slurm_extra sets {bad}, which plugin 2.6 rejects; use resources"
        if res.get("gpu") or "gpu" in str(res.get("gres", "")):
            gpu_rules.add(rule)
            assert res.get("slurm_partition") == "gpu", rule
        else:
            assert not set(GPU_KEYS) & set(res), f"CPU rule {rule} asks for a GPU"
            assert res.get("slurm_partition", prof["default-resources"]["slurm_partition"]) == "cpu", rule
    assert {"train_refiner", "infer_refiner"} <= gpu_rules
    assert not {"render_buffers", "render_rgb", "render_proxy_gt", "sample_scene"} & gpu_rules


def test_runtimes_grow_with_each_retry_as_snakemake_evaluates_them():
    """The profile's strings go through Snakemake's own profile parser and resource evaluator."""
    from snakemake.cli import parse_set_resources
    from snakemake.profiles import ProfileConfigFileParser

    stream = io.StringIO(PROFILE.read_text())
    stream.name = str(PROFILE)
    items = ProfileConfigFileParser().parse(stream)
    parsed = parse_set_resources(items["set-resources"])
    retries = int(profile()["retries"])
    assert retries >= 1
    for rule, resources in parsed.items():
        rt = resources["runtime"]
        values = [rt.evaluate(wildcards={}, input=[], attempt=a, threads=1, rulename=rule, async_run=None).value
                  for a in range(1, retries + 2)]
        assert all(isinstance(v, int) and v > 0 for v in values), (rule, values)
        assert values[1] > values[0], f"{rule}: runtime does not grow on retry: {values}"


def test_a_retry_gets_the_longer_runtime(tmp_path):
    """A job that fails once is retried by Snakemake 9 with the profile's runtime for attempt 2.

    A toy workflow whose only rule is named like a profile rule runs with the shipped profile
    (local executor): attempt 1 fails, attempt 2 writes the runtime it was given.
    """
    prof = profile()
    rule = "render_rgb"
    expr = prof["set-resources"][rule]["runtime"]
    (tmp_path / "Snakefile").write_text(
        f"rule {rule}:\n"
        "    output: 'runtime.txt'\n"
        "    resources: runtime=1\n"
        "    shell: \"test -e tried || {{ touch tried; exit 1; }}; echo {resources.runtime} > {output}\"\n"
    )
    res = subprocess.run(
        [sys.executable, "-m", "snakemake", "-s", str(tmp_path / "Snakefile"), "-d", str(tmp_path),
         "--workflow-profile", str(PROFILE.parent), "--executor", "local", "--cores", "1"],
        cwd=tmp_path, capture_output=True, text=True, timeout=120, env=venv_env(),
    )
    assert res.returncode == 0, res.stderr[-3000:]
    got = int((tmp_path / "runtime.txt").read_text())
    assert got == eval(expr, {"attempt": 2}) and got > eval(expr, {"attempt": 1}), (expr, got)


BLENDER_RULES = ("render_buffers", "render_rgb", "longform_buffers", "longform_rgb")


def dry_run_jobs(*extra, target="results/eval/clean_buffers/synthetic/metrics.json") -> tuple[str, dict[str, list[str]]]:
    """Dry run of the ci config under the profile: (stdout, {rule: [job body, ...]})."""
    import tempfile

    res = subprocess.run(
        [sys.executable, "-m", "snakemake", "-n", "--workflow-profile", str(PROFILE.parent),
         "--configfile", str(REPO / "config" / "ci.yaml"), "-d", tempfile.mkdtemp(prefix="dag-"), target, *extra],
        cwd=REPO, capture_output=True, text=True, timeout=300, env=venv_env(),
    )
    assert res.returncode == 0, res.stderr[-3000:]
    jobs: dict[str, list[str]] = {}
    lines = res.stdout.splitlines()
    for i, line in enumerate(lines):
        m = re.match(r"^(\s*)rule (\w+):$", line)
        if m:
            body = []
            for nxt in lines[i + 1:]:
                if len(nxt) - len(nxt.lstrip()) <= len(m.group(1)):
                    break
                body.append(nxt)
            jobs.setdefault(m.group(2), []).append("\n".join(body))
    return res.stdout, jobs


def job_resources(body: str) -> dict[str, str]:
    return dict(re.findall(r"(\w+)=([^,\n]+)", re.search(r"resources: (.*)", body).group(1)))


def test_a_gpu_render_device_sends_blender_rules_to_the_gpu_partition():
    """render.device: optix (or cuda) puts every Blender job on the gpu partition with one GPU; the
    Mitsuba and CPU rules stay on the cpu partition without one."""
    _, jobs = dry_run_jobs("--config", "render={device: optix}")
    gpu_rules = {r for r, v in profile()["set-resources"].items() if v.get("gpu")}
    for rule, bodies in jobs.items():
        for body in bodies:
            res = job_resources(body)
            if rule in BLENDER_RULES:
                assert res["slurm_partition"] == "gpu" and res.get("gpu") == "1", (rule, res)
            elif rule not in gpu_rules:
                assert res["slurm_partition"] == "cpu" and "gpu" not in res, (rule, res)
    assert {"render_buffers", "render_rgb"} <= set(jobs)


def test_dry_run_with_the_profile_assigns_partitions_and_gpus():
    """Snakemake's view of each job under the profile (ci config): partition, GPU, threads."""
    stdout, _ = dry_run_jobs()
    res = type("R", (), {"stdout": stdout})
    prof = profile()
    seen = set()
    lines = res.stdout.splitlines()
    for i, line in enumerate(lines):
        m = re.match(r"^(\s*)rule (\w+):$", line)
        if not m:
            continue
        indent, rule = len(m.group(1)), m.group(2)
        body = []
        for nxt in lines[i + 1:]:
            if len(nxt) - len(nxt.lstrip()) <= indent:
                break
            body.append(nxt)
        body = "\n".join(body)
        resources = dict(re.findall(r"(\w+)=([^,\n]+)", re.search(r"resources: (.*)", body).group(1)))
        want = prof["set-resources"][rule]
        assert resources["slurm_partition"] == want.get("slurm_partition", prof["default-resources"]["slurm_partition"]), rule
        assert resources.get("gpu") == (str(want["gpu"]) if "gpu" in want else None), rule
        assert int(resources["mem_mb"]) == want["mem_mb"], rule
        threads = re.search(r"threads: (\d+)", body)
        assert int(threads.group(1) if threads else 1) == min(prof.get("set-threads", {}).get(rule, 1), prof["cores"]), rule
        seen.add(rule)
    assert {"render_rgb", "render_proxy_gt", "train_refiner", "infer_refiner", "sample_scene"} <= seen
    for rule, group in prof.get("groups", {}).items():
        if rule in seen:
            assert f"Group job {group} " in res.stdout, f"{rule} not grouped as {group}"


def test_no_slurm_job_arrays():
    """Plugin 2.6-2.7 array tasks check the first task's outputs (issue #447; shown on the test cluster):
    the profile batches with groups instead."""
    prof = profile()
    assert not prof.get("slurm-array-jobs"), "job arrays fail every task whose first task fails or finishes late"
    assert {"render_rgb", "reconstruct_real", "fit_envmap", "ingest_video", "curate_assets_shard"} <= set(prof["groups"])
