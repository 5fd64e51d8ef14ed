"""DiffusionRenderer (inverse renderer) adapter: its 8-bit G-buffer images -> the io.Buffers contract.

Native format (verified in the public code where stated)
-------------------------------------------------------
Read in github.com/nv-tlabs/cosmos1-diffusion-renderer (commit a164852) and the original
github.com/nv-tlabs/diffusion-renderer (SVD-based, commit 8fcf005):

* **Files** (cosmos1, ``cosmos_predict1/diffusion/inference/inference_inverse_renderer.py``):
  ``{video_save_folder}/gbuffer_frames/{clip_name}/{chunk:04d}.{index:04d}.{pass}.jpg`` with
  ``pass`` in basecolor, normal, depth, roughness, metallic (the default ``--inference_passes``);
  one image per pass per frame. Single frames are written by ``cosmos_predict1/utils/io.py``
  ``save_image_or_video`` as **JPEG, quality 85** (lossy, chroma-subsampled). The original SVD
  repository (``inference_svd_rgbx.py``) writes ``{save_dir}/{clip_name}/{chunk:04d}.{index:04d}.{pass}.png``
  (plus ``.rgb.png``). :func:`find_frames` accepts both layouts and both extensions.
* **Clips and chunks** (``diffusion_renderer_utils/dataset_inference.py``, ``inference_utils.py``):
  with ``--group_mode folder`` a clip is a sub-folder of ``--dataset_path`` (``clip_name`` is that
  folder, so the frames must sit one level below the dataset path); frames are sorted by name and
  split into chunks of ``--num_video_frames`` (default 57) starting every
  ``num_video_frames - overlap_n_frames`` frames; the last chunk is padded by repeating its last
  frame; ``--chunk_mode first`` (the default!) keeps only the first chunk, so videos longer than one
  chunk need ``--chunk_mode all``. Frame ``index`` of chunk ``c`` is source frame
  ``c * (num_video_frames - overlap) + index``; with overlap, the earliest chunk's estimate is used.
* **Geometry of the image** (same files): frames are resized with torchvision ``Resize`` (bilinear,
  half-pixel) to ``--resize_resolution`` (default: the output size ``--height`` x ``--width``,
  704 x 1280, i.e. a stretch of the whole frame), then ``CenterCrop`` to the output size
  (offset ``round((resized - out) / 2)``). The SVD version stretches the whole frame to a multiple
  of 64 (``resize_upscale_without_padding``), no crop. :func:`pixel_map` models both. A 3:2 video
  (720 x 480) stretched to 16:9 (1280 x 704) is magnified 1.21 times more horizontally than
  vertically; the network then sees a horizontally stretched scene, and its normals are corrected
  for that (:func:`unstretch`; config ``recon.paper_stack.dr_unstretch_normals``).
* **Values** (``diffusion_renderer_pipeline.py``): the decoded 3-channel output x in [-1, 1] is
  stored as ``uint8((x + 1).clamp(0, 2) / 2 * 255)`` -- a *truncation*, so the unbiased decode is
  ``x = 2 (v + 0.5) / 255 - 1`` (``lsb_offset=0.5``; use 0 for the SVD version, whose diffusers
  PIL conversion rounds).
* **roughness / metallic** are 3-channel images like every pass (the VAE decodes RGB); the public
  code has no packing step, so the scalar is taken as the **mean of the three channels** (robust to
  JPEG chroma noise). **depth** is a relative map in [0, 1]; whether near is dark or bright is not
  stated in the code (``rendering_utils.normalize_depth`` min-max normalises z-depth with background
  1.0, which suggests near = dark); it is returned as decoded, for checking only.

NOT verifiable from the public inference code (training-data conventions are not released):
* **basecolor encoding**: default ``"srgb"`` (decoded with the sRGB curve). Evidence: every linear
  quantity the released code feeds to the VAE is display-encoded first (HDR maps via ``rgb2srgb``,
  EXR input frames via ``** (1 / 2.2)``) and outputs are saved as ordinary 8-bit images; the paper
  does not state it. ``"linear"`` is available.
* **normal axes**: default ``"opengl"`` = camera space, x right, y up, z towards the viewer. Evidence:
  the forward renderer encodes lighting in the same camera space with OpenGL axes (``latlong_vec``,
  ``envmap_vec``; poses read from NeRF-style ``transform_matrix``), and the chrome-ball helper
  ``get_ideal_ball`` uses y up, z towards the viewer. ``"opencv"`` is available.

Our conventions (output)
------------------------
albedo: linear base colour in [0, 1]; roughness, metallic in [0, 1]; normal: **world** unit vectors
(OpenGL camera -> OpenCV ``(x, -y, -z)`` -> world with the frame's c2w from MegaSAM); depth_rel:
the decoded relative depth in [0, 1] (no unit); valid: where the normal decodes to a usable vector
and the sample lies inside the DiffusionRenderer image.
"""

