"""A small G-buffer estimator: display RGB frame -> depth, normals, albedo, roughness, metallic, mask.

The CPU default of the reconstruction stack's intrinsic-image part, in the spirit of DiffusionRenderer's
inverse renderer (learned from synthetic G-buffers), at laptop scale: a U-Net (torch) trained by a
workflow rule on the ground-truth buffers of the ``recon`` split only (never train or test scenes).

Inputs and outputs (per frame, H and W multiples of 8)
------------------------------------------------------
* input: display RGB in [0, 1] (lightcrafter.io.linear_to_display of the linear frame, i.e. what a
  camera records), plus two channels of normalised pixel coordinates (x, y in [-1, 1]) so the network
  can learn the ground plane's depth gradient from image position;
* ``depth``: z-depth in metres of the training scenes' scale (exp of the predicted log-depth; a
  reconstruction rescales it per frame to its cameras' units);
* ``normal_cam``: unit normals in CAMERA coordinates, OpenCV axes (x right, y down, z forward);
* ``albedo``: linear base colour in [0, 1], from the features or as the linear input over a predicted
  shading (config ``albedo_head``, :class:`GBufferNet`); ``roughness``, ``metallic`` in [0, 1];
* ``mask``: probability that the pixel is a surface (1) rather than the environment (0).

Loss (ground-truth surface pixels unless stated): L1 on log depth, (1 - cos) on normals, L1 on
albedo, roughness and metallic, binary cross-entropy on the mask (all pixels). Training is seeded and
single-process; the same config, data and thread count give the same weights.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F
from pydantic import Field

from lightcrafter.config.models import Estimator
from lightcrafter import io
from lightcrafter.recon.weights import SHIPPED_WEIGHTS

OUTPUT_CHANNELS = {"log_depth": 1, "normal": 3, "albedo": 3, "roughness": 1, "metallic": 1, "mask": 1}


class EstimatorConfig(Estimator):
    """Config recon.estimator (:class:`lightcrafter.config.models.Estimator`: widths, steps, batch, crop,
    lr, eval_every, keep_best, seed) plus threads: torch CPU threads."""

    threads: int = Field(2, ge=1, description="torch CPU threads")

    @classmethod
    def from_dict(cls, d: dict | None) -> "EstimatorConfig":
        """Validated; an unknown key or a bad value is a ConfigError (a ValueError) naming it."""
        from lightcrafter.config import validate_section

        return validate_section(cls, dict(d or {}), "recon.estimator")


def frame_coords(h: int, w: int) -> torch.Tensor:
    """(1, 2, H, W) normalised pixel coordinates of a full frame: x then y, each in [-1, 1]."""
    ys = torch.linspace(-1, 1, h).view(1, 1, h, 1).expand(1, 1, h, w)
    xs = torch.linspace(-1, 1, w).view(1, 1, 1, w).expand(1, 1, h, w)
    return torch.cat([xs, ys], dim=1)


def _block(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, padding=1), nn.GroupNorm(min(8, cout), cout), nn.SiLU(),
                         nn.Conv2d(cout, cout, 3, padding=1), nn.GroupNorm(min(8, cout), cout), nn.SiLU())


SHADING_LOG_OFFSET = float(np.log(0.7))  # log shading of a lit surface under scenes.white_radiance = 0.7


def srgb_decode(display: torch.Tensor) -> torch.Tensor:
    """Linear values of sRGB-encoded display values in [0, 1] (IEC 61966-2-1, as io.display_to_linear)."""
    x = display.clamp(0, 1)
    return torch.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def log_chroma(display: torch.Tensor) -> torch.Tensor:
    """(B, 3) log of each frame's mean linear colour over its channel mean (0 for a grey frame): the light's
    colour under a grey-world assumption, which the shading-ratio head maps to the shading's colour."""
    mean = srgb_decode(display).mean(dim=(2, 3)).clamp_min(1e-4)
    return torch.log(mean) - torch.log(mean).mean(dim=1, keepdim=True)


