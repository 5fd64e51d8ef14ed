"""Frame strips for people: a PNG grid with one column per video (e.g. input | proxy | refined |
target) and one row per chosen frame, labelled, nearest-neighbour upscaled so small clips stay legible.

Videos are (N, H, W, 3) DISPLAY values in [0, 1] (:func:`.data.to_display_frames`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

LABEL_PX = 12


def strip_frames(num_frames: int, rows: int = 3) -> list[int]:
    """Evenly spaced frame indices (first and last included), at most ``rows``."""
    if num_frames <= rows:
        return list(range(num_frames))
    return sorted({int(round(i * (num_frames - 1) / (rows - 1))) for i in range(rows)})


def frame_strip(columns: list[tuple[str, np.ndarray]], frames: list[int] | None = None, scale: int = 2,
                gap: int = 2) -> np.ndarray:
    """(H', W', 3) uint8 image: a label row, then one row per frame index, one column per video."""
    from PIL import Image, ImageDraw

    if not columns:
        raise ValueError("frame_strip: no columns")
    n, h, w, _ = columns[0][1].shape
    for label, v in columns:
        if v.shape != (n, h, w, 3):
            raise ValueError(f"frame_strip: column {label!r} is {v.shape}, expected {(n, h, w, 3)}")
    frames = strip_frames(n) if frames is None else frames
    cw, ch = w * scale, h * scale
    width = len(columns) * cw + (len(columns) - 1) * gap
    height = LABEL_PX + len(frames) * ch + (len(frames) - 1) * gap
    img = Image.new("RGB", (width, height), (255, 255, 255))
    draw = ImageDraw.Draw(img)
    for c, (label, v) in enumerate(columns):
        x = c * (cw + gap)
        draw.text((x + 2, 0), label, fill=(0, 0, 0))
        for r, f in enumerate(frames):
            tile = Image.fromarray((np.clip(v[f], 0, 1) * 255 + 0.5).astype(np.uint8)).resize((cw, ch), Image.NEAREST)
            img.paste(tile, (x, LABEL_PX + r * (ch + gap)))
    return np.asarray(img)


def write_strip(path, columns: list[tuple[str, np.ndarray]], **kw) -> Path:
    """Write :func:`frame_strip` as a PNG (atomically)."""
    from PIL import Image

    from lightcrafter.io import atomic_path

    path = Path(path)
    with atomic_path(path) as tmp:
        Image.fromarray(frame_strip(columns, **kw)).save(tmp, format="PNG")
    return path
