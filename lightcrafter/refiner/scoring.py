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
