"""Tiny refiner: shapes, channel concat, fixed empty-prompt embedding, missing weights message."""

import pytest
import torch

from lightcrafter.refiner import MissingWeightsError, Refiner, resolve_config

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)  # un-anchored: the raw network's output (the anchor is tested in test_refiner_small_scale)
    return Refiner(resolve_config({"model": {"ae_coeffs": [8, 4, 4], "proxy_anchor": "none"}}))


def test_tiny_forward_shapes(model):
    c = model.latent_channels
    assert c == 16
    assert model.transformer.config.in_channels == 2 * c  # noisy || proxy, channel concat
    assert model.transformer.config.out_channels == c
    for frames in (1, 3, 5):
        z = torch.randn(2, frames, c, 4, 6)
        out = model(z, torch.randn_like(z), torch.tensor([0, 999]))
        assert out.shape == z.shape
        assert torch.isfinite(out).all()


def test_proxy_and_noisy_must_align_in_time(model):
    c = model.latent_channels
    with pytest.raises(ValueError, match="must match"):
        model(torch.randn(1, 3, c, 4, 6), torch.randn(1, 2, c, 4, 6), torch.tensor([10]))


def test_empty_prompt_embedding_is_fixed_and_padded(model):
    tc = model.transformer.config
    assert model.prompt_embeds.shape == (1, tc.max_text_seq_length, tc.text_embed_dim)
    other = Refiner(resolve_config({"model": {"ae_coeffs": [8, 4, 4], "proxy_anchor": "none"}}))
    assert torch.equal(other.prompt_embeds, model.prompt_embeds)


def test_output_depends_on_proxy(model):
    c = model.latent_channels
    z = torch.randn(1, 3, c, 4, 6)
    t = torch.tensor([500])
    assert not torch.allclose(model(z, torch.zeros_like(z), t), model(z, torch.randn_like(z), t))


def test_paper_without_weights_raises_clear_message(tmp_path):
    cfg = resolve_config({"preset": "paper", "model": {"model_path": str(tmp_path / "nope")}})
    with pytest.raises(MissingWeightsError, match="local CogVideoX-5B-I2V"):
        Refiner(cfg)


def test_unknown_config_key_rejected():
    with pytest.raises(KeyError):
        resolve_config({"trian": {}})
    with pytest.raises(ValueError):
        resolve_config({"infer": {"min_tent_weight": 0.0}})


def test_rotary_embedding_path_runs():
    """The paper model uses 3-D RoPE; exercise that path with tiny dims (head_dim divisible by 16)."""
    from lightcrafter.refiner.model import grid_crop_region

    cfg = resolve_config({"model": {"ae_coeffs": [8, 4, 4],
                                    "transformer": {"use_rotary_positional_embeddings": True}}})
    m = Refiner(cfg)
    z = torch.randn(1, 3, m.latent_channels, 4, 6)
    assert m(z, z, torch.tensor([3])).shape == z.shape
    assert grid_crop_region((2, 3), 6, 4) == ((0, 0), (4, 6))
    assert grid_crop_region((2, 2), 6, 4) == ((0, 1), (4, 5))


@pytest.mark.parametrize("anchor", ["none", "pixel"])
@pytest.mark.parametrize("kind", ["zeros", "ones", "flash"])
@pytest.mark.parametrize("guidance", [0.0, 20.0])
def test_refined_video_of_extreme_proxies_is_finite_and_in_range(kind, guidance, anchor):
    """All-black, all-white and one-frame-flash proxies, CFG off and at 20, fused windows overlapping by one
    latent frame, without an anchor and with the default's (x0 anchor through the pixel colour map and 3x3
    kernel): the refined video is finite, in [-1, 1], and keeps the proxy's frames. An untrained anchored
    refiner (zero-initialised correction, identity anchor) returns a constant proxy, at any guidance."""
    from lightcrafter.refiner import refine_video

    torch.manual_seed(0)
    model_cfg = {"ae_coeffs": [8, 4, 4], "proxy_anchor": "none"} if anchor == "none" else \
        {"ae_coeffs": [8, 4, 4], "anchor_space": "pixel", "anchor_kernel_px": 1}
    cfg = resolve_config({"model": model_cfg, "infer": {"num_steps": 3, "window": 2, "overlap": 1}})
    assert (cfg["model"]["proxy_anchor"] != "none") == (anchor == "pixel")
    model = Refiner(cfg).eval()
    proxy = torch.full((1, 3, 9, 16, 16), -1.0 if kind == "zeros" else 1.0)
    if kind == "flash":
        proxy = torch.full_like(proxy, -1.0)
        proxy[:, :, 4] = 1.0
    with torch.no_grad():
        out = refine_video(model, proxy, cfg, generator=torch.Generator().manual_seed(0), guidance_scale=guidance)
    assert out.shape == proxy.shape and torch.isfinite(out).all() and out.abs().max() <= 1.0
    if anchor == "pixel" and kind != "flash":
        assert (out - proxy).abs().max() < 1e-3


@pytest.mark.parametrize("dtype", ["float32", "bfloat16"])
@pytest.mark.parametrize("training", [False, True])
def test_network_is_finite_at_the_first_and_last_timesteps_in_both_precisions(dtype, training):
    """model.dtype bf16: parameters in bf16 for inference, fp32 masters under autocast for training."""
    torch.manual_seed(0)
    m = Refiner(resolve_config({"model": {"ae_coeffs": [8, 4, 4], "proxy_anchor": "none", "dtype": dtype}}),
                training=training)
    c = m.latent_channels
    z = torch.randn(1, 3, c, 4, 6) * 50  # far outside the unit-variance latents
    for t in (0, 999):
        with torch.no_grad():
            out = m(z, torch.zeros_like(z), torch.tensor([t]))
        assert out.dtype == torch.float32 and torch.isfinite(out).all()
