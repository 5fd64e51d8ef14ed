"""lightcrafter.evaluation: PSNR/SSIM (scikit-image), Warp-SSIM (DIS flow, occlusion masks),
T-CLIP and LPIPS from local weights only, aggregation and bootstrap intervals."""

from __future__ import annotations


import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from lightcrafter import evaluation as ev
from lightcrafter import metrics
from lightcrafter.io import DataError


# ----------------------------------------------------------------------------- helpers
def old_psnr_db(a, b):
    """The hand-written PSNR that lightcrafter.metrics had before it wrapped scikit-image."""
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(1.0 / mse)


def old_ssim_map(a, b):
    """The hand-written SSIM map (Gaussian sigma 1.5, truncate 3.5, reflect), per channel mean."""
    c1, c2 = 0.01**2, 0.03**2

    def blur(x):
        return gaussian_filter(x, sigma=1.5, truncate=3.5, mode="reflect")

    maps = []
    for c in range(a.shape[-1]):
        x, y = a[..., c], b[..., c]
        mx, my = blur(x), blur(y)
        sxx, syy, sxy = blur(x * x) - mx * mx, blur(y * y) - my * my, blur(x * y) - mx * my
        maps.append(((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2)))
    return np.mean(maps, axis=0)


def texture(h, w, sigma=2.0, seed=0):
    rng = np.random.default_rng(seed)
    t = np.stack([gaussian_filter(rng.random((h, w)), sigma) for _ in range(3)], -1)
    return 0.1 + 0.8 * (t - t.min()) / (t.max() - t.min())


def translating_video(n=8, h=64, w=96, step=(2, 1), seed=0):
    """A textured image moving rigidly by ``step`` = (dx, dy) px per frame."""
    big = texture(h + 40, w + 40, seed=seed)
    dx, dy = step
    return np.stack([big[20 - t * dy: 20 - t * dy + h, 20 - t * dx: 20 - t * dx + w] for t in range(n)])


def square_over_background(n=6, h=72, w=112, speed=6):
    """A textured square moving right over a static textured background (it occludes it)."""
    bg, sq = texture(h, w, seed=1), 0.5 + 0.5 * texture(32, 32, 1.5, seed=2)
    frames = []
    for t in range(n):
        f = bg.copy()
        f[20:52, 8 + speed * t: 40 + speed * t] = sq
        frames.append(f)
    return np.stack(frames)


# ----------------------------------------------------------------------------- PSNR / SSIM
def test_psnr_agrees_with_hand_written_and_closed_form():
    rng = np.random.default_rng(0)
    for _ in range(5):
        a, b = rng.random((24, 32, 3)), rng.random((24, 32, 3))
        assert ev.psnr_db(a, b) == pytest.approx(old_psnr_db(a, b), abs=1e-10)
    z = np.zeros((8, 8, 3))
    assert ev.psnr_db(z, z + 0.1) == pytest.approx(20.0)
    assert ev.psnr_db(z, z + 0.01) == pytest.approx(40.0)
    assert ev.psnr_db(z, z) == float("inf")
    r = ev.framewise_psnr(np.stack([z, z]), np.stack([z, z + 0.1]))
    assert r.per_item == (100.0, pytest.approx(20.0)) and r.value == pytest.approx(60.0)


def test_ssim_agrees_with_hand_written():
    """Same Wang et al. settings: the maps are identical; the means differ only because
    scikit-image leaves the 5-px border out (|difference| < 0.01 on these images)."""
    rng = np.random.default_rng(1)
    a = rng.random((48, 64, 3))
    b = np.clip(a + rng.normal(0, 0.1, a.shape), 0, 1)
    old = old_ssim_map(a, b)
    p = ev.SSIM_BORDER_PX
    assert p == 5
    assert np.allclose(ev.ssim_map(a, b), old, atol=1e-12)
    assert ev.ssim(a, b) == pytest.approx(old[p:-p, p:-p].mean(), abs=1e-12)
    assert abs(ev.ssim(a, b) - old.mean()) < 0.01


def test_ssim_closed_form_and_order():
    c1, c2 = 0.01**2, 0.03**2
    a, b = np.full((32, 32, 3), 0.5), np.full((32, 32, 3), 0.25)
    # constant images: no variance, so SSIM is the luminance term alone
    assert ev.ssim(a, b) == pytest.approx((2 * 0.5 * 0.25 + c1) / (0.5**2 + 0.25**2 + c1), abs=1e-12)
    rng = np.random.default_rng(2)
    img = rng.random((32, 32, 3))
    assert ev.ssim(img, img) == pytest.approx(1.0)
    s1 = ev.ssim(img, np.clip(img + rng.normal(0, 0.05, img.shape), 0, 1))
    s2 = ev.ssim(img, np.clip(img + rng.normal(0, 0.2, img.shape), 0, 1))
    assert 1.0 > s1 > s2 > 0.0
    assert c2 > 0


