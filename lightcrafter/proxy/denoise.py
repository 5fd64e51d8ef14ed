"""Intel Open Image Denoise (OIDN) on R's linear HDR frames, through ``pyoidn``.

R's output at ``proxy.spp`` carries Monte Carlo noise (benchmarks/phi_budget.py measures it against 16x
the samples). OIDN's ``RT`` filter takes the noisy linear radiance (H, W, 3, >= 0) and, optionally, the
frame's albedo (linear, [0, 1]) and normals ([-1, 1], any fixed frame) as noise-free auxiliary images
(they come from buffers, not from sampling: ``clean_aux``).
"""

from __future__ import annotations

import numpy as np

from lightcrafter import io


def _import_pyoidn():
    """pyoidn, imported without torch unless this process has already loaded it. pyoidn's own import loads torch
    when it is installed (2 s of each proxy job), which it only needs for tensor inputs; R's frames are NumPy
    arrays. ``sys.modules["torch"] = None`` makes ``import torch`` raise ImportError while pyoidn imports."""
    import sys

    if "pyoidn" in sys.modules or "torch" in sys.modules:
        import pyoidn

        return pyoidn
    sys.modules["torch"] = None
    try:
        import pyoidn
    finally:
        del sys.modules["torch"]
    return pyoidn


def available() -> str | None:
    """None when OIDN can run here, else the reason (one line naming the fix)."""
    try:
        _import_pyoidn()
    except ImportError as exc:
        return f"pyoidn does not import ({exc}); pip install pyoidn"
    return None


def denoise_hdr(color: np.ndarray, albedo: np.ndarray | None = None, normal: np.ndarray | None = None) -> np.ndarray:
    """Denoised linear HDR frame (H, W, 3) float32; non-finite or negative input is rejected."""
    why = available()
    if why:
        raise io.DataError(f"proxy denoiser: {why}")
    pyoidn = _import_pyoidn()

    c = np.ascontiguousarray(color, np.float32)
    if not np.isfinite(c).all() or (c < 0).any():
        raise io.DataError("proxy denoiser: frame has NaN, Inf or negative radiance; fix the render first")
    aux = {}
    if albedo is not None and normal is not None:
        aux = {"albedo": np.ascontiguousarray(np.clip(albedo, 0, 1), np.float32),
               "normal": np.ascontiguousarray(np.clip(normal, -1, 1), np.float32), "clean_aux": True}
    out = pyoidn.denoise(c, hdr=True, **aux)
    return np.maximum(np.nan_to_num(out, nan=0.0, posinf=0.0), 0.0).astype(np.float32)
