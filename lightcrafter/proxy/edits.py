"""Material edits (the paper's material editing): overrides / multipliers on a pixel mask.

An edit changes the buffers *before* rendering, so edited frames go through exactly the same
renderer path as unedited ones. Values stay in the buffer contract's range [0, 1].
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from lightcrafter.io import Buffers


@dataclass(frozen=True)
class MaterialEdit:
    """One edit. ``mask``: (H, W) weights in [0, 1] (None = every surface pixel).

    For each property: ``*_override`` replaces the value, ``*_multiplier`` scales it (applied after
    an override); None leaves it alone. Albedo values are linear RGB triples (or one scalar).
    """

    mask: np.ndarray | None = None
    albedo_override: tuple[float, float, float] | float | None = None
    albedo_multiplier: tuple[float, float, float] | float | None = None
    roughness_override: float | None = None
    roughness_multiplier: float | None = None
    metallic_override: float | None = None
    metallic_multiplier: float | None = None

    @classmethod
    def from_dict(cls, d: dict, mask: np.ndarray | None = None) -> "MaterialEdit":
        keys = {k: d[k] for k in d if k in cls.__dataclass_fields__ and k != "mask"}
        return cls(mask=mask, **keys)


def _edit(values: np.ndarray, override, multiplier, weight: np.ndarray) -> np.ndarray:
    new = values
    if override is not None:
        new = np.broadcast_to(np.asarray(override, dtype=np.float32), values.shape)
    if multiplier is not None:
        new = new * np.asarray(multiplier, dtype=np.float32)
    w = weight if values.ndim == weight.ndim else weight[..., None]
    return np.clip(values * (1 - w) + new * w, 0.0, 1.0).astype(np.float32)


def apply_edits(buffers: Buffers, edits: list[MaterialEdit] | tuple = ()) -> Buffers:
    """Return new buffers with ``edits`` applied in order (geometry, normals and mask untouched)."""
    out = buffers
    for e in edits:
        weight = buffers.mask if e.mask is None else np.clip(np.asarray(e.mask, np.float32), 0, 1) * buffers.mask
        if weight.shape != buffers.shape:
            raise ValueError(f"edit mask shape {weight.shape} != buffer shape {buffers.shape}")
        out = replace(
            out,
            albedo=_edit(out.albedo, e.albedo_override, e.albedo_multiplier, weight),
            roughness=_edit(out.roughness, e.roughness_override, e.roughness_multiplier, weight),
            metallic=_edit(out.metallic, e.metallic_override, e.metallic_multiplier, weight),
        )
    return out