from __future__ import annotations

import os
import re
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lightcrafter.io import DataError, display_to_linear
from lightcrafter.recon.paper_stack.megasam import PixelMap

PASSES = ("basecolor", "normal", "depth", "roughness", "metallic")
SCALAR_PASSES = ("depth", "roughness", "metallic")
EXTENSIONS = ("jpg", "jpeg", "png")
_NAME = re.compile(r"^(\d+)\.(\d+)\.(" + "|".join(PASSES) + r")\.(" + "|".join(EXTENSIONS) + r")$", re.IGNORECASE)
DEFAULT_LSB_OFFSET = 0.5     # cosmos1 truncates when converting to uint8
MIN_NORMAL_LENGTH = 0.3      # decoded normals shorter than this are no estimate (flat grey)


# ----------------------------------------------------------------------------- files
def find_frames(root: str | os.PathLike, num_frames: int, overlap_frames: int = 0,
                passes=PASSES) -> dict[str, list[Path]]:
    """Per pass, the image serving each of the video's ``num_frames`` frames (module docstring).

    Searches ``root`` recursively for ``{chunk}.{index}.{pass}.{jpg|png}``; they must all lie in one
    folder (one clip). Chunk length is read from the files; ``overlap_frames`` is the run's
    ``--overlap_n_frames``. A missing pass or frame raises DataError naming ``root``.
    """
    root = Path(root)
    if not root.is_dir():
        raise DataError(f"{root}: DiffusionRenderer output folder not found; check its command's output")
    found: dict[Path, list[tuple[int, int, str, Path]]] = defaultdict(list)
    for p in root.rglob("*"):
        m = _NAME.match(p.name)
        if m and p.is_file():
            found[p.parent].append((int(m.group(1)), int(m.group(2)), m.group(3).lower(), p))
    if not found:
        return {}
    if len(found) > 1:
        names = ", ".join(str(d.relative_to(root)) for d in sorted(found)[:3])
        raise DataError(f"{root}: G-buffer images of {len(found)} clips ({names}); "
                        f"give the renderer a dataset folder holding this clip only")
    entries = next(iter(found.values()))
    chunk0 = {i for c, i, _, _ in entries if c == 0}
    if not chunk0:
        raise DataError(f"{root}: no chunk 0000 G-buffer images; rerun the inverse renderer")
    chunk_len = max(chunk0) + 1
    step = chunk_len - int(overlap_frames)
    if step <= 0:
        raise DataError(f"{root}: chunks of {chunk_len} frames with overlap {overlap_frames}; set the overlap the renderer ran with")
    table: dict[str, dict[int, tuple[int, Path]]] = defaultdict(dict)
    for c, i, name, p in entries:
        if i >= chunk_len:
            raise DataError(f"{p}: frame index {i} beyond chunk length {chunk_len} (from chunk 0); mixed runs in one folder?")
        g = c * step + i
        if g < num_frames and (g not in table[name] or table[name][g][0] > c):
            table[name][g] = (c, p)
    out = {}
    for name in passes:
        have = table.get(name, {})
        missing = [g for g in range(num_frames) if g not in have]
        if missing:
            hint = "run it with --chunk_mode all" if missing[0] >= chunk_len else "rerun it with every pass"
            raise DataError(f"{root}: no {name} image for {len(missing)} of {num_frames} frames (first: frame {missing[0]}); {hint}")
        out[name] = [have[g][1] for g in range(num_frames)]
    return out