class GBufferNet(nn.Module):
    """U-Net over [RGB, x, y] -> raw output channels of :data:`OUTPUT_CHANNELS`.

    ``albedo_head`` (config recon.estimator.albedo_head): ``direct``, albedo = sigmoid of the head's three
    albedo channels; ``direct_colour``, the same, but the 1x1 output head also takes the input RGB itself
    (which the group norms of the U-Net normalise away over the frame: a pink ground under white light and a grey
    one under pink light look alike to it) and the albedo channels get a learned linear map of the frame's
    :func:`log_chroma`; ``shading_ratio``, log S = those channels + :data:`SHADING_LOG_OFFSET` + a learned linear
    map of the frame's :func:`log_chroma` (the light's colour, which the group norms hide from the U-Net), and
    albedo = min(linear input / S, 1) per channel, with the gradient of the ratio kept where it clips so that
    an over-bright estimate is still pulled down."""

    def __init__(self, widths: list[int], albedo_head: str = "direct"):
        super().__init__()
        if albedo_head not in ("direct", "direct_colour", "shading_ratio"):
            raise ValueError(f"albedo_head {albedo_head!r}: expected direct, direct_colour or shading_ratio")
        self.albedo_head = albedo_head
        self.widths = list(widths)
        self.down = nn.ModuleList()
        cin = 5
        for w in widths:
            self.down.append(_block(cin, w))
            cin = w
        self.up = nn.ModuleList()
        for w_skip, w in zip(reversed(widths[:-1]), reversed(widths[1:])):
            self.up.append(_block(w + w_skip, w_skip))
        head_in = widths[0] + (3 if albedo_head == "direct_colour" else 0)  # + the input RGB
        self.head = nn.Conv2d(head_in, sum(OUTPUT_CHANNELS.values()), 1)
        if albedo_head != "direct":  # the light's colour, from the frame's mean colour (starts at none)
            self.light_tint = nn.Linear(3, 3)
            nn.init.zeros_(self.light_tint.weight)
            nn.init.zeros_(self.light_tint.bias)

    def _albedo(self, raw: torch.Tensor, rgb: torch.Tensor, frame_chroma: torch.Tensor | None = None) -> torch.Tensor:
        if self.albedo_head == "direct":
            return torch.sigmoid(raw)
        if frame_chroma is None:
            frame_chroma = log_chroma(rgb)
        if self.albedo_head == "direct_colour":
            return torch.sigmoid(raw + self.light_tint(frame_chroma)[:, :, None, None])
        log_s = raw + SHADING_LOG_OFFSET + self.light_tint(frame_chroma)[:, :, None, None]
        ratio = srgb_decode(rgb) * torch.exp(-log_s)
        return ratio - (ratio - 1).clamp_min(0).detach()  # value min(ratio, 1), gradient of the ratio

    @property
    def stride(self) -> int:
        return 2 ** (len(self.widths) - 1)

    def forward(self, rgb: torch.Tensor, coords: torch.Tensor | None = None,
                frame_chroma: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """rgb: (B, 3, H, W) display values in [0, 1]; coords: (B, 2, H, W) normalised full-frame pixel
        coordinates (x, y in [-1, 1]; default: those of a full frame, give a crop's own when training
        on crops); frame_chroma: (B, 3) :func:`log_chroma` of the whole frames (default: of ``rgb``; give the
        full frames' when training on crops) -> dict of predictions (see module docstring)."""
        b, _, h, w = rgb.shape
        if h % self.stride or w % self.stride:
            raise ValueError(f"frame {w}x{h}: width and height must be multiples of {self.stride}")
        if coords is None:
            coords = frame_coords(h, w).expand(b, 2, h, w).to(rgb.device)
        x = torch.cat([rgb * 2 - 1, coords], dim=1)
        feats = []
        for i, blk in enumerate(self.down):
            x = blk(x if i == 0 else F.avg_pool2d(x, 2))
            feats.append(x)
        x = feats.pop()
        for blk in self.up:
            skip = feats.pop()
            x = blk(torch.cat([F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False), skip], 1))
        out = self.head(torch.cat([x, rgb * 2 - 1], 1) if self.albedo_head == "direct_colour" else x)
        parts = dict(zip(OUTPUT_CHANNELS, torch.split(out, list(OUTPUT_CHANNELS.values()), dim=1)))
        return {
            "log_depth": parts["log_depth"][:, 0] + 1.5,  # centred on e^1.5 = 4.5 m, the cameras' typical distance
            "normal": F.normalize(parts["normal"] + torch.tensor([0.0, -1.0, 0.0], device=out.device).view(1, 3, 1, 1),
                                  dim=1),
            "albedo": self._albedo(parts["albedo"], rgb, frame_chroma),
            "roughness": torch.sigmoid(parts["roughness"][:, 0]),
            "metallic": torch.sigmoid(parts["metallic"][:, 0] - 2.0),
            "mask_logit": parts["mask"][:, 0],
        }


