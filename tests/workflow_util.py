"""Run Snakemake dry-runs from tests and read the per-rule job counts."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SNAKEMAKE = [sys.executable, "-m", "snakemake"]


def dry_run(*targets: str, configfile: str | None = None, extra: tuple[str, ...] = (),
            workdir: str | Path | None = None, quiet: bool = True) -> subprocess.CompletedProcess:
    """``snakemake -n TARGETS --quiet rules`` in an empty working directory (nothing built yet), or in
    ``workdir`` (what a finished run would redo); ``quiet=False`` lists every job with its outputs."""
    import tempfile

    wd = str(workdir) if workdir is not None else tempfile.mkdtemp(prefix="dag-")
    cmd = [*SNAKEMAKE, "-n", *targets, *(["--quiet", "rules"] if quiet else []), "--cores", "1", "-d", wd]
    if configfile:
        cmd += ["--configfile", str((REPO / configfile).resolve())]
    cmd += list(extra)
    return subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=300, env=venv_env())


def venv_env() -> dict:
    """Environment whose PATH starts with this interpreter's bin/ (rules call ``python``)."""
    import os

    env = dict(os.environ)
    env["PATH"] = str(Path(sys.executable).parent) + os.pathsep + env.get("PATH", "")
    return env


def dry_run_outputs(*targets: str) -> str:
    """A verbose dry run's text: every planned job with its output paths."""
    import tempfile

    cmd = [*SNAKEMAKE, "-n", *targets, "--cores", "1", "-d", tempfile.mkdtemp(prefix="dag-")]
    return subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=300, env=venv_env()).stdout


def job_counts(output: str) -> dict[str, int]:
    """Parse the 'Job stats' table of a dry run into {rule: count} (without 'total')."""
    counts: dict[str, int] = {}
    lines = output.splitlines()
    try:
        start = next(i for i, l in enumerate(lines) if l.strip() == "Job stats:")
    except StopIteration:
        raise AssertionError(f"no job stats in snakemake output:\n{output[-2000:]}")
    for line in lines[start + 3:]:
        m = re.match(r"^(\S+)\s+(\d+)$", line.strip())
        if not m:
            break
        if m.group(1) != "total":
            counts[m.group(1)] = int(m.group(2))
    return counts
