"""Kill the tiny workflow (config/ci.yaml) inside its long stages, rerun, and compare with an uninterrupted run.

Kill points (SIGKILL to Snakemake's whole process group, as a node failure would): inside a Cycles
render, inside the forward renderer R, inside the reconstruction stack Phi, inside envmap fitting and
inside refiner training. Each is detected from the files the stage leaves while it runs (a first frame
without its manifest, Phi's log without its clip, a fit checkpoint or log without its manifest, a
training checkpoint without the model). Snakemake's scheduler may take the stages in any order the DAG
allows (R's jobs can all come after Phi's, envmap fitting before or after both), so each run is killed
at whichever stage not yet hit is seen running first. After every kill the same command is rerun; at the end the
products are compared with the uninterrupted run of tests/test_pipeline_e2e.py: byte-identical scene
specs, asset manifest, ground-truth clip manifests and pair manifests; Phi's manifests and all frames
within the bounds of engines that are not bit-reproducible (see NEAR below).

The killed run builds one target, the full variant's trained refiner (TARGET): every kill point lies on
its path (Cycles for the train and recon scenes, the estimator, Phi, R, the real clip's envmap fit,
training), and it leaves out what the uninterrupted run adds after training (the test scene's renders,
inference, evaluation, long form, edits, report), which would rerun the same rules a second time.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from workflow_util import REPO, venv_env

pytestmark = pytest.mark.slow
CI_CONFIG = str(REPO / "config" / "ci.yaml")
TARGET = "results/refiner/full/model.pt"


def _running(wd: Path, point: str, since: float) -> bool:
    """Whether ``point``'s stage is running: its in-progress file exists, was written at or after ``since``
    (seconds since the epoch; a file a killed run left behind does not count) and its stage is not done."""
    r = wd / "results"

    def new(f: Path) -> bool:
        try:
            return f.stat().st_mtime >= since
        except FileNotFoundError:  # removed by the stage or by Snakemake meanwhile
            return False

    if point == "cycles":
        return any(new(f) and not (f.parent.parent / f"{f.parent.name}.json").exists()
                   for f in r.glob("gt/*/*/rgb/*/0000.exr"))
    if point == "proxy":
        return any(new(f) and not (f.parent.parent / f"{f.parent.name}.json").exists()
                   for f in r.glob("proxy*/*/*/*/0000.exr"))
    if point == "phi":
        recon = r / "recon" / "synthetic"
        return any(new(log) and not (recon / log.stem.removeprefix("synthetic_") / "buffers.json").exists()
                   for log in (wd / "logs" / "recon").glob("synthetic_*.log"))
    if point == "envfit":
        return any(new(log) and not (log.parent.parent.parent / "results" / "envfit" / log.stem / "fit.json").exists()
                   for log in (wd / "logs" / "envfit").glob("*.log"))
    if point == "training":
        return any(new(d / "checkpoints" / "latest.txt") and not (d / "model.pt").exists()
                   for d in r.glob("refiner/*"))
    raise ValueError(point)


def _run_until(wd: Path, points: list[str], timeout_s: float = 2400) -> tuple[str, str | None, float]:
    """Run TARGET; SIGKILL the process group as soon as one of ``points`` is running. Returns
    ('killed' | 'finished' | 'failed: ...', the point killed at or None, seconds)."""
    base = [sys.executable, "-m", "snakemake", "--cores", "2", "-d", str(wd), TARGET]
    tail = ["--configfile", CI_CONFIG]  # last: it takes several values
    cmd = base + tail
    if (wd / ".snakemake" / "locks").is_dir() and any((wd / ".snakemake" / "locks").iterdir()):
        # a SIGKILLed Snakemake cannot release its lock; the documented recovery is --unlock, then the same command
        subprocess.run(base + ["--unlock"] + tail, cwd=REPO, env=venv_env(), check=True, capture_output=True)
    since = time.time() - 1.0  # file times may be rounded down
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, cwd=REPO, env=venv_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                         start_new_session=True)
    while p.poll() is None:
        hit = next((point for point in points if _running(wd, point, since)), None)
        if hit:
            time.sleep(0.5)  # let it write a little more
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()
            return "killed", hit, time.perf_counter() - t0
        if time.perf_counter() - t0 > timeout_s:
            os.killpg(p.pid, signal.SIGKILL)
            return "failed: timeout", None, time.perf_counter() - t0
        time.sleep(0.2)
    err = p.stderr.read().decode()[-3000:]
    return ("finished" if p.returncode == 0 else f"failed: exit {p.returncode}: {err}"), None, time.perf_counter() - t0


KILL_POINTS = ["cycles", "proxy", "phi", "envfit", "training"]


DETERMINISTIC = ["scenes/*/scene.json", "assets/manifest.json", "gt/*/*/buffers.json", "datasets/*/pairs.jsonl",
                 "benchmarks/*/pairs.jsonl", "real/*/rgb.json"]
# Cycles (with OIDN) and Mitsuba are not bit-reproducible between two runs on this machine: frames of
# the same job differ in the last float bits (measured: Cycles radiance at most 9.3e-3 absolute on a
# 4.6 radiance, 2.6e-5 on ordinary pixels; R from ground-truth buffers at most 1.8e-6). Phi trains on
# those frames, so its manifests (content ids, per-frame depth fits, poses) and its proxies carry
# that difference: they are compared within these bounds.
NEAR = ["recon/*/*/buffers.json", "aligned/*/*/buffers.json"]
NEAR_ATOL, NEAR_RTOL = 1e-3, 1e-3  # numbers of Phi's manifests (observed: at most 4e-5 absolute)
# An angle in degrees (a key ending in _deg) gets the tolerance of the unit vectors it comes from, NEAR_ATOL
# radians (observed: the ground plane's normal 0.005 deg apart between two runs, so its turned_deg too)
NEAR_DEG_ATOL = float(np.degrees(NEAR_ATOL))
# Pixel and point counts (sky pixels cut, mask pixels GrabCut took off, SfM points) move by whole pixels where a
# threshold meets the last bits of a depth (observed: 7783 vs 7768 sky pixels cut on s0000_t0, 0.2 %; 61 vs 60
# and 57 vs 54 in other runs); a count within 1 % or 5 is the same. Only these keys are such counts; every other integer (sizes, frame
# counts, settings) must be equal.
COUNT_RTOL, COUNT_ATOL = 1e-2, 5
COUNT_KEYS = frozenset({"sky_pixels_cut", "hole_pixels_filled", "mask_pixels_removed", "points"})


def _assert_json_near(a, b, where: str) -> None:
    """Same structure and strings (content ids aside), integers equal (the counts of COUNT_KEYS within
    COUNT_RTOL or COUNT_ATOL), other numbers within NEAR_ATOL (NEAR_DEG_ATOL for degrees) + NEAR_RTOL * |a|."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), f"{where}: keys differ"
        for k in a:
            if k != "content_id":  # a fingerprint of the input frames, which differ in the last bits
                _assert_json_near(a[k], b[k], f"{where}/{k}")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), f"{where}: lengths differ"
        for i, (x, y) in enumerate(zip(a, b)):
            _assert_json_near(x, y, f"{where}[{i}]")
    elif isinstance(a, int) and isinstance(b, int) and not isinstance(a, bool):
        if where.rsplit("/", 1)[-1] in COUNT_KEYS:
            assert abs(a - b) <= max(COUNT_ATOL, COUNT_RTOL * abs(a)), f"{where}: count {a} vs {b}"
        else:
            assert a == b, f"{where}: {a} vs {b} (an integer that is not a pixel or point count must not change)"
    elif isinstance(a, (int, float)) and not isinstance(a, bool):
        atol = NEAR_DEG_ATOL if where.rsplit("/", 1)[-1].endswith("_deg") else NEAR_ATOL
        assert abs(a - b) <= atol + NEAR_RTOL * abs(a), f"{where}: {a} vs {b}"
    else:
        assert a == b, f"{where}: {a!r} vs {b!r}"


