"""Images and videos on the page; the report folder is self-contained (media copied under media/)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

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


def side_by_side_video(folders: list[Path], out: Path, fps: float = 12.0, scale: int = 2) -> Path | None:
    """An mp4 of the frame folders side by side (linear EXR frames -> display), each upscaled ``scale`` x."""
    from ..io import linear_to_display, read_rgb_exr, to_uint8, write_video

    folders = [f for f in folders if f is not None and (f / "0000.exr").is_file()]
    if not folders:
        return None
    n = min(sum(1 for _ in f.glob("*.exr")) for f in folders)
    frames = []
    for i in range(n):
        row = [to_uint8(linear_to_display(read_rgb_exr(f / f"{i:04d}.exr"))) for f in folders]
        h = min(r.shape[0] for r in row)
        row = [np.repeat(np.repeat(r[:h], scale, 0), scale, 1) for r in row]
        frames.append(np.concatenate([np.pad(r, ((0, 0), (0, 4), (0, 0)), constant_values=255) for r in row], 1))
    write_video(out, np.stack(frames), fps=fps)
    return out
