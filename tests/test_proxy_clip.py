"""scripts/render_proxy.py end to end on a tiny clip, resumability, and bad inputs (one-line errors)."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lightcrafter.clip import write_clip
from lightcrafter.io import read_rgb_exr, write_buffers, write_exr, write_json, write_rgb_exr
from lightcrafter.proxy import synthetic as syn

REPO = Path(__file__).resolve().parents[1]
W, H, N = 24, 16, 3


def make_clip(root: Path, env: np.ndarray | None = None) -> tuple[Path, Path]:
    K = syn.intrinsics(W, H, 0.9)
    c2ws = [syn.look_at([2.5 * np.cos(a), 2.5 * np.sin(a), 1.5], [0, 0, 0.3]) for a in (0.0, 0.1, 0.2)]
    gt = root / "gt" / "s0000" / "t0"
    for i, c in enumerate(c2ws):
        write_buffers(gt / "buffers" / f"{i:04d}.exr", syn.raycast_buffers(K, c, W, H, [syn.Sphere((0, 0, 0.5), 0.5)]))
    write_clip(gt, serve=list(range(N)), K=[K] * N, c2w=c2ws, width=W, height=H, fps=24, camera_static=False,
               scene_static=True, units="metres", producer={"stage": "test"}, content_id="t0", consistent_depth=True,
               extra={"trajectory": "t0"})
    env_path = root / "env.exr"
    write_rgb_exr(env_path, np.full((8, 16, 3), 0.5, np.float32) if env is None else env)
    scene = root / "scenes" / "s0000" / "scene.json"
    write_json(scene, {"format": "lightcrafter.scene/1", "scene_id": "s0000", "num_frames": N, "fps": 24,
                       "lightings": [{"id": "L1", "hdri": str(env_path), "rotation_z_rad": 0.3, "strength": 1.0}],
                       "trajectories": [{"id": "t0", "motion": "orbit_static",
                                         "frames": [{"light_rotation_z_rad": 0.0}] * N}]})
    return gt, scene


def run(gt, scene, out, *extra, repo: Path = REPO):
    return subprocess.run([sys.executable, str(repo / "scripts" / "render_proxy.py"), "--clip", str(gt),
                           "--scene", str(scene), "--light", "L1", "--traj", "t0", "--out", str(out), "--proxy", '{"spp": 2}',
                           *extra],
                          capture_output=True, text=True, timeout=300)


@pytest.mark.slow
def test_cli_renders_every_frame_then_resumes(tmp_path):
    gt, scene = make_clip(tmp_path)
    out = tmp_path / "proxy_gt" / "s0000" / "t0" / "L1"
    p = run(gt, scene, out)
    assert p.returncode == 0, p.stderr
    man = json.loads(out.with_suffix(".json").read_text())
    assert man["num_frames"] == N and man["frames"] == [f"L1/{i:04d}.exr" for i in range(N)]
    assert out.with_suffix(".mp4").stat().st_size > 0
    frames = [read_rgb_exr(out / f"{i:04d}.exr") for i in range(N)]
    assert all(f.shape == (H, W, 3) and np.isfinite(f).all() for f in frames)
    # rerun: complete frames are reused, nothing re-rendered
    (out.with_suffix(".json")).unlink()
    p = run(gt, scene, out)
    assert p.returncode == 0, p.stderr
    assert json.loads(out.with_suffix(".json").read_text())["stats"]["frames"] == 0


@pytest.mark.slow
def test_a_rerun_after_the_renderer_changed_renders_every_frame_again(tmp_path):
    """Frames are resumed only when the code that renders them is the same: after an edit of the renderer the
    workflow reruns the job (its code fingerprint changed), and the job must not keep the old code's frames,
    which match the new job's inputs in everything but the code (lightcrafter.io.CODE_VERSION)."""
    import shutil

    repo = tmp_path / "repo"
    for d in ("scripts", "lightcrafter"):
        shutil.copytree(REPO / d, repo / d, ignore=shutil.ignore_patterns("__pycache__", "*.pt", "*.npz"))
    gt, scene = make_clip(tmp_path)
    out = tmp_path / "proxy" / "L1"
    manifest = out.with_suffix(".json")
    assert run(gt, scene, out, repo=repo).returncode == 0
    manifest.unlink()
    p = run(gt, scene, out, repo=repo)  # same code: every frame resumed
    assert p.returncode == 0, p.stderr
    assert json.loads(manifest.read_text())["stats"]["frames"] == 0
    renderer = repo / "lightcrafter" / "proxy" / "renderer.py"
    renderer.write_text(renderer.read_text() + "\n_EDITED = True\n")  # a code change, not a docstring's
    manifest.unlink()
    p = run(gt, scene, out, repo=repo)
    assert p.returncode == 0, p.stderr
    assert json.loads(manifest.read_text())["stats"]["frames"] == N, "frames of the old renderer were kept"


