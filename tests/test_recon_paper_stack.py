"""Paper-stack backend of Phi: adapters for MegaSAM, DiffusionRenderer and DiffusionLight, and the
command runner.

Fixtures are written in each tool's native format by code in this file that follows the tools'
published behaviour (module docstrings of lightcrafter.recon.paper_stack), independently of the
adapters: MegaSAM's npz with float16 depth and camera-to-world relative to its first camera,
DiffusionRenderer's truncated 8-bit sRGB / OpenGL-normal images, and DiffusionLight's unwrapping of
an ideal chrome ball seen by the camera. Ground truth comes from lightcrafter.proxy.synthetic.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from lightcrafter import clip as clipmod
from lightcrafter import envmap, io
from lightcrafter.camera import intrinsics, opencv_c2w
from lightcrafter.proxy.synthetic import Ground, Sphere, raycast_buffers
from lightcrafter.recon.paper_stack import backend, diffusion_light, diffusion_renderer, megasam
from lightcrafter.recon.paper_stack.megasam import PixelMap

SPHERES = (Sphere((0.0, 0.0, 0.6), 0.6, albedo=(0.8, 0.3, 0.1), roughness=0.3, metallic=0.0),
           Sphere((1.0, 0.6, 0.35), 0.35, albedo=(0.1, 0.5, 0.9), roughness=0.7, metallic=1.0))
GROUND = Ground(albedo=(0.45, 0.45, 0.4), roughness=0.85, metallic=0.0, half_size_m=5.0)
# First camera level, looking along world +Y: MegaSAM's axis change then reproduces the GT axes.
CAMS = (((0.0, -4.0, 1.0), (0.0, 0.0, 1.0)), ((1.5, -3.6, 1.6), (0.2, 0.0, 0.4)), ((-1.8, -3.4, 2.0), (0.0, 0.3, 0.5)))


def gt_cameras(n=3):
    return np.stack([opencv_c2w(eye, tgt) for eye, tgt in CAMS[:n]])


def render(K, c2w, w, h):
    return raycast_buffers(K, c2w, w, h, spheres=SPHERES, ground=GROUND)


def angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=-1), -1.0, 1.0)))


def one_line(exc) -> str:
    msg = str(exc.value)
    assert "\n" not in msg
    return msg


# ----------------------------------------------------------------------------- native writers (tool emulation)
def write_megasam_npz(path, K, c2w_gt, w, h, scale, far=1e2):
    """MegaSAM's final npz of a GT clip: world = first camera (scaled by ``scale``), float16 depth."""
    c0inv = np.linalg.inv(c2w_gt[0])
    cam_c2w, depths, images = [], [], []
    for c in c2w_gt:
        rel = c0inv @ c
        rel[:3, 3] *= scale
        cam_c2w.append(rel)
        b = render(K, c, w, h)
        d = np.where(np.isfinite(b.depth), b.depth * scale, far)
        depths.append(d)
        images.append(io.to_uint8(io.linear_to_display(b.albedo)))
    np.savez(path, images=np.stack(images), depths=np.clip(np.float16(np.stack(depths)), 1e-3, 1e2),
             intrinsic=np.asarray(K, np.float32), cam_c2w=np.stack(cam_c2w).astype(np.float32))


def encode_dr(b: io.Buffers, c2w, depth_rel=None, stretch=1.0):
    """One frame's pass images as cosmos1 writes them: uint8(((x + 1) / 2) * 255) (truncation),
    basecolor sRGB-encoded, normals in OpenGL camera axes, scalars replicated to 3 channels.

    ``stretch``: the image's horizontal over vertical magnification of the video (``sx / sy``). A
    network shown a stretched frame sees a scene stretched along camera x, whose normals are
    diag(1/stretch, 1, 1) n (renormalised): that is what it writes."""
    enc = lambda x01: (np.clip(np.asarray(x01, np.float64), 0, 1) * 255.0).astype(np.uint8)  # noqa: E731
    rep = lambda a: np.repeat(np.asarray(a, np.float64)[..., None], 3, axis=-1)  # noqa: E731
    n_cv = np.asarray(b.normal, np.float64) @ np.asarray(c2w)[:3, :3]        # world -> OpenCV camera
    n_cv = n_cv * np.array([1.0 / stretch, 1.0, 1.0])
    n_cv = n_cv / np.maximum(np.linalg.norm(n_cv, axis=-1, keepdims=True), 1e-12)   # zero (background) stays zero
    n_gl = n_cv * np.array([1.0, -1.0, -1.0])
    if depth_rel is None:
        d = np.where(np.isfinite(b.depth), b.depth, np.nan)
        lo, hi = np.nanmin(d), np.nanmax(d)
        depth_rel = np.where(np.isfinite(d), (d - lo) / (hi - lo), 1.0)
    return {"basecolor": enc(io.linear_to_display(b.albedo)), "normal": enc((n_gl + 1.0) / 2.0),
            "depth": enc(rep(depth_rel)), "roughness": enc(rep(b.roughness)), "metallic": enc(rep(b.metallic))}


def write_dr_frames(folder, frames_passes, chunk_len=None, overlap=0, ext="png", quality=85):
    """Write per-frame pass dicts as {chunk}.{index}.{pass}.{ext} with the renderer's chunking."""
    import imageio.v3 as iio

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    n = len(frames_passes)
    chunk_len = chunk_len or n
    step = chunk_len - overlap
    for c, start in enumerate(range(0, n - overlap, step)):
        idx = list(range(start, min(start + chunk_len, n)))
        idx += [idx[-1]] * (chunk_len - len(idx))          # the renderer pads with the last frame
        for k, g in enumerate(idx):
            for name, img in frames_passes[g].items():
                p = folder / f"{c:04d}.{k:04d}.{name}.{ext}"
                if ext == "jpg":
                    iio.imwrite(p, img, extension=".jpg", quality=quality)
                else:
                    iio.imwrite(p, img, extension=".png")