def read_image(path: str | os.PathLike, name: str) -> np.ndarray:
    """An 8-bit pass image as uint8 (H, W, 3); scalar passes may also be single-channel."""
    import imageio.v3 as iio

    path = Path(path)
    try:
        img = np.asarray(iio.imread(path))
    except Exception as exc:
        raise DataError(f"{path}: unreadable image ({type(exc).__name__}); rerun the inverse renderer") from exc
    if img.dtype != np.uint8:
        raise DataError(f"{path}: {name} must be 8-bit, got {img.dtype}; save the renderer's uint8 output as is")
    if img.ndim == 2 and name in SCALAR_PASSES:
        img = np.repeat(img[..., None], 3, axis=-1)
    if img.ndim != 3 or img.shape[2] != 3:
        raise DataError(f"{path}: {name} must be a 3-channel (H, W, 3) image, got shape {img.shape}")
    return img


# ----------------------------------------------------------------------------- geometry
def pixel_map(src_w: int, src_h: int, out_w: int, out_h: int, resize=None) -> PixelMap:
    """Where the renderer's (out_w x out_h) image samples a ``src_w`` x ``src_h`` video frame.

    ``resize``: None = the whole frame stretched to the output (cosmos1 default, SVD version);
    (h, w) = cosmos1 ``--resize_resolution h w`` then a centre crop; an int s = torchvision's
    shorter-side resize to s (``--resize_resolution s``) then a centre crop.
    """
    if resize is None:
        rw, rh = out_w, out_h
    elif isinstance(resize, (int, np.integer)):
        s = int(resize)
        if src_h <= src_w:
            rh, rw = s, int(s * src_w / src_h)
        else:
            rw, rh = s, int(s * src_h / src_w)
    else:
        rh, rw = (int(v) for v in resize)
    if rw < out_w or rh < out_h:
        raise ValueError(f"resize {rh}x{rw} is smaller than the renderer's output {out_h}x{out_w}")
    left, top = int(round((rw - out_w) / 2.0)), int(round((rh - out_h) / 2.0))
    return PixelMap.resize_crop(src_w, src_h, rw, rh, left=left, top=top, out_w=out_w, out_h=out_h)


def bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sample (H, W, C) at pixel coordinates (x, y) (centres at integers), edge-clamped; also returns
    whether each sample lies within half a pixel of the image."""
    h, w = img.shape[:2]
    inside = (x >= -0.5) & (x <= w - 0.5) & (y >= -0.5) & (y <= h - 0.5)
    xc, yc = np.clip(x, 0.0, w - 1.0), np.clip(y, 0.0, h - 1.0)
    x0, y0 = np.floor(xc).astype(np.int64), np.floor(yc).astype(np.int64)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (xc - x0)[..., None], (yc - y0)[..., None]
    top = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
    bot = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
    return top * (1 - fy) + bot * fy, inside


# ----------------------------------------------------------------------------- decoding
def decode_signed(v: np.ndarray, lsb_offset: float = DEFAULT_LSB_OFFSET) -> np.ndarray:
    """uint8 -> the model's value in [-1, 1]: ``2 (v + lsb_offset) / 255 - 1``."""
    return np.clip(2.0 * (np.asarray(v, np.float64) + lsb_offset) / 255.0 - 1.0, -1.0, 1.0)


def normals_to_opencv(n: np.ndarray, axes: str = "opengl") -> np.ndarray:
    """Camera-space normals in the renderer's axes -> OpenCV camera axes (x right, y down, z forward)."""
    if axes == "opengl":
        return n * np.array([1.0, -1.0, -1.0])
    if axes == "opencv":
        return n
    raise ValueError(f"normal_axes={axes!r}: use 'opengl' or 'opencv'")


def stretch_ratio(source: PixelMap) -> float:
    """Horizontal over vertical magnification of the renderer's image relative to the video
    (1 = aspect kept; 1280x704 from 720x480, cosmos1's default stretch: 1.212)."""
    return float(source.sx / source.sy)


def unstretch(n_cv: np.ndarray, source: PixelMap) -> np.ndarray:
    """Camera-space normals (OpenCV axes) estimated on a stretched image -> normals of the video's scene.

    A network shown a frame magnified ``a = sx / sy`` times more horizontally than vertically sees
    the scene stretched along camera x by ``a`` (X' = a X, same Y and Z); normals transform with the
    inverse transpose, n' ~ diag(1/a, 1, 1) n, so the video's normals are n ~ diag(a, 1, 1) n'
    (renormalised by the caller). Identity when the aspect is kept.
    """
    a = stretch_ratio(source)
    if abs(a - 1.0) < 1e-9:
        return n_cv
    return n_cv * np.array([a, 1.0, 1.0])


