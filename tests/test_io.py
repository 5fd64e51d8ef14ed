"""Shared file contracts: atomic writes, frame-folder claims, NaN-safe buffers, video errors."""

import numpy as np
import pytest

from lightcrafter import io


def test_atomic_path_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "out.json"
    with pytest.raises(RuntimeError):
        with io.atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("killed")
    assert not target.exists() and list(tmp_path.iterdir()) == []


def test_claim_frame_dir_keeps_frames_of_same_inputs_and_drops_stale_ones(tmp_path):
    d = tmp_path / "frames"
    assert io.claim_frame_dir(d, {"spp": 16}) == 0
    io.stamp_frame_dir(d, {"spp": 16})
    io.write_rgb_exr(d / "0000.exr", np.ones((2, 3, 3)))
    assert io.claim_frame_dir(d, {"spp": 16}) == 0  # a resumed run keeps finished frames
    assert (d / "0000.exr").exists()
    assert io.claim_frame_dir(d, {"spp": 32}) == 1  # other inputs: frames are stale
    assert not (d / "0000.exr").exists()


def test_a_killed_writers_temporary_is_removed_on_resume_and_never_read_as_a_frame(tmp_path):
    """A kill inside atomic_path leaves '.0001.<rand>.tmp.exr' beside the finished frames (what the
    kill-and-resume test found): the resumed render removes it, and a dataset read ignores it."""
    from lightcrafter.datasets import _frame_info

    d = tmp_path / "frames"
    io.stamp_frame_dir(d, {"spp": 16})
    io.write_rgb_exr(d / "0000.exr", np.ones((2, 3, 3)))
    debris = d / ".0001.10horhl5.tmp.exr"
    debris.write_bytes(b"half an EXR")
    assert _frame_info(d) == (1, 3, 2)  # hidden temporaries are not frames
    assert io.claim_frame_dir(d, {"spp": 16}) == 0  # finished frames kept...
    assert (d / "0000.exr").exists() and not debris.exists()  # ...the temporary gone


def test_frames_without_a_stamp_are_not_trusted(tmp_path):
    d = tmp_path / "frames"
    io.write_rgb_exr(d / "0000.exr", np.ones((2, 3, 3)))
    assert io.claim_frame_dir(d, {"spp": 16}) == 1


def test_buffers_with_nan_become_invalid_pixels(tmp_path):
    h, w = 3, 4
    b = io.Buffers(depth=np.ones((h, w)), normal=np.tile([0.0, 0.0, 2.0], (h, w, 1)), albedo=np.full((h, w, 3), 1.5),
                   roughness=np.zeros((h, w)), metallic=np.ones((h, w)), mask=np.ones((h, w)))
    b.depth[0, 0] = np.nan
    b.normal[1, 1] = np.nan
    io.write_buffers(tmp_path / "b.exr", b)
    r = io.read_buffers(tmp_path / "b.exr")
    assert r.mask[0, 0] == 0 and r.mask[1, 1] == 0 and r.mask.sum() == h * w - 2
    assert np.isinf(r.depth[0, 0]) and np.isfinite(r.normal).all() and np.isfinite(r.depth[r.mask > 0]).all()
    assert np.allclose(np.linalg.norm(r.normal[r.mask > 0], axis=-1), 1.0)
    assert r.albedo.max() == 1.0


def test_missing_exr_channel_names_file_and_channel(tmp_path):
    io.write_exr(tmp_path / "x.exr", {"depth": np.ones((2, 2))})
    with pytest.raises(io.DataError, match=r"x\.exr: missing EXR channel\(s\) \['normal.X'"):
        io.read_buffers(tmp_path / "x.exr")