def test_killed_runs_resume_to_the_uninterrupted_result(e2e_run, tmp_path_factory):
    wd = tmp_path_factory.mktemp("killed")
    outcomes = {}
    pending = list(KILL_POINTS)
    for _ in range(len(KILL_POINTS) + 1):  # at most one kill per point, then the run that finishes
        status, point, sec = _run_until(wd, pending)
        print(f"run {len(outcomes) + 1}: {status} at {point} after {sec:.1f} s", flush=True)
        assert not status.startswith("failed"), status
        if status == "finished":
            outcomes["final"] = (status, round(sec, 1))
            break
        pending.remove(point)
        outcomes[point] = (status, round(sec, 1))
    assert outcomes.get("final", ("",))[0] == "finished", outcomes
    hit = [p for p, (s, _) in outcomes.items() if s == "killed"]
    assert len(hit) >= 4, f"only {hit} kill points were hit: {outcomes}"
    # training resumed from its checkpoint rather than restarting
    if "training" in hit:
        logs = "".join(f.read_text() for f in (wd / "results" / "refiner").glob("*/train.log"))
        assert "resumed from" in logs
    ref = e2e_run / "results"
    got = wd / "results"

    def pairs(pattern: str):
        """(killed run's file, uninterrupted run's file) for every product of the killed run's target."""
        for g in sorted(got.glob(pattern)):
            f = ref / g.relative_to(got)
            assert f.is_file(), f"{g.relative_to(got)}: made by the killed runs but not by the uninterrupted one"
            yield g, f

    compared = 0
    for pattern in DETERMINISTIC:
        for g, f in pairs(pattern):
            assert g.read_bytes() == f.read_bytes(), f"{f.relative_to(ref)} differs from the uninterrupted run"
            compared += 1
    # the target's inputs: 2 scene specs, the asset manifest, 6 buffer manifests, the pairs, the real clip
    assert compared >= 10, compared
    import json

    near = 0
    for pattern in NEAR:
        for g, f in pairs(pattern):
            _assert_json_near(json.loads(f.read_text()), json.loads(g.read_text()), str(f.relative_to(ref)))
            near += 1
    assert near >= 6
    from lightcrafter.io import read_rgb_exr

    frames = 0
    for g, f in pairs("gt/*/*/rgb/*/*.exr"):  # Cycles: see the bounds above
        np.testing.assert_allclose(read_rgb_exr(g), read_rgb_exr(f), rtol=1e-2, atol=1e-4)
        frames += 1
    for g, f in pairs("proxy/*/*/*/*.exr"):  # R from Phi's buffers: edges may move, the frame may not
        d = np.abs(read_rgb_exr(g) - read_rgb_exr(f))
        assert float(d.mean()) < 1e-3, f"{f.relative_to(ref)}: mean difference {d.mean():.2e}"
        frames += 1
    assert frames > 50
    # nothing half-written is left where a rule would trust it
    assert not list(got.rglob(".*.tmp*"))