def dl_native_map(env_world, c2w0, height, ball_px=257, supersample=4):
    """What DiffusionLight makes of a world ``env_world`` seen by a camera ``c2w0``: an ideal chrome
    ball imaged orthographically along the optical axis, unwrapped as ball2envmap.py does (view at
    +x, ball sampled at (-N_y, -N_z) with align_corners, s-fold grid then box downsampling)."""
    R = np.asarray(c2w0)[:3, :3]
    # 1. the ball image (rows top->bottom, cols left->right), OpenCV camera axes
    t = np.linspace(-1.0, 1.0, ball_px)
    py, px = np.meshgrid(-t, t, indexing="ij")                # py: up, px: right
    nz2 = 1.0 - px**2 - py**2
    n = np.stack([px, -py, -np.sqrt(np.clip(nz2, 0, 1))], axis=-1)   # normal faces the camera (-z)
    view = np.array([0.0, 0.0, -1.0])                         # from the surface to the camera
    r = 2 * np.sum(n * view, -1, keepdims=True) * n - view
    ball = envmap.radiance(env_world, r @ R.T)
    ball[nz2 < 0] = 0.0
    # 2. ball2envmap.py's unwrapping
    hs, ws = height * supersample, 2 * height * supersample
    hh, vv = np.meshgrid(np.linspace(0, 2 * np.pi, ws), np.linspace(0, np.pi, hs), indexing="xy")
    refl = np.stack([np.sin(vv) * np.cos(hh), np.sin(vv) * np.sin(hh), np.cos(vv)], axis=-1)
    N = refl + np.array([1.0, 0.0, 0.0])
    N /= np.maximum(np.linalg.norm(N, axis=-1, keepdims=True), 1e-9)
    gx, gy = -N[..., 1], -N[..., 2]
    col, row = (gx + 1) / 2 * (ball_px - 1), (gy + 1) / 2 * (ball_px - 1)
    hi, _ = diffusion_renderer.bilinear(ball, col, row)
    # 3. downsample by the supersampling factor (box; skimage's anti-aliased resize is centred alike)
    return hi.reshape(height, supersample, 2 * height, supersample, 3).mean(axis=(1, 3)).astype(np.float32)


def spot_world_map(h, w, spots):
    """Dim asymmetric sky/ground gradient plus bright Gaussian spots {direction: radiance}."""
    d = envmap.pixel_directions(h, w)
    env = np.empty((h, w, 3), np.float32)
    env[..., 0] = 0.2 + 0.1 * (d[..., 0] + 1)
    env[..., 1] = 0.2 + 0.1 * (d[..., 1] + 1)
    env[..., 2] = 0.2 + 0.2 * (d[..., 2] + 1)
    for s, val in spots:
        s = np.asarray(s, float) / np.linalg.norm(s)
        env += (val * np.exp(-(1.0 - d @ s) / (1.0 - np.cos(np.radians(7.0)))))[..., None].astype(np.float32)
    return env


def peak_direction(env):
    h, w = env.shape[:2]
    i, j = np.unravel_index(np.argmax(env.sum(-1)), (h, w))
    return envmap.pixel_directions(h, w)[i, j]


# ----------------------------------------------------------------------------- MegaSAM
def test_megasam_roundtrip_recovers_cameras_depth_and_up(tmp_path):
    w, h, scale = 64, 48, 0.37
    K = intrinsics(w, h, 1.0)
    gt = gt_cameras()
    write_megasam_npz(tmp_path / "clip_sgd_cvd_hr.npz", K, gt, w, h, scale)
    assert megasam.find_output(tmp_path) == tmp_path / "clip_sgd_cvd_hr.npz"
    r = megasam.load(tmp_path / "clip_sgd_cvd_hr.npz")
    assert r.depth.dtype == np.float32 and r.depth.shape == (3, h, w) and r.K.shape == (3, 3, 3)
    np.testing.assert_allclose(r.K[2], K, rtol=1e-6)
    # Our world = GT world shifted to the first camera and scaled, with the same axes (level first camera).
    np.testing.assert_allclose(r.c2w[0], megasam.WORLD_FROM_CAM0, atol=1e-6)
    for t in range(3):
        np.testing.assert_allclose(r.c2w[t][:3, :3], gt[t][:3, :3], atol=1e-5)
        np.testing.assert_allclose(r.c2w[t][:3, 3], scale * (gt[t][:3, 3] - gt[0][:3, 3]), atol=1e-5)
        b = render(K, gt[t], w, h)
        gt_valid = np.isfinite(b.depth) & (b.depth * scale < 99.0)
        np.testing.assert_array_equal(r.valid[t], gt_valid)
        rel = r.depth[t][gt_valid] / (scale * b.depth[gt_valid])
        assert np.abs(rel - 1).max() < 1e-3                       # float16: 11-bit mantissa
        assert np.isinf(r.depth[t][~gt_valid]).all()
    # Unprojected ground points of a later frame lie on our Z = const plane (Z is up).
    from lightcrafter.proxy.geometry import unproject

    b2 = render(K, gt[2], w, h)
    ground = r.valid[2] & (b2.normal[..., 2] > 0.999)
    pts = unproject(r.depth[2], r.K[2], r.c2w[2])[ground]
    np.testing.assert_allclose(pts[:, 2], -scale * gt[0][2, 3], atol=2e-3)


def test_megasam_bad_inputs_name_the_file(tmp_path):
    w, h = 16, 12
    K = intrinsics(w, h, 1.0)
    good = dict(images=np.zeros((2, h, w, 3), np.uint8), depths=np.ones((2, h, w), np.float16),
                intrinsic=K.astype(np.float32), cam_c2w=np.repeat(np.eye(4, dtype=np.float32)[None], 2, 0))
    cases = {
        "nokey": ({k: v for k, v in good.items() if k != "cam_c2w"}, "lacks key"),
        "shape": (dict(good, depths=np.ones((2, h, w + 1), np.float16)), "'images' must be"),
        "cams": (dict(good, cam_c2w=np.eye(4, dtype=np.float32)), "'cam_c2w' must be"),
        "K": (dict(good, intrinsic=np.eye(4, dtype=np.float32)), "'intrinsic' must be"),
    }
    for name, (arrays, text) in cases.items():
        p = tmp_path / f"{name}.npz"
        np.savez(p, **arrays)
        with pytest.raises(io.DataError) as e:
            megasam.load(p)
        assert str(p) in one_line(e) and text in str(e.value)
    with pytest.raises(io.DataError) as e:
        megasam.load(tmp_path / "absent.npz")
    assert "absent.npz" in one_line(e)
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(io.DataError) as e:
        megasam.load(tmp_path / "junk.npz")
    assert "junk.npz" in one_line(e)