@pytest.mark.parametrize("content, message", [(b"", "video file is empty"), (b"not a video" * 10, "cannot decode video")])
def test_bad_video_is_a_one_line_error_naming_the_file(tmp_path, content, message):
    path = tmp_path / "clip.mp4"
    path.write_bytes(content)
    with pytest.raises(io.DataError, match=message) as err:
        io.read_video(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_video_round_trip_pads_odd_sizes(tmp_path):
    frames = (np.random.default_rng(0).random((3, 33, 45, 3)) * 255).astype(np.uint8)
    io.write_video(tmp_path / "v.mp4", frames)
    back, fps = io.read_video(tmp_path / "v.mp4")
    assert back.shape == (3, 34, 46, 3) and fps == 24.0


def test_storage_precision_depth_float32_the_rest_half_and_radiance_clipped_to_half(tmp_path):
    """Buffers: depth bit-exact (float32), other channels to half precision; frames: half float,
    radiance beyond 65504 clipped, not turned into inf (a reader would reject the frame)."""
    import OpenEXR

    rng = np.random.default_rng(0)
    h, w = 16, 24
    n = rng.normal(size=(h, w, 3)).astype(np.float32)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    b = io.Buffers(depth=rng.uniform(0.5, 2e5, (h, w)).astype(np.float32), normal=n,
                   albedo=rng.uniform(0, 1, (h, w, 3)).astype(np.float32), roughness=rng.uniform(0, 1, (h, w)).astype(np.float32),
                   metallic=rng.uniform(0, 1, (h, w)).astype(np.float32), mask=np.ones((h, w), np.float32))
    io.write_buffers(tmp_path / "b.exr", b)
    with OpenEXR.File(str(tmp_path / "b.exr"), separate_channels=True) as f:
        types = {k: v.pixels.dtype for k, v in f.channels().items()}
    assert types.pop("depth") == np.float32 and set(types.values()) == {np.dtype(np.float16)}
    r = io.read_buffers(tmp_path / "b.exr")
    np.testing.assert_array_equal(r.depth, b.depth)                        # beyond half's range, exact
    np.testing.assert_allclose(r.albedo, b.albedo, rtol=2.0**-11, atol=2.0**-14)
    assert np.degrees(np.arccos(np.clip((r.normal * n).sum(-1), -1, 1))).max() < 0.1
    rgb = rng.uniform(0, 4, (h, w, 3)).astype(np.float32)
    rgb[0, 0] = 2e5                                                       # a pixel that sees the sun
    io.write_frame_exr(tmp_path / "f.exr", rgb)
    back = io.read_rgb_exr(tmp_path / "f.exr")                             # finite: accepted
    assert back[0, 0].tolist() == [io.HALF_MAX] * 3
    np.testing.assert_allclose(back[1:], rgb[1:], rtol=2.0**-11)
    io.write_rgb_exr(tmp_path / "f32.exr", rgb)
    assert (tmp_path / "f.exr").stat().st_size < 0.75 * (tmp_path / "f32.exr").stat().st_size


def test_display_transform_is_colour_sciences_srgb_and_round_trips():
    """io.linear_to_display writes the sRGB curve itself (importing colour costs every job 1.7 s); it must stay
    colour-science's IEC 61966-2-1 curve, at the knee and in the shadows included, and invert exactly."""
    import colour

    x = np.concatenate([np.linspace(0.0, 1.0, 10001), [io.SRGB_LINEAR_KNEE, 1e-6, 1e-3, 0.0031, 0.0032]])
    np.testing.assert_allclose(io.srgb_encode(x), colour.cctf_encoding(x, function="sRGB"), rtol=0, atol=1e-12)
    v = np.concatenate([np.linspace(0.0, 1.0, 10001), [io.SRGB_DISPLAY_KNEE, 0.04045, 0.04, 0.041]])
    np.testing.assert_allclose(io.srgb_decode(v), colour.cctf_decoding(v, function="sRGB"), rtol=0, atol=1e-12)
    np.testing.assert_allclose(io.display_to_linear(io.linear_to_display(x)), x, atol=1e-6)
    # exposure, clipping and non-finite values: NaN -> 0, +inf -> 1, overexposed -> 1
    out = io.linear_to_display(np.array([np.nan, np.inf, -1.0, 0.5, 2.0]), exposure_ev=1.0)
    np.testing.assert_allclose(out, [0.0, 1.0, 0.0, 1.0, 1.0], atol=1e-7)
    assert out.dtype == np.float32
