"""LPIPS v0.1 (Zhang et al. 2018) in plain torch, from the two weight files in their published formats.

Nothing here needs torchvision or the ``lpips`` package (on this project's CPU machines PyPI's torchvision
wheels link libtorch_cuda.so and do not import beside the CPU torch build), so the same code runs on every
machine and is tested on stand-in weights written in the real formats (tests/test_evaluation.py).

A weights folder (``evaluation.lpips_weights``) holds, directly or under ``checkpoints/`` (a torch hub cache
folder works as is):

* the backbone's torchvision ImageNet state dict: ``alexnet-owt-7be5be79.pth`` (keys ``features.{0,3,6,8,10}``)
  or ``vgg16-397923af.pth`` (keys ``features.{0,2,5,...,28}``); the classifier keys are ignored;
* the LPIPS v0.1 linear layers, as the ``lpips`` package ships them in ``lpips/weights/v0.1/``:
  ``alex.pth`` or ``vgg.pth`` (keys ``lin{k}.model.1.weight`` of shape (1, C_k, 1, 1), non-negative).

Distance of two images in [-1, 1] (B, 3, H, W): the scaling layer, the backbone's ReLU outputs at five depths,
each unit-normalised over channels, squared differences weighted by the linear layer, averaged over the
image, summed over depths (``lpips.LPIPS(net, version="0.1")`` with ``spatial=False``).
"""

from __future__ import annotations

import functools
from pathlib import Path

import torch
import torch.nn as nn
import torch.nn.functional as F

from lightcrafter.io import DataError

#: torchvision checkpoint of each backbone (the torch hub cache name) and the v0.1 linear-layer file.
BACKBONE_FILES = {"alex": "alexnet-owt-7be5be79.pth", "vgg": "vgg16-397923af.pth"}
LINEAR_FILES = {"alex": "alex.pth", "vgg": "vgg.pth"}
#: the LPIPS input scaling layer (ImageNet statistics in [-1, 1] units)
SHIFT = (-0.030, -0.088, -0.188)
SCALE = (0.458, 0.448, 0.450)
#: (kind, out channels, kernel, stride, padding) of torchvision's ``features``; "M" a 3x3/2 (alex) or 2x2/2
#: (vgg) max-pool, "R" a ReLU whose output is tapped when its index is in TAPS
_ALEX = [("C", 64, 11, 4, 2), "R", "M", ("C", 192, 5, 1, 2), "R", "M", ("C", 384, 3, 1, 1), "R",
         ("C", 256, 3, 1, 1), "R", ("C", 256, 3, 1, 1), "R"]
_VGG = [("C", 64, 3, 1, 1), "R", ("C", 64, 3, 1, 1), "R", "M", ("C", 128, 3, 1, 1), "R", ("C", 128, 3, 1, 1), "R",
        "M", ("C", 256, 3, 1, 1), "R", ("C", 256, 3, 1, 1), "R", ("C", 256, 3, 1, 1), "R", "M",
        ("C", 512, 3, 1, 1), "R", ("C", 512, 3, 1, 1), "R", ("C", 512, 3, 1, 1), "R", "M",
        ("C", 512, 3, 1, 1), "R", ("C", 512, 3, 1, 1), "R", ("C", 512, 3, 1, 1), "R"]
LAYERS = {"alex": _ALEX, "vgg": _VGG}
TAPS = {"alex": (1, 4, 7, 9, 11), "vgg": (3, 8, 15, 22, 29)}
#: smallest frame side (pixels) every tapped layer has an output for: AlexNet's 11/4 convolution and two
#: 3/2 pools before the third tap; VGG's four 2/2 pools before the fifth
MIN_SIDE = {"alex": 31, "vgg": 16}


def find_file(folder: Path, name: str) -> Path | None:
    for cand in (folder / name, folder / "checkpoints" / name):
        if cand.is_file():
            return cand
    return None


def _features(net: str) -> nn.Sequential:
    mods, in_ch = [], 3
    for spec in LAYERS[net]:
        if spec == "R":
            mods.append(nn.ReLU(inplace=False))
        elif spec == "M":
            mods.append(nn.MaxPool2d(3, 2) if net == "alex" else nn.MaxPool2d(2, 2))
        else:
            _, out, k, s, p = spec
            mods.append(nn.Conv2d(in_ch, out, k, s, p))
            in_ch = out
    return nn.Sequential(*mods)


def _load(path: Path, what: str) -> dict:
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # truncated file, pickle of something else, ...
        raise DataError(f"{path}: not a torch state dict ({type(exc).__name__}); {what}") from None
    if not isinstance(state, dict):
        raise DataError(f"{path}: holds a {type(state).__name__}, not a state dict; {what}")
    return state


@functools.lru_cache(maxsize=2)
def build(backbone: str, linear: str, net: str = "alex"):
    """The LPIPS module (eval mode, float32, no gradients) from a backbone and a linear-layer file; a
    missing tensor or a wrong shape is a one-line :class:`DataError` naming the file and the fix."""
    if net not in LAYERS:
        raise ValueError(f"lpips net must be one of {sorted(LAYERS)}, got {net!r}")
    feats = _features(net)
    state = _load(Path(backbone), f"use torchvision's {BACKBONE_FILES[net]}")
    with torch.no_grad():
        for name, p in feats.named_parameters():
            key = f"features.{name}"
            if key not in state or tuple(state[key].shape) != tuple(p.shape):
                raise DataError(f"{backbone}: no tensor {key} of shape {tuple(p.shape)} for the LPIPS {net} "
                                f"backbone; use torchvision's {BACKBONE_FILES[net]}")
            p.copy_(state[key])
    lin_state = _load(Path(linear), f"use lpips' weights/v0.1/{LINEAR_FILES[net]}")
    tapped = [[m for m in list(feats)[:t] if isinstance(m, nn.Conv2d)][-1].out_channels for t in TAPS[net]]
    lins = []
    for k, c in enumerate(tapped):
        key = f"lin{k}.model.1.weight"
        w = lin_state.get(key)
        if w is None or tuple(w.shape) != (1, c, 1, 1):
            raise DataError(f"{linear}: no tensor {key} of shape (1, {c}, 1, 1) for LPIPS v0.1 {net}; "
                            f"use lpips' weights/v0.1/{LINEAR_FILES[net]}")
        lins.append(w.float().clone())
    return LPIPS(feats, TAPS[net], lins).eval().requires_grad_(False)


class LPIPS(nn.Module):
    """LPIPS distance; ``forward(a, b)`` takes (B, 3, H, W) in [-1, 1] and returns (B,) distances."""

    def __init__(self, features: nn.Sequential, taps, lins):
        super().__init__()
        self.features, self.taps = features, tuple(taps)
        self.lins = torch.nn.ParameterList([torch.nn.Parameter(w, requires_grad=False) for w in lins])
        self.register_buffer("shift", torch.tensor(SHIFT).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(SCALE).view(1, 3, 1, 1))

    def _taps(self, x):
        out = []
        for i, m in enumerate(self.features):
            x = m(x)
            if i in self.taps:
                out.append(x / (x.pow(2).sum(dim=1, keepdim=True).sqrt() + 1e-10))
        return out

    def forward(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        fa = self._taps((a - self.shift) / self.scale)
        fb = self._taps((b - self.shift) / self.scale)
        return sum(F.conv2d((x - y).pow(2), w).mean(dim=(1, 2, 3)) for x, y, w in zip(fa, fb, self.lins))