def test_megasam_working_grid_matches_released_resize():
    # test_demo.py: about 384*512 pixels, then the top-left multiple of 8
    assert megasam.working_grid(854, 480) == (591, 332, 584, 328)
    assert megasam.working_grid(512, 384) == (512, 384, 512, 384)
    m = megasam.working_map(854, 480)
    assert (m.width, m.height) == (584, 328)
    # pixel centre 0 of the resized image covers source [0, 854/591): its centre
    assert np.isclose((0 - m.ox) / m.sx, 0.5 * 854 / 591 - 0.5)


# ----------------------------------------------------------------------------- DiffusionRenderer
def _dr_clip(tmp_path, ext, quality=85, w=64, h=48):
    K = intrinsics(w, h, 1.0)
    gt = gt_cameras()
    bufs = [render(K, c, w, h) for c in gt]
    write_dr_frames(tmp_path / "gbuffer_frames" / "clip", [encode_dr(b, c) for b, c in zip(bufs, gt)], ext=ext, quality=quality)
    paths = diffusion_renderer.find_frames(tmp_path, 3)
    return gt, bufs, paths


def test_dr_png_roundtrip_recovers_world_normals_and_linear_albedo(tmp_path):
    gt, bufs, paths = _dr_clip(tmp_path, "png")
    assert set(paths) == set(diffusion_renderer.PASSES) and all(len(v) == 3 for v in paths.values())
    worst = 0.0
    for t in range(3):
        f = diffusion_renderer.read_frame({k: paths[k][t] for k in paths}, gt[t])
        m = bufs[t].mask > 0.5
        np.testing.assert_array_equal(f.valid, m)                 # background (zero normal) is invalid
        err = angle_deg(f.normal[m], bufs[t].normal[m])
        worst = max(worst, float(err.max()))
        assert np.abs(f.albedo[m] - bufs[t].albedo[m]).max() < 6e-3   # sRGB-decoded, 8-bit
        assert np.abs(f.roughness[m] - bufs[t].roughness[m]).max() <= 0.5 / 255 + 1e-6
        assert np.abs(f.metallic[m] - bufs[t].metallic[m]).max() <= 0.5 / 255 + 1e-6
        d = np.where(np.isfinite(bufs[t].depth), bufs[t].depth, np.nan)
        assert np.corrcoef(f.depth_rel[m], d[m])[0, 1] > 0.99
    assert worst < 1.0, f"max normal error {worst:.3f} deg after 8-bit quantisation"
    # The wrong encodings are detectably wrong (the test can fail).
    f_lin = diffusion_renderer.read_frame({k: paths[k][0] for k in paths}, gt[0], basecolor_encoding="linear")
    assert np.abs(f_lin.albedo - bufs[0].albedo)[bufs[0].mask > 0.5].max() > 0.1
    f_cv = diffusion_renderer.read_frame({k: paths[k][0] for k in paths}, gt[0], normal_axes="opencv")
    assert np.median(angle_deg(f_cv.normal, bufs[0].normal)[bufs[0].mask > 0.5]) > 30


def test_dr_jpeg_q85_as_released_is_usable(tmp_path):
    from scipy import ndimage

    gt, bufs, paths = _dr_clip(tmp_path, "jpg", w=256, h=192)
    errs, inner = [], []
    for t in range(3):
        f = diffusion_renderer.read_frame({k: paths[k][t] for k in paths}, gt[t])
        m = (bufs[t].mask > 0.5) & f.valid
        e = angle_deg(f.normal, bufs[t].normal)
        n = bufs[t].normal
        edge = bufs[t].mask < 0.5
        edge[:, 1:] |= np.sum(n[:, 1:] * n[:, :-1], -1) < np.cos(np.radians(5))
        edge[1:] |= np.sum(n[1:] * n[:-1], -1) < np.cos(np.radians(5))
        far_from_edges = ndimage.distance_transform_edt(~edge) >= 8       # beyond a JPEG 4:2:0 block
        errs.append(e[m])
        inner.append(e[m & far_from_edges])
    e, i = np.concatenate(errs), np.concatenate(inner)
    # JPEG (quality 85, 4:2:0 chroma) costs ~0.5 deg inside surfaces; colour edges bleed over a block.
    assert np.median(i) < 1.0 and np.percentile(i, 90) < 1.5, (np.median(i), np.percentile(i, 90))
    assert np.median(e) < 1.0 and np.percentile(e, 90) < 5.0, (np.median(e), np.percentile(e, 90))


def test_dr_resampling_onto_another_grid_follows_resize_and_crop(tmp_path):
    W0, H0 = 160, 120
    K0 = intrinsics(W0, H0, 1.0)
    c2w = gt_cameras(1)[0]
    target = PixelMap.resize_crop(W0, H0, 128, 96, out_w=120, out_h=88)     # MegaSAM-like top-left crop
    dr_map = diffusion_renderer.pixel_map(W0, H0, 96, 64, resize=(72, 108))  # resize then centre crop
    assert (dr_map.width, dr_map.height) == (96, 64)
    b_dr = render(dr_map.scale_K(K0), c2w, 96, 64)
    b_t = render(target.scale_K(K0), c2w, 120, 88)
    write_dr_frames(tmp_path / "clip", [encode_dr(b_dr, c2w, stretch=diffusion_renderer.stretch_ratio(dr_map))])
    paths = diffusion_renderer.find_frames(tmp_path, 1)
    one = {k: v[0] for k, v in paths.items()}
    f = diffusion_renderer.read_frame(one, c2w, src_size=(W0, H0), target=target, resize=(72, 108))
    assert f.normal.shape == (88, 120, 3)
    # compare where the GT surface is smooth around the pixel (interpolation across edges is expected)
    n = b_t.normal
    smooth = b_t.mask > 0.5
    for dy in (-2, -1, 0, 1, 2):
        for dx in (-2, -1, 0, 1, 2):
            sh = np.roll(np.roll(n, dy, 0), dx, 1)
            smooth &= (np.roll(np.roll(b_t.mask, dy, 0), dx, 1) > 0.5) & (np.sum(sh * n, -1) > np.cos(np.radians(12)))
    smooth[:3], smooth[-3:], smooth[:, :3], smooth[:, -3:] = False, False, False, False
    m = smooth & f.valid
    assert m.sum() > 2000
    err = angle_deg(f.normal[m], n[m])
    assert np.percentile(err, 95) < 1.5, np.percentile(err, 95)
    # ignoring the centre crop (a plain stretch) lands visibly elsewhere
    g = diffusion_renderer.read_frame(one, c2w, src_size=(W0, H0), target=target, resize=None)
    assert np.percentile(angle_deg(g.normal[m & g.valid], n[m & g.valid]), 95) > 3 * np.percentile(err, 95)
    # the renderer's crop sees less of the frame than the target grid: those pixels are invalid
    x, _ = dr_map.coords_from(target)
    assert not f.valid[:, x[0] < -0.5].any() and (x[0] < -0.5).any()