def test_metrics_module_names_are_thin_wrappers():
    rng = np.random.default_rng(3)
    a, b = rng.random((3, 16, 20, 3)), rng.random((3, 16, 20, 3))
    assert metrics.video_psnr_db(a, b) == pytest.approx(ev.framewise_psnr(a, b).value)
    assert metrics.video_ssim(a, b) == pytest.approx(ev.framewise_ssim(a, b).value)
    assert metrics.ssim(a[0], b[0]) == ev.ssim(a[0], b[0])
    assert np.allclose(metrics.temporal_difference(a), np.abs(np.diff(a, axis=0)).mean(axis=(1, 2, 3)))


def test_bad_inputs_raise():
    v = np.zeros((2, 8, 8, 3))
    with pytest.raises(ValueError, match="linear_to_display"):
        ev.framewise_psnr(v + 1.5, v)
    with pytest.raises(ValueError, match="differ in shape"):
        ev.framewise_ssim(v, np.zeros((3, 8, 8, 3)))
    with pytest.raises(ValueError, match=r"\(N, H, W, 3\)"):
        ev.warp_ssim(np.zeros((2, 8, 8)), v)


# ----------------------------------------------------------------------------- Warp-SSIM
def test_dis_flow_recovers_translation():
    v = translating_video(n=2, step=(2, 1))
    f = ev.dis_flow(v[0], v[1])
    inner = f[10:-10, 10:-10].reshape(-1, 2)
    assert np.allclose(inner.mean(axis=0), [2.0, 1.0], atol=0.05)


def test_warp_ssim_rigid_translation_is_one_and_penalises_flicker_and_shuffling():
    target = translating_video(n=8)
    perfect = ev.warp_ssim(target, target)
    assert perfect.computed and perfect.value > 0.999
    assert len(perfect.per_item) == 7 and len(perfect.info["valid_fraction"]) == 7
    assert perfect.info["flow_source"] == "target"
    d = perfect.to_dict()
    assert d["value"] == perfect.value and len(d["per_item"]) == 7 and d["status"] == "computed"

    gains = np.where(np.arange(8) % 2 == 0, 1.0, 0.6)[:, None, None, None]
    flicker = ev.warp_ssim(target * gains, target)
    assert flicker.value < perfect.value - 0.1

    perm = np.random.default_rng(0).permutation(8)
    assert not np.array_equal(perm, np.arange(8))
    shuffled = ev.warp_ssim(target[perm], target)
    assert shuffled.value < 0.6

    # precomputed flows of the target give the same numbers (flows are reused across methods)
    flows = ev.compute_flows(target)
    assert ev.warp_ssim(target * gains, flows=flows).value == pytest.approx(flicker.value)


def test_warp_ssim_excludes_occluded_pixels():
    video = square_over_background(speed=6)
    flows = ev.compute_flows(video)
    strip, far, square = [], [], []
    for t, valid in enumerate(flows.valid):
        right = 40 + 6 * t                            # the square covers x in [right - 32, right)
        strip.append(valid[24:48, right:right + 6].mean())   # background it covers in frame t+1
        far.append(np.r_[valid[6:14, 6:-6].ravel(), valid[60:66, 6:-6].ravel()].mean())
        square.append(valid[24:48, right - 26:right - 6].mean())
    # DIS smears the square's motion a few px onto the background it covers; the forward-backward
    # and motion-boundary tests still drop most of that band (measured ~0.34 kept) and keep the rest
    assert np.mean(strip) < 0.6
    assert np.mean(far) > 0.85 and np.mean(square) > 0.95
    masked = ev.warp_ssim(video, flows=flows)
    unmasked = ev.warp_ssim(video, flows=flows, mask_occlusions=False)
    assert masked.value > 0.975                       # measured 0.984
    assert masked.value > unmasked.value + 0.02       # measured 0.947 unmasked
    assert np.mean(masked.info["valid_fraction"]) < np.mean(unmasked.info["valid_fraction"])


