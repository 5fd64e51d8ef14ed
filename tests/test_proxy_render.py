"""Renderer R: skips proven by counted work, additivity, analytic point light, furnace, stability."""

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lightcrafter.io import read_buffers, write_buffers
from lightcrafter.proxy import synthetic as syn
from lightcrafter.proxy.edits import MaterialEdit, apply_edits
from lightcrafter.proxy.lighting import AreaLight, Lighting, PointLight
from lightcrafter.proxy.renderer import FrameView, ProxyRenderer, RenderSettings

W, H = 32, 24


def small_scene(w=W, h=H, **sphere_kw):
    K = syn.intrinsics(w, h, 0.9)
    c2w = syn.look_at([2.5, -2.5, 1.8], [0, 0, 0.3])
    kw = dict(albedo=(0.7, 0.5, 0.3), roughness=0.4, metallic=0.0) | sphere_kw
    b = syn.raycast_buffers(K, c2w, w, h, [syn.Sphere((0, 0, 0.5), 0.5, **kw)])
    return K, c2w, b


def sky(h=16, w=32, sun=0.0):
    env = np.full((h, w, 3), 0.5, np.float32)
    env[: h // 2] = (0.6, 0.7, 1.0)
    if sun:
        env[3, 5] = sun
    return env


def render_clip(lighting, views, cache=True, **kw):
    r = ProxyRenderer(lighting, RenderSettings(spp=kw.pop("spp", 4), **kw), cache=cache)
    r.prepare(views)
    return [r.render(v, frame=i) for i, v in enumerate(views)], r.stats


def test_static_clip_builds_meshes_once():
    """Static camera + static scene (rotating light): meshes built once; same frames as rebuilding."""
    K, c2w, b = small_scene()
    views = [FrameView(b, K, c2w, "f0") for _ in range(3)]
    light = Lighting(env=sky(), frame_rotation_z_rad=[0.0, 0.4, 0.8])
    fast, s_fast = render_clip(light, views, cache=True)
    slow, s_slow = render_clip(light, views, cache=False)
    assert s_fast.mesh_builds == 1 and s_slow.mesh_builds == 3
    assert s_fast.visibility_builds == s_slow.visibility_builds == 1
    for a, b_ in zip(fast, slow):
        np.testing.assert_allclose(a, b_, rtol=1e-6, atol=1e-7)
    assert np.abs(fast[0] - fast[2]).max() > 1e-3  # the light did rotate


def test_no_local_lights_samples_none_and_changes_nothing():
    K, c2w, b = small_scene()
    views = [FrameView(b, K, c2w, "f0")]
    none, s_none = render_clip(Lighting(env=sky()), views)
    zero, s_zero = render_clip(Lighting(env=sky(), point_lights=[PointLight((1, 1, 2), (0, 0, 0))],
                                        area_lights=[AreaLight((0, 0, 3), (0, 0, -1), (1, 1), (0, 0, 0))]), views)
    assert s_none.local_light_rays == 0 and s_zero.local_light_rays > 0
    np.testing.assert_allclose(none[0], zero[0], rtol=1e-6, atol=1e-7)


def test_lighting_is_additive():
    K, c2w, b = small_scene()
    views = [FrameView(b, K, c2w, "f0")]
    pl = [PointLight((1.0, -1.0, 2.0), (3.0, 2.0, 1.0))]
    env_only, _ = render_clip(Lighting(env=sky()), views)
    pt_only, _ = render_clip(Lighting(point_lights=pl), views)
    both, _ = render_clip(Lighting(env=sky(), point_lights=pl), views)
    bg = b.mask < 0.5
    np.testing.assert_allclose(both[0][~bg], env_only[0][~bg] + pt_only[0][~bg], rtol=1e-4, atol=1e-6)


def test_point_light_on_lambert_plane_is_analytic():
    w, h = 24, 16
    K = syn.intrinsics(w, h, 0.6)
    c2w = syn.look_at([0.0, -3.0, 3.0], [0, 0, 0])
    b = syn.raycast_buffers(K, c2w, w, h, ground=syn.Ground((0.5, 0.5, 0.5), 1.0, 0.0, 50.0))
    P, I = np.array([0.3, 0.2, 1.5]), 4.0
    img, _ = render_clip(Lighting(point_lights=[PointLight(tuple(P), (I, I, I))]), [FrameView(b, K, c2w, "p")],
                         spp=16, visibility="none")
    import mitsuba as mi

    from lightcrafter.proxy import material
    from lightcrafter.proxy.geometry import unproject

    X = unproject(b.depth, K, c2w).reshape(-1, 3)
    d = P - X
    dist2 = np.sum(d * d, -1)
    wi = d / np.sqrt(dist2)[:, None]  # ground normal is +z: world = local frame up to azimuth
    wo = c2w[:3, 3] - X
    wo /= np.linalg.norm(wo, axis=-1, keepdims=True)
    f = material.eval_cos(mi.Color3f(0.5), mi.Float(1.0), mi.Float(0.0), mi.Vector3f(*[mi.Float(wo[:, k]) for k in range(3)]),
                          mi.Vector3f(*[mi.Float(wi[:, k]) for k in range(3)]))
    expected = np.asarray(f.x) * I / dist2
    ratio = img[0][..., 0].ravel() / expected
    assert abs(np.median(ratio) - 1.0) < 0.01 and np.abs(ratio - 1).max() < 0.05, (np.median(ratio), np.abs(ratio - 1).max())


def test_area_light_matches_point_light_when_small():
    K, c2w, b = small_scene()
    views = [FrameView(b, K, c2w, "f0")]
    area = 0.01 * 0.01
    pt, _ = render_clip(Lighting(point_lights=[PointLight((0.5, -1.0, 2.0), (1.0, 1.0, 1.0))]), views, spp=8)
    ar, _ = render_clip(Lighting(area_lights=[AreaLight((0.5, -1.0, 2.0), (-0.5, 1.0, -1.5), (0.01, 0.01),
                                                        (1.0 / area,) * 3)]), views, spp=8)
    lit = pt[0][..., 0] > 1e-3
    ratio = np.median(ar[0][lit] / pt[0][lit])
    # radiance L over area A facing the point ~ intensity L A cos; the light faces the sphere centre
    assert 0.5 < ratio <= 1.0 + 1e-3


def test_white_furnace_render():
    """Constant unit environment, white metal (F = 1), no occluders: radiance <= 1 + tol everywhere."""
    for r in (0.0, 0.3, 1.0):
        K = syn.intrinsics(W, H, 0.9)
        c2w = syn.look_at([2.5, -2.5, 1.8], [0, 0, 0.3])
        b = syn.raycast_buffers(K, c2w, W, H, [syn.Sphere((0, 0, 0.5), 0.5, (1.0, 1.0, 1.0), r, 1.0)], ground=None)
        img, _ = render_clip(Lighting(env=np.ones((16, 32, 3), np.float32)), [FrameView(b, K, c2w, "w")],
                             spp=64, visibility="none")
        sphere = b.mask > 0.5
        assert img[0][sphere].mean() <= 1.0 + 0.01
        assert img[0][sphere].max() <= 1.0 + 0.15  # per-pixel MC noise at 64 spp
        np.testing.assert_allclose(img[0][~sphere], 1.0, rtol=1e-4)


def test_occluder_outside_view_casts_shadow_with_aggregated_visibility():
    w, h = 32, 24
    K = syn.intrinsics(w, h, 0.8)
    ground = syn.Ground((0.5, 0.5, 0.5), 0.9, 0.0, 20.0)
    sph = [syn.Sphere((0, 0, 1.0), 0.5)]
    c_a = syn.look_at([-4.0, -0.5, 1.3], [0, 0, 0.8])  # sees the sphere's side facing the light
    c_b = syn.look_at([1.2, -1.2, 0.7], [1.2, 0.0, 0.0])  # looks down at the ground beside it... shadow under the light
    b_a = syn.raycast_buffers(K, c_a, w, h, sph, ground)
    b_b = syn.raycast_buffers(K, c_b, w, h, sph, ground)
    light = Lighting(point_lights=[PointLight((-1.2, 0.0, 2.0), (20.0, 20.0, 20.0))])
    views = [FrameView(b_a, K, c_a, "a"), FrameView(b_b, K, c_b, "b")]
    agg, st_agg = render_clip(light, views, visibility="aggregate")
    own, _ = render_clip(light, views, visibility="frame")
    assert st_agg.visibility_builds == 1
    # the sphere projects (from the light) onto x ~ 1.2, y ~ 0: in view b, the centre is in shadow only with aggregation
    centre = (slice(h // 2 - 2, h // 2 + 2), slice(w // 2 - 2, w // 2 + 2))
    assert (b_b.mask[centre] > 0.5).all() and not (b_b.depth[centre] < 0.1).any()
    assert own[1][centre].mean() > 5 * agg[1][centre].mean()


def test_a_frame_without_surface_renders_the_environment_alone():
    """Buffers whose mask is empty everywhere (an estimator that saw no surface): every pixel is the
    environment seen through it, for every visibility mode, instead of an error from the renderer's kernels."""
    from dataclasses import replace

    K, c2w, b = small_scene()
    empty = replace(b, mask=np.zeros_like(b.mask), depth=np.full_like(b.depth, np.inf))
    env = np.ones((16, 32, 3), np.float32)
    for vis in ("aggregate", "frame", "none"):
        img, _ = render_clip(Lighting(env=env), [FrameView(empty, K, c2w, "empty")], visibility=vis)
        np.testing.assert_allclose(img[0], 1.0, rtol=1e-4)


def test_material_edit_changes_only_the_mask():
    K, c2w, b = small_scene()
    mask = np.zeros(b.shape, np.float32)
    mask[:, : W // 2] = 1
    edited = apply_edits(b, [MaterialEdit(mask=mask, albedo_override=(0.0, 0.0, 0.0), metallic_override=0.0,
                                         roughness_multiplier=0.5)])
    assert (edited.albedo[:, W // 2:] == b.albedo[:, W // 2:]).all()
    surf = (b.mask > 0.5) & (mask > 0.5)
    assert (edited.albedo[surf] == 0).all() and np.allclose(edited.roughness[surf], b.roughness[surf] * 0.5)
    a, _ = render_clip(Lighting(env=sky()), [FrameView(b, K, c2w, "x")])
    e, _ = render_clip(Lighting(env=sky()), [FrameView(edited, K, c2w, "y")])
    assert e[0][surf].mean() < 0.5 * a[0][surf].mean()


depth_bad = st.sampled_from([0.0, np.inf, np.nan, -1.0, 1e-9, 1e9])


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(bad=st.lists(st.tuples(st.integers(0, 15), st.integers(0, 11), depth_bad), min_size=1, max_size=30),
       rough=st.sampled_from([0.0, 1.0, 0.5]), metal=st.sampled_from([0.0, 1.0]),
       albedo=st.sampled_from([0.0, 1.0]), sun=st.sampled_from([0.0, 1e3, 1e5]))
def test_render_never_produces_nan_or_inf(tmp_path_factory, bad, rough, metal, albedo, sun):
    """Depth 0 / inf / NaN / negative in the buffer file, extreme materials, a 1e5 sun: finite output."""
    w, h = 16, 12
    K, c2w, b = small_scene(w, h, albedo=(albedo,) * 3, roughness=rough, metallic=metal)
    b.roughness[:], b.metallic[:] = rough, metal
    for j, i, v in bad:
        b.depth[i, j] = v
    path = tmp_path_factory.mktemp("buf") / "b.exr"
    write_buffers(path, b)
    b2 = read_buffers(path)
    img, _ = render_clip(Lighting(env=sky(sun=sun), point_lights=[PointLight((1, -1, 2), (1e5, 1e5, 1e5))]),
                         [FrameView(b2, K, c2w, "s")], spp=4)
    assert np.isfinite(img[0]).all() and (img[0] >= 0).all()


def test_auto_visibility_aggregates_only_static_scenes():
    from lightcrafter.proxy.clip import resolve_visibility

    s = RenderSettings(visibility="auto")
    assert resolve_visibility(s, scene_static=True).visibility == "aggregate"
    assert resolve_visibility(s, scene_static=False).visibility == "frame"
    assert resolve_visibility(RenderSettings(visibility="none"), scene_static=False).visibility == "none"
    # a reconstruction's depth maps disagree between frames: never merged into one shadow mesh
    assert resolve_visibility(s, scene_static=True, consistent_depth=False).visibility == "frame"


def test_stratified_sampler_beats_independent_at_equal_spp():
    """Per-pixel Sobol stratification (default) lowers the error at equal spp: proves the sampler is
    told that consecutive lanes are one pixel's samples (without that it degrades to random)."""
    K, c2w, b = small_scene()
    views = [FrameView(b, K, c2w, "f0")]
    light = Lighting(env=sky(sun=50.0))
    ref, _ = render_clip(light, views, spp=1024, seed=7, sampler="independent")
    err = {}
    for smp in ("multijitter", "independent"):
        img, _ = render_clip(light, views, spp=16, sampler=smp)
        err[smp] = float(np.mean((img[0] - ref[0]) ** 2))
    assert err["multijitter"] < 0.7 * err["independent"], err


def test_a_conda_environments_libllvm_is_found_for_drjit(tmp_path):
    """In a conda env (envs/mitsuba.yaml) libLLVM lies in $CONDA_PREFIX/lib, off the loader's path: the
    newest one there is what DRJIT_LIBLLVM_PATH gets; none there, nothing is set."""
    from lightcrafter.proxy.mitsuba_setup import prefix_libllvm

    assert prefix_libllvm(tmp_path) is None
    (tmp_path / "lib").mkdir()
    for name in ("libLLVM-18.so", "libLLVM-19.so", "libLTO.so"):
        (tmp_path / "lib" / name).write_bytes(b"")
    assert prefix_libllvm(tmp_path).name == "libLLVM-19.so"


def test_oidn_denoiser_brings_a_noisy_render_closer_to_the_converged_one():
    """proxy.denoiser: oidn: 2-spp frames under a sun go through OIDN and land nearer the 1024-spp render
    (mean squared error at least halved); the output stays finite and non-negative."""
    K, c2w, b = small_scene(w=64, h=48)
    views = [FrameView(b, K, c2w, "f0")]
    light = Lighting(env=sky(sun=50.0))
    ref, _ = render_clip(light, views, spp=1024, seed=7)
    noisy, _ = render_clip(light, views, spp=2)
    clean, _ = render_clip(light, views, spp=2, denoiser="oidn")
    assert np.isfinite(clean[0]).all() and (clean[0] >= 0).all()
    mse = lambda x: float(np.mean((x - ref[0]) ** 2))  # noqa: E731
    assert mse(clean[0]) < 0.5 * mse(noisy[0]), (mse(clean[0]), mse(noisy[0]))


def test_oidn_denoiser_runs_without_loading_torch_and_still_takes_it_when_loaded():
    """A proxy job never needs torch: the denoiser imports pyoidn without it (pyoidn alone would load it, 2 s
    of each job). In a process that has torch already, pyoidn imports as usual. Both denoise a frame alike."""
    import subprocess
    import sys

    code = """
import sys, numpy as np
{pre}
from lightcrafter.proxy.denoise import denoise_hdr
x = np.random.default_rng(0).random((24, 32, 3)).astype(np.float32)
y = denoise_hdr(x)
print("torch" in sys.modules, float(y.sum()))
"""
    out = {}
    for pre in ("", "import torch"):
        r = subprocess.run([sys.executable, "-c", code.format(pre=pre)], capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr[-2000:]
        out[pre] = r.stdout.split()
    assert out[""][0] == "False" and out["import torch"][0] == "True", out
    assert out[""][1] == out["import torch"][1]


def test_device_benchmark_interleaves_the_variants_it_can_run_and_names_the_rest(tmp_path):
    """benchmarks/proxy_device.py (the GPU check's Mitsuba part) on a CPU node: llvm_ad_rgb is timed in
    every repeat, cuda_ad_rgb is reported as not run with Mitsuba's reason, and a reference frame saved by
    one run agrees exactly with the next run's (same seed, same variant)."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    common = [sys.executable, str(root / "benchmarks" / "proxy_device.py"), "--width", "48", "--height", "32",
              "--repeats", "3", "--ref-spp", "32", "--threads", "2"]
    r = subprocess.run(common + ["--variants", "llvm_ad_rgb", "cuda_ad_rgb", "--save-ref", str(tmp_path / "ref"),
                                 "--out", str(tmp_path / "a.json")], capture_output=True, text=True, cwd=root, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    a = json.loads((tmp_path / "a.json").read_text())
    llvm = a["variants"]["llvm_ad_rgb"]
    assert llvm["seconds_per_frame"]["n"] == 3 and llvm["seconds_per_frame"]["min"] > 0
    assert llvm["all_finite"] and 10 < llvm["psnr_vs_own_reference_db"] < 60
    if "cuda_ad_rgb" not in a["variants"]:  # a node without a GPU names the reason instead of a number
        assert "cuda_ad_rgb" in a["not_run"] and a["not_run"]["cuda_ad_rgb"]
    assert (tmp_path / "ref" / "llvm_ad_rgb_ref.npy").is_file()

    r = subprocess.run(common + ["--variants", "llvm_ad_rgb", "--compare-ref", str(tmp_path / "ref" / "llvm_ad_rgb_ref.npy"),
                                 "--out", str(tmp_path / "b.json")], capture_output=True, text=True, cwd=root, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    b = json.loads((tmp_path / "b.json").read_text())
    assert b["references_agree"] == {"llvm_ad_rgb_vs_llvm_ad_rgb_ref.npy": True}
    assert b["reference_agreement_psnr_db"]["llvm_ad_rgb_vs_llvm_ad_rgb_ref.npy"] == b["psnr_cap_db"]  # identical
    assert "Infinity" not in (tmp_path / "b.json").read_text()  # strict JSON

    r = subprocess.run(common[:2] + ["--variants", "no_such_variant", "--out", str(tmp_path / "c.json")],
                       capture_output=True, text=True, cwd=root, timeout=600)
    assert r.returncode != 0 and "no Mitsuba variant could render here" in r.stderr.splitlines()[-1]
    assert not (tmp_path / "c.json").exists()
    # a frame of another size is refused before anything renders
    r = subprocess.run(common + ["--width", "64", "--compare-ref", str(tmp_path / "ref" / "llvm_ad_rgb_ref.npy"),
                                 "--out", str(tmp_path / "d.json")], capture_output=True, text=True, cwd=root, timeout=600)
    assert r.returncode != 0 and "pass the --width/--height it was saved with" in r.stderr.splitlines()[-1]
    assert "ready" not in r.stdout


def test_shadow_mesh_cut_keeps_a_smooth_silhouette_from_shadowing_the_ground_behind():
    """A reconstruction's depth and normals are smooth across an object's silhouette. With the camera quads' loose
    cut, the frame's shadow mesh keeps a sheet from the sphere's top to the ground behind it, which darkens that
    ground under a bright sky. ``visibility_mesh.rel_threshold`` cuts the shadow mesh alone: the ground is lit as
    with the true depth, and the camera's own quads (shading without shadows) do not change."""
    from dataclasses import replace

    from scipy.ndimage import gaussian_filter

    from lightcrafter.proxy.visibility import VisibilitySettings

    w, h = 64, 48
    K = syn.intrinsics(w, h, 0.9)
    c2w = syn.look_at([3.0, -3.0, 1.2], [0, 0, 0.5])
    b = syn.raycast_buffers(K, c2w, w, h, [syn.Sphere((0, 0, 0.6), 0.6)], syn.Ground((0.5, 0.5, 0.5), 0.9, 0.0, 20.0))
    n = np.stack([gaussian_filter(b.normal[..., c], 2.0) for c in range(3)], -1)
    smooth = replace(b, depth=np.exp(gaussian_filter(np.log(np.minimum(b.depth, 60.0)), 2.0)).astype(np.float32),
                     normal=(n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-6)).astype(np.float32))
    env = np.full((16, 32, 3), 0.05, np.float32)
    env[:8] = 1.0  # a bright sky over a dark floor

    def render(buf, visibility, cut):
        img, _ = render_clip(Lighting(env=env), [FrameView(buf, K, c2w, "x")], spp=64, visibility=visibility,
                             visibility_mesh=VisibilitySettings(rel_threshold=cut))
        return img[0].mean(-1)

    truth = render(b, "frame", 0.05)
    ground = b.normal[..., 2] > 0.99
    false_shadow = {cut: int(((render(smooth, "frame", cut) < 0.8 * truth) & ground).sum()) for cut in (0.05, 0.02)}
    assert false_shadow[0.05] >= 5 and false_shadow[0.02] == 0, false_shadow
    np.testing.assert_array_equal(render(smooth, "none", 0.05), render(smooth, "none", 0.02))


def test_shadow_mesh_cut_comes_from_the_proxy_config():
    from lightcrafter.proxy import render_settings

    s = render_settings({"rel_threshold": 0.05, "visibility_rel_threshold": 0.02})
    assert (s.rel_threshold, s.visibility_mesh.rel_threshold) == (0.05, 0.02)
    s = render_settings({"rel_threshold": 0.04})  # unset: the camera quads' cut
    assert s.visibility_mesh.rel_threshold == 0.04