# ----------------------------------------------------------------------------- data
@dataclass
class Sample:
    """One training frame: display RGB (3,H,W) in [0,1] and its ground-truth targets."""

    rgb: torch.Tensor
    log_depth: torch.Tensor
    normal_cam: torch.Tensor
    albedo: torch.Tensor
    roughness: torch.Tensor
    metallic: torch.Tensor
    mask: torch.Tensor


def sample_from(display_rgb: np.ndarray, b: io.Buffers, c2w: np.ndarray) -> Sample:
    """Training targets of one frame from its display RGB (H,W,3 in [0,1]) and ground-truth buffers."""
    m = b.mask > 0.5
    n_cam = np.where(m[..., None], b.normal @ np.asarray(c2w)[:3, :3], 0.0)  # world -> camera (R^T n)
    logd = np.where(m, np.log(np.where(m, b.depth, 1.0)), 0.0)
    t = lambda a: torch.from_numpy(np.ascontiguousarray(a, np.float32))  # noqa: E731
    return Sample(rgb=t(display_rgb.transpose(2, 0, 1)), log_depth=t(logd), normal_cam=t(n_cam.transpose(2, 0, 1)),
                  albedo=t(b.albedo.transpose(2, 0, 1)), roughness=t(b.roughness), metallic=t(b.metallic), mask=t(m))


def load_clip_samples(clip_dir: str | Path, frames_dir: str | Path, exposure_ev: float = 0.0) -> list[Sample]:
    """Samples of every frame of a ground-truth clip whose linear video frames are ``frames_dir/{i:04d}.exr``."""
    from lightcrafter.clip import read_clip

    views, info = read_clip(clip_dir)
    out = []
    for i, v in enumerate(views):
        rgb = io.linear_to_display(io.read_rgb_exr(Path(frames_dir) / f"{i:04d}.exr"), exposure_ev)
        if rgb.shape[:2] != v.buffers.shape:
            raise io.DataError(f"{frames_dir}/{i:04d}.exr: frame is {rgb.shape[1]}x{rgb.shape[0]} but clip {info.root} "
                               f"is {info.width}x{info.height}; re-render one of them")
        out.append(sample_from(rgb, v.buffers, v.c2w))
    return out


def _stack(samples: list[Sample]) -> Sample:
    return Sample(**{k: torch.stack([getattr(s, k) for s in samples]) for k in Sample.__dataclass_fields__})


def loss_terms(pred: dict, s: Sample) -> dict[str, torch.Tensor]:
    m = s.mask
    msum = m.sum().clamp_min(1.0)
    cos = (pred["normal"] * s.normal_cam).sum(1)
    return {
        "depth": ((pred["log_depth"] - s.log_depth).abs() * m).sum() / msum,
        "normal": ((1 - cos) * m).sum() / msum,
        "albedo": ((pred["albedo"] - s.albedo).abs().mean(1) * m).sum() / msum,
        "roughness": ((pred["roughness"] - s.roughness).abs() * m).sum() / msum,
        "metallic": ((pred["metallic"] - s.metallic).abs() * m).sum() / msum,
        "mask": F.binary_cross_entropy_with_logits(pred["mask_logit"], m),
    }