def test_dr_normals_of_a_3_2_video_stretched_to_16_9_are_corrected(tmp_path):
    """cosmos1's default stretches a 720x480 video to 1280x704 (here a quarter: 180x120 -> 320x176):
    normals estimated on that image are corrected back to the video's scene; ignoring the stretch
    leaves slanted surfaces visibly off."""
    W0, H0 = 180, 120
    K0 = intrinsics(W0, H0, 1.0)
    c2w = gt_cameras(2)[1]
    dr_map = diffusion_renderer.pixel_map(W0, H0, 320, 176)
    a = diffusion_renderer.stretch_ratio(dr_map)
    assert abs(a - (1280 / 720) / (704 / 480)) < 1e-9 and a > 1.2
    b_dr = render(dr_map.scale_K(K0), c2w, 320, 176)
    write_dr_frames(tmp_path / "clip", [encode_dr(b_dr, c2w, stretch=a)])
    one = {k: v[0] for k, v in diffusion_renderer.find_frames(tmp_path, 1).items()}
    target = PixelMap.resize_crop(W0, H0, W0, H0)
    b_t = render(K0, c2w, W0, H0)
    f = diffusion_renderer.read_frame(one, c2w, src_size=(W0, H0), target=target)
    g = diffusion_renderer.read_frame(one, c2w, src_size=(W0, H0), target=target, unstretch_normals=False)
    from scipy import ndimage

    m = ndimage.binary_erosion(b_t.mask > 0.5, iterations=3) & f.valid & g.valid
    slanted = m & (np.abs((b_t.normal @ c2w[:3, :3])[..., 0]) > 0.3)   # surfaces facing sideways in the camera
    assert slanted.sum() > 200
    fixed, raw = angle_deg(f.normal, b_t.normal), angle_deg(g.normal, b_t.normal)
    assert np.median(fixed[m]) < 1.0 and np.median(fixed[slanted]) < 1.5, (np.median(fixed[m]), np.median(fixed[slanted]))
    print(f"normal error on sideways surfaces: corrected {np.median(fixed[slanted]):.2f} deg, uncorrected {np.median(raw[slanted]):.2f} deg (median)")
    assert np.median(raw[slanted]) > 3 * np.median(fixed[slanted]) and np.median(raw[slanted]) > 3.0, np.median(raw[slanted])


def test_dr_chunks_with_overlap_and_padding_map_to_frames(tmp_path):
    n, h, w = 6, 4, 5
    frames = []
    for g in range(n):
        v = np.full((h, w, 3), 20 * g + 10, np.uint8)
        frames.append({p: v for p in diffusion_renderer.PASSES})
    write_dr_frames(tmp_path, frames, chunk_len=4, overlap=1)        # chunks [0..3], [3..5 + pad]
    assert len(list(tmp_path.glob("0001.0003.*"))) == 5              # the padded frame exists
    paths = diffusion_renderer.find_frames(tmp_path, n, overlap_frames=1)
    for g in range(n):
        img = diffusion_renderer.read_image(paths["roughness"][g], "roughness")
        assert img[0, 0, 0] == 20 * g + 10
    with pytest.raises(io.DataError) as e:                            # a run with --chunk_mode first
        diffusion_renderer.find_frames(tmp_path, 9, overlap_frames=1)
    assert "--chunk_mode all" in one_line(e) and str(tmp_path) in str(e.value)


def test_dr_bad_inputs_name_the_file(tmp_path):
    import imageio.v3 as iio

    h, w = 4, 5
    good = np.full((h, w, 3), 128, np.uint8)
    for p in diffusion_renderer.PASSES:
        iio.imwrite(tmp_path / f"0000.0000.{p}.png", good)
    iio.imwrite(tmp_path / "0000.0000.normal.png", np.full((h, w), 128, np.uint8))     # grey normal
    paths = {k: v[0] for k, v in diffusion_renderer.find_frames(tmp_path, 1).items()}
    with pytest.raises(io.DataError) as e:
        diffusion_renderer.read_frame(paths, np.eye(4))
    assert "0000.0000.normal.png" in one_line(e) and "3-channel" in str(e.value)
    iio.imwrite(tmp_path / "0000.0000.normal.png", np.full((h + 1, w, 3), 128, np.uint8))  # other size
    with pytest.raises(io.DataError) as e:
        diffusion_renderer.read_frame(paths, np.eye(4))
    assert "0000.0000.normal.png" in one_line(e)
    (tmp_path / "0000.0000.metallic.png").unlink()
    with pytest.raises(io.DataError) as e:
        diffusion_renderer.find_frames(tmp_path, 1)
    assert "metallic" in one_line(e) and str(tmp_path) in str(e.value)
    other = tmp_path / "b"
    other.mkdir()
    iio.imwrite(other / "0000.0000.basecolor.png", good)
    with pytest.raises(io.DataError) as e:
        diffusion_renderer.find_frames(tmp_path, 1)
    assert "2 clips" in one_line(e)


