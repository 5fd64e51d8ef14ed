"""Scores of refined clips against their targets, and the statistics the refiner's claims rest on.

Clips are (3, N, H, W) tensors of display values in [-1, 1] (the refiner's layout); scores use the
shared metrics (:mod:`lightcrafter.metrics`) on display values in [0, 1]: PSNR (dB, mean of
per-frame PSNR) and SSIM (mean of per-frame SSIM).
"""

from __future__ import annotations

import numpy as np

from .data import to_display_frames


def clip_scores(video, target) -> dict:
    """{"psnr_db", "ssim"} of one clip against its target."""
    from lightcrafter.metrics import video_psnr_db, video_ssim

    a, b = to_display_frames(video), to_display_frames(target)
    return {"psnr_db": video_psnr_db(a, b), "ssim": video_ssim(a, b)}


def bootstrap_mean_ci(values, n_resamples: int = 10000, level: float = 0.95, seed: int = 0) -> dict:
    """Mean of ``values`` with a percentile bootstrap confidence interval (resampling the values).

    Returns {"mean", "lo", "hi", "n", "level", "n_resamples"}; lo = hi = mean for a single value.
    """
    v = np.asarray(list(values), np.float64)
    if v.size == 0:
        raise ValueError("bootstrap of no values")
    rng = np.random.default_rng(seed)
    means = v[rng.integers(0, v.size, size=(n_resamples, v.size))].mean(axis=1)
    a = (1 - level) / 2
    return {"mean": float(v.mean()), "lo": float(np.quantile(means, a)), "hi": float(np.quantile(means, 1 - a)),
            "n": int(v.size), "level": level, "n_resamples": n_resamples}
