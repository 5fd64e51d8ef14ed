"""Overlap-fused temporal tiling: coverage, weights, exactness for one window, one global step."""

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

import lightcrafter.refiner.sampler as sampler_mod
from lightcrafter.refiner import Refiner, build_scheduler, plan_windows, resolve_config, sample_latent, tent_weights
from lightcrafter.refiner.sampler import guided_prediction
from lightcrafter.refiner.tiling import fused_prediction, fusion_weight_sum

torch.set_num_threads(1)


@given(n=st.integers(1, 120), window=st.integers(1, 16), data=st.data())
@settings(max_examples=300, deadline=None)
def test_window_coverage(n, window, data):
    overlap = data.draw(st.integers(0, window - 1))
    wins = plan_windows(n, window, overlap)
    covered = torch.zeros(n, dtype=torch.bool)
    for s, e in wins:
        assert 0 <= s < e <= n
        assert e - s == min(window, n)  # every window has the trained length (or the whole video)
        covered[s:e] = True
    assert covered.all()
    assert wins[0][0] == 0 and wins[-1][1] == n  # last window shifted to cover the end
    for (s0, e0), (s1, e1) in zip(wins, wins[1:]):
        assert s1 > s0 and e0 - s1 >= overlap  # neighbours share at least `overlap` frames


def test_paper_windows():
    assert plan_windows(13, 13, 3) == [(0, 13)]  # 49 frames: one window
    assert plan_windows(25, 13, 3) == [(0, 13), (10, 23), (12, 25)]  # 97 frames
    assert plan_windows(5, 13, 3) == [(0, 5)]  # shorter than a window


@pytest.mark.parametrize("length", [1, 2, 3, 13])
def test_tent_weights_positive_and_symmetric(length):
    w = tent_weights(length, 0.1)
    assert (w > 0).all() and torch.allclose(w, w.flip(0))
    assert float(w.max()) <= 1.0 and float(w[length // 2]) == float(w.max())  # peak in the middle
    if length % 2:
        assert float(w.max()) == pytest.approx(1.0)
    if length > 1:
        assert float(w[0]) == pytest.approx(0.1)  # edges stay above zero


def test_fusion_is_partition_of_unity():
    n = 26
    wins = plan_windows(n, 13, 3)
    assert (fusion_weight_sum(n, wins, 0.1) > 0).all()
    const = torch.full((1, n, 2, 2, 2), 3.25)
    fused = fused_prediction(lambda s, e: const[:, s:e], tuple(const.shape), wins, 0.1)
    assert torch.allclose(fused, const, atol=1e-6)


class LocalModel(torch.nn.Module):
    """Frame-local fake denoiser: no temporal mixing, so tiling must not change its result."""

    latent_channels = 4

    def forward(self, z, zp, t):
        return 0.5 * torch.tanh(z) + 0.3 * zp + 1e-4 * t.view(-1, 1, 1, 1, 1).float()


def _untiled(model, zp, cfg, noise, steps, gs):
    sched = build_scheduler(cfg)
    sched.set_timesteps(steps)
    z = noise.clone() * sched.init_noise_sigma
    for t in sched.timesteps:
        z = sched.step(guided_prediction(model, z, zp, t, gs), t, z, return_dict=False)[0]
    return z


@pytest.fixture(scope="module")
def tiny():
    torch.manual_seed(0)
    # the paper's sampling (pure-noise start) with an un-anchored random network, so tiling matters
    cfg = resolve_config({"model": {"ae_coeffs": [8, 4, 4], "proxy_anchor": "none"}, "infer": {"strength": 1.0}})
    return cfg, Refiner(cfg).eval()


@pytest.mark.parametrize("frames,window", [(3, 3), (2, 3)])  # exactly one window / shorter than one
def test_one_window_is_exactly_untiled(tiny, frames, window):
    cfg, model = tiny
    g = torch.Generator().manual_seed(1)
    zp = torch.randn(1, frames, model.latent_channels, 4, 6, generator=g)
    noise = torch.randn(zp.shape, generator=g)
    tiled = sample_latent(model, zp, cfg, num_steps=4, guidance_scale=6.0, window=window, overlap=1,
                          init_noise=noise)
    assert torch.equal(tiled, _untiled(model, zp, cfg, noise, 4, 6.0))


def test_tiling_frame_local_model_matches_untiled():
    cfg = resolve_config({"infer": {"strength": 1.0}})
    model = LocalModel()
    g = torch.Generator().manual_seed(2)
    zp = torch.randn(1, 11, 4, 2, 2, generator=g)
    noise = torch.randn(zp.shape, generator=g)
    tiled = sample_latent(model, zp, cfg, num_steps=5, guidance_scale=2.0, window=3, overlap=1, init_noise=noise)
    assert torch.allclose(tiled, _untiled(model, zp, cfg, noise, 5, 2.0), atol=1e-5)


def test_one_global_scheduler_step_per_denoising_step(monkeypatch):
    calls = {"step": 0, "model": 0}
    real_build = sampler_mod.build_scheduler

    def counting_build(cfg, sampler=None):
        s = real_build(cfg, sampler)
        orig = s.step

        def step(*a, **k):
            calls["step"] += 1
            return orig(*a, **k)

        s.step = step
        return s

    class Counting(LocalModel):
        def forward(self, z, zp, t):
            calls["model"] += 1
            return super().forward(z, zp, t)

    monkeypatch.setattr(sampler_mod, "build_scheduler", counting_build)
    zp = torch.randn(1, 9, 4, 2, 2)
    sample_latent(Counting(), zp, resolve_config({"infer": {"strength": 1.0}}), num_steps=6, guidance_scale=6.0, window=3, overlap=1)
    n_windows = len(plan_windows(9, 3, 1))
    assert n_windows == 4
    assert calls["step"] == 6
    assert calls["model"] == 6 * n_windows * 2  # cond + uncond per window per step


def test_dpm_sampler_runs_tiled():
    cfg = resolve_config({"infer": {"sampler": "dpm"}})
    zp = torch.randn(1, 7, 4, 2, 2)
    out = sample_latent(LocalModel(), zp, cfg, num_steps=5, window=3, overlap=1,
                        generator=torch.Generator().manual_seed(0))
    assert out.shape == zp.shape and torch.isfinite(out).all()
