"""Mitsuba variant selection: ``cuda_ad_rgb`` when a CUDA device works, else ``llvm_ad_rgb`` (CPU).

Override with the environment variable ``LIGHTCRAFTER_MI_VARIANT``. The variant is set once per
process (Mitsuba types are variant specific).
"""

from __future__ import annotations

import os

import mitsuba as mi

PREFERRED = ("cuda_ad_rgb", "llvm_ad_rgb")


def ensure_variant() -> str:
    """Set (once) and return the Mitsuba variant used by the proxy renderer."""
    current = mi.variant()
    if current in PREFERRED or (current and current == os.environ.get("LIGHTCRAFTER_MI_VARIANT")):
        return current
    wanted = os.environ.get("LIGHTCRAFTER_MI_VARIANT")
    candidates = (wanted,) if wanted else PREFERRED
    errors = []
    for v in candidates:
        try:
            mi.set_variant(v)
            if v.startswith("cuda"):
                mi.Float([0.0]) + 1  # fails without a usable GPU
            return v
        except Exception as exc:  # noqa: BLE001 - try the next variant
            errors.append(f"{v}: {exc}")
    raise RuntimeError("no usable Mitsuba variant: " + "; ".join(errors))