# ----------------------------------------------------------------------------- T-CLIP
def test_t_clip_not_computed_without_weights(tmp_path):
    v = np.random.default_rng(0).random((3, 16, 16, 3))
    r = ev.t_clip(v, None)
    assert not r.computed and r.value is None and r.status.startswith("not computed: no CLIP weights")
    missing = tmp_path / "nowhere"
    r = ev.t_clip(v, missing)
    assert r.value is None and r.status == f"not computed: no CLIP weights at {missing}"


@pytest.fixture(scope="module")
def tiny_clip_dir(tmp_path_factory):
    """A randomly initialised, tiny transformers CLIP model saved as a local folder."""
    pytest.importorskip("transformers")
    import torch
    from transformers import CLIPConfig, CLIPImageProcessorPil, CLIPModel

    torch.manual_seed(0)
    cfg = CLIPConfig(
        text_config=dict(hidden_size=16, intermediate_size=32, num_hidden_layers=1, num_attention_heads=2,
                         vocab_size=64, max_position_embeddings=16, bos_token_id=0, eos_token_id=1, pad_token_id=1),
        vision_config=dict(hidden_size=16, intermediate_size=32, num_hidden_layers=1, num_attention_heads=2,
                           image_size=32, patch_size=8),
        projection_dim=8)
    folder = tmp_path_factory.mktemp("tiny_clip")
    CLIPModel(cfg).save_pretrained(folder)
    CLIPImageProcessorPil(size={"shortest_edge": 32}, crop_size={"height": 32, "width": 32}).save_pretrained(folder)
    return folder


def test_t_clip_with_tiny_local_weights(tiny_clip_dir, tmp_path):
    import torch
    from transformers import CLIPImageProcessorPil, CLIPModel

    rng = np.random.default_rng(0)
    still = np.repeat(rng.random((1, 40, 48, 3)), 4, axis=0)
    r = ev.t_clip(still, tiny_clip_dir)
    assert r.computed and r.value == pytest.approx(1.0, abs=1e-6) and len(r.per_item) == 3

    video = rng.random((5, 40, 48, 3))
    r = ev.t_clip(video, tiny_clip_dir)
    # independent computation through transformers' own image-feature API
    model = CLIPModel.from_pretrained(tiny_clip_dir).eval()
    proc = CLIPImageProcessorPil.from_pretrained(tiny_clip_dir)
    px = proc(images=list(np.round(video * 255).astype(np.uint8)), return_tensors="pt")["pixel_values"]
    with torch.no_grad():
        feats = model.get_image_features(pixel_values=px)
    feats = getattr(feats, "pooler_output", feats).double().numpy()
    feats /= np.linalg.norm(feats, axis=1, keepdims=True)
    adjacent = np.sum(feats[:-1] * feats[1:], axis=1)
    assert np.allclose(r.per_item, adjacent, atol=1e-6)
    assert r.value == pytest.approx(adjacent.mean(), abs=1e-6)
    assert r.value < 1.0 - 1e-4
    g = feats @ feats.T
    assert ev.t_clip(video, tiny_clip_dir, pairs="all").value == pytest.approx(
        (g.sum() - np.trace(g)) / 20, abs=1e-6)

    broken = tmp_path / "broken_clip"
    broken.mkdir()
    with pytest.raises(DataError, match="preprocessor_config.json"):
        ev.t_clip(video, broken)


# ----------------------------------------------------------------------------- LPIPS
def test_lpips_not_computed_without_weights(tmp_path):
    v = np.random.default_rng(0).random((2, 16, 16, 3))
    r = ev.lpips_video(v, v, None)
    assert r.value is None and r.status.startswith("not computed: no LPIPS weights configured")
    r = ev.lpips_video(v, v, tmp_path / "nowhere")
    assert r.value is None and r.status == f"not computed: no LPIPS weights at {tmp_path / 'nowhere'}"
    r = ev.lpips_video(v, v, tmp_path)
    assert r.value is None and "alexnet-owt-7be5be79.pth is missing" in r.status


ALEX_FEATURES = {0: (64, 3, 11), 3: (192, 64, 5), 6: (384, 192, 3), 8: (256, 384, 3), 10: (256, 256, 3)}