# ----------------------------------------------------------------------------- errors
def buffer_errors(pred: dict[str, np.ndarray], gt: io.Buffers, c2w: np.ndarray | None = None,
                  align_depth_scale: bool = True) -> dict[str, float]:
    """Errors of predicted buffers against ground truth on pixels that are surface in both.

    ``pred``: depth (H,W, metres or any scale), normal (H,W,3, WORLD when c2w is None, else camera
    coordinates rotated to world with c2w), albedo (H,W,3 linear), roughness, metallic (H,W), mask (H,W).
    depth_abs_rel: mean |d - d_gt| / d_gt after a median depth scale when ``align_depth_scale``;
    normal_deg: mean angle; albedo_psnr_db: PSNR of linear albedo (peak 1); roughness/metallic MAE;
    mask_iou.
    """
    m_gt = gt.mask > 0.5
    m_p = np.asarray(pred["mask"]) > 0.5
    both = m_gt & m_p & np.isfinite(pred["depth"]) & (pred["depth"] > 0)
    out = {"mask_iou": float((m_gt & m_p).sum() / max((m_gt | m_p).sum(), 1)), "pixels": int(both.sum())}
    if not both.any():
        return out | {"depth_abs_rel": float("nan"), "normal_deg": float("nan"), "albedo_psnr_db": float("nan"),
                      "roughness_mae": float("nan"), "metallic_mae": float("nan")}
    d, dg = pred["depth"][both], gt.depth[both]
    if align_depth_scale:
        d = d * np.median(dg / d)
    n = np.asarray(pred["normal"], np.float64)
    if c2w is not None:
        n = n @ np.asarray(c2w)[:3, :3].T
    cos = np.clip((n[both] * gt.normal[both]).sum(-1) / np.maximum(np.linalg.norm(n[both], axis=-1), 1e-9), -1, 1)
    mse = float(np.mean((pred["albedo"][both] - gt.albedo[both]) ** 2))
    return out | {
        "depth_abs_rel": float(np.mean(np.abs(d - dg) / dg)),
        "normal_deg": float(np.degrees(np.mean(np.arccos(cos)))),
        "albedo_psnr_db": float(10 * np.log10(1.0 / max(mse, 1e-12))),
        "roughness_mae": float(np.mean(np.abs(pred["roughness"][both] - gt.roughness[both]))),
        "metallic_mae": float(np.mean(np.abs(pred["metallic"][both] - gt.metallic[both]))),
    }


# ----------------------------------------------------------------------------- train / predict
@torch.no_grad()
def predict(model: GBufferNet | EstimatorEnsemble, display_rgb: np.ndarray) -> dict[str, np.ndarray]:
    """Predictions for display frames (N,H,W,3) in [0,1] (or one frame (H,W,3); anything else is a
    ValueError); numpy arrays per key:
    depth (metres of the training scale), normal_cam (OpenCV camera axes), albedo, roughness, metallic, mask."""
    x = np.asarray(display_rgb, np.float32)
    if not np.isfinite(x).all():
        raise ValueError(f"estimator input has {int((~np.isfinite(x)).sum())} NaN/Inf values; frames must be finite "
                         "display RGB (lightcrafter.io.linear_to_display maps them)")
    if x.min() < 0 or x.max() > 1:
        raise ValueError(f"estimator input spans [{x.min():.3g}, {x.max():.3g}], not display values in [0, 1]; convert "
                         "linear frames with lightcrafter.io.linear_to_display first")
    single = x.ndim == 3
    if single:
        x = x[None]
    model.eval()
    dev = next(model.parameters()).device
    outs = []
    for k in range(0, len(x), 8):
        p = model(torch.from_numpy(np.ascontiguousarray(x[k:k + 8].transpose(0, 3, 1, 2))).to(dev))
        p = {key: v.cpu() for key, v in p.items()}
        outs.append({"depth": torch.exp(p["log_depth"]).numpy(), "normal_cam": p["normal"].permute(0, 2, 3, 1).numpy(),
                     "albedo": p["albedo"].permute(0, 2, 3, 1).numpy(), "roughness": p["roughness"].numpy(),
                     "metallic": p["metallic"].numpy(), "mask": torch.sigmoid(p["mask_logit"]).numpy()})
    res = {k: np.concatenate([o[k] for o in outs]) for k in outs[0]}
    return {k: v[0] for k, v in res.items()} if single else res


def _validation_errors(model: GBufferNet | EstimatorEnsemble,
                       val: list[tuple[np.ndarray, io.Buffers, np.ndarray]]) -> dict[str, float]:
    rows = []
    for rgb, b, c2w in val:
        p = predict(model, rgb)
        rows.append(buffer_errors({"depth": p["depth"], "normal": p["normal_cam"], "albedo": p["albedo"],
                                   "roughness": p["roughness"], "metallic": p["metallic"], "mask": p["mask"]}, b, c2w))
    keys = [k for k in rows[0] if k != "pixels"]
    return {k: float(np.nanmean([r[k] for r in rows])) for k in keys}


