"""Envmap fitting (lightcrafter.envfit): the shared objective, both solvers against R and each
other, recovery of a known map / yaw, numerical stability and bad inputs, outputs and resume."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from lightcrafter import envmap, io
from lightcrafter.clip import read_clip, write_clip
from lightcrafter.envfit import synthetic as es
from lightcrafter.envfit.evaluate import TrueObjective, sh_error
from lightcrafter.envfit.fit import FitSettings, data_weights, fit_envmap, optimize, prepare
from lightcrafter.envfit.response import GAMMA_MAX, GAMMA_MIN, CameraResponse, fit_response
from lightcrafter.envfit.model import LOG_FLOOR_REL, EnvParams, MapHead, l1_tonemapped, log_of_map, tv_log
from lightcrafter.envfit.tracing import Tracer, bilinear_taps
from lightcrafter.envfit.transport import build_transport, memory_bound_bytes
from lightcrafter.io import DataError
from lightcrafter.proxy import synthetic as syn
from lightcrafter.proxy.lighting import Lighting, lighting_from_file
from lightcrafter.proxy.renderer import ProxyRenderer, RenderSettings

REPO = Path(__file__).resolve().parents[1]
W, H, N = 32, 24, 5
QUICK = dict(transport_spp=32, checkpoint_every=0)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A 5-frame orbit clip of four spheres on a ground plane and its video under sky_map()."""
    root = tmp_path_factory.mktemp("envfit")
    clip = es.write_synthetic_clip(root / "clip", n=N, width=W, height=H)
    env = es.sky_map()
    frames = es.render_video(clip, env, root / "frames", spp=64)
    return {"root": root, "clip": clip, "frames_dir": root / "frames", "env": env, "frames": frames}


def video_dir(root: Path, frames: np.ndarray) -> Path:
    for i, f in enumerate(frames):
        io.write_rgb_exr(root / f"{i:04d}.exr", f)
    return root


# ----------------------------------------------------------------------------- objective pieces
def test_map_head_is_envmap_rotate_and_exposure():
    rng = np.random.default_rng(0)
    env = (rng.random((16, 32, 3)) + 0.05).astype(np.float32)
    head = MapHead(16, 32)
    for yaw, pitch, ev in [(0.0, 0.0, 0.0), (0.3, 0.0, 1.0), (-1.1, 0.7, -0.5), (3.0, -0.4, 0.2)]:
        got = head.baked(EnvParams.create(np.log(env), yaw, pitch, ev))
        want = envmap.apply_exposure(envmap.rotate(env, yaw, pitch), ev)
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)


def test_yaw_pitch_gradients_match_finite_differences():
    rng = np.random.default_rng(1)
    head = MapHead(16, 32)
    env = torch.tensor(rng.random((16, 32, 3)) + 0.1, dtype=torch.float64)
    weight = torch.tensor(rng.random((16, 32, 3)))

    def f(y, p):
        return (head.rotate(env, y, p) * weight).sum()

    for y0, p0 in [(0.37, 0.21), (-0.9, -0.3), (2.5, 0.05)]:
        y = torch.tensor(y0, dtype=torch.float64, requires_grad=True)
        p = torch.tensor(p0, dtype=torch.float64, requires_grad=True)
        f(y, p).backward()
        eps = 1e-6
        t = lambda v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
        fd_y = (f(t(y0 + eps), t(p0)) - f(t(y0 - eps), t(p0))) / (2 * eps)
        fd_p = (f(t(y0), t(p0 + eps)) - f(t(y0), t(p0 - eps))) / (2 * eps)
        assert float(y.grad) == pytest.approx(float(fd_y), rel=1e-5, abs=1e-6)
        assert float(p.grad) == pytest.approx(float(fd_p), rel=1e-5, abs=1e-6)


