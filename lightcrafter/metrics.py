"""Image/video quality metrics on DISPLAY values in [0, 1] (after io.linear_to_display).

Kept for the code that imports these names; the implementations and their documentation live in
:mod:`lightcrafter.evaluation` (PSNR and SSIM via scikit-image, Warp-SSIM, T-CLIP, LPIPS,
aggregation and bootstrap intervals). Videos are arrays shaped (N, H, W, 3); per-video scores are
means of per-frame scores.

* ``psnr_db``: 10 log10(1 / MSE), data range 1; identical frames give +inf (capped at 100 dB in
  ``video_psnr_db`` so means stay finite).
* ``ssim``: Wang et al. 2004 via ``skimage.metrics.structural_similarity`` (Gaussian window
  sigma = 1.5 px, 11 taps, K1 = 0.01, K2 = 0.03, population covariance), per channel then averaged,
  the 5-px border excluded from the mean.
* ``temporal_difference``: mean absolute difference between consecutive frames, per transition.
* LPIPS / T-CLIP need network weights from local folders (lightcrafter.evaluation's registry reports
  them "not computed: <reason>" otherwise).
"""

from __future__ import annotations

from .evaluation import (  # noqa: F401  (re-exported names)
    PSNR_CAP_DB,
    display_psnr_db,
    psnr_db,
    ssim,
    temporal_difference,
    video_psnr_db,
    video_ssim,
)

