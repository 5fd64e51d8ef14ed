"""Scheduler parameterisation is CogVideoX-5B's (set explicitly), and t=999 trains finitely."""

import json

import torch

from lightcrafter.refiner import Refiner, build_scheduler, resolve_config
from lightcrafter.refiner.training import training_loss

torch.set_num_threads(1)


def test_scheduler_is_vpred_trailing_zero_snr():
    cfg = resolve_config({})
    for sampler in ("ddim", "dpm"):
        s = build_scheduler(cfg, sampler)
        assert s.config.prediction_type == "v_prediction"
        assert s.config.timestep_spacing == "trailing"
        assert s.config.rescale_betas_zero_snr
        assert s.config.beta_schedule == "scaled_linear"
        assert s.config.snr_shift_scale == 1.0
        assert float(s.alphas_cumprod[-1]) < 1e-6  # zero terminal SNR
        s.set_timesteps(50)
        assert int(s.timesteps[0]) == 999  # trailing spacing starts at the last training step


def test_class_defaults_differ_so_explicit_config_matters():
    from diffusers import CogVideoXDDIMScheduler

    assert CogVideoXDDIMScheduler().config.prediction_type != "v_prediction"


def test_local_model_scheduler_file_wins(tmp_path):
    (tmp_path / "scheduler").mkdir()
    (tmp_path / "scheduler" / "scheduler_config.json").write_text(json.dumps(
        {"_class_name": "CogVideoXDDIMScheduler", "prediction_type": "v_prediction", "snr_shift_scale": 2.5,
         "rescale_betas_zero_snr": True, "beta_schedule": "scaled_linear"}))
    cfg = resolve_config({"model": {"model_path": str(tmp_path)}})
    assert build_scheduler(cfg).config.snr_shift_scale == 2.5


def test_loss_finite_at_t999():
    torch.manual_seed(0)
    cfg = resolve_config({"model": {"ae_coeffs": [8, 4, 4]}})
    model = Refiner(cfg)
    s = build_scheduler(cfg, "ddim")
    x0 = torch.randn(1, 3, model.latent_channels, 4, 6)
    noise = torch.randn_like(x0)
    t = torch.tensor([999])
    v = s.get_velocity(x0, noise, t)
    assert torch.allclose(v, -x0, atol=1e-3)  # sqrt(ab)=0: v = -x0
    loss = training_loss(model, s, x0, torch.randn_like(x0), t, noise)
    assert torch.isfinite(loss)
    loss.backward()
    assert all(torch.isfinite(p.grad).all() for p in model.transformer.parameters() if p.grad is not None)
