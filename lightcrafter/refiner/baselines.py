"""Baselines evaluated beside the refiner, so a user sees what the diffusion buys.

* **Affine colour** (:func:`fit_affine_colour`): per channel c, target_c ~ gain_c * proxy_c + offset_c,
  least squares over every pixel of the fit pairs, on display values in [-1, 1]; applied to a proxy
  and clipped to [-1, 1]. Fitted on training pairs only, never on the clip it is applied to.
* **One-step regressor** (:func:`regress_video`): the refiner's own network and latent space trained
  as a deterministic proxy -> target map (``training.train(objective="regression")``: proxy latent in
  both inputs at a fixed timestep, L2 between its x0 estimate and the target latent), as in
  Difix3D+'s single-step fine-tuning.
"""

from __future__ import annotations

import torch


def fit_affine_colour(dataset) -> dict:
    """{"gain": [3], "offset": [3]} fitted over all pairs of ``dataset`` (items with proxy, target)."""
    n = torch.zeros(3, dtype=torch.float64)
    sx, sy, sxx, sxy = (torch.zeros(3, dtype=torch.float64) for _ in range(4))
    for i in range(len(dataset)):
        item = dataset[i]
        x = item["proxy"].double().reshape(3, -1)
        y = item["target"].double().reshape(3, -1)
        n += x.shape[1]
        sx += x.sum(1)
        sy += y.sum(1)
        sxx += (x * x).sum(1)
        sxy += (x * y).sum(1)
    if float(n[0]) == 0:
        raise ValueError("fit_affine_colour: no pairs")
    var = sxx / n - (sx / n) ** 2
    cov = sxy / n - (sx / n) * (sy / n)
    gain = torch.where(var > 1e-12, cov / var.clamp_min(1e-12), torch.ones_like(var))
    offset = sy / n - gain * sx / n
    return {"gain": [float(g) for g in gain], "offset": [float(o) for o in offset]}


def apply_affine_colour(params: dict, video: torch.Tensor) -> torch.Tensor:
    """(..., 3, N, H, W) proxy in [-1, 1] -> colour-corrected video in [-1, 1]."""
    g = torch.tensor(params["gain"], dtype=video.dtype).view(3, 1, 1, 1)
    o = torch.tensor(params["offset"], dtype=video.dtype).view(3, 1, 1, 1)
    return (video * g + o).clamp(-1, 1)


@torch.no_grad()
def regress_video(model, proxy_video: torch.Tensor, pad_mode: str = "error") -> torch.Tensor:
    """(B, 3, N, H, W) proxy in [-1, 1] -> the regressor's output in [-1, 1] (one network evaluation)."""
    from .frames import pad_to_4k1
    from .training import regression_x0

    video, n = pad_to_4k1(proxy_video, pad_mode)
    x0 = regression_x0(model, model.ae.encode(video.to(model.device)))
    return model.ae.decode(x0)[:, :, :n].clamp(-1, 1).cpu()


def load_regressor(model_path):
    """The regressor stored in a refiner's ``model.pt`` (baselines.regressor), or None."""
    from .model import Refiner

    st = torch.load(model_path, map_location="cpu", weights_only=False)
    reg = (st.get("baselines") or {}).get("regressor")
    if not reg:
        return None
    model = Refiner(st["config"])
    model.load_weights(reg)
    model.ae.load_state_dict(reg["ae"])
    return model.to_configured_device().eval()


def load_affine_colour(model_path) -> dict | None:
    st = torch.load(model_path, map_location="cpu", weights_only=False)
    return (st.get("baselines") or {}).get("affine_colour")