def test_manifest_comparison_allows_a_moved_pixel_count_but_not_a_changed_size():
    _assert_json_near({"phi": {"sky_pixels_cut": 7783, "points": 653}},
                      {"phi": {"sky_pixels_cut": 7768, "points": 650}}, "m")
    _assert_json_near({"phi": {"sky_pixels_cut": 61}}, {"phi": {"sky_pixels_cut": 60}}, "m")
    _assert_json_near({"phi": {"sky_pixels_cut": 57}}, {"phi": {"sky_pixels_cut": 54}}, "m")
    with pytest.raises(AssertionError, match="count"):
        _assert_json_near({"phi": {"sky_pixels_cut": 7783}}, {"phi": {"sky_pixels_cut": 7000}}, "m")
    with pytest.raises(AssertionError, match="count"):
        _assert_json_near({"phi": {"sky_pixels_cut": 61}}, {"phi": {"sky_pixels_cut": 54}}, "m")
    # an angle in degrees: the tolerance of the unit vectors it comes from (1e-3 rad), not 1e-3 deg
    _assert_json_near({"ground_plane": {"turned_deg": 0.132}}, {"ground_plane": {"turned_deg": 0.127}}, "m")
    with pytest.raises(AssertionError, match="turned_deg"):
        _assert_json_near({"ground_plane": {"turned_deg": 0.132}}, {"ground_plane": {"turned_deg": 0.232}}, "m")
    with pytest.raises(AssertionError, match="offset"):
        _assert_json_near({"ground_plane": {"offset": 0.132}}, {"ground_plane": {"offset": 0.127}}, "m")
    for key in ("width", "frames", "registered"):
        with pytest.raises(AssertionError, match="must not change"):
            _assert_json_near({key: 192}, {key: 191}, "m")