def test_tv_wraps_around_u_and_its_gradient_across_the_seam():
    h, w = 6, 8
    lm = torch.zeros((h, w, 1), dtype=torch.float64)
    lm[:, 0] = 1.0  # a one-column ridge at u = 0: jumps to u = 1 and (wrapped) from u = W - 1
    assert float(tv_log(lm)) == pytest.approx(2 * h)  # both horizontal edges, no vertical ones
    lm2 = torch.zeros((h, w, 1), dtype=torch.float64)
    lm2[0] = 1.0  # a top-row ridge: one vertical edge per column, no wrap from the bottom row
    assert float(tv_log(lm2)) == pytest.approx(w)
    rng = np.random.default_rng(2)
    x = torch.tensor(rng.normal(size=(h, w, 3)), dtype=torch.float64, requires_grad=True)
    tv_log(x).backward()
    eps = 1e-7
    for r, c in [(2, 0), (2, w - 1), (0, 0), (h - 1, w - 1)]:
        for ch in range(3):
            xp, xm = x.detach().clone(), x.detach().clone()
            xp[r, c, ch] += eps
            xm[r, c, ch] -= eps
            fd = float(tv_log(xp) - tv_log(xm)) / (2 * eps)
            assert float(x.grad[r, c, ch]) == pytest.approx(fd, abs=1e-6)
    # a step exactly at the seam costs the same as anywhere else (u = W wraps to u = 0)
    a = torch.zeros((h, w, 1), dtype=torch.float64)
    a[:, : w // 2] = 1.0
    assert float(tv_log(a)) == pytest.approx(float(tv_log(torch.roll(a, 3, dims=1))))


def test_bilinear_taps_follow_the_envmap_convention():
    import drjit as dr
    import mitsuba as mi

    from lightcrafter.envfit.tracing import bilinear_taps_dr
    from lightcrafter.proxy.mitsuba_setup import ensure_variant

    ensure_variant()
    rng = np.random.default_rng(3)
    d = rng.normal(size=(500, 3))
    d = np.concatenate([d, [[1e-9, 0, 1], [0, 0, -1], [-1, 1e-9, 0], [-1, -1e-9, 0], [1, 0, 0]]])
    env = rng.random((16, 32, 3))
    idx, wts = bilinear_taps(d, 16, 32)
    got = (env.reshape(-1, 3)[idx] * wts[..., None]).sum(1)
    want = envmap.sample_bilinear(env, *envmap.direction_to_uv(d))
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12)
    idx_d, wts_d = bilinear_taps_dr(mi.Vector3f(*[mi.Float(d[:, k].astype(np.float32)) for k in range(3)]), 16, 32)
    got_d = sum(env.reshape(-1, 3)[np.asarray(i)] * np.asarray(w_)[:, None] for i, w_ in zip(idx_d, wts_d))
    dr.eval()
    np.testing.assert_allclose(got_d, want, atol=2e-4)


# ----------------------------------------------------------------------------- solvers vs R
def test_transport_and_reference_render_match_R_in_expectation(scene):
    """Both solvers' estimators of R(S^i, L) are unbiased against R itself (MIS), within MC noise."""
    from lightcrafter.envfit.reference import render_loss_and_grad

    views, _ = read_clip(scene["clip"])
    env = scene["env"]
    r = ProxyRenderer(Lighting(env=env), RenderSettings(spp=1024, seed=7))
    r.prepare(views)
    truth = r.render(views[2]).reshape(-1, 3).astype(np.float64)
    tracer = Tracer(views, RenderSettings())
    px = np.arange(W * H)
    t1 = build_transport(tracer, views[2], px, 256, seed=1).apply(env)
    t2 = build_transport(tracer, views[2], px, 256, seed=2).apply(env)
    noise = np.abs(t1 - t2).mean() / np.sqrt(2)  # per-pixel MC error of one 256-sample estimate
    assert np.abs(t1 - truth).mean() < 1.5 * noise + 1e-3
    se_of_mean = noise / np.sqrt(len(px))  # the frame mean averages the per-pixel errors away
    np.testing.assert_allclose(t1.mean(0), truth.mean(0), atol=8 * se_of_mean + 1e-3 * truth.mean())
    _, _, rad = render_loss_and_grad(tracer, views[2], px, np.zeros((len(px), 3)), env, 256, 99)
    np.testing.assert_allclose(rad.mean(0), truth.mean(0), atol=8 * se_of_mean + 1e-3 * truth.mean())


