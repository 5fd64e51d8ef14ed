"""Numerical stability of the reconstruction stack Phi on stiff and extreme frames.

The estimator (random initialisation and the shipped weights) and the default Phi get black, saturated,
1e4-bright and noise-only frames, a one-pixel-wide object, an all-sky frame and depth ratios of 1e4:
outputs stay finite and in range (unit normals, materials and mask in [0, 1], positive depth), and
what cannot be reconstructed is reported (a one-line ReconstructionError naming the clip), not hidden.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lightcrafter import io
from lightcrafter.recon import estimator as est
from lightcrafter.recon.weights import SHIPPED_WEIGHTS

H, W = 32, 48


def _linear_frames() -> dict[str, np.ndarray]:
    """Linear HDR frames (H, W, 3) of the extreme cases, as a camera video would carry them."""
    rng = np.random.default_rng(0)
    one_px = np.full((H, W, 3), 0.2, np.float32)
    one_px[:, W // 2] = (0.9, 0.1, 0.1)  # a one-pixel-wide red pole
    sky = np.tile(np.linspace(1.5, 0.3, H, dtype=np.float32)[:, None, None], (1, W, 3)) * np.float32([0.6, 0.8, 1.0])
    return {"black": np.zeros((H, W, 3), np.float32), "saturated": np.ones((H, W, 3), np.float32),
            "bright_1e4": np.full((H, W, 3), 1e4, np.float32),
            "noise": rng.random((H, W, 3)).astype(np.float32) ** 2 * 4.0, "one_pixel_object": one_px, "all_sky": sky}


def _models():
    torch.manual_seed(0)
    models = [("random_init", est.GBufferNet([8, 16, 24]).eval()),
              ("random_init_shading_ratio", est.GBufferNet([8, 16, 24], "shading_ratio").eval()),
              ("random_init_direct_colour", est.GBufferNet([8, 16, 24], "direct_colour").eval())]
    if SHIPPED_WEIGHTS.is_file():
        models.append(("shipped", est.load(SHIPPED_WEIGHTS)))
    return models


def _check_ranges(p: dict, where: str) -> None:
    for k, v in p.items():
        assert np.isfinite(v).all(), f"{where}: {k} has non-finite values"
    assert (p["depth"] > 0).all(), f"{where}: non-positive depth"
    np.testing.assert_allclose(np.linalg.norm(p["normal_cam"], axis=-1), 1.0, atol=1e-4, err_msg=f"{where}: normals")
    for k in ("albedo", "roughness", "metallic", "mask"):
        assert p[k].min() >= 0 and p[k].max() <= 1, f"{where}: {k} outside [0, 1]"


@pytest.mark.parametrize("name,model", _models(), ids=lambda x: x if isinstance(x, str) else "")
def test_estimator_outputs_stay_finite_and_in_range_on_extreme_frames(name, model):
    frames = _linear_frames()
    disp = np.stack([io.linear_to_display(f) for f in frames.values()])
    p = est.predict(model, disp)
    for i, case in enumerate(frames):
        _check_ranges({k: v[i] for k, v in p.items()}, f"{name}/{case}")
    # the display transform saturates a 1e4-bright frame exactly like a merely white one: same answer
    np.testing.assert_array_equal(p["albedo"][1], p["albedo"][2])


def test_estimator_rejects_frames_that_are_not_display_values():
    model = est.GBufferNet([8, 16]).eval()
    bad = np.zeros((H, W, 3), np.float32)
    bad[3, 4, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        est.predict(model, bad)
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        est.predict(model, np.full((H, W, 3), 1e4, np.float32))  # linear radiance passed by mistake


def test_depth_fit_and_normals_from_depth_with_a_1e4_depth_ratio():
    from lightcrafter.recon.cameras import prior_intrinsics
    from lightcrafter.recon.default import apply_depth_fit, normals_from_depth

    K = prior_intrinsics(W, H, np.radians(50))
    depth = np.full((H, W), 1e3, np.float64)
    depth[10:20, 10:30] = 0.1  # a near object in front of a background 1e4 times farther
    n = normals_from_depth(depth, K)
    assert np.isfinite(n).all()
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-6)
    fitted = apply_depth_fit(depth, np.array([2.0, 1e-3]))
    assert np.isfinite(fitted).all() and (fitted > 0).all()
    # a shift that would make far inverse depth negative marks those pixels invalid, never negative
    cut = apply_depth_fit(depth, np.array([1.0, -5e-3]))
    assert (cut[10:20, 10:30] > 0).all() and np.isinf(cut[0, 0])


def test_proxy_of_a_1e4_depth_ratio_frame_is_finite():
    from lightcrafter.clip import FrameView
    from lightcrafter.proxy import synthetic as syn
    from lightcrafter.proxy.lighting import Lighting
    from lightcrafter.proxy.renderer import ProxyRenderer, RenderSettings

    K = syn.intrinsics(W, H, np.radians(50))
    depth = np.full((H, W), 1e3, np.float32)
    depth[10:20, 10:30] = 0.1
    normal = np.zeros((H, W, 3), np.float32)
    normal[..., 1] = -1.0  # facing an OpenCV camera at the origin looking along +Y (world)
    b = io.Buffers(depth=depth, normal=normal, albedo=np.full((H, W, 3), 0.5, np.float32),
                   roughness=np.full((H, W), 0.5, np.float32), metallic=np.zeros((H, W), np.float32),
                   mask=np.ones((H, W), np.float32))
    c2w = syn.look_at([0, -1, 0], [0, 0, 0])
    env = np.ones((16, 32, 3), np.float32)
    for vis in ("frame", "aggregate"):
        img = ProxyRenderer(Lighting(env=env), RenderSettings(spp=4, visibility=vis)).render(FrameView(b, K, c2w, "x"))
        assert np.isfinite(img).all() and (img >= 0).all(), vis


def _video(tmp_path, frames, name):
    d = tmp_path / name
    for i, f in enumerate(frames):
        io.write_rgb_exr(d / f"{i:04d}.exr", f)
    return d


@pytest.mark.parametrize("case", ["black", "saturated", "all_sky"])
def test_phi_on_a_uniform_video_takes_the_static_camera_and_writes_valid_buffers(tmp_path, case):
    """A video too uniform for structure from motion has no measurable motion: the documented fallback
    is a static camera (counted in the manifest's phi.method); the buffers are finite and in range."""
    from lightcrafter.clip import read_clip
    from lightcrafter.recon.default import DefaultSettings, reconstruct_default

    model = est.GBufferNet([8, 16]).eval()
    wpath = tmp_path / "est.pt"
    est.save(model, est.EstimatorConfig(widths=[8, 16]), wpath)
    f = _linear_frames()[case]
    video = _video(tmp_path, [f] * 5, case)
    m = reconstruct_default(video, tmp_path / "clip", estimator_path=wpath, fps=24, scene_static=True,
                            settings=DefaultSettings(fov_x_deg=50.0, albedo_detail_px=1.0))
    assert m["phi"]["method"].startswith("static")
    views, _ = read_clip(tmp_path / "clip")
    for v in views:
        b = v.buffers
        ok = b.mask > 0.5
        assert np.isfinite(b.normal).all() and np.isfinite(b.albedo).all()
        assert (b.depth[ok] > 0).all() and np.isfinite(b.depth[ok]).all()
        np.testing.assert_allclose(np.linalg.norm(b.normal[ok], axis=-1), 1.0, atol=1e-4)
        assert 0 <= b.albedo.min() and b.albedo.max() <= 1


def test_phi_on_a_noise_only_video_reports_the_failure(tmp_path):
    """Independent noise in every frame has motion but no structure: structure from motion fails and Phi
    says so in one line naming the clip (the workflow then counts it as left out), nothing is written."""
    from lightcrafter.recon.cameras import ReconstructionError
    from lightcrafter.recon.default import DefaultSettings, reconstruct_default

    rng = np.random.default_rng(1)
    frames = [rng.random((64, 96, 3)).astype(np.float32) for _ in range(5)]
    video = _video(tmp_path, frames, "noise")
    model = est.GBufferNet([8, 16]).eval()
    wpath = tmp_path / "est.pt"
    est.save(model, est.EstimatorConfig(widths=[8, 16]), wpath)
    with pytest.raises(ReconstructionError, match="noise_clip") as exc:
        reconstruct_default(video, tmp_path / "clip", estimator_path=wpath, fps=24, scene_static=True,
                            settings=DefaultSettings(fov_x_deg=50.0), name="noise_clip")
    assert "\n" not in str(exc.value)
    assert not (tmp_path / "clip" / "buffers.json").exists()


def test_holes_of_the_mask_are_filled_and_the_sky_is_kept():
    from lightcrafter.recon.default import fill_from_nearest, hole_pixels

    valid = np.ones((20, 30), bool)
    valid[:5] = False  # sky: touches the border, 25 % of the frame
    valid[10:12, 10:12] = False  # an enclosed hole
    valid[19, 29] = False  # a one-pixel notch at the border: smaller than 1 % of the frame
    holes = hole_pixels(valid, 0.01)
    assert holes[10:12, 10:12].all() and holes[19, 29] and not holes[:5].any()
    assert not hole_pixels(valid, 0.0).any()
    vals = np.where(valid, np.arange(600.0).reshape(20, 30), np.nan)
    filled = fill_from_nearest(vals, valid, holes)
    assert np.isfinite(filled[holes]).all() and np.isnan(filled[:5]).all()
    assert filled[19, 29] in (vals[18, 29], vals[19, 28])


def _wall_over_ground() -> tuple[np.ndarray, np.ndarray]:
    """A display frame (uint8 (40, 60, 3)): an orange wall of the environment (rows 0-14) above a pink textured
    ground (rows 15-39) with a red box on it; and an estimator's surface probability that is sure of the upper
    wall (0.02) and of most of the ground (0.999) but calls the wall's lower third (rows 10-14) a surface with
    probability 0.95, as it does where the environment shows behind the edge of the ground."""
    rng = np.random.default_rng(0)
    img = np.zeros((40, 60, 3), np.float32)
    img[:15] = (0.85, 0.5, 0.25)
    img[15:] = (0.75, 0.55, 0.6)
    img[25:32, 20:28] = (0.8, 0.1, 0.1)
    img = np.clip(img + rng.normal(0, 0.03, img.shape), 0, 1)
    prob = np.full((40, 60), 0.999, np.float32)
    prob[:10] = 0.02
    prob[10:15] = 0.95
    prob[15:18] = 0.95  # the ground's own unsure rows next to the wall stay surface
    return (img * 255).round().astype(np.uint8), prob


def test_grabcut_takes_the_unsure_environment_off_the_surface_and_keeps_the_ground():
    from lightcrafter.recon.default import refine_mask_grabcut

    img, prob = _wall_over_ground()
    before = prob > 0.9
    assert before[10:15].all()  # the estimator's mask alone keeps the wall's lower rows
    after = refine_mask_grabcut(img[None], prob[None], 0.9)[0]
    assert after[10:15].mean() < 0.05, "the wall the estimator was unsure of is still surface"
    assert after[15:].mean() > 0.99, "ground or box pixels were taken off the surface"
    assert not after[:10].any()
    np.testing.assert_array_equal(after, refine_mask_grabcut(img[None], prob[None], 0.9)[0])  # same video, same mask


def test_grabcut_leaves_a_frame_without_sure_background_or_a_uniform_frame_as_the_estimator_said():
    from lightcrafter.recon.default import refine_mask_grabcut

    img, prob = _wall_over_ground()
    no_bg = np.maximum(prob, 0.5)  # nothing sure to be background: no colour to learn it from
    np.testing.assert_array_equal(refine_mask_grabcut(img[None], no_bg[None], 0.9)[0], no_bg > 0.9)
    one_px = np.full_like(prob, 0.02)
    one_px[20, 30] = 0.999  # one sure surface pixel: a degenerate colour model, no error
    np.testing.assert_array_equal(refine_mask_grabcut(img[None], one_px[None], 0.9)[0], one_px > 0.9)
    for value in (0, 255):  # a black and a saturated frame: one colour for surface and background alike
        flat = np.full_like(img, value)
        out = refine_mask_grabcut(flat[None], prob[None], 0.9)[0]
        assert out.dtype == bool and out.shape == prob.shape
        assert out[prob > 0.995].all() and not out[prob < 0.1].any()  # the sure pixels keep their labels


def test_ground_plane_is_recovered_from_noisy_points_with_outliers_and_degenerate_input_is_refused():
    from lightcrafter.recon.default import fit_ground_plane

    rng = np.random.default_rng(0)
    n_true = np.array([0.1, -0.05, 1.0]) / np.linalg.norm([0.1, -0.05, 1.0])
    xy = rng.uniform(-3, 3, (2000, 2))
    z = (0.4 - n_true[0] * xy[:, 0] - n_true[1] * xy[:, 1]) / n_true[2]
    pts = np.c_[xy, z] + rng.normal(0, 0.01, (2000, 3))
    pts[:600] += rng.uniform(0.2, 1.5, (600, 1)) * [0, 0, 1]  # 30 % outliers above the plane (objects)
    dist = np.full(2000, 4.0)
    n, o, frac = fit_ground_plane(pts, dist, 0.02, 25.0)
    assert np.degrees(np.arccos(n @ n_true)) < 1.0 and abs(o - 0.4) < 0.02 and 0.6 < frac < 0.75
    assert fit_ground_plane(pts[:2], dist[:2], 0.02, 25.0) is None
    line = np.c_[np.linspace(0, 1, 50), np.zeros(50), np.zeros(50)]  # collinear: no plane
    assert fit_ground_plane(line, np.ones(50), 0.02, 25.0) is None
    wall = np.c_[rng.uniform(-1, 1, 500), np.zeros(500), rng.uniform(0, 2, 500)]  # vertical: not a ground
    assert fit_ground_plane(wall, np.ones(500), 0.02, 25.0) is None


def test_sky_beyond_the_ground_is_cut_and_an_object_on_the_ground_is_kept():
    """A camera 1.5 m above the ground plane z = 0 looks at the horizon over a ground that ends 30 m away: the
    estimator's "surface" at 80 m beyond it (the sky as a far wall) is cut; a 1 m box 6 m away, rising above
    the horizon, stays, and so does the ground."""
    import math

    from lightcrafter.camera import intrinsics, opencv_c2w
    from lightcrafter.recon.default import cut_sky_beyond_ground, plane_depth

    w, h = 64, 48
    K = intrinsics(w, h, math.radians(60.0))
    c2w = opencv_c2w([0.0, 0.0, 1.5], [0.0, 20.0, 1.3])
    n, o = np.array([0.0, 0.0, 1.0]), 0.0
    zp = plane_depth(n, o, K, c2w, h, w)
    ground = np.isfinite(zp) & (zp < 30.0)                     # a ground that ends 30 m away
    depth = np.where(ground, zp, 80.0)                          # the rest: a "wall" at 80 m
    box = np.zeros((h, w), bool)
    box[14:30, 28:36] = True                                   # rises above the horizon (row ~ 22)
    depth[box] = 6.0
    normal = np.where(ground[..., None], n, [0.0, -1.0, 0.0])   # the wall and the box face the camera
    surface = np.ones((h, w), bool)
    mask, cut = cut_sky_beyond_ground(depth[None], normal[None], surface[None], (n, o), K[None], c2w[None], 0.05,
                                      25.0, 1.5)
    sky = ~ground & ~box
    assert cut == int(sky.sum()) > int((~np.isfinite(zp)).sum())  # the sky and the wall below the horizon
    assert not mask[0][sky].any() and mask[0][box].all() and mask[0][ground & ~box].all()
    # a frame without ground pixels is left alone
    none, cut0 = cut_sky_beyond_ground(np.full((1, h, w), 80.0), normal[None], surface[None], (n, o), K[None],
                                       c2w[None], 0.05, 25.0, 1.5)
    assert cut0 == 0 and none.all()


def _ground_camera(tilt_deg: float):
    """A 64x48 camera (60 deg fov, OpenCV axes) 1.5 m above z = 0 looking at (0, 2, 0), and the z-depth map of
    the plane through the origin tilted by ``tilt_deg`` about the world y axis: (w, h, K, c2w, normal, depth)."""
    import math

    from lightcrafter.camera import intrinsics, opencv_c2w
    from lightcrafter.recon.default import plane_depth

    w, h = 64, 48
    K = intrinsics(w, h, math.radians(60.0))
    c2w = opencv_c2w([0.0, 0.0, 1.5], [0.0, 2.0, 0.0])
    t = math.radians(tilt_deg)
    n = np.array([math.sin(t), 0.0, math.cos(t)])
    return w, h, K, c2w, n, plane_depth(n, 0.0, K, c2w, h, w)


def test_ground_plane_turned_to_the_predicted_normals_keeps_its_pixels_and_takes_their_tilt():
    """A static camera 1.5 m above z = 0 looks down at the ground; its depth map is the ground's tilted by 6 deg
    about the view direction (what a monocular estimator guesses), its predicted normals are the true +Z with
    3 deg of noise. ``normal_from='depth'`` snaps to the 6-deg plane; ``predicted`` takes the same pixels and
    turns the plane to within 1 deg of +Z; an unknown choice is one line."""
    import math

    from lightcrafter.recon.default import plane_depth, snap_to_ground_plane

    w, h, K, c2w, n_tilted, depth = _ground_camera(6.0)
    assert np.isfinite(depth).all()
    rng = np.random.default_rng(0)
    normals = np.array([0.0, 0.0, 1.0]) + rng.normal(0, math.radians(3.0), (h, w, 3)) * [1, 1, 0]
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    surface = np.ones((1, h, w), bool)
    args = (depth[None], normals[None], surface, K[None], c2w[None], 0.05, 25.0)
    _, _, (n_d, _), info_d = snap_to_ground_plane(*args, normal_from="depth")
    d_p, n_p_world, (n_p, o_p), info_p = snap_to_ground_plane(*args, normal_from="predicted")
    assert math.degrees(math.acos(n_d @ n_tilted)) < 0.5
    assert math.degrees(math.acos(n_p[2])) < 1.0 and info_p["ground_plane"]["turned_deg"] > 4.0
    assert info_p["ground_plane"]["support_fraction"] == info_d["ground_plane"]["support_fraction"] == 1.0
    np.testing.assert_allclose(d_p[0], plane_depth(n_p, o_p, K, c2w, h, w), rtol=1e-6)
    assert np.isfinite(d_p).all() and (d_p > 0).all()
    np.testing.assert_allclose(n_p_world[0], np.broadcast_to(n_p, (h, w, 3)), atol=1e-12)
    with pytest.raises(ValueError, match="ground_plane_normal"):
        snap_to_ground_plane(*args, normal_from="sky")


def test_depth_sfm_ground_takes_the_mean_of_the_depths_and_the_sfm_points_tilt():
    """The depth puts the ground 6 deg off +Z; SfM points seen on it lie on a plane 2 deg off the other way
    (plus points on an object above it, which the trimmed fit drops): ``depth_sfm`` turns the snapped plane to
    the mean of the two normals, through the inliers' offset; with ``sfm_weight`` 1 to the SfM points' plane
    alone. Too few points seen on the ground, or no SfM at all, keep the depth's plane."""
    import math

    from lightcrafter.recon.default import MIN_SFM_GROUND_POINTS, plane_depth, snap_to_ground_plane

    w, h, K, c2w, n_depth, depth = _ground_camera(6.0)
    *_, n_sfm, sfm_plane_depth = _ground_camera(-2.0)
    rng = np.random.default_rng(1)
    uv = np.stack([rng.uniform(0, w - 1, 60), rng.uniform(h / 2, h - 1, 60)], 1)  # lower half: the ground
    z = sfm_plane_depth[np.round(uv[:, 1]).astype(int), np.round(uv[:, 0]).astype(int)]
    rays = np.linalg.inv(K) @ np.concatenate([uv.T, np.ones((1, len(uv)))])  # OpenCV camera rays, z = 1
    pts = (c2w[:3, :3] @ (rays * z)).T + c2w[:3, 3]
    pts[:8, 2] += 0.4  # points on an object standing on the ground
    obs = [(uv, np.arange(len(uv)))]
    normals = np.broadcast_to(n_depth, (h, w, 3)).copy()
    args = (depth[None], normals[None], np.ones((1, h, w), bool), K[None], c2w[None], 0.05, 25.0)
    d, n_w, (n, o), info = snap_to_ground_plane(*args, normal_from="depth_sfm", sfm=(pts, obs))
    want = (n_depth + n_sfm) / np.linalg.norm(n_depth + n_sfm)
    assert math.degrees(math.acos(min(1.0, n @ want))) < 0.3
    g = info["ground_plane"]
    assert g["normal_from"] == "depth_sfm" and g["sfm_ground_points"] == 60 and abs(g["turned_deg"] - 4.0) < 0.3
    np.testing.assert_allclose(d[0], plane_depth(n, o, K, c2w, h, w), rtol=1e-6)
    np.testing.assert_allclose(n_w[0], np.broadcast_to(n, (h, w, 3)), atol=1e-12)
    for tol in (None, 0.01):  # weight 1: the SfM points' plane alone, by trimmed least squares or RANSAC
        _, _, (n_s, _), _ = snap_to_ground_plane(*args, normal_from="depth_sfm", sfm=(pts, obs), sfm_tol_rel=tol,
                                                 sfm_weight=1.0)
        assert math.degrees(math.acos(min(1.0, n_s @ n_sfm))) < 0.3
    steep = pts.copy()
    steep[:, 2] += 0.8 * (steep[:, 0] - steep[:, 0].mean())  # points on a 39-deg slope: not ground
    for sfm in (None, (pts, [(uv[: MIN_SFM_GROUND_POINTS - 1], np.arange(MIN_SFM_GROUND_POINTS - 1))]),
                (steep, obs)):
        _, _, (n_only, _), info = snap_to_ground_plane(*args, normal_from="depth_sfm", sfm=sfm)
        assert math.degrees(math.acos(min(1.0, n_only @ n_depth))) < 0.5 and info["ground_plane"]["turned_deg"] == 0
    assert info["ground_plane"]["sfm_plane_tilt_deg"] > 25.0


def test_sfm_ground_plane_by_ransac_survives_the_mismatches_of_a_repeated_texture():
    """SfM points seen on the ground: 60 % on a plane 3 deg off +Z, 40 % triangulated off it (mismatched
    features on a repeated texture land anywhere along their rays). Trimmed least squares keeps a tilt of
    several degrees; ``tol_rel`` (RANSAC) finds the plane. RANSAC needs the camera centres and finds nothing
    without enough points."""
    import math

    from lightcrafter.recon.default import MIN_SFM_GROUND_POINTS, sfm_ground_normal

    rng = np.random.default_rng(3)
    tilt = math.radians(3.0)
    n_true = np.array([math.sin(tilt), 0.0, math.cos(tilt)])
    xy = rng.uniform(-2.0, 2.0, (300, 2))
    z = -(n_true[0] * xy[:, 0]) / n_true[2]  # n . x = 0
    pts = np.column_stack([xy, z])
    bad = rng.random(300) < 0.4
    cams = np.array([[0.0, -4.0, 2.0], [0.5, -4.0, 2.0]])
    toward = pts[bad] - cams[0]  # mismatches slide along the camera ray
    pts[bad] = cams[0] + toward * rng.uniform(0.6, 1.4, (int(bad.sum()), 1))
    on = [np.ones((4, 4), bool)]
    obs = [(np.zeros((300, 2)), np.arange(300))]

    def err(n):
        return math.degrees(math.acos(min(1.0, abs(float(n @ n_true)))))

    n_lsq, count = sfm_ground_normal(pts, obs, on)
    n_ransac, _ = sfm_ground_normal(pts, obs, on, tol_rel=0.01, cameras=cams, max_tilt_deg=25.0)
    assert count == 300 and err(n_lsq) > 2.0 and err(n_ransac) < 0.5 and n_ransac[2] > 0
    with pytest.raises(ValueError, match="camera centres"):
        sfm_ground_normal(pts, obs, on, tol_rel=0.01)
    few = [(np.zeros((MIN_SFM_GROUND_POINTS - 1, 2)), np.arange(MIN_SFM_GROUND_POINTS - 1))]
    assert sfm_ground_normal(pts, few, on, tol_rel=0.01, cameras=cams) is None
