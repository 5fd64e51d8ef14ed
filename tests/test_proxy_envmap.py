"""Envmap convention (lat-long, Blender world), rotation, Mitsuba equivalence, validation."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lightcrafter import envmap
from lightcrafter.io import DataError, write_exr, write_rgb_exr


@settings(max_examples=50, deadline=None)
@given(st.floats(0.0, 0.999), st.floats(0.001, 0.999))
def test_uv_direction_round_trip(u, v):
    uu, vv = envmap.direction_to_uv(envmap.uv_to_direction(u, v))
    assert abs(((uu - u + 0.5) % 1.0) - 0.5) < 1e-9 and abs(vv - v) < 1e-9


def test_documented_axes():
    u, v = envmap.direction_to_uv(np.array([[1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float))
    np.testing.assert_allclose(u[:3], [0.5, 0.25, 0.75])
    np.testing.assert_allclose(v, [0.5, 0.5, 0.5, 0.0, 1.0])


def test_rotation_moves_features_counter_clockwise():
    rng = np.random.default_rng(0)
    env = rng.random((16, 32, 3)).astype(np.float32)
    m = envmap.uv_to_direction(0.3, 0.4)
    theta = 0.9
    rotated = m @ envmap.rot_z(theta).T
    np.testing.assert_allclose(envmap.radiance(env, rotated, theta), envmap.radiance(env, m, 0.0), atol=1e-6)


def test_rotate_yaw_by_whole_columns_is_a_roll():
    rng = np.random.default_rng(1)
    env = rng.random((8, 16, 3)).astype(np.float32)
    out = envmap.rotate(env, yaw_rad=2 * np.pi * 3 / 16)
    # content turns counter-clockwise (+Y towards -X): u decreases by 3 columns
    np.testing.assert_allclose(out, np.roll(env, -3, axis=1), atol=1e-5)
    assert np.allclose(envmap.rotate(env), env)


def test_rotate_pitch_moves_zenith():
    env = np.zeros((32, 64, 3), np.float32)
    env[:2] = 1.0  # bright zenith cap
    out = envmap.rotate(env, pitch_rad=np.pi / 2)  # +Z -> +X
    u, v = envmap.direction_to_uv(np.array([1.0, 0, 0]))
    assert envmap.sample_bilinear(out, u, v).min() > 0.9 and out[:2].mean() < 0.1


def test_mitsuba_envmap_reproduces_the_convention():
    import drjit as dr
    import mitsuba as mi

    from lightcrafter.proxy.mitsuba_setup import ensure_variant

    ensure_variant()
    rng = np.random.default_rng(2)
    env = rng.random((8, 16, 3)).astype(np.float32)
    em = mi.load_dict({"type": "envmap", "bitmap": mi.Bitmap(envmap.mitsuba_data(env)),
                       "to_world": mi.ScalarTransform4f(envmap.MITSUBA_TO_WORLD.tolist())})
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    si = dr.zeros(mi.SurfaceInteraction3f, len(d))
    si.wi = -mi.Vector3f(*[mi.Float(d[:, k]) for k in range(3)])
    got = em.eval(si)
    got = np.stack([np.asarray(got.x), np.asarray(got.y), np.asarray(got.z)], -1)
    want = envmap.sample_bilinear(env, *envmap.direction_to_uv(d))
    np.testing.assert_allclose(got, want, atol=2e-4)


def test_validation_names_the_file(tmp_path):
    env = np.ones((4, 8, 3), np.float32)
    env[1, 1, 0] = np.nan
    write_rgb_exr(tmp_path / "nan.exr", env)
    with pytest.raises(DataError, match="nan.exr.*NaN"):
        envmap.load(tmp_path / "nan.exr")
    env[1, 1, 0] = -0.5
    write_rgb_exr(tmp_path / "neg.exr", env)
    with pytest.raises(DataError, match="neg.exr.*negative"):
        envmap.load(tmp_path / "neg.exr")
    env[1, 1, 0] = -1e-4  # compression ringing: clamped
    write_rgb_exr(tmp_path / "ring.exr", env)
    assert envmap.load(tmp_path / "ring.exr").min() == 0.0
    write_exr(tmp_path / "y.exr", {"Y": np.full((4, 8), 2.0, np.float32)})
    assert envmap.load(tmp_path / "y.exr").shape == (4, 8, 3)
    write_exr(tmp_path / "bad.exr", {"Z": np.ones((4, 8), np.float32)})
    with pytest.raises(DataError, match="bad.exr"):
        envmap.load(tmp_path / "bad.exr")


def test_exposure_scales_linearly():
    env = np.ones((4, 8, 3), np.float32)
    np.testing.assert_allclose(envmap.apply_exposure(env, 1.0, 0.5), 1.0)