def test_reference_and_fast_objectives_agree_on_the_same_map(scene):
    """Same frame, same map (a perturbed one, so the residual is not just noise): the fast and the
    reference data terms and their gradients agree; both match R's own at high sample counts."""
    from lightcrafter.envfit.fast import build_fast_objective
    from lightcrafter.envfit.reference import ReferenceObjective

    s = FitSettings()
    pb = prepare(scene["clip"], scene["frames_dir"], s)
    env = torch.tensor(es.sky_map(lobe_dir=(0.4, -0.6, 0.5)) * 0.7)
    fast = build_fast_objective(pb.tracer, pb.views, pb.video, 0, 256, seed=5, env_height=64, env_width=128)
    ref = ReferenceObjective(pb.tracer, pb.views, pb.video, spp=256, pixels=0, seed=6)
    true = TrueObjective(pb, spp=512, reduction="mean")
    imgs = true.renders(env.numpy())
    for i in pb.video.fitted:
        e_f = env.clone().requires_grad_(True)
        lf = fast.data_loss(e_f, i, 0)
        lf.backward()
        e_r = env.clone().requires_grad_(True)
        lr = ref.data_loss(e_r, i, 0)
        lr.backward()
        px = pb.video.used[i]
        lt = l1_tonemapped(torch.tensor(imgs[i].reshape(-1, 3)[px]), fast.observed_tm[i].double())
        assert float(lf.detach()) == pytest.approx(float(lt), rel=0.03)
        assert float(lr.detach()) == pytest.approx(float(lt), rel=0.03)
        gf, gr = e_f.grad.numpy().ravel(), e_r.grad.numpy().ravel()
        assert np.corrcoef(gf, gr)[0, 1] > 0.9
        assert np.linalg.norm(gf) == pytest.approx(np.linalg.norm(gr), rel=0.1)
        # numpy-formed gradient == torch autograd through the sparse product
        e_a = env.clone().requires_grad_(True)
        fast.data_loss_autograd(e_a, i).backward()
        np.testing.assert_allclose(e_f.grad.numpy(), e_a.grad.numpy(), rtol=1e-4, atol=1e-9)


@pytest.mark.slow
def test_fit_recovers_low_frequency_content_and_rerender_psnr(scene):
    s = FitSettings(iterations=600, lr=1e-2, **QUICK)
    pb = prepare(scene["clip"], scene["frames_dir"], s)
    res = optimize(pb, s)
    true = scene["env"]
    before = sh_error(np.exp(pb.init_log_map), true)["aligned_relative_error"]
    after = sh_error(res.env, true)
    assert before > 0.3 and after["aligned_relative_error"] < 0.12, (before, after)
    ev = TrueObjective(pb, spp=128)(res.env, res.params["log_map"])
    assert ev["psnr_db"] > 36.0, ev
    assert all(np.isfinite([p["loss"] for p in res.curve]))


def test_reference_solver_descends_and_moves_every_parameter(scene):
    s = FitSettings(solver="reference", iterations=80, lr=1e-2, ref_spp=4, checkpoint_every=0)
    pb = prepare(scene["clip"], scene["frames_dir"], s)
    res = optimize(pb, s)
    losses = [p["loss"] for p in res.curve]
    assert np.mean(losses[-15:]) < 0.7 * np.mean(losses[:15])
    assert res.params["yaw_rad"] != 0 and res.params["pitch_rad"] != 0 and res.params["exposure_ev"] != 0
    assert np.abs(res.params["log_map"] - pb.init_log_map).max() > 0.1


def test_known_yaw_comes_back(scene, tmp_path):
    """Video under the known map turned by 0.3 rad: starting from the unturned map (map held fixed,
    so yaw is not absorbed by the texels), the fitted yaw is 0.3 rad within 0.02 rad (< half a texel,
    2 pi / 128 = 0.049 rad) and pitch stays within 0.02 rad of 0."""
    yaw = 0.3
    es.render_video(scene["clip"], envmap.rotate(scene["env"], yaw), tmp_path, spp=64)
    s = FitSettings(iterations=300, fit_map=False, init_match_mean=False, **QUICK)
    pb = prepare(scene["clip"], tmp_path, s, init_map=scene["env"])
    res = optimize(pb, s)
    assert res.params["yaw_rad"] == pytest.approx(yaw, abs=0.02)
    assert abs(res.params["pitch_rad"]) < 0.02
    assert abs(res.params["exposure_ev"]) < 0.05