def check_set_errors(model: GBufferNet | EstimatorEnsemble, path: str | Path) -> dict[str, float]:
    """Mean buffer errors (:func:`buffer_errors`) of ``model`` on a check set written by
    scripts/ship_estimator.py (npz: rgb, c2w and ground-truth buffer arrays per frame)."""
    d = np.load(path)
    val = []
    for i in range(len(d["rgb"])):
        m = d["mask"][i].astype(np.float32)
        b = io.Buffers(depth=np.where(m > 0.5, d["depth"][i].astype(np.float32), np.inf),
                       normal=d["normal"][i].astype(np.float32), albedo=d["albedo"][i].astype(np.float32),
                       roughness=d["roughness"][i].astype(np.float32), metallic=d["metallic"][i].astype(np.float32),
                       mask=m)
        val.append((d["rgb"][i].astype(np.float32), b, d["c2w"][i]))
    return _validation_errors(model, val)


def _scale_linear(rgb: torch.Tensor, gain: torch.Tensor) -> torch.Tensor:
    """Display-referred frames (sRGB decoded approximately as gamma 2.2) with their linear radiance scaled by
    ``gain`` (broadcast: one per frame, or one per frame and channel), clipped to [0, 1] as a camera would."""
    return ((rgb.clamp_min(0) ** 2.2) * gain).clamp(0, 1) ** (1 / 2.2)


def train_estimator(train: list[Sample], val: list[tuple[np.ndarray, io.Buffers, np.ndarray]], cfg: EstimatorConfig,
                    log=print) -> tuple[GBufferNet, list[dict]]:
    """Train from scratch; returns (model, curve) where curve lists validation errors against
    optimizer steps and seconds of training (evaluation time excluded)."""
    if not train:
        raise io.DataError("G-buffer estimator: no training frames (the recon split is empty); "
                           "give scenes.splits a recon share")
    from lightcrafter.devices import resolve_device

    dev = resolve_device(cfg.device, "recon.estimator.device")
    torch.manual_seed(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    model = GBufferNet(cfg.widths, cfg.albedo_head).to(dev)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(cfg.steps, 1), eta_min=cfg.lr * 0.05)
    curve, seconds = [], 0.0
    best = (float("inf"), 0, None)  # (validation normal error, step, weights)
    for step in range(1, cfg.steps + 1):
        t0 = time.perf_counter()
        model.train()
        idx = torch.randint(len(train), (cfg.batch,), generator=gen).tolist()
        batch = _stack([train[i] for i in idx])
        h, w = batch.rgb.shape[-2:]
        coords = frame_coords(h, w).expand(len(idx), 2, h, w)
        if cfg.augment_wb_ev > 0:  # white balance: the light's colour changes, the albedo target does not
            v = (torch.rand(len(idx), 3, 1, 1, generator=gen) * 2 - 1) * cfg.augment_wb_ev
            batch.rgb = _scale_linear(batch.rgb, torch.exp2(v - v.mean(dim=1, keepdim=True)))
        chroma = log_chroma(batch.rgb)  # of the whole frames (the exposure scaling below changes it only by clipping)
        if cfg.crop:
            ch, cw = min(cfg.crop[0], h), min(cfg.crop[1], w)
            y0 = int(torch.randint(h - ch + 1, (1,), generator=gen)) // 8 * 8
            x0 = int(torch.randint(w - cw + 1, (1,), generator=gen)) // 8 * 8
            batch = Sample(**{k: getattr(batch, k)[..., y0:y0 + ch, x0:x0 + cw] for k in Sample.__dataclass_fields__})
            coords = coords[..., y0:y0 + ch, x0:x0 + cw]
        if bool(torch.rand((), generator=gen) < 0.5):  # horizontal flip: mirror x, the x coordinate and normals' x
            batch = Sample(**{k: torch.flip(getattr(batch, k), dims=[-1]) for k in Sample.__dataclass_fields__})
            batch.normal_cam = batch.normal_cam * torch.tensor([-1.0, 1.0, 1.0]).view(1, 3, 1, 1)
            coords = torch.flip(coords, dims=[-1]) * torch.tensor([-1.0, 1.0]).view(1, 2, 1, 1)
        if cfg.augment_ev > 0:  # exposure: scale linear radiance (sRGB decoded approximately) by 2^u
            u = (torch.rand(len(idx), 1, 1, 1, generator=gen) * 2 - 1) * cfg.augment_ev
            batch.rgb = _scale_linear(batch.rgb, torch.exp2(u))
        if dev.type != "cpu":  # all random draws above stay on the CPU generator
            batch = Sample(**{k: getattr(batch, k).to(dev) for k in Sample.__dataclass_fields__})
            coords, chroma = coords.to(dev), chroma.to(dev)
        terms = loss_terms(model(batch.rgb, coords.contiguous(), chroma), batch)
        loss = sum(terms.values())
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        seconds += time.perf_counter() - t0
        if val and (step % cfg.eval_every == 0 or step == cfg.steps):
            errs = _validation_errors(model, val)
            curve.append({"step": step, "seconds": round(seconds, 2), "loss": float(loss.detach()), **errs})
            if cfg.keep_best and errs["normal_deg"] < best[0]:
                best = (errs["normal_deg"], step, {k: v.detach().clone() for k, v in model.state_dict().items()})
            log(f"estimator step {step}: loss {float(loss.detach()):.4f} " + " ".join(f"{k} {v:.3f}" for k, v in errs.items()))
    if cfg.keep_best and best[2] is not None:
        model.load_state_dict(best[2])
        for c in curve:
            c["selected"] = c["step"] == best[1]
    return model, curve