def _standin_lpips_weights(folder, seed=0, under_checkpoints=False):
    """Random weights in the real formats: torchvision's AlexNet ``features.*`` keys and shapes (plus a
    classifier key, which LPIPS ignores) and lpips' v0.1 ``lin{k}.model.1.weight`` (non-negative)."""
    import torch

    g = torch.Generator().manual_seed(seed)
    d = folder / "checkpoints" if under_checkpoints else folder
    d.mkdir(parents=True, exist_ok=True)
    backbone = {}
    for i, (o, c, k) in ALEX_FEATURES.items():
        backbone[f"features.{i}.weight"] = torch.randn(o, c, k, k, generator=g) * (2.0 / (c * k * k)) ** 0.5
        backbone[f"features.{i}.bias"] = torch.randn(o, generator=g) * 0.01
    backbone["classifier.6.bias"] = torch.zeros(1000)
    torch.save(backbone, d / "alexnet-owt-7be5be79.pth")
    lin = {f"lin{k}.model.1.weight": torch.rand(1, c, 1, 1, generator=g) * 0.1
           for k, c in enumerate((64, 192, 384, 256, 256))}
    torch.save(lin, d / "alex.pth")
    return backbone, lin


def _lpips_by_hand(a, b, backbone, lin):
    """LPIPS v0.1 written out layer by layer from the two state dicts (an independent check of the wiring)."""
    import torch
    import torch.nn.functional as F

    shift = torch.tensor([-0.030, -0.088, -0.188]).view(1, 3, 1, 1)
    scale = torch.tensor([0.458, 0.448, 0.450]).view(1, 3, 1, 1)

    def taps(x):
        x = (x - shift) / scale
        out = []
        for i, stride, pad, pool in ((0, 4, 2, False), (3, 1, 2, True), (6, 1, 1, True), (8, 1, 1, False),
                                     (10, 1, 1, False)):
            if pool:
                x = F.max_pool2d(x, 3, 2)
            x = F.relu(F.conv2d(x, backbone[f"features.{i}.weight"], backbone[f"features.{i}.bias"], stride, pad))
            out.append(x / (x.pow(2).sum(1, keepdim=True).sqrt() + 1e-10))
        return out

    return sum((F.conv2d((x - y) ** 2, lin[f"lin{k}.model.1.weight"])).mean(dim=(1, 2, 3))
               for k, (x, y) in enumerate(zip(taps(a), taps(b))))


def test_lpips_from_standin_weights_in_the_real_formats(tmp_path):
    import torch

    backbone, lin = _standin_lpips_weights(tmp_path)
    rng = np.random.default_rng(0)
    a = rng.random((3, 64, 64, 3))
    noisy = [np.clip(a + rng.normal(0, s, a.shape), 0, 1) for s in (0.02, 0.1, 0.3)]
    same = ev.lpips_video(a, a, tmp_path)
    assert same.computed and np.allclose(same.per_item, 0.0, atol=1e-7)
    vals = [ev.lpips_video(n, a, tmp_path).value for n in noisy]
    assert 0 < vals[0] < vals[1] < vals[2]                      # more noise, farther
    assert ev.lpips_video(a, noisy[1], tmp_path).value == pytest.approx(vals[1], rel=1e-5)  # symmetric
    to_t = lambda x: torch.from_numpy(x.transpose(0, 3, 1, 2).astype(np.float32)) * 2 - 1  # noqa: E731
    ref = _lpips_by_hand(to_t(noisy[1]), to_t(a), backbone, lin).numpy()
    np.testing.assert_allclose(ev.lpips_video(noisy[1], a, tmp_path).per_item, ref, rtol=1e-4)
    # a torch hub cache folder (files under checkpoints/) works as is
    hub = tmp_path / "hub"
    _standin_lpips_weights(hub, under_checkpoints=True)
    assert ev.lpips_video(noisy[1], a, hub).value == pytest.approx(vals[1], rel=1e-5)


def test_lpips_weights_of_another_network_or_a_broken_file_are_one_line_errors(tmp_path):
    import torch

    from lightcrafter.io import DataError

    v = np.zeros((1, 32, 32, 3))
    _standin_lpips_weights(tmp_path)
    wrong = tmp_path / "wrong"
    wrong.mkdir()
    torch.save({"features.0.weight": torch.zeros(64, 3, 3, 3)}, wrong / "alexnet-owt-7be5be79.pth")  # vgg's first conv
    (wrong / "alex.pth").write_bytes((tmp_path / "alex.pth").read_bytes())
    with pytest.raises(DataError, match=r"alexnet-owt-7be5be79.pth: no tensor features.0.weight of shape"):
        ev.lpips_video(v, v, wrong)
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "alexnet-owt-7be5be79.pth").write_bytes((tmp_path / "alexnet-owt-7be5be79.pth").read_bytes())
    (broken / "alex.pth").write_bytes(b"truncated")
    with pytest.raises(DataError, match=r"alex.pth: not a torch state dict.*weights/v0.1/alex.pth"):
        ev.lpips_video(v, v, broken)
    no_lin = tmp_path / "no_lin"
    no_lin.mkdir()
    (no_lin / "alexnet-owt-7be5be79.pth").write_bytes((tmp_path / "alexnet-owt-7be5be79.pth").read_bytes())
    r = ev.lpips_video(v, v, no_lin)
    assert r.value is None and "alex.pth is missing" in r.status