# ----------------------------------------------------------------------------- stability
def test_sun_1e5_times_the_sky_stays_finite(scene, tmp_path):
    env = es.sky_map(sun=1e5)
    es.render_video(scene["clip"], env, tmp_path, spp=64)
    s = FitSettings(iterations=300, lr=1e-2, **QUICK)
    pb = prepare(scene["clip"], tmp_path, s)
    res = optimize(pb, s)
    losses = np.array([p["loss"] for p in res.curve])
    assert np.isfinite(losses).all() and np.isfinite(res.env).all() and (res.env > 0).all()
    assert losses[-30:].mean() < losses[:30].mean()
    # starting from the true map (sun included): the log floor keeps it finite and it does not diverge
    s2 = replace(s, init_match_mean=False, iterations=100)
    pb2 = prepare(scene["clip"], tmp_path, s2, init_map=env)
    res2 = optimize(pb2, s2)
    assert np.isfinite(res2.env).all() and res2.env.max() > 1e3
    assert np.mean([p["loss"] for p in res2.curve[-20:]]) < 2 * res2.curve[0]["loss"] + 1.0


def test_black_and_saturated_videos(scene, tmp_path):
    frames = scene["frames"]
    with pytest.raises(DataError, match="black"):
        prepare(scene["clip"], video_dir(tmp_path / "black", np.zeros_like(frames)), FitSettings())
    with pytest.raises(DataError, match="saturated"):
        prepare(scene["clip"], video_dir(tmp_path / "white", np.ones_like(frames)), FitSettings())
    # one black frame among fitted ones: dropped and reported, the fit still runs
    part = frames.copy()
    part[0] = 0
    s = FitSettings(iterations=50, **QUICK)
    pb = prepare(scene["clip"], video_dir(tmp_path / "part", part), s)
    assert pb.video.dropped_black == [0] and pb.video.fitted == [4]
    assert np.isfinite(optimize(pb, s).env).all()
    # a video clipped at a level (plateau): detected, clipped pixels left out
    level = float(np.quantile(frames, 0.9))
    pb = prepare(scene["clip"], video_dir(tmp_path / "clip", np.minimum(frames, level)), s)
    assert pb.video.saturation_level == pytest.approx(level) and pb.video.saturated_pixels > 0
    assert all(pb.video.frames[i].reshape(-1, 3)[pb.video.used[i]].max() < level for i in pb.video.fitted)
    # an HDR render has no plateau: nothing is cut
    assert prepare(scene["clip"], scene["frames_dir"], s).video.saturation_level is None


def test_static_and_one_frame_clips(tmp_path):
    static = es.write_synthetic_clip(tmp_path / "static", n=9, width=W, height=H, static=True)
    es.render_video(static, es.sky_map(), tmp_path / "sf", spp=32)
    s = FitSettings(iterations=60, **QUICK)
    pb = prepare(static, tmp_path / "sf", s)
    res = optimize(pb, s)
    assert pb.video.fitted == [0, 4, 8] and res.stats["transport_matrices"] == 1  # one view, one matrix
    assert np.isfinite(res.env).all()
    one = es.write_synthetic_clip(tmp_path / "one", n=1, width=W, height=H)
    es.render_video(one, es.sky_map(), tmp_path / "of", spp=32)
    for solver in ("fast", "reference"):
        s1 = FitSettings(solver=solver, iterations=20, ref_spp=2, **QUICK)
        pb1 = prepare(one, tmp_path / "of", s1)
        assert pb1.video.fitted == [0] and np.isfinite(optimize(pb1, s1).env).all()


def test_moving_objects_use_each_frames_own_visibility(scene, tmp_path):
    """scene_static false (objects move): R's visibility is the frame's own mesh, for both solvers."""
    import shutil

    clip = tmp_path / "dyn"
    shutil.copytree(scene["clip"], clip)
    man = json.loads((clip / "buffers.json").read_text())
    man["scene_static"] = False
    io.write_json(clip / "buffers.json", man)
    for solver in ("fast", "reference"):
        s = FitSettings(solver=solver, iterations=10, ref_spp=2, **QUICK)
        pb = prepare(clip, scene["frames_dir"], s)
        assert pb.render.visibility == "frame"
        assert np.isfinite(optimize(pb, s).env).all()


def test_log_of_zero_radiance_is_floored():
    env = np.ones((4, 8, 3), np.float32)
    env[1, 2] = 0.0
    lm = log_of_map(env)
    assert np.isfinite(lm).all()
    assert lm[1, 2, 0] == pytest.approx(np.log(LOG_FLOOR_REL * env.mean()), rel=1e-5)
    with pytest.raises(DataError, match="all zero"):
        log_of_map(np.zeros((4, 8, 3)), "init.exr")


