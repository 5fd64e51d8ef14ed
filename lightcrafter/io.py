"""File formats shared by every stage (the data contracts of docs/architecture.md).

Conventions
-----------
* World frame: right-handed, Z up (Blender's), metres.
* Camera: OpenCV (x right, y down, z forward). ``K`` is 3x3 in pixels, ``c2w`` is the 4x4
  camera-to-world matrix, both per frame in ``cameras.json``.
* Buffers: one EXR per frame with the channels in :data:`BUFFER_CHANNELS`:
  ``depth`` is z-depth along the optical axis in metres (invalid = +inf, mask = 0),
  ``normal.{X,Y,Z}`` world-space unit normals, ``albedo.{R,G,B}`` linear base colour,
  ``roughness`` and ``metallic`` in [0, 1], ``mask`` in {0, 1} (1 = surface, 0 = background).
* Radiance frames: linear HDR RGB (scene-referred, no view transform), channels R, G, B.
* Storage precision (all EXRs ZIP-compressed, lossless): video frames (ground truth, proxies, ingested
  and refined frames) are **half float**: 11 significant bits (0.05 %, far below an 8-bit display
  step) and a range to 65504, beyond which a frame's radiance is clipped (:data:`HALF_MAX`; only pixels
  that see an emitter directly, already white on display). Buffers are half float except ``depth``,
  which stays **float32**: half's relative step at 10 m is 5 mm, enough to move a shadow ray's origin
  through its own surface, and Phi's arbitrary-unit depths can exceed 65504. Environment maps stay
  float32 (a sun texel of a PolyHaven HDRI exceeds 65504), as do confidences and the paper stack's
  inputs.
* Display frames: produced only by :func:`linear_to_display` (exposure, then the sRGB
  encoding curve of IEC 61966-2-1, checked against colour-science's, clipped to [0, 1]); the same
  transform is used for proxies and targets.

Every writer here is atomic: data goes to a temporary name in the destination folder and is
renamed into place only when complete, so a killed job never leaves a file a rerun would trust.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from .errors import DataError  # noqa: F401  (defined there, so that scripts/_cli.py imports nothing else)

BUFFER_CHANNELS = (
    "depth",
    "normal.X",
    "normal.Y",
    "normal.Z",
    "albedo.R",
    "albedo.G",
    "albedo.B",
    "roughness",
    "metallic",
    "mask",
)
RGB_CHANNELS = ("R", "G", "B")


# ----------------------------------------------------------------------------- atomic writes
@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` if the block succeeds.

    The temporary name keeps the suffix so that format-sniffing writers (EXR, MP4) work.
    On any exception the temporary file is removed and ``path`` is left untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp_path, 0o666 & ~umask)
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def write_text(path: str | os.PathLike, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def write_json(path: str | os.PathLike, data) -> None:
    """Write JSON atomically with sorted keys, so equal data gives byte-identical files."""
    write_text(path, json.dumps(data, indent=2, sort_keys=True) + "\n")


def read_json(path: str | os.PathLike):
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: file not found; run the stage that produces it first")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise DataError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno}); delete it and rerun") from exc


def write_jsonl(path: str | os.PathLike, records) -> None:
    text = "".join(json.dumps(r, sort_keys=True) + "\n" for r in records)
    write_text(path, text)


def read_jsonl(path: str | os.PathLike) -> list[dict]:
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: file not found; run the stage that produces it first")
    out = []
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError as exc:
            raise DataError(f"{path}:{lineno}: not valid JSON ({exc.msg}); delete it and rerun") from exc
    return out


def fingerprint(obj) -> str:
    """Short sha256 of JSON-serialisable data (sorted keys): equal inputs, equal fingerprint."""
    import hashlib

    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:16]


# The code that makes a product is part of what the product comes from. An entry point (scripts/_cli.py) sets
# this to its code fingerprint (lightcrafter.codeversion); frame-folder stamps, clip content ids and the resume
# fingerprints of fits and training runs fold it in (:func:`product_fingerprint`), so a job that reruns after a
# code change never keeps frames, maps or checkpoints the old code made. Empty outside entry points (library
# calls, tests, benchmarks): there, products of the same inputs are reused as before.
CODE_VERSION = ""


def product_fingerprint(inputs) -> str:
    """:func:`fingerprint` of ``inputs`` and of the running code (:data:`CODE_VERSION`, when set): the identity
    of a product that is resumed or reused (frame folders, clips, fits, checkpoints)."""
    return fingerprint({"inputs": inputs, "code": CODE_VERSION}) if CODE_VERSION else fingerprint(inputs)


def claim_frame_dir(frame_dir: str | os.PathLike, inputs) -> int:
    """Drop frames in ``frame_dir`` that were not rendered from ``inputs``; return how many went.

    Frame folders keep complete frames across a killed run (resume), but a rerun with other
    inputs (scene spec, settings, upstream buffers) must not reuse them. The folder's
    ``.inputs.json`` (written by :func:`stamp_frame_dir` before the first frame) records the
    fingerprint of what its frames come from, the code that renders them included
    (:func:`product_fingerprint`); when it differs or is missing, every ``*.exr``
    in the folder is deleted. Temporaries a killed writer left behind (``.*.tmp*``, see
    :func:`atomic_path`) are always deleted: they were never renamed into place, so never trusted.
    """
    frame_dir = Path(frame_dir)
    for debris in frame_dir.glob(".*.tmp*"):
        debris.unlink(missing_ok=True)
    stamp = frame_dir / ".inputs.json"
    have = None
    if stamp.is_file():
        try:
            have = json.loads(stamp.read_text()).get("fingerprint")
        except (json.JSONDecodeError, AttributeError):
            have = None
    removed = 0
    if have != product_fingerprint(inputs):
        for f in frame_dir.glob("[!.]*.exr"):
            f.unlink()
            removed += 1
    return removed


def stamp_frame_dir(frame_dir: str | os.PathLike, inputs) -> None:
    """Record that frames in ``frame_dir`` are rendered from ``inputs`` (call before writing any)."""
    write_json(Path(frame_dir) / ".inputs.json", {"fingerprint": product_fingerprint(inputs)})


# ----------------------------------------------------------------------------- EXR
HALF_MAX = 65504.0   # the largest finite half-float value
FLOAT32_BUFFER_CHANNELS = ("depth",)   # buffer channels stored as float32 (module docstring); the rest half


def write_exr(path: str | os.PathLike, channels: dict[str, np.ndarray], half: bool | tuple[str, ...] = False) -> None:
    """Write single-part scanline EXR with one float channel per key (H x W arrays), atomically.

    ``half``: True = every channel half float, a tuple = those channels half, the others float32.
    Finite values beyond the half range are clipped to +-HALF_MAX (inf and NaN are kept).
    """
    import OpenEXR

    arrays = {}
    shape = None
    for name, arr in channels.items():
        as_half = half is True or (not isinstance(half, bool) and name in half)
        if as_half:
            a = np.asarray(arr, dtype=np.float32)
            arr = np.where(np.isfinite(a), np.clip(a, -HALF_MAX, HALF_MAX), a)
        arr = np.ascontiguousarray(arr, dtype=np.float16 if as_half else np.float32)
        if arr.ndim != 2:
            raise ValueError(f"{path}: channel {name!r} must be 2-D (H, W), got shape {arr.shape}")
        if shape is not None and arr.shape != shape:
            raise ValueError(f"{path}: channel {name!r} has shape {arr.shape}, expected {shape}")
        shape = arr.shape
        arrays[name] = arr
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_path(path) as tmp:
        with OpenEXR.File(header, arrays) as f:
            f.write(str(tmp))


def read_exr(path: str | os.PathLike, required: tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
    """Read every channel of a single-part EXR as float32 (H, W) arrays.

    ``required`` names channels that must be present; a missing one raises :class:`DataError`.
    """
    import OpenEXR

    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: EXR not found; run the stage that produces it first")
    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            chans = {name: np.asarray(ch.pixels, dtype=np.float32) for name, ch in f.channels().items()}
    except Exception as exc:  # OpenEXR raises plain RuntimeError/Exception on corrupt files
        raise DataError(f"{path}: unreadable EXR ({exc}); delete it and rerun the stage that wrote it") from exc
    if required:
        missing = [c for c in required if c not in chans]
        if missing:
            raise DataError(f"{path}: missing EXR channel(s) {missing}; expected {list(required)}")
    return chans


def write_rgb_exr(path: str | os.PathLike, rgb: np.ndarray, half: bool = False) -> None:
    """Write linear HDR RGB (H, W, 3) as channels R, G, B (float32; half float with ``half``)."""
    rgb = np.asarray(rgb, dtype=np.float32)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"{path}: expected (H, W, 3) linear RGB, got {rgb.shape}")
    write_exr(path, {c: rgb[..., i] for i, c in enumerate(RGB_CHANNELS)}, half=half)


def write_frame_exr(path: str | os.PathLike, rgb: np.ndarray) -> None:
    """One video frame (linear RGB, H x W x 3) in the frames' storage precision: half float, values
    beyond HALF_MAX clipped (module docstring)."""
    write_rgb_exr(path, rgb, half=True)


def read_rgb_exr(path: str | os.PathLike, allow_nonfinite: bool = False) -> np.ndarray:
    """Read linear HDR RGB (H, W, 3); NaN/Inf is an error naming the file unless allowed."""
    ch = read_exr(path, RGB_CHANNELS)
    rgb = np.stack([ch[c] for c in RGB_CHANNELS], axis=-1)
    if not allow_nonfinite and not np.isfinite(rgb).all():
        bad = int((~np.isfinite(rgb)).any(axis=-1).sum())
        raise DataError(f"{path}: {bad} pixel(s) with NaN/Inf radiance; re-render this frame")
    return rgb


@dataclass
class Buffers:
    """Per-frame G-buffers in the shared contract (see module docstring).

    depth: (H, W) z-depth in metres, +inf where invalid.
    normal: (H, W, 3) world-space unit normals (zeros where invalid).
    albedo: (H, W, 3) linear base colour in [0, 1].
    roughness, metallic: (H, W) in [0, 1].
    mask: (H, W) 1 on surfaces, 0 on background / invalid.
    """

    depth: np.ndarray
    normal: np.ndarray
    albedo: np.ndarray
    roughness: np.ndarray
    metallic: np.ndarray
    mask: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.depth.shape)


def write_buffers(path: str | os.PathLike, b: Buffers) -> None:
    write_exr(
        path,
        {
            "depth": b.depth,
            "normal.X": b.normal[..., 0],
            "normal.Y": b.normal[..., 1],
            "normal.Z": b.normal[..., 2],
            "albedo.R": b.albedo[..., 0],
            "albedo.G": b.albedo[..., 1],
            "albedo.B": b.albedo[..., 2],
            "roughness": b.roughness,
            "metallic": b.metallic,
            "mask": b.mask,
        },
        half=tuple(c for c in BUFFER_CHANNELS if c not in FLOAT32_BUFFER_CHANNELS),
    )


def read_buffers(path: str | os.PathLike) -> Buffers:
    """Read a buffer EXR. NaN anywhere becomes invalid (mask 0, depth inf), never propagated.

    Out-of-range materials are clipped to [0, 1]; normals are re-normalised.
    """
    ch = read_exr(path, BUFFER_CHANNELS)
    depth = ch["depth"].copy()
    normal = np.stack([ch["normal.X"], ch["normal.Y"], ch["normal.Z"]], axis=-1)
    albedo = np.stack([ch["albedo.R"], ch["albedo.G"], ch["albedo.B"]], axis=-1)
    rough, metal, mask = ch["roughness"], ch["metallic"], ch["mask"]
    invalid = ~np.isfinite(depth) | (depth <= 0) | (mask < 0.5)
    for arr in (normal, albedo):
        invalid |= ~np.isfinite(arr).all(axis=-1)
    invalid |= ~np.isfinite(rough) | ~np.isfinite(metal)
    nlen = np.linalg.norm(np.nan_to_num(normal), axis=-1)
    invalid |= nlen < 1e-6
    depth[invalid] = np.inf
    normal = np.where(invalid[..., None], 0.0, np.nan_to_num(normal) / np.maximum(nlen, 1e-12)[..., None])
    albedo = np.clip(np.nan_to_num(albedo), 0.0, 1.0)
    rough = np.clip(np.nan_to_num(rough, nan=0.5), 0.0, 1.0)
    metal = np.clip(np.nan_to_num(metal), 0.0, 1.0)
    return Buffers(
        depth=depth.astype(np.float32),
        normal=normal.astype(np.float32),
        albedo=albedo.astype(np.float32),
        roughness=rough.astype(np.float32),
        metallic=metal.astype(np.float32),
        mask=(~invalid).astype(np.float32),
    )


# ----------------------------------------------------------------------------- cameras
def write_cameras(path: str | os.PathLike, width: int, height: int, Ks, c2ws) -> None:
    """cameras.json: OpenCV convention, K in pixels, c2w camera-to-world (world Z up, metres)."""
    frames = [
        {"index": i, "K": np.asarray(K, float).round(9).tolist(), "c2w": np.asarray(c, float).round(9).tolist()}
        for i, (K, c) in enumerate(zip(Ks, c2ws))
    ]
    write_json(path, {"convention": "opencv", "width": int(width), "height": int(height), "frames": frames})


def read_cameras(path: str | os.PathLike) -> tuple[int, int, np.ndarray, np.ndarray]:
    """Return (width, height, K[N,3,3], c2w[N,4,4])."""
    data = read_json(path)
    if data.get("convention") != "opencv":
        raise DataError(f"{path}: camera convention {data.get('convention')!r}, expected 'opencv'")
    K = np.array([f["K"] for f in data["frames"]], dtype=np.float64)
    c2w = np.array([f["c2w"] for f in data["frames"]], dtype=np.float64)
    if K.shape[1:] != (3, 3) or c2w.shape[1:] != (4, 4) or len(K) == 0:
        raise DataError(f"{path}: expected N>0 frames of 3x3 K and 4x4 c2w, got {K.shape} and {c2w.shape}")
    return int(data["width"]), int(data["height"]), K, c2w


# ----------------------------------------------------------------------------- display
#: IEC 61966-2-1 sRGB encoding: linear segment below this linear value, power 1 / 2.4 above
SRGB_LINEAR_KNEE = 0.0031308
#: the same knee on display values (0.04045 in the standard's rounding; colour-science uses the exact value)
SRGB_DISPLAY_KNEE = 12.92 * SRGB_LINEAR_KNEE


def srgb_encode(x: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB encoding of linear values in [0, 1] (float64 in, float64 out).

    Written out rather than taken from colour-science (whose ``cctf_encoding(x, function="sRGB")`` it equals to
    1e-12, tests/test_io.py) because importing ``colour`` costs 1.7 s, and nearly every job of a run writes a
    display frame: that import alone was about a tenth of the default run's job-seconds.
    """
    power = 1.055 * np.power(np.maximum(x, SRGB_LINEAR_KNEE), 1 / 2.4) - 0.055
    return np.where(x <= SRGB_LINEAR_KNEE, 12.92 * x, power)


