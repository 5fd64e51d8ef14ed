"""The clip contract: one video's scene state (G-buffers + cameras), written and read in one place.

Every producer of scene state writes its clips through :func:`write_clip`: Blender (ground truth),
the reconstruction stack Phi (estimates), Align (estimates in the ground-truth frame) and real-video
reconstruction. Every consumer (the forward renderer R, envmap fitting, evaluation) reads them with
:func:`read_clip`. So ground truth and estimates are interchangeable and comparable.

Layout of a clip folder::

    buffers/{i:04d}.exr      G-buffers of the *distinct* frames (io.Buffers contract: z-depth, world
                             normals, linear base colour, roughness, metallic, mask)
    confidence/{i:04d}.exr   optional per-pixel confidence in [0, 1] (channel ``confidence``)
    cameras.json             K (3x3, pixels) and c2w (4x4) of every frame (io.write_cameras: OpenCV
                             camera axes, world right-handed Z up)
    buffers.json             the manifest, written last: a folder without it is an incomplete clip

Manifest (``format: lightcrafter.clip/1``)::

    width, height            pixels
    num_frames, fps          frame count of the video and its frame rate (frames per second)
    frames                   for every frame index, the buffer EXR serving it (relative path); a
                             static camera over a static scene lists one file num_frames times
    cameras                  "cameras.json"
    confidence               per-frame relative paths, or null when the producer has none
    camera_static            the camera does not move
    scene_static             no object moves
    consistent_depth         the depth maps of different frames agree (ground truth): only then is a
                             shadow mesh merged over frames valid; a reconstruction's frames disagree
                             by more than R's shadow offset, and merged layers shadow each other
    units                    "metres" (Blender, aligned estimates) or "arbitrary" (a reconstruction's
                             own scale, e.g. structure from motion: one unknown scale per clip)
    producer                 what wrote it and with which settings ({"stage": "blender" | "phi" | ...})
    content_id               fingerprint of what the frames were made from; consumers fold it into
                             their own inputs so a re-made clip re-renders everything downstream
    + any producer-specific keys (scene_id, trajectory, clip_id, ...)

This module also holds the one resumable frame-folder helper (:class:`FrameFolder`) used by every
stage that writes a folder of per-frame files.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from lightcrafter import io

FORMAT = "lightcrafter.clip/1"
MANIFEST = "buffers.json"
CAMERAS = "cameras.json"
UNITS = ("metres", "arbitrary")


# ----------------------------------------------------------------------------- frame folders
def readable(path: Path, reader: Callable) -> bool:
    """True when ``path`` exists and ``reader(path)`` succeeds (a truncated frame is not readable)."""
    if not Path(path).is_file():
        return False
    try:
        reader(path)
        return True
    except io.DataError:
        return False


class FrameFolder:
    """A resumable folder of per-frame files ``{i:04d}{suffix}`` made from one set of ``inputs``.

    Use::

        ff = FrameFolder(folder, inputs)            # inputs: JSON-able description of what frames come from
        for i in ff.missing(indices, reader):       # drops frames of other inputs, lists absent/unreadable ones
            ff.stamp()                              # (idempotent) before the first frame is written
            io.write_...(ff.path(i), ...)           # atomic writes: a kill never leaves a trusted partial frame

    A killed job keeps its finished frames; a rerun with the same inputs renders only the missing
    ones; a rerun with other inputs (spec, settings, upstream buffers) deletes the stale frames first.
    """

    def __init__(self, folder: str | os.PathLike, inputs, suffix: str = ".exr"):
        self.folder = Path(folder)
        self.inputs = inputs
        self.suffix = suffix
        self._stamped = False

    def path(self, i: int) -> Path:
        return self.folder / f"{i:04d}{self.suffix}"

    def missing(self, indices: Iterable[int], reader: Callable) -> list[int]:
        """Claim the folder for ``inputs`` (stale frames are deleted), then list the indices whose
        frame is absent or unreadable by ``reader``."""
        io.claim_frame_dir(self.folder, self.inputs)
        return [i for i in indices if not readable(self.path(i), reader)]

    def stamp(self) -> None:
        """Record the inputs (once) before the first frame is written."""
        if not self._stamped:
            io.stamp_frame_dir(self.folder, self.inputs)
            self._stamped = True


# ----------------------------------------------------------------------------- clips
@dataclass
class FrameView:
    """One frame's inputs to the renderer: buffers, K (3x3 px, OpenCV), c2w (4x4, world Z up), and a
    cache key naming the buffer content (e.g. its file path); frames with equal key, K and c2w share
    meshes."""

    buffers: io.Buffers
    K: np.ndarray
    c2w: np.ndarray
    key: str

    def cache_key(self) -> tuple:
        return (self.key, np.asarray(self.K, np.float64).round(9).tobytes(),
                np.asarray(self.c2w, np.float64).round(9).tobytes())


@dataclass
class ClipInfo:
    """A clip's manifest, parsed (see the module docstring for the keys)."""

    root: Path
    width: int
    height: int
    num_frames: int
    fps: float
    frames: list[str]
    camera_static: bool
    scene_static: bool
    consistent_depth: bool
    units: str
    producer: dict
    content_id: str | None
    confidence: list[str] | None
    manifest: dict = field(repr=False, default_factory=dict)

    @property
    def distinct_frames(self) -> list[int]:
        """Indices of the first frame served by each distinct buffer file."""
        seen, out = set(), []
        for i, rel in enumerate(self.frames):
            if rel not in seen:
                seen.add(rel)
                out.append(i)
        return out