def test_init_map_with_black_texels_and_all_black_init(scene, tmp_path):
    env = scene["env"].copy()
    env[:10] = 0.0  # black sky band
    s = FitSettings(iterations=40, **QUICK)
    pb = prepare(scene["clip"], scene["frames_dir"], s, init_map=env)
    assert np.isfinite(pb.init_log_map).all()
    assert np.isfinite(optimize(pb, s).env).all()
    path = tmp_path / "black.exr"
    io.write_rgb_exr(path, np.zeros((8, 16, 3), np.float32))
    with pytest.raises(DataError, match="black.exr"):
        prepare(scene["clip"], scene["frames_dir"], s, init_map=path)


def test_inputs_that_cannot_be_fitted(scene, tmp_path):
    frames = scene["frames"]
    d = video_dir(tmp_path / "short", frames[:-1])
    with pytest.raises(DataError, match="4 frames"):
        prepare(scene["clip"], d, FitSettings())
    d = video_dir(tmp_path / "long", np.concatenate([frames, frames[:1]]))
    with pytest.raises(DataError, match="unexpected"):
        prepare(scene["clip"], d, FitSettings())
    d = video_dir(tmp_path / "size", frames[:, :-1])
    with pytest.raises(DataError, match="clip's resolution"):
        prepare(scene["clip"], d, FitSettings())
    with pytest.raises(DataError, match="not found"):
        prepare(scene["clip"], tmp_path / "nope", FitSettings())
    bad = frames.copy()
    bad[1, 3, 3, 0] = np.nan
    d = video_dir(tmp_path / "nan", bad)
    with pytest.raises(DataError, match="0001.exr"):
        prepare(scene["clip"], d, FitSettings())
    # a clip that sees only sky: no valid pixel
    sky = tmp_path / "skyclip"
    K = syn.intrinsics(W, H, 0.9)
    c2w = syn.look_at([0, 0, 1.0], [1.0, 0.0, 1.6])
    io.write_buffers(sky / "buffers" / "0000.exr", syn.raycast_buffers(K, c2w, W, H, [], None))
    write_clip(sky, serve=[0], K=[K], c2w=[c2w], width=W, height=H, fps=24, camera_static=True, scene_static=True,
               units="metres", producer={"stage": "test"}, content_id="sky")
    d = video_dir(tmp_path / "skyframes", frames[:1])
    with pytest.raises(DataError, match="no valid pixel"):
        prepare(sky, d, FitSettings())


# ----------------------------------------------------------------------------- outputs and resume
def test_fit_envmap_outputs_render_with_R_and_rerun_is_skipped(scene, tmp_path):
    out = tmp_path / "fit"
    s = FitSettings(iterations=120, lr=1e-2, **QUICK)
    render = RenderSettings(spp=4)
    m = fit_envmap(scene["clip"], scene["frames_dir"], out, s, render)
    env = io.read_rgb_exr(out / "envmap.exr")
    assert env.shape == (64, 128, 3) and np.isfinite(env).all()
    lt = lighting_from_file(out / "lighting.json")
    np.testing.assert_array_equal(lt.env, env)  # baked: the lighting file adds no rotation / exposure
    p = np.load(out / "params.npz")
    head = MapHead(64, 128)
    np.testing.assert_allclose(head.baked(EnvParams.create(p["log_map"], float(p["yaw_rad"]), float(p["pitch_rad"]),
                                                           float(p["exposure_ev"]))), env, rtol=1e-6)
    curve = json.loads((out / "loss_curve.json").read_text())["points"]
    assert [c["iteration"] for c in curve] == list(range(120))
    assert all(b["seconds"] >= a["seconds"] for a, b in zip(curve, curve[1:]))
    pseudo = json.loads((out / "pseudo.json").read_text())
    assert pseudo["num_frames"] == N and (out / "pseudo.mp4").is_file()
    views, _ = read_clip(scene["clip"])
    r = ProxyRenderer(lt, RenderSettings(spp=4))
    r.prepare(views)
    # frames are stored in half float (lightcrafter.io): equal to R's render up to half's rounding
    np.testing.assert_allclose(io.read_rgb_exr(out / "pseudo" / "0003.exr"), r.render(views[3], frame=3),
                               rtol=2.0**-11, atol=1e-6)
    assert m["pseudo_psnr_db"]["mean"] > 25
    mtime = (out / "params.npz").stat().st_mtime_ns
    m2 = fit_envmap(scene["clip"], scene["frames_dir"], out, s, render)
    assert m2 == m and (out / "params.npz").stat().st_mtime_ns == mtime
    # other settings: a new fit
    m3 = fit_envmap(scene["clip"], scene["frames_dir"], out, replace(s, iterations=60), render)
    assert m3["fingerprint"] != m["fingerprint"]
    assert len(json.loads((out / "loss_curve.json").read_text())["points"]) == 60


