"""PBR-conditioned video refiner (paper: "PBR-Conditioned Diffusion Refinement").

Public API:
  resolve_config(overrides) -> cfg dict         (config.py; keys documented in KEY_DOCS)
  Refiner(cfg)                                  (model.py: transformer over [noisy || proxy] latents)
  DCTPatchAutoencoder, CogVideoXVAE             (autoencoder.py)
  build_scheduler(cfg, sampler)                 (schedule.py: CogVideoX v-pred / zero-SNR / trailing)
  train(cfg, dataset, out_dir), load_model(path)  (training.py)
  sample_latent(...), refine_video(model, proxy, cfg)  (sampler.py: CFG + overlap-fused tiling)
  plan_windows, tent_weights, fused_prediction  (tiling.py)
  PairsDataset, read_pairs                      (data.py)
"""

import importlib

# Names are imported on first use (PEP 562), so that reading the config (e.g. when the workflow
# validates it at start-up) does not import torch and diffusers.
_WHERE = {
    "CogVideoXVAE": "autoencoder", "DCTPatchAutoencoder": "autoencoder",
    "KEY_DOCS": "config", "resolve_config": "config",
    "PairsDataset": "data", "read_pairs": "data",
    "FrameCountError": "frames", "check_frames": "frames", "latent_frames": "frames", "pad_to_4k1": "frames",
    "MissingWeightsError": "model", "Refiner": "model",
    "refine_video": "sampler", "sample_latent": "sampler",
    "build_scheduler": "schedule",
    "fused_prediction": "tiling", "plan_windows": "tiling", "tent_weights": "tiling",
    "load_model": "training", "train": "training",
}


def __getattr__(name):
    if name in _WHERE:
        return getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "CogVideoXVAE", "DCTPatchAutoencoder", "KEY_DOCS", "resolve_config", "PairsDataset", "read_pairs",
    "FrameCountError", "check_frames", "latent_frames", "pad_to_4k1", "MissingWeightsError", "Refiner",
    "refine_video", "sample_latent", "build_scheduler", "fused_prediction", "plan_windows", "tent_weights",
    "load_model", "train",
]
