"""Overlap-fused temporal tiling (paper appendix, "Long-video overlap fusion").

Windows W_j = [s_j, s_j + T') with s_j = j * (T' - kappa'); the last window is shifted left so it
ends exactly at N' (it may then overlap its neighbour by more than kappa'); a latent shorter than
T' is one window covering it. Per-window predictions are fused in prediction space with temporal
tent weights that are strictly positive at the window edges:

    eps = sum_j C_j^T(w_j * eps_j) / (sum_j C_j^T(w_j) + delta)

and the caller applies ONE scheduler step to the full latent. Memory: only the full-length latent,
the fused accumulator and one window's activations are alive at a time (windows run sequentially).
"""

from __future__ import annotations

from typing import Callable

import torch

FUSION_DELTA = 1e-8


def plan_windows(num_latent: int, window: int, overlap: int) -> list[tuple[int, int]]:
    """[(start, end)] latent-frame windows covering [0, num_latent); see module docstring."""
    if num_latent < 1:
        raise ValueError(f"num_latent={num_latent} must be >= 1")
    if window < 1 or not 0 <= overlap < window:
        raise ValueError(f"window={window}, overlap={overlap}: need window >= 1 and 0 <= overlap < window")
    if num_latent <= window:
        return [(0, num_latent)]
    stride = window - overlap
    starts = list(range(0, num_latent - window + 1, stride))
    if starts[-1] + window < num_latent:
        starts.append(num_latent - window)  # last window shifted to end at num_latent
    return [(s, s + window) for s in starts]


def tent_weights(length: int, min_weight: float = 0.1) -> torch.Tensor:
    """(length,) symmetric tent, 1 at the centre, ``min_weight`` (> 0) at both outermost frames."""
    if not min_weight > 0:
        raise ValueError("min_weight must be > 0")
    if length == 1:
        return torch.ones(1)
    pos = torch.arange(length, dtype=torch.float64)
    centre = (length - 1) / 2
    w = 1.0 - (1.0 - min_weight) * (pos - centre).abs() / centre
    return w.float()


def fusion_weight_sum(num_latent: int, windows, min_weight: float) -> torch.Tensor:
    """(num_latent,) sum_j C_j^T(w_j): the denominator of the fusion."""
    total = torch.zeros(num_latent)
    for s, e in windows:
        total[s:e] += tent_weights(e - s, min_weight)
    return total


def fused_prediction(
    predict: Callable[[int, int], torch.Tensor],
    latent_shape: tuple,
    windows: list[tuple[int, int]],
    min_weight: float = 0.1,
) -> torch.Tensor:
    """Fuse ``predict(start, end) -> (B, end-start, C, h, w)`` over windows along dim 1.

    With a single window covering everything the prediction is returned unchanged (bit-exact).
    """
    if len(windows) == 1 and windows[0] == (0, latent_shape[1]):
        return predict(0, latent_shape[1])
    num = None
    for s, e in windows:
        pred = predict(s, e).float()
        if num is None:
            num = torch.zeros(latent_shape, device=pred.device)
        w = tent_weights(e - s, min_weight).to(pred.device)
        num[:, s:e] += pred * w.view(1, -1, 1, 1, 1)
    den = fusion_weight_sum(latent_shape[1], windows, min_weight).to(num.device)
    return num / (den.view(1, -1, 1, 1, 1) + FUSION_DELTA)