def srgb_decode(v: np.ndarray) -> np.ndarray:
    """Inverse of :func:`srgb_encode` on [0, 1] (colour-science's ``cctf_decoding(v, function="sRGB")``)."""
    power = np.power((np.maximum(v, SRGB_DISPLAY_KNEE) + 0.055) / 1.055, 2.4)
    return np.where(v <= SRGB_DISPLAY_KNEE, v / 12.92, power)


def linear_to_display(rgb_linear: np.ndarray, exposure_ev: float = 0.0) -> np.ndarray:
    """The one display transform: scale by 2**exposure_ev, sRGB-encode (IEC 61966-2-1), clip.

    Input is linear scene-referred RGB; output is display-referred float in [0, 1].
    NaN maps to 0, +inf to 1.
    """
    x = np.nan_to_num(np.asarray(rgb_linear, dtype=np.float64), nan=0.0, posinf=1.0, neginf=0.0)
    x = np.clip(x * (2.0**exposure_ev), 0.0, 1.0)
    return np.clip(srgb_encode(x), 0.0, 1.0).astype(np.float32)


def display_to_linear(rgb_display: np.ndarray, exposure_ev: float = 0.0) -> np.ndarray:
    """Inverse of :func:`linear_to_display` on [0, 1] (clipped highlights are not recovered)."""
    x = np.clip(np.asarray(rgb_display, dtype=np.float64), 0.0, 1.0)
    return (srgb_decode(x) / (2.0**exposure_ev)).astype(np.float32)