def _assert_clean_failure(p, out, name):
    assert p.returncode == 1
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and name in lines[0], p.stderr
    assert not out.with_suffix(".json").exists() and not out.with_suffix(".mp4").exists()
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.slow
@pytest.mark.parametrize("case", ["shape", "channel", "env_nan", "env_negative", "cameras_count"])
def test_bad_input_is_one_line_naming_the_file(tmp_path, case):
    env = None
    if case == "env_nan":
        env = np.full((8, 16, 3), 0.5, np.float32)
        env[2, 3, 1] = np.nan
    if case == "env_negative":
        env = np.full((8, 16, 3), 0.5, np.float32)
        env[2, 3, 1] = -1.0
    gt, scene = make_clip(tmp_path, env)
    bad = gt / "buffers" / "0001.exr"
    name = {"env_nan": "env.exr", "env_negative": "env.exr", "shape": "0001.exr", "channel": "0001.exr",
            "cameras_count": "cameras.json"}[case]
    if case == "shape":
        write_buffers(bad, syn.raycast_buffers(syn.intrinsics(W + 2, H, 0.9), syn.look_at([2, 2, 1], [0, 0, 0]), W + 2, H))
    if case == "channel":
        write_exr(bad, {"depth": np.ones((H, W), np.float32)})
    if case == "cameras_count":
        cams = json.loads((gt / "cameras.json").read_text())
        cams["frames"] = cams["frames"][:2]
        (gt / "cameras.json").write_text(json.dumps(cams))
    out = tmp_path / "proxy_gt" / "L1"
    _assert_clean_failure(run(gt, scene, out), out, name)


@pytest.mark.slow
def test_proxy_vs_cycles_reads_the_pipeline_layout(tmp_path):
    """benchmarks/proxy_vs_cycles.py on the pipeline's directory layout: bench JSON shape, PSNR per motion."""
    gt, scene = make_clip(tmp_path)
    for i in range(N):  # stand-in "Cycles" frames: mid grey
        write_rgb_exr(gt / "rgb" / "L1" / f"{i:04d}.exr", np.full((H, W, 3), 0.2, np.float32))
    write_json(gt / "rgb" / "L1.json", {"frames": [f"rgb/L1/{i:04d}.exr" for i in range(N)],
                                        "render": {"spp": 16, "max_bounces": 4}})
    out = tmp_path / "bench.json"
    p = subprocess.run([sys.executable, str(REPO / "benchmarks" / "proxy_vs_cycles.py"), "--results", str(tmp_path),
                        "--logs", str(tmp_path / "logs"), "--out", str(out), "--spp", "2"],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    res = json.loads(out.read_text())
    for key in ("name", "varied", "metric", "higher_is_better", "machine", "chosen", "points"):
        assert key in res
    assert res["points"][0]["setting"] == "orbit_static" and np.isfinite(res["points"][0]["value"])
    assert len(res["clips"][0]["psnr_db_per_frame"]) == N


def test_proxy_spp_benchmark_times_r_and_cycles_in_interleaved_rounds(tmp_path):
    """benchmarks/proxy_spp.py at a tiny size: both renderers' spp ladders are timed once per round, R then
    Cycles, and each speed ratio is the median of the per-round ratios with their range."""
    out = tmp_path / "proxy_spp.json"
    p = subprocess.run([sys.executable, str(REPO / "benchmarks" / "proxy_spp.py"), "--out", str(out), "--width", "32",
                        "--height", "24", "--spp", "1", "4", "16", "--cycles-spp", "1", "4", "16", "--ref-spp", "256",
                        "--cycles-ref-spp", "128", "--rounds", "3"], capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    assert [ln.split(":")[0] for ln in p.stdout.splitlines() if ln.startswith("round")] == \
        ["round 1/3", "round 2/3", "round 3/3"]
    res = json.loads(out.read_text())
    assert res["rounds"] == 3 and [q["setting"] for q in res["points"]] == [1, 4, 16]
    for key in ("speed_ratio_at_equal_error", "speed_ratio_at_equal_noise"):
        sr = res[key]
        assert len(sr["per_round"]) == 3
        best = sr["ratio_at_common_best"]
        per = [r["common_best"] for r in sr["per_round"]]
        assert None not in per
        per.sort()
        assert best["n"] == 3 and best["median"] == round(per[1], 2) and (best["min"], best["max"]) == \
            (round(per[0], 2), round(per[-1], 2))