def test_camera_response_fit_recovers_a_known_tone_curve():
    rng = np.random.default_rng(3)
    rendered = [rng.uniform(0.0, 1.5, size=(4000, 3)).astype(np.float32) for _ in range(3)]
    truth = CameraResponse(gamma=1.7, gain_rgb=(2.0, 1.6, 1.1))
    observed = [truth.apply(r) for r in rendered]
    got, stats = fit_response(rendered, observed)
    assert got.gamma == pytest.approx(1.7, rel=0.02)
    np.testing.assert_allclose(got.gain_rgb, truth.gain_rgb, rtol=0.03)
    assert stats["display_rmse_after"] < 0.1 * stats["display_rmse_before"]
    # a video that already is the render: the identity (nothing to gain), and no lit pixel: the identity
    same, _ = fit_response(rendered, rendered)
    assert same.gamma == pytest.approx(1.0, abs=0.01) and np.allclose(same.gain_rgb, 1.0, atol=0.01)
    black, why = fit_response([np.zeros((10, 3))], [np.zeros((10, 3))])
    assert black.is_identity and "no lit pixel" in why["note"]
    # extreme values stay finite and the curve stays within its bounds
    wild, _ = fit_response([np.full((50, 3), 1e4)], [np.full((50, 3), 1e-6)])
    assert GAMMA_MIN <= wild.gamma <= GAMMA_MAX and np.isfinite(wild.apply(np.full((2, 3), 1e4))).all()


def test_pseudo_input_through_the_fitted_camera_response(scene, tmp_path):
    """A video whose camera applied a tone curve: with ``fit_response`` the pseudo-input is rendered
    through the curve fitted after the map, closer to the video, and the curve is recorded in both manifests."""
    curve = CameraResponse(gamma=1.8, gain_rgb=(1.5, 1.5, 1.5))
    frames = video_dir(tmp_path / "toned", [curve.apply(f) for f in scene["frames"]])
    s = FitSettings(iterations=150, lr=1e-2, **QUICK)
    render = RenderSettings(spp=4)
    plain = fit_envmap(scene["clip"], frames, tmp_path / "plain", s, render)
    toned = fit_envmap(scene["clip"], frames, tmp_path / "toned_fit", replace(s, fit_response=True), render)
    assert "response" not in plain["fit"]
    got = toned["fit"]["response"]
    # the map, fitted first, takes part of the curve (measured: gamma 1.17, +0.34 dB); the rest goes to the curve
    assert 1.05 < got["gamma"] < 1.8 and got["display_rmse_after"] < got["display_rmse_before"]
    assert toned["pseudo_psnr_db"]["mean"] > plain["pseudo_psnr_db"]["mean"] + 0.15
    pseudo = json.loads((tmp_path / "toned_fit" / "pseudo.json").read_text())
    assert pseudo["response"]["gamma"] == got["gamma"]
    # the frames on disk are R's render through the recorded curve
    views, _ = read_clip(scene["clip"])
    r = ProxyRenderer(lighting_from_file(tmp_path / "toned_fit" / "lighting.json"), render)
    r.prepare(views)
    expect = CameraResponse(got["gamma"], tuple(got["gain_rgb"])).apply(r.render(views[2], frame=2))
    np.testing.assert_allclose(io.read_rgb_exr(tmp_path / "toned_fit" / "pseudo" / "0002.exr"), expect,
                               rtol=2.0**-10, atol=1e-5)


def test_killed_fit_resumes_from_its_checkpoint(scene, tmp_path):
    s = FitSettings(iterations=90, checkpoint_every=40, transport_spp=32)
    pb = prepare(scene["clip"], scene["frames_dir"], s)
    full = optimize(pb, s)

    class Killed(Exception):
        pass

    def kill(it, seconds, params):
        raise Killed

    ck = tmp_path / ".checkpoint.pt"
    with pytest.raises(Killed):
        optimize(pb, s, checkpoint=ck, fingerprint="fp", snapshot=kill, snapshot_at=[85])
    assert ck.is_file()
    resumed = optimize(pb, s, checkpoint=ck, fingerprint="fp")
    assert resumed.stats["resumed_from"] == 80
    np.testing.assert_allclose(resumed.params["log_map"], full.params["log_map"], atol=1e-5)
    assert resumed.params["yaw_rad"] == pytest.approx(full.params["yaw_rad"], abs=1e-6)
    # a checkpoint of other inputs is not resumed
    other = optimize(pb, s, checkpoint=ck, fingerprint="other")
    assert other.stats["resumed_from"] is None


