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
* LPIPS / T-CLIP need network weights: :func:`perceptual_metrics` computes them only from local
  weights folders, else reports why it skipped.
"""

from __future__ import annotations

from .evaluation import (  # noqa: F401  (re-exported names)
    PSNR_CAP_DB,
    display_psnr_db,
    lpips_video,
    psnr_db,
    ssim,
    t_clip,
    temporal_difference,
    video_psnr_db,
    video_ssim,
)


def perceptual_metrics(a, b, lpips_weights: str | None = None,
                       clip_weights: str | None = None) -> tuple[dict, list[str]]:
    """LPIPS(a, b) and T-CLIP(a) from local weights; returns (scores, skip messages).

    ``a`` is the method's display video, ``b`` the target's. A metric that cannot be computed gets
    no entry in ``scores`` and a line "<name>: skipped, not computed: <reason>" in the messages.
    """
    scores, skipped = {}, []
    for res in (lpips_video(a, b, lpips_weights), t_clip(a, clip_weights)):
        if res.computed:
            scores[res.name] = res.value
        else:
            skipped.append(f"{res.name}: skipped, {res.status}")
    return scores, skipped
