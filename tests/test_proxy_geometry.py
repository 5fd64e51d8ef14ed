"""Geometry from buffers: unprojection round trip, discontinuity cuts, pixel-exact quads, frame alignment."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lightcrafter.proxy import geometry as geo
from lightcrafter.proxy import synthetic as syn


def _cam(w=24, h=16, cx_shift=0.0, cy_shift=0.0):
    K = syn.intrinsics(w, h, 0.9)
    K[0, 2] += cx_shift
    K[1, 2] += cy_shift
    return K, syn.look_at([2.0, -1.5, 1.2], [0.0, 0.0, 0.2])


@settings(max_examples=30, deadline=None)
@given(st.floats(-3, 3), st.floats(-3, 3), st.floats(0.05, 50.0))
def test_unproject_project_round_trip(cx_shift, cy_shift, scale):
    K, c2w = _cam(cx_shift=cx_shift, cy_shift=cy_shift)
    rng = np.random.default_rng(0)
    depth = (rng.uniform(0.5, 2.0, (16, 24)) * scale).astype(np.float32)
    pts = geo.unproject(depth, K, c2w)
    u, v, z = geo.project(pts, K, c2w)
    jj, ii = np.meshgrid(np.arange(24), np.arange(16))
    np.testing.assert_allclose(u, jj, atol=1e-6 * 24)
    np.testing.assert_allclose(v, ii, atol=1e-6 * 16)
    np.testing.assert_allclose(z, depth, rtol=1e-6)


def test_unproject_invalid_depth_is_nan():
    K, c2w = _cam()
    depth = np.ones((16, 24), np.float32)
    depth[0, 0], depth[0, 1], depth[0, 2] = 0.0, np.inf, np.nan
    pts = geo.unproject(depth, K, c2w)
    assert np.isnan(pts[0, :3]).all() and np.isfinite(pts[1:]).all()


def _two_planes(w=24, h=16):
    """Fronto-parallel plane at z=2 on the left half, z=4 on the right half (camera looks along +Y)."""
    K = syn.intrinsics(w, h, 0.9)
    c2w = syn.look_at([0, 0, 0], [0, 1, 0])
    depth = np.full((h, w), 2.0, np.float32)
    depth[:, w // 2:] = 4.0
    return depth, K, c2w


def test_discontinuities_are_cut():
    depth, K, c2w = _two_planes()
    valid = np.ones(depth.shape, bool)
    horiz, vert = geo.continuity(depth, valid, K, None, 0.05)
    assert not horiz[:, 11].any()  # the step between columns 11 and 12
    assert horiz[:, :11].all() and horiz[:, 12:].all() and vert.all()
    for build in (geo.pixel_quad_mesh, geo.pixel_grid_mesh):
        m = build(depth, valid, K, c2w, None, 0.05)
        y = m.vertices[m.faces][..., 1]  # world y = camera depth here
        span = y.max(1) - y.min(1)
        assert span.max() < 0.5, f"{build.__name__}: a face bridges the 2 m step"


def test_cut_does_not_happen_on_grazing_plane_with_normals():
    w, h = 48, 32
    K = syn.intrinsics(w, h, 0.9)
    c2w = syn.look_at([0, 0, 0.3], [0, 10, 0.0])  # low camera, ground seen at grazing angles
    b = syn.raycast_buffers(K, c2w, w, h, ground=syn.Ground(half_size_m=100))
    valid = b.mask > 0.5
    h_no, _ = geo.continuity(b.depth, valid, K, None, 0.05)
    h_n, v_n = geo.continuity(b.depth, valid, K, b.normal @ c2w[:3, :3], 0.05)
    both_valid_v = valid[:-1] & valid[1:]
    assert v_n[both_valid_v].all()
    assert h_n.sum() >= h_no.sum()


def test_quad_mesh_is_exact_for_a_plane_and_covers_pixel_footprints():
    w, h = 24, 16
    K, c2w = _cam(w, h, cx_shift=1.3, cy_shift=-0.7)
    b = syn.raycast_buffers(K, c2w, w, h, ground=syn.Ground(half_size_m=100))
    m = geo.pixel_quad_mesh(b.depth, b.mask > 0.5, K, c2w, b.normal)
    inner = np.ones(len(m.faces) // 2, bool)
    # every corner of a fully interior quad lies on the plane z = 0
    z = m.vertices[:, 2].reshape(-1, 4)
    np.testing.assert_allclose(z[inner], 0.0, atol=1e-5)
    # the corners project to the pixel corners
    u, v, _ = geo.project(m.vertices.astype(np.float64), K, c2w)
    pix = m.face_pixel[::2]
    cols, rows = pix % w, pix // w
    np.testing.assert_allclose(u.reshape(-1, 4)[:, 0], cols - 0.5, atol=1e-3)
    np.testing.assert_allclose(v.reshape(-1, 4)[:, 2], rows + 0.5, atol=1e-3)


def test_border_mask_removes_border_pixels():
    depth, K, c2w = _two_planes()
    m = geo.pixel_quad_mesh(depth, np.ones(depth.shape, bool), K, c2w, None, 0.05, border_px=2)
    pix = m.face_pixel
    rows, cols = pix // 24, pix % 24
    assert rows.min() == 2 and rows.max() == 13 and cols.min() == 2 and cols.max() == 21


def test_bilateral_keeps_edges_and_smooths_noise():
    depth, K, c2w = _two_planes()
    rng = np.random.default_rng(1)
    noisy = depth * (1 + 0.005 * rng.standard_normal(depth.shape)).astype(np.float32)
    valid = np.ones(depth.shape, bool)
    out = geo.bilateral_depth(noisy, valid, sigma_px=1.5, sigma_rel=0.02)
    assert np.abs(out - depth).mean() < np.abs(noisy - depth).mean() * 0.7
    assert np.abs(out[:, 11] - 2.0).max() < 0.05 and np.abs(out[:, 12] - 4.0).max() < 0.1


@pytest.mark.parametrize("cx_shift,cy_shift", [(0.0, 0.0), (2.5, -1.5)])
def test_mitsuba_camera_rays_hit_their_own_pixel(cx_shift, cy_shift):
    """Frame alignment: a ray through pixel (i, j)'s footprint hits the quad built for pixel (i, j)."""
    import drjit as dr
    import mitsuba as mi

    from lightcrafter.proxy.camera import sensor_from_opencv
    from lightcrafter.proxy.mitsuba_setup import ensure_variant
    from lightcrafter.proxy.renderer import _mesh, _scene

    ensure_variant()
    w, h = 24, 16
    K, c2w = _cam(w, h, cx_shift, cy_shift)
    b = syn.raycast_buffers(K, c2w, w, h, [syn.Sphere((0, 0, 0.4), 0.4)])
    m = geo.pixel_quad_mesh(b.depth, b.mask > 0.5, K, c2w, b.normal)
    scene = _scene({"m": _mesh("m", m.vertices, m.faces)})
    sensor = sensor_from_opencv(K, c2w, w, h)
    jj, ii = np.meshgrid(np.arange(w), np.arange(h))
    rng = np.random.default_rng(0)
    for k in range(3):
        ju, jv = (0.5, 0.5) if k == 0 else rng.uniform(0.05, 0.95, 2)
        pos = mi.Point2f(mi.Float(((jj + ju) / w).ravel()), mi.Float(((ii + jv) / h).ravel()))
        ray, _ = sensor.sample_ray(0.0, 0.0, pos, mi.Point2f(0.5))
        si = scene.ray_intersect(ray)
        hit = np.asarray(si.is_valid())
        face = np.asarray(si.prim_index)
        assert (hit == (b.mask.ravel() > 0.5)).all()
        assert (m.face_pixel[face[hit]] == np.flatnonzero(hit)).all()
        if k:
            continue
        # through the pixel centre, the z-depth along the optical axis reproduces the buffer
        z = np.asarray(dr.dot(si.p - mi.Point3f(*map(float, c2w[:3, 3])), mi.Vector3f(*map(float, c2w[:3, 2]))))
        np.testing.assert_allclose(z[hit], b.depth.ravel()[hit], rtol=0.05)
