"""recon.multiview: the plane sweep around the estimator's depth (recon.depth_multiview)."""

from __future__ import annotations

import numpy as np
import pytest

from lightcrafter.recon import multiview as mv

H, W, F_PX = 48, 64, 60.0
K = np.array([[F_PX, 0, (W - 1) / 2], [0, F_PX, (H - 1) / 2], [0, 0, 1.0]])


def _camera(x_m: float) -> np.ndarray:
    """A camera at (x_m, 0, 0) looking along +z (OpenCV axes = world axes)."""
    c2w = np.eye(4)
    c2w[0, 3] = x_m
    return c2w


def _wall(cams: list[np.ndarray], z_m: float, texture: bool) -> tuple[np.ndarray, np.ndarray]:
    """Display frames (N, H, W, 3) of a wall z = z_m (world) with a texture in its x, y (metres), and its z-depth."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    frames = []
    for c2w in cams:
        x = (u - K[0, 2]) / F_PX * z_m + c2w[0, 3]
        y = (v - K[1, 2]) / F_PX * z_m
        g = np.full_like(x, 0.5)
        if texture:
            g += (0.12 * np.sin(7.3 * x + 1.0) * np.cos(5.1 * y) + 0.1 * np.sin(17.9 * x + 6.7 * y)
                  + 0.08 * np.cos(11.3 * x - 13.7 * y + 2.0))
        frames.append(np.repeat(g[..., None], 3, -1))
    return np.clip(np.stack(frames), 0, 1).astype(np.float32), np.full((len(cams), H, W), z_m)


def test_a_wrong_prior_on_a_textured_wall_comes_back_to_the_wall():
    cams = [_camera(x) for x in (-0.6, -0.3, 0.0, 0.3, 0.6)]
    frames, depth = _wall(cams, 2.0, texture=True)
    prior = depth * 1.12
    out, info = mv.refine_depth(frames, prior, np.repeat(K[None], 5, 0), np.stack(cams), np.ones(5, bool))
    inner = (slice(None), slice(6, -6), slice(6, -6))  # the edges see past the other frames
    err = np.abs(np.log(out[inner] / depth[inner]))
    assert np.median(err) < 0.01 < np.log(1.12) / 5
    assert info["multiview_changed_fraction"] > 0.5


def test_what_the_views_cannot_tell_keeps_its_prior():
    """A wall without texture, a camera that does not move, an unregistered frame and pixels with no depth keep the
    prior exactly; nothing comes out non-finite."""
    cams = [_camera(x) for x in (-0.3, 0.0, 0.3)]
    flat, depth = _wall(cams, 2.0, texture=False)
    prior = depth * 1.1
    out, info = mv.refine_depth(flat, prior, np.repeat(K[None], 3, 0), np.stack(cams), np.ones(3, bool))
    assert np.array_equal(out, prior) and info["multiview_changed_fraction"] == 0.0

    still = [_camera(0.0)] * 3
    tex, depth = _wall(still, 2.0, texture=True)
    out, _ = mv.refine_depth(tex, depth * 1.1, np.repeat(K[None], 3, 0), np.stack(still), np.ones(3, bool))
    assert np.array_equal(out, depth * 1.1)

    tex, depth = _wall(cams, 2.0, texture=True)
    prior = depth * 1.1
    prior[1, :10] = np.inf
    prior[1, 10:12] = np.nan
    prior[1, 12:14] = 0.0
    out, _ = mv.refine_depth(tex, prior, np.repeat(K[None], 3, 0), np.stack(cams), np.array([True, True, False]))
    assert np.array_equal(out[2], prior[2])                     # unregistered: not refined
    assert np.array_equal(out[1, :14], prior[1, :14], equal_nan=True)  # no depth: kept as it was
    assert np.isfinite(out[1, 14:]).all() and (out[1, 14:] > 0).all()


def test_bad_plane_sweep_settings_are_refused():
    with pytest.raises(ValueError, match="odd window_px"):
        mv.PlaneSweepSettings(window_px=4)
    with pytest.raises(ValueError, match="hypotheses >= 3"):
        mv.PlaneSweepSettings(hypotheses=2)


@pytest.mark.parametrize("moving, scene_static, on, refined", [(True, True, True, True), (True, False, True, False),
                                                               (False, True, True, False), (True, True, False, False)])
def test_phi_refines_depth_only_for_a_moving_camera_in_a_static_scene(tmp_path, monkeypatch, moving, scene_static, on,
                                                                      refined):
    """recon.depth_multiview reaches reconstruct_default from the config, and the sweep runs only where the views see
    one rigid scene from several places: a moving camera (not a static one) and a static scene (not moving objects);
    its counts land in the clip's manifest."""
    from lightcrafter import io
    from lightcrafter.recon import default as phi
    from lightcrafter.recon import estimator as est
    from lightcrafter.recon.cameras import CameraTrack

    n = 3
    cams = [_camera(x) for x in (-0.3, 0.0, 0.3)]
    frames, _ = _wall(cams, 2.0, texture=True)
    video = tmp_path / "video"
    for i, f in enumerate(frames):
        io.write_rgb_exr(video / f"{i:04d}.exr", io.display_to_linear(f))
    wpath = tmp_path / "est.pt"
    est.save(est.GBufferNet([8, 16]).eval(), est.EstimatorConfig(widths=[8, 16]), wpath)
    track = CameraTrack(K=np.repeat(K[None], n, 0), c2w=np.stack(cams if moving else [cams[1]] * n),
                        registered=np.ones(n, bool), points=np.zeros((0, 3)), observations=[], static=not moving,
                        info={"method": "colmap" if moving else "static", "registered": n, "frames": n})
    monkeypatch.setattr(phi, "estimate_cameras", lambda *a, **k: track)
    monkeypatch.setattr(phi, "depth_fits", lambda *a, **k: np.tile([1.0, 0.0], (n, 1)))
    calls = []

    def sweep(display, depth, K_, c2w, registered):
        calls.append(depth.shape)
        return depth, {"multiview_changed_fraction": 0.5, "multiview_median_abs_log_change": 0.01}

    monkeypatch.setattr(mv, "refine_depth", sweep)
    from lightcrafter.config import raw_config, validate

    cfg = validate(raw_config(overrides={"recon": {"depth_multiview": on}}))
    settings = phi.settings_from_config(cfg, ground_plane=False, mask_refine="none", albedo_detail_px=0.0)
    assert settings.depth_multiview is on
    m = phi.reconstruct_default(video, tmp_path / "clip", estimator_path=wpath, fps=24, scene_static=scene_static,
                                settings=settings)
    assert (calls == [(n, H, W)]) is refined
    assert ("multiview_changed_fraction" in m["phi"]) is refined
