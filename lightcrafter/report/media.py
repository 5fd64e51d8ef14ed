"""Images and videos on the page; the report folder is self-contained (media copied under media/)."""

from __future__ import annotations

from pathlib import Path

from ..io import side_by_side_video  # noqa: F401  (re-exported; it lives in io so that scripts using it do not
# depend on the report package, lightcrafter.codeversion)
from .common import _esc


# ----------------------------------------------------------------------------- media
def _video_tag(path: Path, rel_to: Path) -> str:
    return (f"<video controls loop muted playsinline src='{_esc(_rel(path, rel_to))}'></video>" if path.is_file()
            else "")


def _img_tag(path: Path, rel_to: Path, cls="strip") -> str:
    return f"<img class='{cls}' src='{_esc(_rel(path, rel_to))}'>" if path.is_file() else ""


def _rel(path: Path, base: Path) -> str:
    """The page's link to ``path`` from the report folder ``base``. Media outside the folder are copied
    into ``base/media/`` (under their path relative to the results folder), so the report folder is
    self-contained: it can be copied or shared without the run's results."""
    import os
    import shutil

    path, base = Path(path).resolve(), Path(base).resolve()
    if base not in path.parents:
        try:
            rel = path.relative_to(base.parent)
        except ValueError:
            rel = Path(path.name)
        dest = base / "media" / rel
        if not dest.is_file() or dest.stat().st_mtime < path.stat().st_mtime or dest.stat().st_size != path.stat().st_size:
            dest.parent.mkdir(parents=True, exist_ok=True)
            tmp = dest.with_name(f".{dest.name}.tmp")
            shutil.copy2(path, tmp)
            os.replace(tmp, dest)
        path = dest
    return os.path.relpath(path, base)
