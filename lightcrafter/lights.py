"""Light sources: where HDR environment maps referenced by a scene spec live on disk.

A lighting's ``hdri`` is either ``builtin:NAME.exr`` (one of the eight CC0 HDRIs that ship
inside the bpy wheel, under ``<bpy>/<version>/datafiles/studiolights/world/``) or a path to a
lat-long HDR file. The bundled directory is found without importing ``bpy`` (importing it
costs about a second and loads all of Blender); ``bpy.utils.system_resource`` is the fallback.
"""

from __future__ import annotations

import functools
import importlib.util
from pathlib import Path

from lightcrafter.io import DataError

BUILTIN_PREFIX = "builtin:"
HDRI_SUFFIXES = (".exr",)  # OpenEXR only: Cycles and the proxy renderer (lightcrafter.envmap) both read it


@functools.lru_cache(maxsize=1)
def builtin_hdri_dir() -> Path:
    """Directory of the HDRIs bundled with the bpy wheel (``.../datafiles/studiolights/world``)."""
    spec = importlib.util.find_spec("bpy")
    if spec is not None:
        roots = list(spec.submodule_search_locations or []) or ([str(Path(spec.origin).parent)] if spec.origin else [])
        for root in roots:
            hits = sorted(Path(root).glob("*/datafiles/studiolights/world"))
            if hits:
                return hits[-1]
    try:
        import bpy  # fallback: ask Blender itself

        return Path(bpy.utils.system_resource("DATAFILES")) / "studiolights" / "world"
    except ImportError as exc:
        raise DataError(
            "bpy: not installed, so builtin:*.exr HDRIs are unavailable; install the pinned bpy wheel"
        ) from exc


def builtin_hdris() -> list[str]:
    """Sorted file names (e.g. ``forest.exr``) of the HDRIs bundled with bpy."""
    folder = builtin_hdri_dir()
    if not folder.is_dir():
        return []
    return sorted(p.name for p in folder.iterdir() if p.suffix.lower() in HDRI_SUFFIXES)


def resolve_hdri(ref: str) -> Path:
    """Map a spec's HDRI reference (``builtin:NAME.exr`` or a file path) to an existing file.

    Raises :class:`DataError` with a one-line message naming the file and the fix if it is missing.
    """
    ref = str(ref)
    if ref.startswith(BUILTIN_PREFIX):
        name = ref[len(BUILTIN_PREFIX) :]
        path = builtin_hdri_dir() / name
        if not path.is_file():
            raise DataError(
                f"{ref}: no such bundled HDRI in {builtin_hdri_dir()}; use one of {builtin_hdris()} or a file path"
            )
        return path
    path = Path(ref)
    if not path.is_file():
        raise DataError(f"{path}: HDRI file not found; fix the lighting's 'hdri' path or use builtin:NAME.exr")
    return path


@functools.lru_cache(maxsize=64)
def hdri_white_radiance(ref: str) -> float:
    """Radiance (linear) that a white Lambertian ground plane (normal +Z) reflects under the HDRI at
    strength 1: the cosine-weighted upper-hemisphere irradiance E divided by pi, with E integrated over
    the lat-long map's pixels (solid angle sin(theta) dtheta dphi; lightcrafter.envmap convention).

    Scene sampling divides light strengths by it, so every lighting gives the ground the same
    exposure (``scenes.white_radiance``) up to the sampled strength factor: without it the bundled
    HDRIs span 14x in brightness (night 0.16 to city 2.19) and bright ones clip the display range.
    """
    import numpy as np

    from lightcrafter import envmap

    env = envmap.load(resolve_hdri(ref))
    h, w = env.shape[:2]
    # The weight cos(up) x solid angle depends on the row only (lat-long map): per-row sums of float32
    # luminance in blocks of rows, accumulated in float64. Exact, and an 8k or 16k PolyHaven map needs no
    # full-size float64 arrays (the former per-pixel direction array alone was 3 GB at 16k).
    rows = np.arange(h)
    cos_up = np.clip(envmap.pixel_directions(h, 1)[:, 0, 2], 0.0, None)
    solid_angle = (np.pi / h) * (2 * np.pi / w) * np.sin(np.pi * (rows + 0.5) / h)
    weights = np.array([0.2126, 0.7152, 0.0722], np.float32)  # Rec. 709 / linear sRGB luminance weights
    row_sums = np.empty(h, np.float64)
    for r0 in range(0, h, 256):
        row_sums[r0:r0 + 256] = (env[r0:r0 + 256] @ weights).sum(axis=1, dtype=np.float64)
    e_over_pi = float((row_sums * cos_up * solid_angle).sum() / np.pi)
    if not e_over_pi > 0:
        raise DataError(f"{ref}: the HDRI's upper hemisphere is black; it cannot light a scene, remove it")
    return e_over_pi