def to_uint8(display: np.ndarray) -> np.ndarray:
    return np.clip(np.round(np.asarray(display) * 255.0), 0, 255).astype(np.uint8)


# ----------------------------------------------------------------------------- video
def write_video(path: str | os.PathLike, frames_uint8, fps: float = 24.0) -> None:
    """Encode display frames (N, H, W, 3) uint8 as H.264 MP4 (yuv420p), atomically.

    Odd sizes are padded by one edge pixel to satisfy yuv420p.
    """
    frames = np.asarray(frames_uint8)
    if frames.ndim != 4 or frames.shape[-1] != 3 or len(frames) == 0:
        raise ValueError(f"{path}: expected (N>0, H, W, 3) frames, got {frames.shape}")
    ph, pw = frames.shape[1] % 2, frames.shape[2] % 2
    if ph or pw:
        frames = np.pad(frames, ((0, 0), (0, ph), (0, pw), (0, 0)), mode="edge")
    with atomic_path(path) as tmp:
        _ffmpeg_write(tmp, frames, fps)


def _ffmpeg_write(path: Path, frames: np.ndarray, fps: float) -> None:
    import imageio_ffmpeg

    n, h, w, _ = frames.shape
    writer = imageio_ffmpeg.write_frames(
        str(path), (w, h), fps=fps, codec="libx264", pix_fmt_out="yuv420p", quality=8,
        macro_block_size=1, ffmpeg_log_level="error", output_params=["-f", "mp4"],
    )
    writer.send(None)
    for f in frames:
        writer.send(np.ascontiguousarray(f))
    writer.close()