def test_lpips_of_constant_and_one_pixel_frames_is_finite(tmp_path):
    _standin_lpips_weights(tmp_path)
    for shape in ((2, 1, 1, 3), (2, 63, 63, 3)):  # below AlexNet's 11 px receptive start, and ordinary
        zero, one = np.zeros(shape), np.ones(shape)
        if shape[1] < 16:  # no answer: not computed, with the reason
            r = ev.lpips_video(zero, one, tmp_path)
            assert r.value is None and "smaller than the 31 px" in r.status
            continue
        r = ev.lpips_video(zero, one, tmp_path)
        assert np.isfinite(r.per_item).all() and r.value > 0
        assert ev.lpips_video(one, one, tmp_path).value == pytest.approx(0.0, abs=1e-7)


# ----------------------------------------------------------------------------- intervals
def test_bootstrap_ci_covers_the_mean_and_narrows():
    rng = np.random.default_rng(123)
    true_mean, covered, trials = 0.7, 0, 200
    for i in range(trials):
        ci = ev.bootstrap_ci(rng.normal(true_mean, 0.1, 40), n_resamples=2000, seed=i)
        covered += ci["low"] <= true_mean <= ci["high"]
    assert 0.88 <= covered / trials <= 0.99          # nominal 0.95 (percentile bootstrap runs a bit narrow)

    small = ev.bootstrap_ci(rng.normal(true_mean, 0.1, 20), n_resamples=2000)
    large = ev.bootstrap_ci(rng.normal(true_mean, 0.1, 320), n_resamples=2000)
    assert (large["high"] - large["low"]) < 0.4 * (small["high"] - small["low"])   # ~1/4 expected

    v = rng.normal(0, 1, 30)
    assert ev.bootstrap_ci(v) == ev.bootstrap_ci(v)                  # fixed seed: reproducible
    assert ev.bootstrap_ci(v)["n_resamples"] == ev.BOOTSTRAP_RESAMPLES
    # below the documented minimum: the mean, no interval, and the reason; nothing at all is an error
    few = ev.bootstrap_ci([1.0, 2.0, 3.0])
    assert few["mean"] == 2.0 and few["low"] is None and few["high"] is None and few["n"] == 3
    assert few["too_few"] == f"too few clips for an interval (3 < {ev.MIN_CLIPS_FOR_INTERVAL})"
    assert set(few) == set(ev.bootstrap_ci(v))                       # one shape
    assert ev.bootstrap_ci(v)["too_few"] is None
    assert ev.bootstrap_ci([0.5] * 8)["low"] == ev.bootstrap_ci([0.5] * 8)["high"] == 0.5  # constant values
    for bad in ([], [1.0, float("nan")] * 4):
        with pytest.raises(ValueError, match="need finite per-clip values"):
            ev.bootstrap_ci(bad)


def test_paired_bootstrap_ci():
    rng = np.random.default_rng(7)
    base = rng.normal(25.0, 3.0, 60)                 # per-clip PSNR, large between-clip spread
    better = base + 0.5 + rng.normal(0, 0.2, 60)     # +0.5 dB on every clip
    ci = ev.paired_bootstrap_ci(better, base)
    assert ci["low"] > 0 and ci["low"] <= 0.5 <= ci["high"]
    unpaired = ev.bootstrap_ci(better)
    assert (ci["high"] - ci["low"]) < 0.2 * (unpaired["high"] - unpaired["low"])
    with pytest.raises(ValueError, match="pair the same clips"):
        ev.paired_bootstrap_ci(better, base[:-1])