def buffer_path(clip_dir: str | os.PathLike, i: int) -> Path:
    """Where a producer writes the buffers of distinct frame ``i``."""
    return Path(clip_dir) / "buffers" / f"{i:04d}.exr"


def confidence_path(clip_dir: str | os.PathLike, i: int) -> Path:
    return Path(clip_dir) / "confidence" / f"{i:04d}.exr"


def buffer_frames(clip_dir: str | os.PathLike, inputs) -> FrameFolder:
    """The resumable buffers/ folder of a clip being produced from ``inputs``."""
    return FrameFolder(Path(clip_dir) / "buffers", inputs)


def write_confidence(clip_dir: str | os.PathLike, i: int, confidence: np.ndarray) -> None:
    c = np.clip(np.nan_to_num(np.asarray(confidence, np.float32), nan=0.0), 0.0, 1.0)
    io.write_exr(confidence_path(clip_dir, i), {"confidence": c})


def read_confidence(path: str | os.PathLike) -> np.ndarray:
    return io.read_exr(path, ("confidence",))["confidence"]


def write_clip(clip_dir: str | os.PathLike, *, serve: list[int], K: np.ndarray, c2w: np.ndarray, width: int,
               height: int, fps: float, camera_static: bool, scene_static: bool, units: str, producer: dict,
               content_id: str | None, confidence: bool = False, extra: dict | None = None,
               consistent_depth: bool = False) -> dict:
    """Write ``cameras.json`` and then the manifest ``buffers.json`` of a clip whose buffer files exist.

    ``serve[i]`` is the distinct frame whose buffers (``buffers/{serve[i]:04d}.exr``) serve frame i.
    ``K`` (N, 3, 3) and ``c2w`` (N, 4, 4) are per frame (OpenCV camera, world Z up). Every listed buffer
    file must already be complete; the manifest is written last and atomically. ``content_id`` (what the
    frames were made from) is stored with the producer's code folded in (:func:`lightcrafter.io.product_fingerprint`
    when an entry point set the code version), so consumers of a clip re-made by changed code re-make theirs.
    """
    clip_dir = Path(clip_dir)
    n = len(serve)
    if units not in UNITS:
        raise ValueError(f"units={units!r}: use one of {UNITS}")
    K, c2w = np.asarray(K, np.float64), np.asarray(c2w, np.float64)
    if K.shape != (n, 3, 3) or c2w.shape != (n, 4, 4):
        raise ValueError(f"{clip_dir}: {n} frames need K (N,3,3) and c2w (N,4,4), got {K.shape}, {c2w.shape}")
    for j in sorted(set(serve)):
        if not buffer_path(clip_dir, j).is_file():
            raise io.DataError(f"{buffer_path(clip_dir, j)}: buffer frame missing; rerun the stage that writes it")
    if content_id is not None and io.CODE_VERSION:
        content_id = io.product_fingerprint(content_id)
    io.write_cameras(clip_dir / CAMERAS, width, height, K, c2w)
    manifest = {
        "format": FORMAT,
        "width": int(width), "height": int(height), "num_frames": n, "fps": float(fps),
        "buffer_frames": len(set(serve)),
        "frames": [f"buffers/{j:04d}.exr" for j in serve],
        "cameras": CAMERAS,
        "confidence": [f"confidence/{j:04d}.exr" for j in serve] if confidence else None,
        "camera_static": bool(camera_static), "scene_static": bool(scene_static),
        "consistent_depth": bool(consistent_depth), "units": units, "producer": producer, "content_id": content_id,
        **(extra or {}),
    }
    io.write_json(clip_dir / MANIFEST, manifest)
    return manifest


