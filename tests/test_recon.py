"""Reconstruction stack: Align, camera helpers, the estimator's plumbing, and the default backend's pieces."""

import json
from pathlib import Path

import numpy as np
import pytest

from lightcrafter import clip as clipmod
from lightcrafter import io
from lightcrafter.proxy import synthetic as syn
from lightcrafter.recon import align
from lightcrafter.recon.default import depth_scales, normals_from_depth, up_rotation

W, H, N = 48, 32, 4
REPO = Path(__file__).resolve().parents[1]


def _rot(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _gt_clip(root, static=False, seed=0):
    K = syn.intrinsics(W, H, 0.9)
    angles = [0.0] * N if static else [0.0, 0.08, 0.16, 0.24]
    c2ws = [syn.look_at([2.5 * np.cos(a), 2.5 * np.sin(a), 1.4], [0, 0, 0.3]) for a in angles]
    spheres = [syn.Sphere((0, 0, 0.5), 0.5, albedo=(0.7, 0.2, 0.1), roughness=0.3)]
    for i, c in enumerate(c2ws):
        io.write_buffers(clipmod.buffer_path(root, i), syn.raycast_buffers(K, c, W, H, spheres))
    return clipmod.write_clip(root, serve=list(range(N)), K=[K] * N, c2w=c2ws, width=W, height=H, fps=24,
                              camera_static=static, scene_static=True, units="metres", producer={"stage": "test"},
                              content_id=f"gt{seed}")


def _transformed(gt_root, out, R, t, s, depth_extra=1.0, noise=None):
    """A 'reconstruction': the ground truth under x_est = (R^T (x_gt - t)) / s, depth scale extra, optional
    per-pixel depth noise."""
    views, info = clipmod.read_clip(gt_root)
    c2w = []
    for i, v in enumerate(views):
        b = v.buffers
        d = b.depth / s * depth_extra
        if noise is not None:
            d = d * (1 + noise[i])
        io.write_buffers(clipmod.buffer_path(out, i), io.Buffers(
            depth=np.where(np.isfinite(b.depth), d, np.inf).astype(np.float32),
            normal=(b.normal @ R).astype(np.float32), albedo=b.albedo, roughness=b.roughness, metallic=b.metallic,
            mask=b.mask))
        e = np.eye(4)
        e[:3, :3] = R.T @ v.c2w[:3, :3]
        e[:3, 3] = R.T @ (v.c2w[:3, 3] - t) / s
        c2w.append(e)
    clipmod.write_clip(out, serve=list(range(N)), K=[v.K for v in views], c2w=c2w, width=W, height=H, fps=24,
                       camera_static=info.camera_static, scene_static=True, units="arbitrary",
                       producer={"stage": "phi"}, content_id="est")


@pytest.mark.parametrize("static", [False, True])
def test_known_similarity_is_undone(tmp_path, static):
    _gt_clip(tmp_path / "gt", static)
    R, t, s = _rot([0.3, -0.5, 0.8], 1.1), np.array([0.4, -2.0, 0.7]), 3.7
    _transformed(tmp_path / "gt", tmp_path / "est", R, t, s, depth_extra=1.3)
    man = align.align_clip(tmp_path / "est", tmp_path / "gt", tmp_path / "al")
    assert man["units"] == "metres" and man["producer"]["stage"] == "align"
    va, _ = clipmod.read_clip(tmp_path / "al")
    vg, _ = clipmod.read_clip(tmp_path / "gt")
    for a, g in zip(va, vg):
        np.testing.assert_allclose(a.c2w, g.c2w, atol=1e-4)
        ok = np.isfinite(g.buffers.depth)
        np.testing.assert_allclose(a.buffers.depth[ok], g.buffers.depth[ok], rtol=1e-4)
        # normals are stored in half float (lightcrafter.io): 2^-11 relative, after the rotation
        np.testing.assert_allclose(a.buffers.normal, g.buffers.normal, atol=1e-3)


def test_per_pixel_errors_survive_alignment(tmp_path):
    """Align removes one similarity and one depth scale, never local errors."""
    _gt_clip(tmp_path / "gt")
    rng = np.random.default_rng(0)
    noise = rng.normal(0, 0.05, (N, H, W)).astype(np.float32)
    R, t, s = _rot([0, 0, 1], 0.7), np.array([1.0, 2.0, 0.0]), 0.5
    _transformed(tmp_path / "gt", tmp_path / "est", R, t, s, noise=noise)
    align.align_clip(tmp_path / "est", tmp_path / "gt", tmp_path / "al")
    va, _ = clipmod.read_clip(tmp_path / "al")
    vg, _ = clipmod.read_clip(tmp_path / "gt")
    for i, (a, g) in enumerate(zip(va, vg)):
        ok = np.isfinite(g.buffers.depth)
        rel = a.buffers.depth[ok] / g.buffers.depth[ok] - 1
        k = np.median(1 + noise[i][ok])
        np.testing.assert_allclose(1 + rel, (1 + noise[i][ok]) / np.median(1 + noise), rtol=2e-3)
        assert np.std(rel) == pytest.approx(np.std(noise[i][ok]) / k, rel=0.05)


def test_align_rejects_mismatched_clips(tmp_path):
    _gt_clip(tmp_path / "gt")
    views, _ = clipmod.read_clip(tmp_path / "gt")
    clipmod.write_clip(tmp_path / "gt", serve=[0, 1, 2], K=[v.K for v in views[:3]], c2w=[v.c2w for v in views[:3]],
                       width=W, height=H, fps=24, camera_static=False, scene_static=True, units="metres",
                       producer={}, content_id="x")
    _gt_clip(tmp_path / "gt2")
    _transformed(tmp_path / "gt2", tmp_path / "est", np.eye(3), np.zeros(3), 1.0)
    with pytest.raises(io.DataError, match="frames"):
        align.align_clip(tmp_path / "est", tmp_path / "gt", tmp_path / "al")


def test_skipped_clip_reads_as_one_line_error(tmp_path):
    clipmod.write_skipped(tmp_path / "c", "structure from motion registered 2/17 frames")
    assert clipmod.is_skipped(tmp_path / "c").startswith("structure from motion")
    with pytest.raises(io.DataError, match="left out"):
        clipmod.read_clip(tmp_path / "c")


def test_up_rotation_takes_the_vector_to_z():
    for up in ([0, 0, 1], [0, 0, -1], [1, 2, 3], [0.01, -1, 0.2]):
        Q = up_rotation(np.array(up, float))
        np.testing.assert_allclose(Q @ (np.array(up) / np.linalg.norm(up)), [0, 0, 1], atol=1e-12)
        np.testing.assert_allclose(Q @ Q.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(Q) == pytest.approx(1.0)


def test_normals_from_depth_of_a_plane():
    K = syn.intrinsics(W, H, 0.9)
    c2w = syn.look_at([0, -3, 2], [0, 0, 0])
    b = syn.raycast_buffers(K, c2w, W, H, [], syn.Ground())
    n_cam = normals_from_depth(np.where(np.isfinite(b.depth), b.depth, 1.0), K)
    n_world = n_cam @ c2w[:3, :3].T
    inner = n_world[2:-2, 2:-2][np.isfinite(b.depth[2:-2, 2:-2])]
    np.testing.assert_allclose(inner, np.broadcast_to([0, 0, 1], inner.shape), atol=1e-4)


def test_depth_scales_follow_sfm_points_and_fill_gaps():
    from lightcrafter.recon.cameras import CameraTrack

    n, h, w = 5, 8, 8
    depth = np.full((n, h, w), 2.0)
    uv = np.stack(np.meshgrid(np.arange(w), np.arange(h)), -1).reshape(-1, 2).astype(float)
    pts, obs = [], []
    c2w = np.repeat(np.eye(4)[None], n, 0)
    truth = [3.0, 3.0, None, 3.3, 3.0]  # frame 2 sees too few points
    for i, s in enumerate(truth):
        if s is None:
            obs.append((np.zeros((0, 2)), np.zeros(0, np.int64)))
            continue
        ids = np.arange(len(pts), len(pts) + len(uv))
        pts += [[0.0, 0.0, 2.0 * s]] * len(uv)
        obs.append((uv, ids))
    tr = CameraTrack(K=np.repeat(np.eye(3)[None], n, 0), c2w=c2w, registered=np.ones(n, bool),
                     points=np.array(pts), observations=obs, static=False)
    s = depth_scales(tr, depth, min_points=4)
    np.testing.assert_allclose(s, [3.0, 3.0, 3.0, 3.0, 3.0])  # gap filled, the 3.3 outlier removed by the median


def test_planar_depth_fit_turns_a_tilted_ground_to_the_sfm_points_tilt():
    """The estimator predicts a ground whose inverse depth is compressed (x 0.6), shifted and rolled (a slope
    across the image); the SfM points (15 % of them outliers) lie on the true ground. ``planar`` recovers the
    true depth and the ground's normal; ``scale`` and ``affine`` keep the roll."""
    from lightcrafter.proxy.geometry import camera_rays
    from lightcrafter.recon.cameras import CameraTrack
    from lightcrafter.recon.default import apply_depth_fit, depth_fits

    n, h, w = 3, 32, 48
    K = syn.intrinsics(w, h, 0.9)
    truth = syn.raycast_buffers(K, syn.look_at([0, -3, 2.1], [0, 0, 0]), w, h, [], syn.Ground()).depth
    assert np.isfinite(truth).all()
    wrong = 1.0 / (0.6 / truth + 0.02 + 0.12 * camera_rays(K, h, w)[..., 0])
    rng = np.random.default_rng(0)
    pick = rng.choice(h * w, 120, replace=False)
    uv = np.stack([pick % w, pick // w], 1).astype(float)
    z = truth.reshape(-1)[pick] * np.where(rng.random(120) < 0.15, rng.uniform(0.5, 2.0, 120), 1.0)
    c2w = np.repeat(np.eye(4)[None], n, 0)
    pts = np.concatenate([np.c_[(uv - K[:2, 2]) / np.diag(K)[:2] * z[:, None], z]] * n)
    obs = [(uv, np.arange(i * 120, (i + 1) * 120)) for i in range(n)]
    tr = CameraTrack(K=np.repeat(K[None], n, 0), c2w=c2w, registered=np.ones(n, bool), points=pts,
                     observations=obs, static=False)
    pred = np.repeat(wrong[None], n, 0)
    err = {}
    for mode in ("scale", "affine", "planar"):
        fit = depth_fits(tr, pred, min_points=8, mode=mode)
        d = apply_depth_fit(wrong, fit[1], K)
        roll = np.arcsin(np.clip(np.abs(normals_from_depth(d, K)[4:-4, 4:-4, 0]), 0, 1))  # the true normal has no x
        err[mode] = (float(np.median(np.abs(d / truth - 1))), float(np.degrees(np.median(roll))))
    assert err["planar"][0] < 0.01 and err["planar"][1] < 0.5, err  # printed on failure: (depth rel. error, roll deg)
    assert err["scale"][1] > 4 and err["affine"][1] > 4, err  # the roll stays without the plane terms
    with pytest.raises(ValueError, match="intrinsics"):
        apply_depth_fit(wrong, np.array([1.0, 0.0, 0.1, 0.0]))
    with pytest.raises(ValueError, match="planar"):
        depth_fits(tr, pred, min_points=8, mode="plane")


def test_estimator_forward_shapes_and_units():
    import torch

    from lightcrafter.recon.estimator import GBufferNet, predict

    torch.manual_seed(0)
    m = GBufferNet([8, 16, 16])
    p = predict(m, np.random.default_rng(0).random((2, 32, 48, 3)).astype(np.float32))
    assert p["depth"].shape == (2, 32, 48) and (p["depth"] > 0).all()
    np.testing.assert_allclose(np.linalg.norm(p["normal_cam"], axis=-1), 1.0, atol=1e-5)
    for k in ("albedo", "roughness", "metallic", "mask"):
        assert p[k].min() >= 0 and p[k].max() <= 1
    with pytest.raises(ValueError, match="multiples of 4"):
        m(torch.zeros(1, 3, 30, 48))


def test_shading_ratio_albedo_keeps_the_inputs_colour_and_level():
    """With albedo_head shading_ratio the albedo follows the input's absolute colour: the same frame with its
    linear red doubled about doubles the albedo's red where it does not clip (the shading S, seen through
    group norms, moves little); green and blue stay. The direct head of the same weights barely moves (its
    group norms remove a frame's uniform colour)."""
    import torch

    from lightcrafter import io
    from lightcrafter.recon.estimator import GBufferNet, predict

    rng = np.random.default_rng(0)
    lin = (0.05 + 0.2 * rng.random((32, 48, 3))).astype(np.float32)
    red = lin * np.float32([2.0, 1.0, 1.0])
    nets = {}
    for head in ("direct", "shading_ratio"):
        torch.manual_seed(0)
        nets[head] = GBufferNet([8, 16], head)
    # the same U-Net with the other head (its light tint starts at none)
    nets["shading_ratio"].load_state_dict(nets["direct"].state_dict(), strict=False)
    a, b = (predict(nets["shading_ratio"], io.linear_to_display(x))["albedo"] for x in (lin, red))
    ok = b[..., 0] < 1
    assert ok.mean() > 0.5
    gain = np.median(b[..., 0][ok] / a[..., 0][ok])
    assert 1.7 < gain < 2.5, gain
    assert abs(np.median(b[..., 1:] / a[..., 1:]) - 1) < 0.25
    d0, d1 = (predict(nets["direct"], io.linear_to_display(x))["albedo"] for x in (lin, red))
    assert abs(np.median(d1[..., 0] / d0[..., 0]) - 1) < 0.2
    with pytest.raises(ValueError, match="albedo_head"):
        GBufferNet([8, 16], "ratio")


def _flat_surface(albedo: np.ndarray, h: int = 16, w: int = 24) -> tuple[np.ndarray, io.Buffers]:
    """A frame (display values, 16x24 by default) of one uniform surface of linear ``albedo`` facing the camera
    4 m away, lit to shading 0.7 (as scenes.white_radiance lights the ground), and its ground-truth buffers."""
    a = np.broadcast_to(np.float32(albedo), (h, w, 3)).copy()
    b = io.Buffers(depth=np.full((h, w), 4.0, np.float32), normal=np.broadcast_to(np.float32([0, 0, 1]), (h, w, 3)),
                   albedo=a, roughness=np.full((h, w), 0.5, np.float32), metallic=np.zeros((h, w), np.float32),
                   mask=np.ones((h, w), np.float32))
    return io.linear_to_display(a * np.float32(0.7)), b


def test_direct_colour_head_tells_a_pink_ground_from_a_grey_one():
    """Two frames of one uniform surface under the same light, pink (albedo 0.6, 0.35, 0.35) and grey (0.4):
    the direct head's group norms normalise a uniform colour away, so after training on both it gives them
    one albedo (each off by about half their difference); direct_colour, whose head sees the input's colour,
    fits both."""
    from lightcrafter.recon import estimator as est

    frames = [_flat_surface(alb) for alb in ((0.6, 0.35, 0.35), (0.4, 0.4, 0.4))]
    samples = [est.sample_from(rgb, b, np.eye(4)) for rgb, b in frames]
    err = {}
    for head in ("direct", "direct_colour"):
        cfg = est.EstimatorConfig(widths=[8, 16], steps=150, batch=2, crop=None, lr=1e-2, eval_every=150,
                                  keep_best=False, threads=1, albedo_head=head)
        model, _ = est.train_estimator(samples, [], cfg, log=lambda m: None)
        pred = est.predict(model, np.stack([rgb for rgb, _ in frames]))["albedo"]
        err[head] = max(float(np.abs(pred[i] - f[1].albedo).mean()) for i, f in enumerate(frames))
    assert err["direct"] > 0.04, err  # half the mean channel difference is 0.05
    assert err["direct_colour"] < 0.02, err


def test_white_balance_augmentation_keeps_the_light_colour_out_of_the_albedo():
    """A grey (0.4) and a pink (0.6, 0.35, 0.35) surface under a white light are the training set. Shown the grey
    surface under a pink light (a frame that looks like the pink surface), the estimator trained without
    recon.estimator.augment_wb_ev calls it pink; the one trained with it (each frame under a light of another
    colour) has learnt that a frame's colour may be the light's, and its albedo moves toward grey."""
    from lightcrafter.recon import estimator as est

    surfaces = [np.float32([0.4, 0.4, 0.4]), np.float32([0.6, 0.35, 0.35])]
    samples = [est.sample_from(*_flat_surface(alb), np.eye(4)) for alb in surfaces]
    shown = _flat_surface(surfaces[1])[0]  # the pink surface's frame: also the grey one under a pink light
    err = {}
    for wb in (0.0, 1.0):
        cfg = est.EstimatorConfig(widths=[8, 16], steps=150, batch=4, crop=None, lr=1e-2, eval_every=150,
                                  keep_best=False, threads=1, albedo_head="direct_colour", augment_wb_ev=wb)
        model, _ = est.train_estimator(samples, [], cfg, log=lambda m: None)
        pred = est.predict(model, shown[None])["albedo"][0]
        err[wb] = float(np.abs(pred - surfaces[0]).mean())  # against the grey surface the frame also could be
    assert err[0.0] > 0.08, err  # pink: (0.2 + 0.05 + 0.05) / 3 = 0.1 from grey
    assert err[1.0] < 0.8 * err[0.0], err  # seeds 0-2: 0.66-0.72 of it


def test_shading_ratio_albedo_is_pulled_down_where_it_clips():
    """Where input / S exceeds 1 the albedo is 1 and its loss still has a gradient on S, so an over-bright
    estimate can fall below 1 again."""
    import torch

    from lightcrafter.recon.estimator import GBufferNet

    torch.manual_seed(0)
    net = GBufferNet([8, 16], "shading_ratio")
    rgb = torch.full((1, 3, 16, 16), 0.99)
    raw = torch.full((1, 3, 16, 16), -3.0, requires_grad=True)  # tiny shading: ratio far above 1
    alb = net._albedo(raw, rgb)
    assert float(alb.detach().max()) == 1.0
    (alb - 0.5).abs().mean().backward()
    assert raw.grad is not None and float(raw.grad.mean()) < 0  # a larger shading lowers the loss


def test_saved_estimator_loads_with_its_albedo_head(tmp_path):
    """The head is part of the saved config: a shading-ratio estimator loads as one and predicts the same."""
    import torch

    from lightcrafter.recon import estimator as est

    torch.manual_seed(0)
    cfg = est.EstimatorConfig(widths=[8, 16], albedo_head="shading_ratio")
    net = est.GBufferNet(cfg.widths, cfg.albedo_head)
    with torch.no_grad():
        net.light_tint.weight.copy_(torch.eye(3))
    est.save(net, cfg, tmp_path / "e.pt")
    back = est.load(tmp_path / "e.pt")
    assert back.albedo_head == "shading_ratio"
    x = np.random.default_rng(0).random((16, 24, 3)).astype(np.float32)
    np.testing.assert_array_equal(est.predict(back, x)["albedo"], est.predict(net, x)["albedo"])


def test_estimator_learns_a_clip(tmp_path):
    """A few hundred steps on one clip beat the untrained network on its depth and normals."""
    from lightcrafter.recon import estimator as est

    _gt_clip(tmp_path / "gt")
    views, _ = clipmod.read_clip(tmp_path / "gt")
    samples, val = [], []
    for v in views:
        rgb = np.clip(v.buffers.albedo * (0.3 + 0.7 * np.clip(v.buffers.normal[..., 2:], 0, 1)), 0, 1)
        rgb = np.where(v.buffers.mask[..., None] > 0, rgb, 0.8)
        samples.append(est.sample_from(rgb, v.buffers, v.c2w))
        val.append((rgb, v.buffers, v.c2w))
    cfg = est.EstimatorConfig(widths=[8, 16, 16], steps=150, batch=4, crop=None, eval_every=150, lr=3e-3, threads=1)
    untrained = est._validation_errors(est.GBufferNet(cfg.widths), val)
    _, curve = est.train_estimator(samples, val, cfg, log=lambda m: None)
    assert curve[-1]["normal_deg"] < 0.7 * untrained["normal_deg"]
    assert curve[-1]["mask_iou"] > 0.9


def test_training_script_takes_a_clip_once_per_video_it_is_paired_with(tmp_path):
    """scripts/train_estimator.py with one clip under two lights (scenes.recon_lightings: 2): every frame of both
    videos trains (a clip repeats in --clips, once per video), and the weights are written."""
    import subprocess
    import sys

    from lightcrafter.recon import estimator as est

    _gt_clip(tmp_path / "gt")
    views, _ = clipmod.read_clip(tmp_path / "gt")
    videos = []
    for light, tint in (("L0", (1.0, 0.9, 0.8)), ("L2", (0.6, 0.7, 1.0))):
        for i, v in enumerate(views):
            shade = np.clip(v.buffers.normal[..., 2:], 0, 1) * np.asarray(tint, np.float32)
            io.write_rgb_exr(tmp_path / "rgb" / light / f"{i:04d}.exr",
                             np.where(v.buffers.mask[..., None] > 0, v.buffers.albedo * shade, 0.5).astype(np.float32))
        videos.append(str(tmp_path / "rgb" / f"{light}.json"))
    clip = str(tmp_path / "gt" / "buffers.json")
    cfg = json.dumps({"widths": [8, 16], "steps": 2, "batch": 2, "crop": None, "eval_every": 2, "threads": 1})
    res = subprocess.run([sys.executable, str(REPO / "scripts" / "train_estimator.py"), "--clips", clip, clip,
                          "--videos", *videos, "--config-json", cfg, "--out", str(tmp_path / "m.pt"),
                          "--curve", str(tmp_path / "curve.json")], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert f"train_estimator: {2 * len(views)} frames, 2 steps" in res.stdout
    assert est.load(tmp_path / "m.pt").albedo_head == "direct"


def test_static_detection_survives_a_rotating_light():
    """A fixed camera whose lighting changes between frames is static; a panning one is not."""
    from lightcrafter.recon.cameras import median_motion_px

    rng = np.random.default_rng(1)
    tex = (rng.random((80, 120)) > 0.5).astype(np.float32)
    import cv2

    tex = cv2.GaussianBlur(tex, (0, 0), 1.0)
    frames_static, frames_pan = [], []
    for i in range(5):
        shade = 0.4 + 0.5 * np.clip(np.sin(np.linspace(0, 3, 120)[None, :] + i), 0, 1)  # moving shading
        frames_static.append(np.repeat((tex * shade * 255)[..., None], 3, -1).astype(np.uint8)[:64, :96])
        frames_pan.append(np.repeat((tex * 200)[..., None], 3, -1).astype(np.uint8)[:64, 3 * i:3 * i + 96])
    assert median_motion_px(np.stack(frames_static)) < 0.5
    assert median_motion_px(np.stack(frames_pan)) > 2.0


def test_a_camera_far_off_the_path_counts_as_unregistered():
    """A study clip's structure from motion put one of 13 cameras 1.9e8 times farther from the path than the
    others, and Align turned that into cameras 6e7 m off: such a camera is dropped, the rest of a path kept."""
    from lightcrafter.recon.cameras import FAR_CAMERA_FACTOR, drop_far_cameras

    n = 13
    c2w = np.repeat(np.eye(4)[None], n, axis=0)
    c2w[:, :3, 3] = np.linspace([2.6, 4.1, -0.1], [-4.3, -6.0, 0.1], n)  # a straight path, as that clip's
    reg = np.ones(n, bool)
    assert drop_far_cameras(c2w, reg).all()  # the path's ends are ~2x the median distance
    far = c2w.copy()
    far[10, :3, 3] = (3.3e8, 4.8e8, 2.5e8)
    kept = drop_far_cameras(far, reg)
    assert kept.sum() == n - 1 and not kept[10]
    near_limit = c2w.copy()
    typical = np.median(np.linalg.norm(c2w[:, :3, 3] - np.median(c2w[:, :3, 3], 0), axis=1))
    near_limit[10, :3, 3] = np.median(c2w[:, :3, 3], 0) + [0.9 * FAR_CAMERA_FACTOR * typical, 0.0, 0.0]
    assert drop_far_cameras(near_limit, reg).all()
    still = np.repeat(np.eye(4)[None], n, axis=0)  # every camera at one point: nothing to measure, all kept
    assert drop_far_cameras(still, reg).all()
    unreg = reg.copy()
    unreg[[0, 1]] = False  # frames already unregistered stay so
    assert (drop_far_cameras(far, unreg) == (unreg & kept)).all()


def _orbit_c2w(n: int, step_deg: float = 4.0) -> np.ndarray:
    """(n, 4, 4) camera-to-world poses (OpenCV axes) of an orbit at constant speed around +Z, 3 m out and 1 m up,
    looking at the origin."""
    out = np.repeat(np.eye(4)[None], n, 0)
    for k in range(n):
        th = np.radians(step_deg * k)
        c = np.array([3 * np.cos(th), 3 * np.sin(th), 1.0])
        f = -c / np.linalg.norm(c)
        r = np.cross(f, [0.0, 0.0, 1.0])
        r /= np.linalg.norm(r)
        out[k, :3, :3] = np.stack([r, np.cross(r, f) * -1, f], 1)
        out[k, :3, 3] = c
    return out


def test_unregistered_frames_continue_the_cameras_motion():
    """recon.sfm.fill_unregistered: ``motion`` poses the frames SfM left out of an orbit at constant speed exactly,
    in a gap and past both ends of the clip (``nearest`` is 4 degrees per missing frame off); registered frames
    keep their poses; a half turn between registered frames (no real logarithm) falls back to the nearest pose;
    the mode is checked."""
    from lightcrafter.config.models import SfM
    from lightcrafter.recon.cameras import fill_unregistered_poses
    from lightcrafter.recon.evaluate import rotation_angle_deg

    gt = _orbit_c2w(13)
    reg = np.ones(13, bool)
    reg[[0, 1, 2, 3, 7, 8, 12]] = False
    seen = np.where(reg[:, None, None], gt, np.nan)
    near = fill_unregistered_poses(seen, reg, "nearest")
    moved = fill_unregistered_poses(seen, reg, SfM(fill_unregistered="motion").fill_unregistered)
    assert np.allclose(moved[reg], gt[reg]) and np.allclose(near[reg], gt[reg])
    assert np.allclose(moved, gt, atol=1e-8)
    near_err = [rotation_angle_deg(near[i, :3, :3], gt[i, :3, :3]) for i in range(13)]
    assert max(near_err) == pytest.approx(16.0, abs=1e-6)  # frame 0 takes frame 4's pose
    half = np.repeat(np.eye(4)[None], 3, 0)
    half[2, :3, :3] = np.diag([-1.0, -1.0, 1.0])  # a half turn about z between frames 0 and 2
    got = fill_unregistered_poses(half, np.array([True, False, True]), "motion")
    assert np.all(np.isfinite(got)) and (np.allclose(got[1], half[0]) or np.allclose(got[1], half[2]))
    with pytest.raises(ValueError, match="fill_unregistered='spline'"):
        fill_unregistered_poses(gt, reg, "spline")


def test_a_frame_posed_against_a_wrong_part_of_the_model_counts_as_unregistered():
    """A frame whose depth scale (its SfM points' depths over the estimator's) is more than
    recon.sfm.max_depth_scale_ratio off the clip's median frame was posed against a wrong part of the model: it
    counts as unregistered and is posed on the path between its neighbours (or takes a neighbour's pose with
    fill_unregistered: nearest); a consistent clip, and frames with too few points to
    measure, keep theirs; too few frames left is the usual one-line error; the manifest counts the outliers and
    the spread."""
    from lightcrafter.config.models import SfM
    from lightcrafter.recon import cameras

    rng = np.random.default_rng(0)
    n, h, w = 9, 48, 64
    K = cameras.intrinsics(w, h, 1.0)
    pts = np.column_stack([rng.uniform(-1, 1, 200), rng.uniform(-0.7, 0.7, 200), rng.uniform(3, 6, 200)])
    c2w = np.repeat(np.eye(4)[None], n, axis=0)
    c2w[:, 0, 3] = np.linspace(-0.3, 0.3, n)  # a sideways path, OpenCV axes, looking along +z
    depth = np.zeros((n, h, w))
    obs = []
    for i in range(n):
        pc = pts - c2w[i, :3, 3]
        uv = (pc @ K.T)[:, :2] / pc[:, 2:]
        inside = (uv[:, 0] > 0) & (uv[:, 0] < w - 1) & (uv[:, 1] > 0) & (uv[:, 1] < h - 1)
        obs.append((uv[inside], np.flatnonzero(inside)))
        col, row = np.rint(uv[inside]).astype(int).T
        depth[i] = 4.5
        depth[i, row, col] = pc[inside, 2] * 0.5 * (1 + 0.05 * rng.standard_normal())  # estimator units: 2x off
    track = cameras.CameraTrack(K=np.repeat(K[None], n, 0), c2w=c2w, registered=np.ones(n, bool), points=pts,
                                observations=obs, static=False)
    scales, off = cameras.depth_scale_outliers(track, depth, 10.0)
    assert np.allclose(scales, 2.0, rtol=0.2) and not off.any()  # one scale over the clip: nothing dropped
    bad = depth.copy()
    bad[6] *= 200.0  # frame 6 posed 200x off the rest
    scales, off = cameras.depth_scale_outliers(track, bad, 10.0)
    assert np.flatnonzero(off).tolist() == [6]
    few = cameras.CameraTrack(**{**track.__dict__, "observations": [o if i != 6 else (o[0][:3], o[1][:3])
                                                                   for i, o in enumerate(obs)]})
    scales, off = cameras.depth_scale_outliers(few, bad, 10.0)
    assert np.isnan(scales[6]) and not off.any()  # 3 points are too few to measure: no verdict

    got = cameras.accept_model(K, c2w, np.ones(n, bool), pts, obs, SfM(), "c", depth=bad)  # what _colmap returns
    assert not got.registered[6] and got.registered.sum() == n - 1 and len(got.observations[6][1]) == 0
    assert np.allclose(got.c2w[6], c2w[6])  # posed on the path between its neighbours (fill_unregistered: motion)
    near = cameras.accept_model(K, c2w, np.ones(n, bool), pts, obs, SfM(fill_unregistered="nearest"), "c", depth=bad)
    assert np.allclose(near.c2w[6], c2w[5]) or np.allclose(near.c2w[6], c2w[7])  # a neighbour's pose
    assert got.info["depth_scale_outliers"] == 1 and got.info["depth_scale_spread"] > 100
    kept = cameras.accept_model(K, c2w, np.ones(n, bool), pts, obs, SfM(max_depth_scale_ratio=None), "c", depth=bad)
    assert kept.registered.all() and "depth_scale_outliers" not in kept.info  # null: off
    worse = bad.copy()
    worse[[1, 2, 3, 4]] *= 300.0  # frames 1-4 and 6 at 200-600x, the 4 others at 1x: 4 dropped, 5/9 < 60 %
    with pytest.raises(cameras.ReconstructionError, match=r"^c: .*registered 5/9 frames .*4 at another depth scale"):
        cameras.accept_model(K, c2w, np.ones(n, bool), pts, obs, SfM(), "c", depth=worse)
    assert SfM(max_depth_scale_ratio=None).max_depth_scale_ratio is None


def test_static_detection_looks_at_the_surface_not_a_background_turning_with_the_light():
    """A fixed camera over a static table whose background (the environment map at infinity) turns with a
    rotating light, as in a study clip that structure from motion then took for a moving camera: the surface
    keeps still; without the surface mask the background's motion dominates."""
    import cv2

    from lightcrafter.recon.cameras import median_motion_px

    rng = np.random.default_rng(2)
    fg = cv2.GaussianBlur((rng.random((64, 96)) > 0.5).astype(np.float32), (0, 0), 1.0)
    bg = cv2.GaussianBlur((rng.random((40, 400)) > 0.5).astype(np.float32), (0, 0), 1.0)
    frames, surface = [], []
    for i in range(5):
        f = np.zeros((64, 96), np.float32)
        f[:40] = bg[:, 6 * i:6 * i + 96]  # the environment turns: 6 px per frame
        f[40:] = fg[40:]
        frames.append(np.repeat((f * 220 + 20)[..., None], 3, -1).astype(np.uint8))
        m = np.zeros((64, 96), bool)
        m[40:] = True
        surface.append(m)
    frames, surface = np.stack(frames), np.stack(surface)
    assert median_motion_px(frames) > 2.0
    assert median_motion_px(frames, surface=surface) < 0.5
    assert median_motion_px(frames, surface=np.zeros_like(surface)) == median_motion_px(frames)  # no surface


def test_static_ground_truth_camera_takes_its_scale_from_depth_not_from_the_estimates_jitter():
    """A static camera (the paper's static_rotating_light motion) reconstructed with a little drift:
    the centres' spread ratio would be ~0 (or an error); the depth maps give the true scale."""
    n = 5
    gt = np.repeat(np.eye(4)[None], n, axis=0)
    gt[:, :3, 3] = (1.0, -4.0, 1.5)
    est = np.repeat(np.eye(4)[None], n, axis=0)
    est[:, 2, 3] = 0.01 * np.arange(n)                    # drift of a monocular tracker
    d_gt = [np.full((4, 6), 3.0, np.float32)] * n
    d_est = [np.full((4, 6), 1.5, np.float32)] * n      # scale 2 in the depth maps
    sim = align.estimate(est, gt, d_est, d_gt)
    assert abs(sim.scale - 2.0) < 1e-9 and abs(sim.depth_scale - 1.0) < 1e-9


def test_sfm_retries_its_overrides_in_order_and_records_the_attempt_that_succeeded(monkeypatch):
    """recon.sfm.retry: a clip the configured settings reject is run again with each override in turn; the
    track says which attempt registered it; when every attempt fails the error names the clip and the count;
    an override with an unknown key is a one-line config error."""
    from lightcrafter.config import ConfigError
    from lightcrafter.config.models import SfM
    from lightcrafter.recon import cameras

    seen = []

    def fake_colmap(frames, K, s, name, tmp, depth=None):
        seen.append((s.upscale, s.init_min_tri_angle_deg))
        if s.init_min_tri_angle_deg > 5:
            raise cameras.ReconstructionError(f"{name}: structure from motion found no model")
        return cameras.CameraTrack(
            K=np.repeat(K[None], len(frames), 0), c2w=np.repeat(np.eye(4)[None], len(frames), 0),
            registered=np.ones(len(frames), bool), points=np.zeros((0, 3)),
            observations=[(np.zeros((0, 2)), np.zeros(0, np.int64))] * len(frames), static=False,
            info={"method": "colmap"})

    monkeypatch.setattr(cameras, "_colmap", fake_colmap)
    monkeypatch.setattr(cameras, "median_motion_px", lambda frames, **kw: 5.0)  # a moving camera
    frames = np.zeros((4, 16, 24, 3), np.uint8)
    s = SfM(upscale=2, init_min_tri_angle_deg=8.0,
            retry=[{"init_min_tri_angle_deg": 6.0}, {"init_min_tri_angle_deg": 4.0, "abs_pose_min_num_inliers": 15}])
    track = cameras.estimate_cameras(frames, 0.9, s, name="clipA")
    assert seen == [(2, 8.0), (2, 6.0), (2, 4.0)]  # in order, each keeping the keys it does not override
    assert track.info["sfm_attempt"] == 2 and len(track.info["sfm_failed_attempts"]) == 2
    seen.clear()
    track = cameras.estimate_cameras(frames, 0.9, SfM(init_min_tri_angle_deg=4.0, retry=[{"upscale": 2}]), name="b")
    assert seen == [(1, 4.0)] and track.info["sfm_attempt"] == 0 and "sfm_failed_attempts" not in track.info
    with pytest.raises(cameras.ReconstructionError, match=r"clipC: .*no model \(after 2 attempts"):
        cameras.estimate_cameras(frames, 0.9, SfM(retry=[{"upscale": 3}]), name="clipC")
    with pytest.raises(ConfigError, match=r"recon\.sfm.*retry\[0\] has unknown key\(s\) \['upscal'\]"):
        from lightcrafter.config import validate_section

        validate_section(SfM, {"retry": [{"upscal": 2}]}, "recon.sfm")


def test_sfm_enlarges_small_frames_to_min_width_and_leaves_large_ones():
    """recon.sfm.min_width_px: the smallest integer factor (at most 4) that brings the frames to that width;
    frames already as wide are not enlarged (a user's 720-px video is not run at 1440 px)."""
    from lightcrafter.config.models import SfM

    s = SfM(min_width_px=320)
    assert [s.upscale_for(w) for w in (192, 160, 320, 720, 50)] == [2, 2, 1, 1, 4]
    assert SfM(upscale=3).upscale_for(720) == 3  # without min_width_px the fixed factor applies


def test_ground_tilt_is_the_angle_of_phis_mean_normal_on_the_true_ground():
    from dataclasses import replace

    from lightcrafter.recon.evaluate import ground_pixels, ground_tilt_deg

    h, w = 4, 6
    n_gt = np.zeros((h, w, 3), np.float32)
    n_gt[..., 2] = 1.0
    n_gt[0] = [1.0, 0.0, 0.0]  # a wall: not ground
    gt = io.Buffers(depth=np.full((h, w), 2.0, np.float32), normal=n_gt, albedo=np.zeros((h, w, 3), np.float32),
                    roughness=np.zeros((h, w), np.float32), metallic=np.zeros((h, w), np.float32),
                    mask=np.ones((h, w), np.float32))
    assert ground_pixels(gt).sum() == (h - 1) * w
    t = np.radians(10.0)
    n_phi = np.broadcast_to(np.array([np.sin(t), 0.0, np.cos(t)], np.float32), (h, w, 3)).copy()
    n_phi[0] = [0.0, 1.0, 0.0]  # Phi's wall is wrong too, but it is not ground
    phi = replace(gt, normal=n_phi)
    assert abs(ground_tilt_deg([phi, phi], [gt, gt]) - 10.0) < 1e-4
    assert ground_tilt_deg([gt], [gt]) < 1e-3
    no_ground = replace(gt, mask=np.zeros((h, w), np.float32))
    assert np.isnan(ground_tilt_deg([phi], [no_ground]))


def test_albedo_colour_gain_undoes_a_clip_wide_tint_from_the_pixels_surface_in_both():
    """Phi's albedo = the truth's under a per-channel tint (the light's colour taken into it), with garbage on
    a row that is not surface in Phi: the gain undoes the tint over both frames from the other pixels alone;
    with no pixel surface in both it is ones."""
    from dataclasses import replace

    from lightcrafter.recon.evaluate import albedo_colour_gain

    rng = np.random.default_rng(3)
    h, w = 8, 10
    frames_gt, frames_phi = [], []
    tint = np.array([0.8, 1.0, 1.25])
    for _ in range(2):
        a = rng.uniform(0.2, 0.7, (h, w, 3)).astype(np.float32)
        gt = io.Buffers(depth=np.full((h, w), 2.0, np.float32), normal=np.zeros((h, w, 3), np.float32), albedo=a,
                        roughness=np.zeros((h, w), np.float32), metallic=np.zeros((h, w), np.float32),
                        mask=np.ones((h, w), np.float32))
        mask = np.ones((h, w), np.float32)
        mask[0] = 0.0  # not surface in Phi: its (garbage) albedo must not count
        pa = (a * tint).astype(np.float32)
        pa[0] = 5.0
        frames_gt.append(gt)
        frames_phi.append(replace(gt, albedo=pa, mask=mask))
    g = albedo_colour_gain(frames_phi, frames_gt)
    np.testing.assert_allclose(g, 1.0 / tint, rtol=1e-5)
    assert np.all(albedo_colour_gain([replace(frames_phi[0], mask=np.zeros((h, w), np.float32))], frames_gt[:1]) == 1.0)


def _bricks(h: int = 48, w: int = 72) -> np.ndarray:
    """A brick-like albedo (H, W, 3): light tiles with one-pixel dark mortar lines every 4 pixels."""
    a = np.empty((h, w, 3), np.float32)
    a[:] = (0.55, 0.6, 0.65)
    a[::4] = (0.2, 0.2, 0.22)
    a[:, ::6] = (0.2, 0.2, 0.22)
    return a


def test_albedo_detail_gives_a_smooth_albedo_the_inputs_texture_but_not_the_shading():
    """The input = a brick albedo under smooth shading (a gradient across the frame); the estimator's albedo = the
    bricks blurred away. Its texture ratio brings the mortar lines back (error to the true albedo drops by more
    than half) and carries no shading: on a frame of uniform colour under the same gradient the ratio is 1."""
    import cv2

    from lightcrafter.recon.default import albedo_detail

    truth = _bricks()
    h, w = truth.shape[:2]
    shading = np.linspace(0.4, 1.6, w, dtype=np.float32)[None, :, None] * np.ones((h, 1, 1), np.float32)
    frame = truth * shading
    smooth = cv2.GaussianBlur(truth, (0, 0), 3.0)
    inner = (slice(4, -4), slice(4, -4))
    err = lambda a: float(np.sqrt(((a - truth)[inner] ** 2).mean()))  # noqa: E731
    detailed = np.clip(smooth * albedo_detail(frame[None], 1.0), 0, 1)
    assert err(detailed) < 0.5 * err(smooth)
    flat = np.full_like(truth, 0.5) * shading
    np.testing.assert_allclose(albedo_detail(flat[None], 1.0)[inner], 1.0, atol=2e-3)


def test_albedo_detail_of_a_static_view_leaves_out_an_edge_that_moves_with_the_light():
    """A static camera, the light rotating: a shadow's edge crosses the ground at another column in each of 5
    frames. The median over the frames gives the ground no edge (ratio 1 everywhere), while one frame alone
    would print the edge into the albedo."""
    from lightcrafter.recon.default import albedo_detail

    frames = np.full((5, 24, 40, 3), 0.6, np.float32)
    for k in range(5):
        frames[k, :, : 6 + 7 * k] *= 0.3  # in shadow left of a column that moves with the light
    assert np.abs(albedo_detail(frames[2:3], 1.0) - 1.0).max() > 0.3
    np.testing.assert_allclose(albedo_detail(frames, 1.0), 1.0, atol=1e-6)


def test_albedo_detail_is_one_on_black_and_bounded_on_extreme_frames():
    """Black frames give a ratio of 1 (the estimator's albedo is kept), and a 1e4-bright speck on black or on
    noise gives a finite ratio within its documented bounds."""
    from lightcrafter.recon.default import DETAIL_RATIO_RANGE, albedo_detail

    black = np.zeros((1, 16, 16, 3), np.float32)
    np.testing.assert_array_equal(albedo_detail(black, 1.0), 1.0)
    rng = np.random.default_rng(0)
    for base in (black[0], rng.random((16, 16, 3)).astype(np.float32)):
        f = base.copy()
        f[8, 8] = 1e4
        r = albedo_detail(f[None], 1.0)
        assert np.isfinite(r).all()
        assert r.min() >= DETAIL_RATIO_RANGE[0] and r.max() <= DETAIL_RATIO_RANGE[1]
