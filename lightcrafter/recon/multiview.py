"""Depth from several views where the camera moves: a plane sweep around the estimator's depth.

For each registered frame of a moving camera, every pixel's depth is tried at ``hypotheses`` values d * exp(delta),
delta evenly spaced over [-range_log, +range_log] (log depth: a relative range around the prior d, which is z-depth
in the cameras' units, OpenCV axes). The frame's grey image (display values) is compared with each of its ``views``
nearest registered frames warped through that depth, by normalised cross-correlation (NCC) over a square window of
``window_px`` pixels; the light is fixed within a clip, so brightness constancy holds up to view-dependent
highlights. A pixel's cost is the mean of its better half of the views that see it at every hypothesis (a point
hidden in one view is not judged by it); the best hypothesis is refined between its neighbours by a parabola, and
replaces the prior only where the match is confident: the window is textured (standard deviation >=
``min_texture``), the best cost beats the mean over hypotheses by ``min_margin``, and the best is not at either end
of the range. Elsewhere the prior stays, as it does on a frame with no registered neighbour.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PlaneSweepSettings:
    range_log: float = 0.3      # hypotheses span d * exp([-range_log, +range_log])
    hypotheses: int = 25
    views: int = 4              # nearest registered frames compared with each frame
    window_px: int = 7          # NCC window side (odd)
    min_texture: float = 0.02   # standard deviation of the window's grey display values
    min_margin: float = 0.1     # mean cost over hypotheses minus the best cost (cost = 1 - NCC, in [0, 2])

    def __post_init__(self):
        if not self.range_log > 0 or self.hypotheses < 3 or self.views < 1 or self.window_px < 3 \
                or self.window_px % 2 == 0:
            raise ValueError(f"plane sweep settings {self}: need range_log > 0, hypotheses >= 3, views >= 1 and an "
                             "odd window_px >= 3")


def grey(display_rgb: np.ndarray) -> np.ndarray:
    """Rec. 709 luma of display RGB (..., 3) in [0, 1]."""
    return np.asarray(display_rgb, np.float32) @ np.array([0.2126, 0.7152, 0.0722], np.float32)


def neighbour_frames(registered: np.ndarray, i: int, views: int) -> list[int]:
    """The ``views`` registered frames nearest to frame i (ties: the earlier first), i itself excluded."""
    reg = [j for j in np.flatnonzero(np.asarray(registered, bool)) if j != i]
    return sorted(reg, key=lambda j: (abs(j - i), j))[:views]


def _box(x, window_px: int):
    """Mean over a square window of ``window_px`` (odd) around each pixel of a torch tensor (B, 1, H, W); at the
    borders over the part of the window inside the frame."""
    import torch.nn.functional as F

    return F.avg_pool2d(x, window_px, stride=1, padding=window_px // 2, count_include_pad=False)


def _ncc_cost(ref, warped, valid, window_px: int):
    """1 - NCC per pixel over a window (torch tensors (B, 1, H, W)); NaN where the warp left the frame."""
    def box(x):
        return _box(x, window_px)

    mr, mw = box(ref), box(warped)
    var_r = (box(ref * ref) - mr * mr).clamp_min(0)
    var_w = (box(warped * warped) - mw * mw).clamp_min(0)
    cov = box(ref * warped) - mr * mw
    ncc = cov / (var_r * var_w + 1e-8).sqrt()
    cost = 1.0 - ncc.clamp(-1.0, 1.0)
    full = box(valid.float()) > 0.999  # the whole window inside the other frame
    return cost.masked_fill(~full, float("nan"))


def refine_depth(display_rgb: np.ndarray, depth: np.ndarray, K: np.ndarray, c2w: np.ndarray, registered: np.ndarray,
                 settings: PlaneSweepSettings = PlaneSweepSettings()) -> tuple[np.ndarray, dict]:
    """(depth (N, H, W) refined where the views agree, info): display_rgb (N, H, W, 3) in [0, 1]; depth (N, H, W)
    z-depth in the cameras' units (non-finite or <= 0: no depth, kept); K (N, 3, 3) px; c2w (N, 4, 4) OpenCV axes;
    registered (N,) bool (an unregistered frame is neither refined nor used as a view). info: the fraction of valid
    pixels changed and the median |log| change over them."""
    import torch
    import torch.nn.functional as F

    s = settings
    depth = np.asarray(depth, np.float64)
    n, h, w = depth.shape
    g = torch.from_numpy(grey(display_rgb)).float()[:, None]            # (N, 1, H, W)
    deltas = torch.linspace(-s.range_log, s.range_log, s.hypotheses, dtype=torch.float64)
    v, u = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij")
    pix = torch.stack([u, v, torch.ones_like(u)], -1)                   # pixel centres at integers
    out = depth.copy()
    changed, moved, valid_total = 0, [], 0
    for i in np.flatnonzero(np.asarray(registered, bool)):
        views = neighbour_frames(registered, i, s.views)
        d0 = torch.from_numpy(depth[i])
        ok = torch.isfinite(d0) & (d0 > 0)
        valid_total += int(ok.sum())
        if not views or not ok.any():
            continue
        rays = pix @ torch.linalg.inv(torch.from_numpy(np.asarray(K[i], np.float64))).T   # z = 1
        d = torch.where(ok, d0, torch.ones_like(d0))[None] * torch.exp(deltas)[:, None, None]  # (D, H, W)
        pts = rays[None] * d[..., None]                                  # ref camera frame
        costs = []
        ref = g[i:i + 1].expand(s.hypotheses, 1, h, w)
        for j in views:
            rel = torch.linalg.inv(torch.from_numpy(np.asarray(c2w[j], np.float64))) @ \
                torch.from_numpy(np.asarray(c2w[i], np.float64))         # ref camera -> camera j
            pj = pts @ rel[:3, :3].T + rel[:3, 3]
            uvw = pj @ torch.from_numpy(np.asarray(K[j], np.float64)).T
            z = uvw[..., 2]
            uj, vj = uvw[..., 0] / z, uvw[..., 1] / z
            inside = (z > 0) & (uj >= 0) & (uj <= w - 1) & (vj >= 0) & (vj <= h - 1)
            grid = torch.stack([uj / (w - 1) * 2 - 1, vj / (h - 1) * 2 - 1], -1).float()
            grid = torch.where(inside[..., None], grid, torch.full_like(grid, -2.0))
            warped = F.grid_sample(g[j:j + 1].expand(s.hypotheses, 1, h, w), grid, mode="bilinear",
                                   padding_mode="zeros", align_corners=True)
            costs.append(_ncc_cost(ref, warped, inside[:, None], s.window_px)[:, 0])
        c = torch.stack(costs)                                           # (V, D, H, W), NaN: not seen
        cover = torch.isfinite(c).all(1)                                 # (V, H, W): a view that sees every hypothesis
        k = cover.sum(0)
        half = ((k + 1) // 2).clamp_min(1)
        c = torch.where(cover[:, None], c, torch.full_like(c, float("inf"))).sort(dim=0).values
        take = torch.arange(len(views))[:, None, None] < half            # each hypothesis' better half of the views
        c = torch.where(take[:, None] & torch.isfinite(c), c, torch.zeros_like(c)).sum(0) / half
        best = c.argmin(0)                                               # (H, W)
        c_best = c.gather(0, best[None])[0]
        inner = (best > 0) & (best < s.hypotheses - 1)
        lo = c.gather(0, (best - 1).clamp_min(0)[None])[0]
        hi = c.gather(0, (best + 1).clamp_max(s.hypotheses - 1)[None])[0]
        curv = lo - 2 * c_best + hi
        off = torch.where(inner & (curv > 1e-9), 0.5 * (lo - hi) / curv.clamp_min(1e-9), torch.zeros_like(c_best))
        step = float(deltas[1] - deltas[0])
        delta = deltas[best].float() + off.clamp(-0.5, 0.5) * step
        mr = _box(g[i:i + 1], s.window_px)
        sd = (_box(g[i:i + 1] ** 2, s.window_px) - mr ** 2).clamp_min(0).sqrt()
        sure = ok & inner & (k > 0) & (sd[0, 0] >= s.min_texture) & (c.mean(0) - c_best >= s.min_margin)
        out[i] = np.where(sure.numpy(), depth[i] * np.exp(delta.double().numpy()), depth[i])
        changed += int(sure.sum())
        moved.append(np.abs(delta[sure].numpy()))
    moved = np.concatenate(moved) if moved else np.zeros(0)
    return out, {"multiview_changed_fraction": round(changed / max(valid_total, 1), 4),
                 "multiview_median_abs_log_change": round(float(np.median(moved)), 4) if len(moved) else None}
