"""Mitsuba variant selection: ``cuda_ad_rgb`` when a CUDA device works, else ``llvm_ad_rgb`` (CPU).

Override with the environment variable ``LIGHTCRAFTER_MI_VARIANT``. The variant is set once per
process (Mitsuba types are variant specific).

The LLVM variants JIT-compile with libLLVM (version 19 here; Debian's 15 aborts). Dr.Jit finds it on
the loader's path (``apt install libllvm19``) or at ``DRJIT_LIBLLVM_PATH``; inside a conda environment
(``envs/mitsuba.yaml`` installs conda-forge's libllvm19 into ``$CONDA_PREFIX/lib``, which the loader
does not search) that variable is set to the environment's library when it is not set already.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import mitsuba as mi

PREFERRED = ("cuda_ad_rgb", "llvm_ad_rgb")


def prefix_libllvm(prefix: str | os.PathLike = sys.prefix) -> Path | None:
    """The libLLVM shared library of an environment prefix (``lib/libLLVM-19.so``, ``libLLVM.so.19.1``,
    ...), newest version first; None when there is none."""
    lib = Path(prefix) / "lib"
    found = sorted((p for p in lib.glob("libLLVM*.so*") if p.is_file()), key=lambda p: p.name, reverse=True) if lib.is_dir() else []
    return found[0] if found else None


def _point_drjit_at_prefix_llvm() -> None:
    if not os.environ.get("DRJIT_LIBLLVM_PATH"):
        lib = prefix_libllvm()
        if lib is not None:
            os.environ["DRJIT_LIBLLVM_PATH"] = str(lib)


def ensure_variant() -> str:
    """Set (once) and return the Mitsuba variant used by the proxy renderer."""
    current = mi.variant()
    if current in PREFERRED or (current and current == os.environ.get("LIGHTCRAFTER_MI_VARIANT")):
        return current
    wanted = os.environ.get("LIGHTCRAFTER_MI_VARIANT")
    candidates = (wanted,) if wanted else PREFERRED
    _point_drjit_at_prefix_llvm()
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