def test_fast_fit_is_deterministic(scene):
    s = FitSettings(iterations=40, **QUICK)
    a = optimize(prepare(scene["clip"], scene["frames_dir"], s), s)
    b = optimize(prepare(scene["clip"], scene["frames_dir"], s), s)
    np.testing.assert_array_equal(a.params["log_map"], b.params["log_map"])
    assert [c["loss"] for c in a.curve] == [c["loss"] for c in b.curve]


def test_fit_does_not_depend_on_where_the_clip_lies(scene, tmp_path):
    """The fast solver's pixel sample is seeded by the view, not by the clip's folder: a copy of the clip
    elsewhere (an absolute path, another results folder) gives the same map."""
    import shutil

    moved = Path(shutil.copytree(scene["clip"], tmp_path / "elsewhere" / "clip"))
    s = FitSettings(iterations=20, transport_pixels=64, **QUICK)
    here = optimize(prepare(scene["clip"], scene["frames_dir"], s), s)
    there = optimize(prepare(moved, scene["frames_dir"], s), s)
    assert len(prepare(moved, scene["frames_dir"], s).video.used[0]) > 64  # the sample is a real subset
    np.testing.assert_array_equal(here.params["log_map"], there.params["log_map"])


def test_data_weights_and_memory_bound(scene):
    pb = prepare(scene["clip"], scene["frames_dir"], FitSettings())
    w = data_weights(pb.video, "sum")
    assert w[0] == 3 * len(pb.video.fitted) * len(pb.video.used[0])
    assert data_weights(pb.video, "mean")[0] == 1.0
    tr = build_transport(pb.tracer, pb.views[0], pb.video.used[0][:200], 16, seed=0)
    assert 0 < tr.nbytes <= memory_bound_bytes(1, 200, 16)


@pytest.mark.slow
def test_cli_writes_outputs_and_reports_bad_input_in_one_line(scene, tmp_path):
    script = REPO / "scripts" / "fit_envmap.py"
    p = subprocess.run([sys.executable, str(script), "--clip", str(scene["clip"]), "--frames", str(tmp_path / "none"),
                        "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=300)
    assert p.returncode == 1 and p.stderr.strip().count("\n") == 0 and "frame folder not found" in p.stderr
    p = subprocess.run([sys.executable, str(script), "--clip", str(scene["clip"]), "--frames", str(scene["frames_dir"]),
                        "--out", str(tmp_path / "o"), "--settings-json", '{"iterations": 30, "transport_spp": 16}',
                        "--proxy", '{"spp": 2}'],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    assert json.loads((tmp_path / "o" / "fit.json").read_text())["fit"]["solver"] == "fast"


def test_envfit_benchmark_runs_the_two_solvers_in_interleaved_rounds(tmp_path):
    """benchmarks/envfit.py at a tiny size: fast, reference, fast, reference; the speedup is the median of the
    per-round speedups with its range, each round timed at the same snapshots."""
    out = tmp_path / "envfit.json"
    p = subprocess.run([sys.executable, str(REPO / "benchmarks" / "envfit.py"), "--out", str(out), "--width", "32",
                        "--height", "24", "--frames", "5", "--iterations", "25", "--video-spp", "8", "--eval-spp", "8",
                        "--threads", "1", "--rounds", "3", "--skip-paper", "--gt-maps"],
                       capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, p.stderr[-2000:]
    order = [ln.split(": ")[1].split(" solver")[0] for ln in p.stdout.splitlines() if ln.startswith("round ")]
    assert order == ["fast", "reference"] * 3
    sp = json.loads(out.read_text())["speedup"]
    assert sp["rounds"] == 3 and len(sp["per_round"]) == 3
    per = [r["speedup"] for r in sp["per_round"]]
    assert None not in per
    per.sort()
    assert sp["speedup"] == {"median": round(per[1], 2), "min": round(per[0], 2),
                                                 "max": round(per[2], 2), "n": 3}
    assert sp["goal_met"] == (sp["speedup"]["median"] >= sp["goal"])