# ----------------------------------------------------------------------------- DiffusionLight
def test_dl_camera_frame_map_comes_back_aligned_in_world(tmp_path):
    # a first camera with yaw, pitch and roll; two bright spots placed in the camera's view cone
    c2w0 = opencv_c2w((0.5, -3.0, 1.4), (1.5, 0.5, 0.4))
    roll = np.radians(12.0)
    c, s = np.cos(roll), np.sin(roll)
    c2w0[:3, :3] = c2w0[:3, :3] @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    R = c2w0[:3, :3]
    spot_a = R @ np.array([0.55, -0.35, 0.76])       # right of and above the optical axis (camera frame)
    spot_b = R @ np.array([-0.8, 0.15, 0.3])         # well to the left, slightly below
    env_w = spot_world_map(64, 128, [(spot_a, 40.0), (spot_b, 15.0)])
    native = dl_native_map(env_w, c2w0, height=32)
    io.write_rgb_exr(tmp_path / "hdr" / "clip.exr", native)
    path = diffusion_light.find_output(tmp_path)
    back = diffusion_light.to_world(diffusion_light.load(path), c2w0, out_height=64)
    assert back.shape == (64, 128, 3)
    na = spot_a / np.linalg.norm(spot_a)
    assert angle_deg(peak_direction(back), na) < 3.0                  # a pixel is 2.8 deg
    d = envmap.pixel_directions(64, 128)
    lum = back.sum(-1)
    wgt = np.clip(lum - np.percentile(lum, 99), 0, None) * (d @ na > np.cos(np.radians(20)))
    centroid = (d * wgt[..., None]).sum((0, 1))
    assert angle_deg(centroid / np.linalg.norm(centroid), na) < 0.5    # sub-pixel: the inversion is exact
    # the second spot: mask out the first one and look again
    masked = np.where((d @ (spot_a / np.linalg.norm(spot_a)) > np.cos(np.radians(25)))[..., None], 0, back)
    assert angle_deg(peak_direction(masked), spot_b / np.linalg.norm(spot_b)) < 5.0
    # the whole map in front of the camera agrees (behind it the ball's rim compresses everything)
    fwd = R[:, 2]
    front = d @ fwd > np.cos(np.radians(100))
    corr = np.corrcoef(np.log(back[front]).ravel(), np.log(env_w[front]).ravel())[0, 1]
    assert corr > 0.97, corr
    # the mirrored reading of the map (y -> -y in the map's own frame) is detectably wrong
    mirrored = diffusion_light.to_world(native[:, ::-1], c2w0, out_height=64)
    assert angle_deg(peak_direction(mirrored), spot_a / np.linalg.norm(spot_a)) > 20


def test_dl_layout_centre_is_forward_quarter_is_left():
    d = diffusion_light.camera_directions(32, 64, supersample=4)
    np.testing.assert_allclose(d[15:17, 31:33].mean((0, 1)) / np.linalg.norm(d[15:17, 31:33].mean((0, 1))),
                               [0, 0, 1], atol=0.02)
    assert d[16, 16, 0] < -0.99 and d[16, 48, 0] > 0.99 and d[0, 0, 1] < -0.99
    col, row = diffusion_light.native_pixel(d, 32, 64, 4)             # exact inverse
    np.testing.assert_allclose(col[:, 1:-1], np.broadcast_to(np.arange(1, 63), (32, 62)), atol=1e-9)
    np.testing.assert_allclose(row, np.broadcast_to(np.arange(32)[:, None], (32, 64)), atol=1e-9)


def test_dl_bad_inputs_name_the_file(tmp_path):
    io.write_rgb_exr(tmp_path / "square.exr", np.ones((16, 16, 3), np.float32))
    with pytest.raises(io.DataError) as e:
        diffusion_light.load(tmp_path / "square.exr")
    assert "square.exr" in one_line(e) and "2:1" in str(e.value)
    io.write_rgb_exr(tmp_path / "other.exr", np.ones((8, 16, 3), np.float32))
    with pytest.raises(io.DataError) as e:
        diffusion_light.find_output(tmp_path)
    assert "2 EXR files" in one_line(e)
    assert diffusion_light.find_output(tmp_path / "nothing") is None


# ----------------------------------------------------------------------------- the runner
W0, H0, N_FRAMES = 64, 48, 2


@pytest.fixture(scope="module")
def staged(tmp_path_factory):
    """Native outputs of the three tools for a 64x48, 2-frame synthetic video, and its frames."""
    root = tmp_path_factory.mktemp("staged")
    K0 = intrinsics(W0, H0, 1.0)
    gt = gt_cameras(N_FRAMES)
    frames = root / "frames"
    frames.mkdir()
    import imageio.v3 as iio

    for t in range(N_FRAMES):
        b = render(K0, gt[t], W0, H0)
        iio.imwrite(frames / f"f{t:03d}.png", io.to_uint8(io.linear_to_display(b.albedo)))
    grid = megasam.working_map(W0, H0)                      # 512 x 384 for a 64 x 48 video
    write_megasam_npz(root / "ms.npz", grid.scale_K(K0), gt, grid.width, grid.height, scale=0.5)
    dr = diffusion_renderer.pixel_map(W0, H0, 96, 64)        # the renderer's stretch to 96 x 64
    write_dr_frames(root / "dr" / "gbuffer_frames" / "clip",
                    [encode_dr(render(dr.scale_K(K0), c, 96, 64), c, stretch=diffusion_renderer.stretch_ratio(dr)) for c in gt])
    env_w = spot_world_map(32, 64, [(gt[0][:3, :3] @ np.array([0.4, -0.5, 0.77]), 30.0)])
    io.write_rgb_exr(root / "dl.exr", dl_native_map(env_w, gt[0], height=16))
    return {"root": root, "frames": frames, "gt": gt, "grid": grid, "K0": K0, "env_world": env_w}


def fake_commands(staged, counter):
    py = sys.executable
    root = staged["root"]
    log = f"echo {{clip}} >> {counter}"
    return {
        # checks its inputs like the real tool would need them, then emits MegaSAM's final npz
        "megasam": f"test $(ls {{frames}} | wc -l) -eq {{num_frames}} && {log} && "
                   f"{py} -c 'import shutil, sys; shutil.copy(sys.argv[1], sys.argv[2])' {root}/ms.npz {{out}}/{{clip}}_sgd_cvd_hr.npz",
        "diffusion_renderer": f"test -d {{frames_root}}/{{clip}} && {log} && "
                              f"{py} -c 'import shutil, sys; shutil.copytree(sys.argv[1], sys.argv[2])' {root}/dr {{out}}/run",
        "diffusion_light": f"test -f {{frame0_dir}}/{{clip}}.png && {log} && "
                           f"mkdir -p {{out}}/hdr && cp {root}/dl.exr {{out}}/hdr/{{clip}}.exr",
    }