@dataclass
class GBufferFrame:
    """One frame in our conventions (module docstring): albedo (H, W, 3) linear, roughness and
    metallic (H, W) in [0, 1], normal (H, W, 3) world unit (zeros where invalid), depth_rel (H, W)
    in [0, 1], valid (H, W) bool."""

    albedo: np.ndarray
    roughness: np.ndarray
    metallic: np.ndarray
    normal: np.ndarray
    depth_rel: np.ndarray
    valid: np.ndarray


def decode_frame(images: dict[str, np.ndarray], c2w: np.ndarray, *, source: PixelMap | None = None,
                 target: PixelMap | None = None, lsb_offset: float = DEFAULT_LSB_OFFSET,
                 basecolor_encoding: str = "srgb", normal_axes: str = "opengl",
                 min_normal_length: float = MIN_NORMAL_LENGTH, unstretch_normals: bool = True) -> GBufferFrame:
    """Decode one frame's uint8 pass images (dict pass -> (H, W, 3)) to our conventions.

    ``c2w`` (4, 4): the frame's OpenCV camera-to-world (from MegaSAM, our world). With ``source``
    (the renderer image's :class:`PixelMap`) and ``target`` (the clip grid's, e.g. MegaSAM's), the
    passes are resampled bilinearly onto the target grid (normals renormalised after sampling) and,
    with ``unstretch_normals``, corrected for the renderer's anisotropic stretch (:func:`unstretch`).
    """
    if basecolor_encoding not in ("srgb", "linear"):
        raise ValueError(f"basecolor_encoding={basecolor_encoding!r}: use 'srgb' or 'linear'")
    shapes = {k: v.shape for k, v in images.items()}
    if len(set(shapes.values())) != 1:
        raise DataError(f"pass images of one frame differ in size: {shapes}; rerun the inverse renderer")
    stack = np.concatenate([decode_signed(images[k], lsb_offset) for k in PASSES], axis=-1)  # (H, W, 15)
    if source is not None and target is not None:
        x, y = source.coords_from(target)
        stack, inside = bilinear(stack, x, y)
    else:
        inside = np.ones(stack.shape[:2], bool)
    base01 = np.clip((stack[..., 0:3] + 1.0) / 2.0, 0.0, 1.0)
    albedo = display_to_linear(base01) if basecolor_encoding == "srgb" else base01.astype(np.float32)
    n = normals_to_opencv(stack[..., 3:6], normal_axes)
    if source is not None and unstretch_normals:
        n = unstretch(n, source)
    length = np.linalg.norm(n, axis=-1)
    valid = inside & (length >= min_normal_length)
    n_cam = n / np.maximum(length, 1e-12)[..., None]
    n_world = n_cam @ np.asarray(c2w, np.float64)[:3, :3].T
    n_world = np.where(valid[..., None], n_world, 0.0)
    depth_rel = ((stack[..., 6:9].mean(axis=-1) + 1.0) / 2.0)
    rough = np.clip((stack[..., 9:12].mean(axis=-1) + 1.0) / 2.0, 0.0, 1.0)
    metal = np.clip((stack[..., 12:15].mean(axis=-1) + 1.0) / 2.0, 0.0, 1.0)
    return GBufferFrame(albedo=np.asarray(albedo, np.float32), roughness=rough.astype(np.float32),
                        metallic=metal.astype(np.float32), normal=n_world.astype(np.float32),
                        depth_rel=depth_rel.astype(np.float32), valid=valid)


def read_frame(paths: dict[str, Path], c2w: np.ndarray, src_size: tuple[int, int] | None = None,
               target: PixelMap | None = None, resize=None, **decode_kw) -> GBufferFrame:
    """Read and decode frame ``paths`` (pass -> image file). With ``src_size`` = (width, height) of
    the source video and ``target`` (the clip grid's PixelMap) the passes are resampled onto it,
    the renderer's geometry given by ``resize`` (see :func:`pixel_map`)."""
    images = {k: read_image(paths[k], k) for k in PASSES}
    h, w = images["basecolor"].shape[:2]
    for k, im in images.items():
        if im.shape[:2] != (h, w):
            raise DataError(f"{paths[k]}: {k} is {im.shape[1]}x{im.shape[0]} but basecolor is {w}x{h}; rerun the inverse renderer")
    source = pixel_map(src_size[0], src_size[1], w, h, resize) if (src_size is not None and target is not None) else None
    return decode_frame(images, c2w, source=source, target=target if source is not None else None, **decode_kw)

