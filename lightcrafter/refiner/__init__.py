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
  fit_refiner(cfg, pairs, out_dir)              (fit.py: carve validation, train, select, baselines -> model.pt)
  carve_validation                              (validation.py: whole train-split scenes held out)
  fit_affine_colour, regress_video              (baselines.py)
  clip_scores                                   (scoring.py)
  write_strip                                   (strip.py: input | proxy | refined | target PNGs)

Small scale. The paper fine-tunes a 5B model pretrained on video, so it can sample from pure noise.
The ``tiny`` preset trains a 2-layer transformer from scratch on a few clips and has no such prior;
sampling from pure noise drifts and the output loses the scene. What the tiny preset adds, each a
config key (the ``paper`` preset keeps the paper's values):

* ``infer.strength`` (SDEdit): start from the proxy latent noised to an intermediate timestep;
* ``model.proxy_anchor``: the network predicts a correction of the proxy, zero at initialisation,
  so an untrained model returns the proxy (model.py); the loss stays the v-MSE;
* ``train.timesteps: sampler_range``: train on the timesteps sampling visits;
* ``select.*``: checkpoint, strength, guidance, ``infer.residual_scale`` (the weight of the
  transformer's correction on the learned anchor; 0 = the anchor map alone) and
  ``infer.correction_blur_px`` / ``correction_blur_frames`` (a Gaussian on that correction in each frame
  and along the clip, which loses its token grid and its 4-frame steps) chosen on validation scenes
  carved out of the train split (never test), with limits on the block grid, the 4-frame jump and
  Warp-SSIM; ``baselines.*``: a one-step regressor with the same network, and an affine colour fit,
  trained on the same pairs and evaluated beside the refiner;
* ``infer.num_samples``: the refined video is the mean of several samples (a posterior-mean
  estimate, which PSNR rewards); ``model.ae_normalisation``, ``train.hflip``: latent scaling and
  augmentation of the tiny model.
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
    "fit_refiner": "fit", "carve_validation": "validation",
    "fit_affine_colour": "baselines", "regress_video": "baselines",
    "clip_scores": "scoring", "write_strip": "strip",
}


def __getattr__(name):
    if name in _WHERE:
        return getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "CogVideoXVAE", "DCTPatchAutoencoder", "KEY_DOCS", "resolve_config", "PairsDataset", "read_pairs",
    "FrameCountError", "check_frames", "latent_frames", "pad_to_4k1", "MissingWeightsError", "Refiner",
    "refine_video", "sample_latent", "build_scheduler", "fused_prediction", "plan_windows", "tent_weights",
    "load_model", "train", "fit_refiner", "carve_validation", "fit_affine_colour", "regress_video",
    "clip_scores", "write_strip",
]
