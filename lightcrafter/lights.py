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
