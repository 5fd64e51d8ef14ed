"""Long-form relighting check: a long clip refined with overlap-fused temporal tiling (the paper) vs
independent chunks, compared frame by frame.

Measures, on display values in [0, 1]:

* per-transition temporal difference: mean |frame[i+1] - frame[i]| of the refined video, split into
  transitions that cross a chunk boundary of the independent-chunk run and interior ones;
  ``boundary_over_interior`` > 1 means jumps at the seams (1 is seamless);
* per-transition Warp-SSIM (lightcrafter.evaluation, flow computed on the target video);
* PSNR against the target (frame-wise mean).

Chunk boundaries: latent window j of ``window`` latent frames covers latent frames [j*window,
(j+1)*window); latent frame 0 is pixel frame 0 and latent frame k >= 1 holds pixel frames 4k-3..4k, so
the seam after latent frame e-1 is the transition from pixel frame 4(e-1) to 4(e-1)+1.
"""

from __future__ import annotations

import numpy as np


def chunk_boundaries(num_pixel_frames: int, window: int) -> list[int]:
    """Transition indices i (frame i -> i+1) that cross an independent-chunk seam."""
    num_latent = (num_pixel_frames - 1) // 4 + 1
    return [4 * (e - 1) for e in range(window, num_latent, window) if 4 * (e - 1) + 1 < num_pixel_frames]


def temporal_difference(video: np.ndarray) -> np.ndarray:
    v = np.asarray(video, np.float64)
    return np.abs(np.diff(v, axis=0)).reshape(len(v) - 1, -1).mean(axis=1)


def analyse(videos: dict[str, np.ndarray], target: np.ndarray, window: int) -> dict:
    """Per-mode curves and summary for display videos (N, H, W, 3) keyed by mode (e.g. fused, chunks, proxy)."""
    from lightcrafter.evaluation import compute_flows, framewise_psnr, warp_ssim

    n = len(target)
    seams = chunk_boundaries(n, window)
    interior = [i for i in range(n - 1) if i not in seams]
    flows = compute_flows(target)
    curves, summary = {}, {}
    for mode, v in videos.items():
        td = temporal_difference(v)
        ws = warp_ssim(v, flows=flows)
        curves[mode] = {"temporal_difference": td.tolist(), "warp_ssim": list(ws.per_item or [])}
        b = float(np.mean(td[seams])) if seams else float("nan")
        it = float(np.mean(td[interior])) if interior else float("nan")
        summary[mode] = {"warp_ssim": ws.value, "temporal_diff_boundary": b, "temporal_diff_interior": it,
                         "boundary_over_interior": b / it if it and np.isfinite(b) else float("nan"),
                         "psnr_db": framewise_psnr(v, target).value}
    summary["target"] = {"temporal_diff_boundary": float(np.mean(temporal_difference(target)[seams])) if seams else None,
                         "temporal_diff_interior": float(np.mean(temporal_difference(target)[interior]))}
    return {"frames": n, "window_latent": window, "seams": seams, "summary": summary, "curves": curves}


def plot(result: dict, png) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lightcrafter.io import atomic_path

    fig, axes = plt.subplots(2, 1, figsize=(8, 5), dpi=110, sharex=True)
    for mode, c in result["curves"].items():
        axes[0].plot(c["temporal_difference"], label=mode, lw=1)
        axes[1].plot(c["warp_ssim"], label=mode, lw=1)
    for ax in axes:
        for s in result["seams"]:
            ax.axvline(s, color="grey", lw=0.5, ls=":")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("temporal difference")
    axes[1].set_ylabel("Warp-SSIM")
    axes[1].set_xlabel("transition i -> i+1 (dotted: independent-chunk seams)")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    with atomic_path(png) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
