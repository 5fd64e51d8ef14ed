"""The camera's response: a global tone curve between R's linear radiance and a real video's frames.

A real video is not linear scene radiance: its camera applied a tone curve (often steeper than
sRGB's in the mid-tones) and a white balance before encoding, and ingest can only undo the sRGB
curve (:func:`lightcrafter.io.display_to_linear`). The map fit (:mod:`.fit`) models the light;
this models the camera, applied to R's output before it is compared with the video::

    out_c = gain_c * max(x_c, 0) ** gamma        x, out: linear RGB (display = sRGB(out), io.linear_to_display)

One ``gamma`` (unitless, > 0) and three channel gains. Fitted after the map (``envfit.fit_response``),
by least squares on display values (the space the pseudo-input is scored in,
:func:`lightcrafter.metrics.display_psnr_db`) over the used pixels of the fitted frames; frames the
fit did not use are not looked at. gamma is bounded to [GAMMA_MIN, GAMMA_MAX]. The map, fitted first
with no curve, takes part of a camera's curve (tests: a video through gamma 1.8 gives 1.17), so gamma is
what the map could not explain, not the camera's own curve; it also takes any global contrast error of
Phi's buffers (on the default's 9 train Cycles clips, which have no camera curve, 0.98-1.44, median
1.13: benchmarks/envfit_response.py, docs/phi.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GAMMA_MIN, GAMMA_MAX = 0.5, 3.0


@dataclass(frozen=True)
class CameraResponse:
    """out = gain_rgb * max(x, 0) ** gamma, per channel, linear RGB in and out (module doc)."""

    gamma: float = 1.0
    gain_rgb: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def apply(self, rgb_linear: np.ndarray) -> np.ndarray:
        """The response of (..., 3) linear RGB, float32; non-finite input stays non-finite."""
        x = np.maximum(np.asarray(rgb_linear, np.float32), 0.0)
        return (np.asarray(self.gain_rgb, np.float32) * x ** np.float32(self.gamma)).astype(np.float32)

    def as_dict(self) -> dict:
        return {"gamma": round(float(self.gamma), 6), "gain_rgb": [round(float(g), 6) for g in self.gain_rgb],
                "model": "out = gain_rgb * max(x, 0) ** gamma on linear RGB"}

    @property
    def is_identity(self) -> bool:
        return self.gamma == 1.0 and tuple(self.gain_rgb) == (1.0, 1.0, 1.0)


def fit_response(rendered: list[np.ndarray], observed: list[np.ndarray], max_pixels: int = 60000,
                 seed: int = 0) -> tuple[CameraResponse, dict]:
    """Least-squares response (module doc) taking ``rendered`` (P_i, 3) linear radiance to ``observed``
    (P_i, 3) linear frames, both the used pixels of the fitted frames. Returns (response, stats):
    stats has the display RMSE before and after and the pixels used. With no pixel where the render
    and the video are both above black, the response is the identity and stats say why."""
    from scipy.optimize import least_squares

    from lightcrafter.io import linear_to_display

    def stack(arrays):
        if not arrays:
            return np.zeros((0, 3))
        return np.concatenate([np.asarray(x, np.float64).reshape(-1, 3) for x in arrays])

    pred, obs = stack(rendered), stack(observed)
    if pred.shape != obs.shape:
        raise ValueError(f"fit_response: {pred.shape} rendered values for {obs.shape} observed")
    keep = np.isfinite(pred).all(axis=1) & np.isfinite(obs).all(axis=1) & (pred.max(axis=1) > 0)
    pred, obs = np.maximum(pred[keep], 0.0), obs[keep]
    if len(pred) == 0 or not (obs > 0).any():
        return CameraResponse(), {"pixels": int(len(pred)), "note": "no lit pixel: identity response"}
    if len(pred) > max_pixels:
        sel = np.sort(np.random.default_rng([int(seed), 0xC0FE]).choice(len(pred), size=max_pixels, replace=False))
        pred, obs = pred[sel], obs[sel]
    target = linear_to_display(obs).astype(np.float64)
    log_pred = np.log(np.maximum(pred, 1e-12))

    def residual(theta):
        out = np.exp(theta[:3] + np.exp(theta[3]) * log_pred)
        return (linear_to_display(out).astype(np.float64) - target).ravel()

    lo, hi = np.log(GAMMA_MIN), np.log(GAMMA_MAX)
    sol = least_squares(residual, np.zeros(4), bounds=([-10, -10, -10, lo], [10, 10, 10, hi]), method="trf",
                        diff_step=1e-4, max_nfev=200)
    response = CameraResponse(gamma=float(np.exp(sol.x[3])), gain_rgb=tuple(float(g) for g in np.exp(sol.x[:3])))
    before = float(np.sqrt(np.mean(residual(np.zeros(4)) ** 2)))
    after = float(np.sqrt(np.mean(sol.fun ** 2)))
    if not after < before:  # the identity is as good: keep it
        response = CameraResponse()
        after = before
    return response, {"pixels": int(len(pred)), "display_rmse_before": round(before, 6),
                      "display_rmse_after": round(after, 6)}