def test_blockiness_and_block_jump_find_the_grid_and_the_jumps_and_nothing_else():
    rng = np.random.default_rng(0)
    from scipy.ndimage import gaussian_filter as gf

    smooth = np.clip(0.5 + gf(rng.normal(0, 0.3, (9, 64, 96, 3)), (0, 3, 3, 0)), 0, 1)
    b8 = ev.blockiness(smooth, 8).value
    assert 0.8 < b8 < 1.2                                    # a natural image has no grid
    # the same frames with their 8x8 blocks' means shifted by a little: an 8-px grid, also seen at 16 px
    offs = np.kron(rng.normal(0, 0.03, (9, 8, 12, 1)), np.ones((1, 8, 8, 1)))
    blocky = np.clip(smooth + offs, 0, 1)
    assert ev.blockiness(blocky, 8).value > 1.5 * b8 and ev.blockiness(blocky, 16).value > 1.3
    # a slow drift with jumps at transitions 0 and 4: the jump ratio rises well above 1; a steady drift is 1
    steps = np.array([0.0, 3, 4, 5, 6, 9, 10, 11, 12]) * 0.01
    drift = np.clip(smooth[:1] + steps[:, None, None, None], 0, 1)
    assert ev.block_jump(drift).value > 2.5
    steady = np.clip(smooth[:1] + np.arange(9)[:, None, None, None] * 0.01, 0, 1)
    assert ev.block_jump(steady).value == pytest.approx(1.0, abs=0.05)
    assert ev.block_jump(drift).info["boundary_transitions"] == [0, 4]  # 9 frames: transitions 0..7
    # no answer: constant frames, frozen video, too few frames or pixels
    const = np.full((9, 64, 96, 3), 0.4)
    assert not ev.blockiness(const).computed and "constant" in ev.blockiness(const).status
    assert not ev.block_jump(const).computed and not ev.block_jump(smooth[:5]).computed
    assert not ev.blockiness(smooth[:, :10, :10]).computed


def test_the_metric_registry_is_the_one_list(monkeypatch):
    """evaluate_video computes every registered metric, evaluate_target the no-reference ones, and the
    report's labels come from the same entries: a new metric is one entry."""
    from lightcrafter import report

    rng = np.random.default_rng(0)
    tgt = np.clip(rng.random((6, 48, 64, 3)), 0, 1)
    ctx = ev.Context(tgt, ev.compute_flows(tgt))
    res = ev.evaluate_video(np.clip(tgt + 0.05, 0, 1), ctx)
    assert list(res) == list(ev.METRICS)
    assert res["lpips"].value is None and res["t_clip"].value is None      # no weights: not computed
    assert res["psnr_db"].value == pytest.approx(-10 * np.log10(np.mean((np.clip(tgt + 0.05, 0, 1) - tgt) ** 2)),
                                                 rel=1e-3)
    assert set(ev.evaluate_target(ctx)) == {n for n, m in ev.METRICS.items() if not m.needs_reference}
    assert set(report.METRIC_LABELS) == set(ev.METRICS)
    monkeypatch.setitem(ev.METRICS, "mean_level", ev.Metric("mean_level", "mean", None, False,
                                                             lambda v, c: ev.MetricResult("mean_level", float(v.mean()))))
    assert ev.evaluate_video(tgt, ctx)["mean_level"].value == pytest.approx(tgt.mean())
    assert "mean_level" in ev.evaluate_target(ctx)
    with pytest.raises(ValueError, match="differ in shape"):
        ev.evaluate_video(tgt[:3], ctx)


def test_metrics_on_identical_constant_tiny_and_frozen_videos():
    """Known values where they exist, finite values elsewhere, and a reason where an input has no answer."""
    rng = np.random.default_rng(0)
    a = rng.random((3, 32, 32, 3))
    assert ev.framewise_ssim(a, a).value == pytest.approx(1.0) and ev.framewise_psnr(a, a).value == ev.PSNR_CAP_DB
    c = np.full((3, 32, 32, 3), 0.5)
    assert ev.framewise_ssim(c, c).value == pytest.approx(1.0)
    assert 0 <= ev.framewise_ssim(c, np.zeros_like(c)).value < 0.01
    frozen = np.repeat(a[:1], 4, axis=0)                      # zero flow
    assert ev.warp_ssim(frozen, frozen).value == pytest.approx(1.0)
    one = np.full((3, 1, 1, 3), 0.5)
    assert ev.framewise_psnr(one, one).value == ev.PSNR_CAP_DB
    assert "smaller than SSIM" in ev.framewise_ssim(one, one).status
    res = ev.evaluate_video(one, ev.Context.of(one))
    assert "OpenCV's DIS" in res["warp_ssim"].status and not res["blockiness_8"].computed
    with pytest.raises(ValueError, match="optical flow: frames 1x1"):
        ev.compute_flows(one)
    assert "one-frame clip" in ev.evaluate_video(a[:1], ev.Context.of(a[:1]))["warp_ssim"].status