def test_runner_assembles_a_clip_and_resumes(staged, tmp_path):
    counter = tmp_path / "runs.txt"
    cmds = fake_commands(staged, counter)
    out = tmp_path / "clip_a"
    man = backend.reconstruct_paper_stack(staged["frames"], out, cmds, fps=12, scene_static=True)
    assert counter.read_text().split() == ["clip_a"] * 3
    assert man["units"] == "arbitrary" and man["producer"]["stage"] == "phi" and man["producer"]["backend"] == "paper_stack"
    assert man["scene_static"] is True and man["fps"] == 12.0 and man["num_frames"] == N_FRAMES
    views, info = clipmod.read_clip(out)
    grid, gt = staged["grid"], staged["gt"]
    assert (info.width, info.height) == (grid.width, grid.height) == (512, 384)
    for t, v in enumerate(views):
        np.testing.assert_allclose(v.c2w[:3, :3], gt[t][:3, :3], atol=1e-5)
        b = render(grid.scale_K(staged["K0"]), gt[t], grid.width, grid.height)
        m = (v.buffers.mask > 0.5) & (b.mask > 0.5)
        assert m.sum() > 0.95 * (b.mask > 0.5).sum() and (v.buffers.mask > 0.5).sum() < 1.02 * (b.mask > 0.5).sum()
        np.testing.assert_allclose(v.buffers.depth[m] / b.depth[m], 0.5, rtol=2e-3)
        # normals come from 96x64 images upsampled to 512x384: exact inside surfaces, blurred at edges
        err = angle_deg(v.buffers.normal[m], b.normal[m])
        assert np.median(err) < 0.5 and np.percentile(err, 90) < 2.0, (np.median(err), np.percentile(err, 90))
        assert np.median(np.abs(v.buffers.albedo[m] - b.albedo[m])) < 0.02
    env = envmap.load(out / "envmap_init.exr")
    d_true = gt[0][:3, :3] @ np.array([0.4, -0.5, 0.77])
    assert angle_deg(peak_direction(env), d_true / np.linalg.norm(d_true)) < 8.0
    assert len(man["source_frames"]) == N_FRAMES and (out / man["source_frames"][1]).is_file()
    assert man["diagnostics"]["dr_depth_rank_corr"] and min(man["diagnostics"]["dr_depth_rank_corr"]) > 0.9
    timing = json.loads((out / "timing.json").read_text())
    assert set(timing["tool_seconds"]) == set(backend.TOOLS)

    # a rerun reuses every tool's finished outputs and rewrites an identical manifest
    before = (out / "buffers.json").read_text()
    backend.reconstruct_paper_stack(staged["frames"], out, cmds, fps=12, scene_static=True)
    assert counter.read_text().split() == ["clip_a"] * 3
    assert (out / "buffers.json").read_text() == before
    # another DiffusionLight command reruns only that tool
    cmds2 = dict(cmds, diffusion_light=cmds["diffusion_light"] + " && true")
    backend.reconstruct_paper_stack(staged["frames"], out, cmds2, fps=12, scene_static=True)
    assert counter.read_text().split() == ["clip_a"] * 4


def test_runner_failures_are_one_line_naming_clip_and_tool(staged, tmp_path):
    counter = tmp_path / "runs.txt"
    cmds = fake_commands(staged, counter)
    out = tmp_path / "clip_b"
    with pytest.raises(backend.ToolError) as e:
        backend.reconstruct_paper_stack(staged["frames"], out, dict(cmds, diffusion_renderer="echo oops >&2; exit 3"),
                                        fps=12, scene_static=False)
    msg = one_line(e)
    assert msg.startswith("clip_b: diffusion_renderer command failed (exit 3)") and "diffusion_renderer.log" in msg
    assert "oops" in (out / ".work" / "diffusion_renderer.log").read_text()
    assert not (out / "buffers.json").exists()
    with pytest.raises(backend.ToolError) as e:
        backend.reconstruct_paper_stack(staged["frames"], out, dict(cmds, diffusion_light="true"), fps=12, scene_static=False)
    assert one_line(e).startswith("clip_b: diffusion_light wrote nothing at ") and "diffusion_light/out" in str(e.value)
    with pytest.raises(backend.ToolError) as e:
        backend.reconstruct_paper_stack(staged["frames"], out, dict(cmds, megasam="sleep 20"), fps=12,
                                        scene_static=False, timeouts={"megasam": 0.5})
    assert one_line(e).startswith("clip_b: megasam command timed out after 0.5 s")
    assert not (out / "buffers.json").exists()
    with pytest.raises(ValueError, match="unknown placeholder"):
        backend.reconstruct_paper_stack(staged["frames"], out, dict(cmds, megasam="run {video}"), fps=12, scene_static=False)
    with pytest.raises(ValueError, match="missing"):
        backend.reconstruct_paper_stack(staged["frames"], out, {"megasam": "true"}, fps=12, scene_static=False)


def test_runner_rejects_a_megasam_grid_that_is_not_the_released_one(staged, tmp_path):
    root = tmp_path / "bad"
    root.mkdir()
    write_megasam_npz(root / "ms.npz", intrinsics(W0, H0, 1.0), staged["gt"], W0, H0, scale=1.0)   # source size, not the working grid
    cmds = fake_commands(staged, tmp_path / "runs.txt")
    cmds["megasam"] = f"cp {root}/ms.npz {{out}}/x_sgd_cvd_hr.npz"
    with pytest.raises(io.DataError) as e:
        backend.reconstruct_paper_stack(staged["frames"], tmp_path / "clip_c", cmds, fps=12, scene_static=True)
    assert one_line(e).startswith("clip_c: megasam: ") and "working grid" in str(e.value)


# ----------------------------------------------------------------------------- the script, with format stand-ins
STANDIN = Path(__file__).resolve().parent / "standin_tools.py"


def standin_commands() -> dict:
    py = f"{sys.executable} {STANDIN}"
    return {"megasam": f"{py} megasam {{frames}} {{out}} {{clip}}",
            "diffusion_renderer": f"{py} diffusion_renderer {{frames_root}} {{out}}",
            "diffusion_light": f"{py} diffusion_light {{frame0_dir}} {{out}}"}