ENSEMBLE_FORMAT = "lightcrafter.estimator_ensemble/1"


class EstimatorEnsemble(nn.Module):
    """Several trained :class:`GBufferNet` members (e.g. the same set and schedule under other seeds) whose
    predictions are averaged: log-depth (a geometric mean of depth), unit normals (mean, renormalised),
    albedo, roughness and metallic, and the mask's logit. The shipped weights are one (``recon.estimator.weights:
    shipped``; scripts/ship_estimator.py --add-member), saved by :func:`save_ensemble`; :func:`load` reads both
    kinds of file, so every path that takes a weights file takes an ensemble."""

    def __init__(self, members: list[GBufferNet]):
        super().__init__()
        if not members:
            raise ValueError("an estimator ensemble needs at least one member")
        self.members = nn.ModuleList(members)

    @property
    def stride(self) -> int:
        return max(m.stride for m in self.members)

    def forward(self, rgb: torch.Tensor, coords: torch.Tensor | None = None,
                frame_chroma: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        outs = [m(rgb, coords, frame_chroma) for m in self.members]
        mean = {k: torch.stack([o[k] for o in outs]).mean(0) for k in outs[0]}
        mean["normal"] = F.normalize(mean["normal"], dim=1)
        return mean


def save(model: GBufferNet, cfg: EstimatorConfig, path: str | Path, extra: dict | None = None) -> None:
    with io.atomic_path(path) as tmp:
        torch.save({"state": model.state_dict(), "config": cfg.model_dump(), **(extra or {})}, tmp)


def save_ensemble(members: list[dict], path: str | Path) -> None:
    """Write an ensemble file from members as :func:`save` writes them (dicts with ``state`` and ``config``,
    extra keys kept), in order."""
    with io.atomic_path(path) as tmp:
        torch.save({"format": ENSEMBLE_FORMAT, "members": list(members)}, tmp)


def _member(st, path: Path, fix: str, where: str = "") -> GBufferNet:
    if not isinstance(st, dict) or "state" not in st or not isinstance(st.get("config"), dict) \
            or "widths" not in st["config"]:
        raise io.DataError(f"{path}: not a G-buffer estimator file{where} (no 'state' and 'config' entries, as "
                           f"lightcrafter.recon.estimator.save writes); {fix}")
    model = GBufferNet(st["config"]["widths"], st["config"].get("albedo_head", "direct"))
    try:
        model.load_state_dict(st["state"])
    except RuntimeError:
        raise io.DataError(f"{path}: its weights{where} do not fit the network its config names (widths "
                           f"{st['config']['widths']}: another network shape or an edited file); {fix}") from None
    return model


def _read(path: str | Path) -> tuple[Path, object, str]:
    """(path, what torch.load returned, the fix a one-line error names) for a weights file; a missing or unreadable
    file is a DataError of one line naming the file and the fix."""
    import pickle
    import zipfile

    path = Path(path)
    if path == SHIPPED_WEIGHTS:
        fix = "restore it with `git checkout lightcrafter/recon/weights`, or set recon.estimator.weights: train"
    elif path.name == "model.pt" and path.parent.name == "estimator":
        fix = "delete it and rerun the train_gbuffer_estimator rule, or set recon.estimator.weights: shipped"
    else:
        fix = ("point recon.estimator.weights at a file written by lightcrafter.recon.estimator.save, or set it to "
               "shipped or train")
    if not path.is_file():
        raise io.DataError(f"{path}: G-buffer estimator weights not found; {fix}")
    try:
        st = torch.load(path, map_location="cpu", weights_only=False)
    except (RuntimeError, EOFError, pickle.UnpicklingError, zipfile.BadZipFile, AttributeError, ValueError,
            TypeError, ModuleNotFoundError) as exc:
        why = str(exc).strip().splitlines()[0] if str(exc).strip() else "truncated or corrupt"
        raise io.DataError(f"{path}: unreadable estimator weights ({type(exc).__name__}: {why[:120]}); {fix}") from None
    if isinstance(st, dict) and "members" in st and (not isinstance(st["members"], list) or not st["members"]):
        raise io.DataError(f"{path}: an estimator ensemble file with no members; {fix}")
    return path, st, fix


def _networks(path: Path, st, fix: str) -> list[GBufferNet]:
    if isinstance(st, dict) and "members" in st:
        return [_member(m, path, fix, f" (member {i})") for i, m in enumerate(st["members"])]
    return [_member(st, path, fix)]


def saved_members(path: str | Path) -> list[dict]:
    """The networks a weights file holds, as :func:`save` wrote each (dicts with ``state`` and ``config``): one for
    a network's file, each member in order for an ensemble's. Checked as :func:`load` checks them (one line naming
    the file and the fix); for building another ensemble with :func:`save_ensemble`."""
    path, st, fix = _read(path)
    _networks(path, st, fix)
    return list(st["members"]) if "members" in st else [st]


def load(path: str | Path) -> GBufferNet | EstimatorEnsemble:
    """The estimator saved at ``path`` (:func:`save`, or an :class:`EstimatorEnsemble` saved by
    :func:`save_ensemble`); a missing, corrupt or mismatched file is a DataError of one line naming the file and
    the fix."""
    path, st, fix = _read(path)
    nets = _networks(path, st, fix)
    if "members" in st:
        model, device = EstimatorEnsemble(nets), st["members"][0]["config"].get("device", "cpu")
    else:
        model, device = nets[0], (st.get("config") or {}).get("device", "cpu")
    from lightcrafter.devices import resolve_device

    return model.to(resolve_device(device, "recon.estimator.device")).eval()


def curve_bench(curve: list[dict], cfg: EstimatorConfig, metric: str = "normal_deg") -> dict:
    """The training curve in the benchmark shape (docs/architecture.md), one series per error."""
    import os
    import platform

    points = []
    for key in ("normal_deg", "depth_abs_rel", "albedo_psnr_db"):
        points += [{"series": key, "setting": c["step"], "seconds": c["seconds"], "value": c[key]} for c in curve]
    return {"name": "gbuffer_estimator", "varied": "training steps (seconds of training on this machine)",
            "metric": metric, "higher_is_better": False, "machine": {"cores": os.cpu_count(), "platform": platform.platform()},
            "chosen": next((c["step"] for c in curve if c.get("selected")), cfg.steps), "chosen_series": metric,
            "points": points,
            "note": "validation errors on held-out recon-split trajectories; albedo_psnr_db is higher-is-better"}


def write_curve(path: str | Path, curve: list[dict], cfg: EstimatorConfig) -> None:
    io.write_text(path, json.dumps(curve_bench(curve, cfg), indent=1, sort_keys=True) + "\n")
