"""Image/video quality metrics on DISPLAY values in [0, 1] (after io.linear_to_display).

Videos are arrays shaped (N, H, W, 3). Per-video scores are means of per-frame scores.

* ``psnr_db``: 10 log10(1 / MSE), data range 1; identical frames give +inf (capped at 100 dB in
  ``video_psnr_db`` so means stay finite).
* ``ssim``: Wang et al. 2004, Gaussian window sigma = 1.5 px truncated to 11 taps, K1 = 0.01,
  K2 = 0.03, per channel then averaged; borders use 'reflect' padding.
* ``temporal_difference``: mean absolute difference between consecutive frames, per transition.
* LPIPS / CLIP need network weights: :func:`perceptual_metrics` computes them only when a local
  weights path is configured and the package is importable, else reports why it skipped.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

PSNR_CAP_DB = 100.0


def psnr_db(a: np.ndarray, b: np.ndarray) -> float:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.shape != b.shape:
        raise ValueError(f"psnr: shapes differ {a.shape} vs {b.shape}")
    mse = float(np.mean((a - b) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(1.0 / mse)


def display_psnr_db(linear: np.ndarray, linear_ref: np.ndarray, exposure_ev: float = 0.0) -> float:
    """PSNR (dB, peak 1) of two LINEAR images after the shared display transform (io.linear_to_display)."""
    from .io import linear_to_display

    return psnr_db(linear_to_display(linear, exposure_ev), linear_to_display(linear_ref, exposure_ev))


def video_psnr_db(a: np.ndarray, b: np.ndarray) -> float:
    """Mean over frames of per-frame PSNR (dB), each capped at PSNR_CAP_DB."""
    return float(np.mean([min(psnr_db(x, y), PSNR_CAP_DB) for x, y in zip(a, b)]))


def ssim(a: np.ndarray, b: np.ndarray) -> float:
    """SSIM of two (H, W, C) or (H, W) display images in [0, 1]."""
    from scipy.ndimage import gaussian_filter

    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.shape != b.shape:
        raise ValueError(f"ssim: shapes differ {a.shape} vs {b.shape}")
    if a.ndim == 2:
        a, b = a[..., None], b[..., None]
    c1, c2 = 0.01**2, 0.03**2

    def blur(x):
        return gaussian_filter(x, sigma=1.5, truncate=3.5, mode="reflect")

    vals = []
    for c in range(a.shape[-1]):
        x, y = a[..., c], b[..., c]
        mx, my = blur(x), blur(y)
        sxx, syy, sxy = blur(x * x) - mx * mx, blur(y * y) - my * my, blur(x * y) - mx * my
        s = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
        vals.append(s.mean())
    return float(np.mean(vals))


def video_ssim(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.mean([ssim(x, y) for x, y in zip(a, b)]))


def temporal_difference(video: np.ndarray) -> np.ndarray:
    """(N-1,) mean |frame[i+1] - frame[i]| for a (N, H, W, C) video."""
    v = np.asarray(video, np.float64)
    return np.abs(np.diff(v, axis=0)).reshape(len(v) - 1, -1).mean(axis=1)


def perceptual_metrics(a: np.ndarray, b: np.ndarray, lpips_weights: str | None = None,
                       clip_weights: str | None = None) -> tuple[dict, list[str]]:
    """LPIPS / CLIP scores if local weights are configured; returns (scores, skip messages)."""
    scores, skipped = {}, []
    for name, path in (("lpips", lpips_weights), ("clip_frame_consistency", clip_weights)):
        if not path or not Path(path).exists():
            skipped.append(f"{name}: skipped, no local weights configured (got {path!r}); nothing is downloaded")
            continue
        skipped.append(f"{name}: skipped, weights at {path} but no loader is implemented yet")
    return scores, skipped