def run_reconstruct(frames, out, settings, *extra, env=None):
    import os
    import subprocess

    repo = Path(__file__).resolve().parents[1]
    cmd = [sys.executable, str(repo / "scripts" / "reconstruct.py"), "--frames", str(frames), "--out", str(out),
           "--backend", "paper_stack", "--name", out.name, "--fps", "12", "--settings-json", json.dumps(settings), *extra]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=dict(os.environ, **(env or {})))


def write_video(folder, n, w=96, h=64):
    rng = np.random.default_rng(1)
    for i in range(n):
        io.write_rgb_exr(Path(folder) / f"{i:04d}.exr", rng.uniform(0.05, 0.8, (h, w, 3)).astype(np.float32))


def test_script_retry_after_a_hung_tool_sees_one_clip_keeps_the_aspect_and_cleans_up(tmp_path):
    """A 3:2 video through scripts/reconstruct.py with the tools' format stand-ins: the first attempt's
    DiffusionRenderer hangs and is stopped by its timeout (leftovers stay, the job fails); the retry
    hands the tools a frames folder holding this clip only (the stand-in exits non-zero otherwise, as
    --group_mode folder would render a second clip), writes the clip on the video's full 96x64 grid (the
    strip MegaSAM's crop to multiples of 8 removed is filled, not a hole) and removes the tools' work."""
    write_video(tmp_path / "video", 5)
    out = tmp_path / "s0_t0"
    marker = tmp_path / "hung-once"
    settings = {"commands": standin_commands(), "timeouts": {"diffusion_renderer": 10.0}}  # the retry's tool
    # must finish in it while the other test worker renders
    p = run_reconstruct(tmp_path / "video", out, settings, env={"STANDIN_HANG_ONCE": f"diffusion_renderer:{marker}"})
    assert p.returncode == 1 and "diffusion_renderer command timed out after 10 s" in p.stderr, p.stderr[-2000:]
    assert marker.is_file() and (out / ".work" / "frames").is_dir() and not (out / "buffers.json").exists()
    p = run_reconstruct(tmp_path / "video", out, settings, env={"STANDIN_HANG_ONCE": f"diffusion_renderer:{marker}"})
    assert p.returncode == 0, p.stderr[-3000:]
    views, info = clipmod.read_clip(out)
    assert (info.width, info.height, info.num_frames) == (96, 64, 5) and info.units == "arbitrary"
    grid = megasam.working_map(96, 64)
    assert (grid.width, grid.height) == (536, 360)          # the crop drops the last 0.9% columns
    for v in views:
        assert v.buffers.mask[:, -2:].all() and v.buffers.mask[-2:].all()
    assert not (out / ".work").exists() and not (out / "tool_grid").exists()


def test_one_frame_clip_takes_the_static_camera_path(tmp_path):
    """MegaSAM's tracker cannot start on one frame: the megasam command's UniDepth npz (depth, fov on
    a long side of 640) gives a level static camera with K from the fov, metric units."""
    write_video(tmp_path / "image", 1, w=120, h=80)
    out = tmp_path / "mit_scene_d0"
    p = run_reconstruct(tmp_path / "image", out, {"commands": standin_commands()})
    assert p.returncode == 0, p.stderr[-3000:]
    views, info = clipmod.read_clip(out)
    assert info.num_frames == 1 and info.camera_static and info.units == "metres"
    assert (info.width, info.height) == (120, 80)
    # fov 60 deg; UniDepth's 640x427 grid rounds 426.7 rows, so square pixels are restored (resample.square_pixels)
    np.testing.assert_allclose(views[0].K[0, 0], (120 / 2) / np.tan(np.radians(30)), rtol=1e-3)
    assert views[0].K[0, 0] == views[0].K[1, 1]
    np.testing.assert_allclose(views[0].c2w[:3, :3], megasam.WORLD_FROM_CAM0[:3, :3], atol=1e-12)
    assert views[0].buffers.mask.mean() > 0.99
    # a MegaSAM final npz where UniDepth's was expected is a one-line error naming the file
    cmds = dict(standin_commands(), megasam="mkdir -p {out} && " + sys.executable + " -c \"import numpy as np, sys; "
                "np.savez(sys.argv[1], images=np.zeros((1, 2, 2, 3), np.uint8))\" {out}/x_sgd_cvd_hr.npz")
    p = run_reconstruct(tmp_path / "image", tmp_path / "mit_bad", {"commands": cmds})
    assert p.returncode == 1 and "lacks key(s) ['depth', 'fov']" in p.stderr and "x_sgd_cvd_hr.npz" in p.stderr, p.stderr[-2000:]