def read_video(path: str | os.PathLike, max_frames: int | None = None) -> tuple[np.ndarray, float]:
    """Decode a video to (N, H, W, 3) uint8 display frames and its fps.

    Empty or undecodable videos raise :class:`DataError` naming the file.
    """
    import imageio_ffmpeg

    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: video not found; check the path in config")
    if path.stat().st_size == 0:
        raise DataError(f"{path}: video file is empty; replace it or remove it from config")
    try:
        reader = imageio_ffmpeg.read_frames(str(path), pix_fmt="rgb24")
        meta = reader.__next__()
        w, h = meta["size"]
        frames = []
        for buf in reader:
            frames.append(np.frombuffer(buf, dtype=np.uint8).reshape(h, w, 3))
            if max_frames is not None and len(frames) >= max_frames:
                reader.close()
                break
    except Exception as exc:
        raise DataError(f"{path}: cannot decode video ({str(exc).splitlines()[0]}); re-encode it as H.264 MP4") from exc
    if not frames:
        raise DataError(f"{path}: video has no frames; replace it or remove it from config")
    return np.stack(frames), float(meta.get("fps", 24.0))


def side_by_side_video(folders: list[Path], out: Path, fps: float = 12.0, scale: int = 2) -> Path | None:
    """An mp4 of the frame folders side by side (linear EXR frames -> display), each upscaled ``scale`` x."""
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
