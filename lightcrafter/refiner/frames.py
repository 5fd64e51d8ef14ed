"""Frame-count rules of the CogVideoX latent space (4x temporal, causal first frame).

N pixel frames map to (N - 1) / 4 + 1 latent frames, so N must be 4k + 1. Other counts either raise
(``pad_frames='error'``) or are padded by repeating the last frame up to the next 4k + 1 and the
output is cropped back to N frames (``pad_frames='repeat_last'``).
"""

from __future__ import annotations

import torch


class FrameCountError(ValueError):
    """A video whose frame count is not 4k + 1."""


def latent_frames(num_pixel_frames: int) -> int:
    check_frames(num_pixel_frames)
    return (num_pixel_frames - 1) // 4 + 1


def check_frames(n: int) -> None:
    if n < 1 or (n - 1) % 4:
        lo = max(1, 4 * ((n - 1) // 4) + 1)
        raise FrameCountError(
            f"{n} frames: the CogVideoX latent needs 4k+1 frames (e.g. {lo} or {lo + 4}); "
            "trim the video or set refiner infer.pad_frames: repeat_last"
        )


def pad_to_4k1(video: torch.Tensor, mode: str = "error") -> tuple[torch.Tensor, int]:
    """Pad a (B, C, N, H, W) video along N to 4k+1 frames; return it and the original N."""
    n = video.shape[2]
    if n >= 1 and (n - 1) % 4 == 0:
        return video, n
    if mode != "repeat_last":
        check_frames(n)
    target = 4 * ((n - 1) // 4 + 1) + 1
    pad = video[:, :, -1:].expand(-1, -1, target - n, -1, -1)
    return torch.cat([video, pad], dim=2), n


def pad_to_latent_frames(video: torch.Tensor, min_latent: int | None) -> tuple[torch.Tensor, int]:
    """Repeat the last frame of a (B, C, N, H, W) 4k+1-frame video up to ``4 (min_latent - 1) + 1``
    frames (a transformer with learned positional embeddings sees whole windows only); return it and
    the original N. ``None`` or a long enough video: unchanged."""
    n = video.shape[2]
    need = 4 * (int(min_latent) - 1) + 1 if min_latent else 0
    if n >= need:
        return video, n
    return torch.cat([video, video[:, :, -1:].expand(-1, -1, need - n, -1, -1)], dim=2), n