# ----------------------------------------------------------------------------- the shipped site scripts
FAKE_CHECKOUT_SCRIPTS = {
    # path in the tool's checkout -> a stand-in that parses the released script's flags and writes what
    # the released script writes, where it writes it (relative to the checkout, as they do)
    ("megasam", "UniDepth/scripts/demo_mega-sam.py"): '''
import argparse, os, sys, numpy as np
sys.path.insert(0, os.environ["STANDIN_DIR"]); import standin_tools as s
from lightcrafter.recon.paper_stack import megasam as ms
ap = argparse.ArgumentParser(); ap.add_argument("--scene-name"); ap.add_argument("--img-path"); ap.add_argument("--outdir")
a = ap.parse_args()
frames = s._frames(__import__("pathlib").Path(a.img_path)); h0, w0 = frames[0].shape[:2]; g = ms.unidepth_map(w0, h0)
os.makedirs(f"{a.outdir}/{a.scene_name}", exist_ok=True)
for i in range(len(frames)):
    np.savez(f"{a.outdir}/{a.scene_name}/{i:05d}.npz", depth=s._ramp(g.height, g.width), fov=np.float64(60.0))
''',
    ("megasam", "Depth-Anything/run_videos.py"): '''
import argparse, os, numpy as np
ap = argparse.ArgumentParser(); [ap.add_argument(f) for f in ("--encoder", "--load-from", "--img-path", "--outdir")]
a = ap.parse_args(); os.makedirs(a.outdir, exist_ok=True); np.save(f"{a.outdir}/00000.npy", np.zeros((4, 4), np.float32))
''',
    ("megasam", "camera_tracking_scripts/test_demo.py"): '''
import argparse, os
ap = argparse.ArgumentParser()
for f in ("--datapath", "--weights", "--scene_name", "--mono_depth_path", "--metric_depth_path"): ap.add_argument(f)
ap.add_argument("--disable_vis", action="store_true"); a = ap.parse_args()
assert a.disable_vis and not a.metric_depth_path.endswith(" ")
os.makedirs(f"reconstructions/{a.scene_name}", exist_ok=True); os.makedirs("outputs", exist_ok=True)
open(f"reconstructions/{a.scene_name}/datapath.txt", "w").write(a.datapath); open(f"outputs/{a.scene_name}_droid.npz", "wb").write(b"x")
''',
    ("megasam", "cvd_opt/preprocess_flow.py"): '''
import argparse, os
ap = argparse.ArgumentParser(); [ap.add_argument(f) for f in ("--datapath", "--model", "--scene_name")]
ap.add_argument("--mixed_precision", action="store_true"); a = ap.parse_args()
os.makedirs(f"cache_flow/{a.scene_name}", exist_ok=True); open(f"cache_flow/{a.scene_name}/flows.npy", "wb").write(b"x")
''',
    ("megasam", "cvd_opt/cvd_opt.py"): '''
import argparse, os, shutil, sys, tempfile
sys.path.insert(0, os.environ["STANDIN_DIR"]); import standin_tools as s
ap = argparse.ArgumentParser(); [ap.add_argument(f) for f in ("--scene_name", "--w_grad", "--w_normal")]; a = ap.parse_args()
frames = open(f"reconstructions/{a.scene_name}/datapath.txt").read()
t = tempfile.mkdtemp(); s.megasam(frames, t, a.scene_name); os.makedirs("outputs_cvd", exist_ok=True)
shutil.move(f"{t}/outputs_cvd/{a.scene_name}_sgd_cvd_hr.npz", f"outputs_cvd/{a.scene_name}_sgd_cvd_hr.npz")
''',
    ("diffusion_renderer", "cosmos_predict1/diffusion/inference/inference_inverse_renderer.py"): '''
import argparse, os, sys
sys.path.insert(0, os.environ["STANDIN_DIR"]); import standin_tools as s
ap = argparse.ArgumentParser()
for f in ("--checkpoint_dir", "--diffusion_transformer_dir", "--dataset_path", "--num_video_frames", "--group_mode",
          "--chunk_mode", "--save_video", "--video_save_folder"): ap.add_argument(f)
a = ap.parse_args(); assert a.chunk_mode == "all" and a.group_mode == "folder"
s.diffusion_renderer(a.dataset_path, a.video_save_folder)
''',
    ("diffusion_light", "inpaint.py"): '''
import argparse, os, shutil
ap = argparse.ArgumentParser(); ap.add_argument("--dataset"); ap.add_argument("--output_dir"); a = ap.parse_args()
os.makedirs(f"{a.output_dir}/square", exist_ok=True)
for f in os.listdir(a.dataset): shutil.copy(f"{a.dataset}/{f}", f"{a.output_dir}/square/{f[:-4]}_ev-00.png")
''',
    ("diffusion_light", "ball2envmap.py"): '''
import argparse, os, shutil
ap = argparse.ArgumentParser(); ap.add_argument("--ball_dir"); ap.add_argument("--envmap_dir"); a = ap.parse_args()
shutil.copytree(a.ball_dir, a.envmap_dir)
''',
    ("diffusion_light", "exposure2hdr.py"): '''
import argparse, os, sys, tempfile
sys.path.insert(0, os.environ["STANDIN_DIR"]); import standin_tools as s
ap = argparse.ArgumentParser(); ap.add_argument("--input_dir"); ap.add_argument("--output_dir"); a = ap.parse_args()
for f in os.listdir(a.input_dir):
    t = tempfile.mkdtemp(); open(f"{t}/{f.replace('_ev-00', '')}", "wb").write(b"")
    s.diffusion_light(t, os.path.dirname(a.output_dir))
''',
}


def fake_checkouts(root: Path) -> dict:
    env = {"STANDIN_DIR": str(STANDIN.parent), "PYTHONPATH": str(STANDIN.parents[1]),
           "PATH": f"{Path(sys.executable).parent}:{__import__('os').environ['PATH']}"}
    for (tool, rel), code in FAKE_CHECKOUT_SCRIPTS.items():
        p = root / tool / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(code.lstrip())
    for tool, var in (("megasam", "MEGASAM_ROOT"), ("diffusion_renderer", "DIFFUSION_RENDERER_ROOT"),
                      ("diffusion_light", "DIFFUSION_LIGHT_ROOT")):
        env[var] = str(root / tool)
    return env


@pytest.mark.parametrize("n_frames", [3, 1])
def test_shipped_site_scripts_run_the_released_commands_and_leave_nothing_in_the_checkouts(tmp_path, n_frames, monkeypatch):
    """config/paper.yaml's commands (config/site/*.sh, taken from the tools' READMEs) against checkouts
    whose scripts are format stand-ins accepting the released flags: the clip is assembled, and each
    checkout holds only its own files afterwards (MegaSAM's cwd-relative intermediates are removed)."""
    import os
    import yaml

    repo = STANDIN.parents[1]
    commands = yaml.safe_load((repo / "config" / "paper.yaml").read_text())["recon"]["paper_stack"]["commands"]
    commands = {t: c.replace("config/site/", f"{repo}/config/site/") for t, c in commands.items()}
    for k, v in fake_checkouts(tmp_path / "checkouts").items():
        monkeypatch.setenv(k, v)
    before = {p for p in (tmp_path / "checkouts").rglob("*") if p.is_file()}
    frames = tmp_path / "frames"
    frames.mkdir()
    import imageio.v3 as iio

    for i in range(n_frames):
        iio.imwrite(frames / f"{i:05d}.png", np.full((48, 72, 3), 40 * i + 30, np.uint8))
    man = backend.reconstruct_paper_stack(frames, tmp_path / "clip", commands, fps=12, scene_static=True, clip_id="c0")
    assert man["num_frames"] == n_frames and man["camera_static"] == (n_frames == 1)
    after = {p for p in (tmp_path / "checkouts").rglob("*") if p.is_file() and "__pycache__" not in p.parts}
    assert after == before, sorted(str(p.relative_to(tmp_path)) for p in after - before)