def manifest_path(clip: str | os.PathLike) -> Path:
    """A clip folder or its manifest -> the manifest path."""
    p = Path(clip)
    return p / MANIFEST if p.is_dir() or p.suffix != ".json" else p


def read_info(clip: str | os.PathLike) -> ClipInfo:
    """Parse and check a clip's manifest (the folder or its ``buffers.json``)."""
    mpath = manifest_path(clip)
    man = io.read_json(mpath)
    if isinstance(man, dict) and man.get("skipped"):
        raise io.DataError(f"{mpath}: this clip was left out ({man['skipped']}); it has no buffers")
    frames = man.get("frames")
    if not isinstance(frames, list) or not frames or not all(isinstance(f, str) for f in frames):
        raise io.DataError(f"{mpath}: 'frames' must be a non-empty list of buffer EXR paths; rerun the stage that wrote it")
    if "num_frames" in man and int(man["num_frames"]) != len(frames):
        raise io.DataError(f"{mpath}: num_frames={man['num_frames']} but {len(frames)} frame entries; rerun its stage")
    units = man.get("units", "metres")
    if units not in UNITS:
        raise io.DataError(f"{mpath}: units={units!r}, expected one of {UNITS}")
    conf = man.get("confidence")
    return ClipInfo(
        root=mpath.parent, width=int(man["width"]), height=int(man["height"]), num_frames=len(frames),
        fps=float(man.get("fps", 24.0)), frames=frames,
        camera_static=bool(man.get("camera_static", False)), scene_static=bool(man.get("scene_static", True)),
        consistent_depth=bool(man.get("consistent_depth", False)), units=units, producer=dict(man.get("producer") or {}), content_id=man.get("content_id"),
        confidence=conf if isinstance(conf, list) else None, manifest=man,
    )


def read_cameras(info: ClipInfo) -> tuple[np.ndarray, np.ndarray]:
    """(K (N,3,3), c2w (N,4,4)) of a clip, checked against its manifest."""
    cam_path = info.root / info.manifest.get("cameras", CAMERAS)
    width, height, K, c2w = io.read_cameras(cam_path)
    if len(K) != info.num_frames:
        raise io.DataError(f"{cam_path}: {len(K)} cameras but {manifest_path(info.root)} lists {info.num_frames} frames")
    if (width, height) != (info.width, info.height):
        raise io.DataError(f"{cam_path}: {width}x{height} but the manifest says {info.width}x{info.height}")
    return K, c2w


def read_clip(clip: str | os.PathLike) -> tuple[list[FrameView], ClipInfo]:
    """Load and validate every frame of a clip; returns (views, info). Buffers shared by several
    frames are read once."""
    info = read_info(clip)
    K, c2w = read_cameras(info)
    cache: dict[str, io.Buffers] = {}
    views = []
    for i, rel in enumerate(info.frames):
        path = info.root / rel
        if rel not in cache:
            b = io.read_buffers(path)
            if b.shape != (info.height, info.width):
                raise io.DataError(f"{path}: buffer is {b.shape[1]}x{b.shape[0]} but the clip is "
                                   f"{info.width}x{info.height}; rerun the stage that wrote it")
            cache[rel] = b
        views.append(FrameView(buffers=cache[rel], K=K[i], c2w=c2w[i], key=str(path)))
    return views, info


def identity(clip: str | os.PathLike) -> dict:
    """What a consumer's outputs depend on: the manifest (content id included) and the cameras."""
    info = read_info(clip)
    cams = info.root / info.manifest.get("cameras", CAMERAS)
    return {"manifest": info.manifest, "cameras": io.read_json(cams) if cams.is_file() else None}


def write_skipped(clip_dir: str | os.PathLike, reason: str, extra: dict | None = None) -> dict:
    """Mark a clip that its producer could not make (e.g. structure from motion failed): a manifest
    with ``skipped`` and the reason, no buffers. Consumers check :func:`is_skipped` and leave it out."""
    man = {"format": FORMAT, "skipped": str(reason), **(extra or {})}
    io.write_json(Path(clip_dir) / MANIFEST, man)
    return man


def is_skipped(clip: str | os.PathLike) -> str | None:
    """The reason a clip was skipped, or None for a real clip."""
    man = io.read_json(manifest_path(clip))
    return man.get("skipped") if isinstance(man, dict) else None
