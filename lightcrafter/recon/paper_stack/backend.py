"""The paper-stack backend of Phi: run MegaSAM, DiffusionRenderer and DiffusionLight by configured
shell commands, check what they wrote, and assemble a clip (lightcrafter.clip) from it.

The tools need GPUs and weights and are installed by the user (cluster); this module only runs the
commands the config gives and converts their native outputs with the adapters of this package.

Command templates
-----------------
``commands`` maps each tool (``megasam``, ``diffusion_renderer``, ``diffusion_light``) to a shell
command line (run by bash, working directory unchanged, environment inherited) in which these
placeholders are replaced by shell-quoted values (write literal braces as ``{{`` and ``}}``):

=================  ===============================================================================
``{frames}``       folder of the video's frames, ``00000.png``, ``00001.png``, ... (8-bit RGB, source size)
``{frames_root}``  folder holding only ``{frames}`` as its sub-folder ``{clip}`` (DiffusionRenderer's
                   ``--dataset_path`` with ``--group_mode folder``)
``{frame0}``       the first frame, ``{clip}.png``
``{frame0_dir}``   folder holding only ``{frame0}`` (DiffusionLight's ``--dataset``)
``{out}``          an empty folder for this tool's outputs (emptied before each run)
``{work}``         the clip's working folder (frames, tool outputs, logs)
``{clip}``         the clip id (letters, digits, ``_ . -``), e.g. MegaSAM's ``--scene_name``
``{fps}``          frames per second of the source video
``{num_frames}``   number of frames
``{width}``        source frame width in pixels
``{height}``       source frame height in pixels
=================  ===============================================================================

What each command must leave under ``{out}`` (searched recursively):

* megasam: one ``*.npz`` in MegaSAM's final format (``cvd_opt.py``'s ``{scene}_sgd_cvd_hr.npz``;
  if several npz files are left, the only ``*_sgd_cvd_hr.npz``), see :mod:`.megasam`; for a
  one-frame clip (``{num_frames}`` = 1: MegaSAM's tracker cannot start) the one ``{frame}.npz`` of
  MegaSAM's UniDepth stage (the static-camera path, see :mod:`.megasam`);
* diffusion_renderer: ``{chunk:04d}.{index:04d}.{pass}.jpg|png`` of every pass for every frame,
  in one folder (run it with ``--chunk_mode all`` for videos longer than one chunk), see
  :mod:`.diffusion_renderer`;
* diffusion_light: one ``*.exr`` (``exposure2hdr.py``'s map of ``{frame0}``), see :mod:`.diffusion_light`.

A command that exits non-zero, runs past its timeout, or leaves nothing raises :class:`ToolError`
(one line naming the clip, the tool and its log). A tool whose run finished and whose outputs are
unchanged is not run again (``{work}/{tool}.done.json`` records the command, the input frames'
fingerprint and the outputs' digest), so a killed job resumes after the last finished tool.

The clip
--------
Written with ``lightcrafter.clip``: the pixel grid is MegaSAM's working grid (about 384 x 512 px,
see :mod:`.megasam`); buffers/ via the resumable FrameFolder; ``envmap_init.exr`` (DiffusionLight
in our world frame, lightcrafter.envmap convention, relative radiance); ``source/{i:04d}.png``
(MegaSAM's RGB frames: the 8-bit display pixels the cameras and buffers refer to); then
cameras.json and the manifest last (any manifest from an earlier run is removed first). Units
"arbitrary" (MegaSAM's scale); producer ``{"stage": "phi", "backend": "paper_stack", ...}``; the
manifest's ``diagnostics`` hold MegaSAM's far-clipped share, the valid share and the rank correlation
of DiffusionRenderer's relative depth with MegaSAM's depth on three frames (+1 = near is dark in the
renderer's depth pass and the grids line up; near 0 = they do not). The tools' run times go to
``timing.json`` beside the manifest (they vary between runs; consumers fingerprint the manifest).
Buffers: depth from MegaSAM; normal, albedo, roughness, metallic from DiffusionRenderer (resampled
onto MegaSAM's grid); mask = MegaSAM depth valid and a usable normal.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import signal
import string
import subprocess
import time
from pathlib import Path

import numpy as np

from lightcrafter import clip as clipmod
from lightcrafter import io
from lightcrafter.recon.paper_stack import diffusion_light, diffusion_renderer, megasam

TOOLS = ("megasam", "diffusion_renderer", "diffusion_light")
PLACEHOLDERS = ("frames", "frames_root", "frame0", "frame0_dir", "out", "work", "clip", "fps",
                "num_frames", "width", "height")
DEFAULT_TIMEOUT_S = 6 * 3600.0
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
EXPECTED = {
    "megasam": "*.npz (MegaSAM's *_sgd_cvd_hr.npz, or UniDepth's {frame}.npz for a one-frame clip)",
    "diffusion_renderer": "{chunk}.{index}.{pass}.jpg|png G-buffer images",
    "diffusion_light": "*.exr (exposure2hdr.py's map)",
}


class ToolError(RuntimeError):
    """A configured tool command failed, timed out or wrote nothing (one line: clip, tool, log)."""


# ----------------------------------------------------------------------------- commands
def check_commands(commands: dict) -> dict[str, str]:
    """Validate the templates: every tool present, only known placeholders. Returns them."""
    if not isinstance(commands, dict):
        raise ValueError(f"commands must map {list(TOOLS)} to shell command templates, got {type(commands).__name__}")
    missing = [t for t in TOOLS if not commands.get(t)]
    unknown = sorted(set(commands) - set(TOOLS))
    if missing or unknown:
        raise ValueError(f"paper_stack commands: missing {missing}, unknown {unknown}; give one template for each of {list(TOOLS)}")
    for tool in TOOLS:
        tpl = commands[tool]
        if not isinstance(tpl, str):
            raise ValueError(f"paper_stack commands[{tool!r}] must be a string, got {type(tpl).__name__}")
        try:
            fields = [f for _, f, _, _ in string.Formatter().parse(tpl) if f is not None]
        except ValueError as exc:
            raise ValueError(f"paper_stack commands[{tool!r}]: {exc}; write literal braces as {{{{ and }}}}") from exc
        bad = sorted({f for f in fields if f not in PLACEHOLDERS})
        if bad:
            raise ValueError(f"paper_stack commands[{tool!r}]: unknown placeholder(s) {bad}; use {list(PLACEHOLDERS)}")
    return {t: commands[t] for t in TOOLS}


def render_command(template: str, values: dict) -> str:
    """The template with every placeholder replaced by its shell-quoted value."""
    import shlex

    return template.format(**{k: shlex.quote(str(v)) for k, v in values.items()})


def _digest_tree(folder: Path) -> str:
    """sha256 over the relative paths and contents of every file under ``folder``."""
    h = hashlib.sha256()
    for p in sorted(q for q in folder.rglob("*") if q.is_file()):
        h.update(str(p.relative_to(folder)).encode() + b"\0")
        with open(p, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()[:16]


def run_tool(tool: str, template: str, values: dict, *, clip_id: str, work: Path, inputs_fp: str,
             finder, timeout_s: float) -> tuple[Path, str, float | None]:
    """Run one tool unless its finished outputs for these inputs are already there.

    Returns (what ``finder`` located, digest of the outputs, seconds the command ran or None when
    reused). Raises ToolError on a non-zero exit, a timeout or no output.
    """
    out = Path(values["out"])
    stamp_path = work / f"{tool}.done.json"
    log_path = work / f"{tool}.log"
    key = io.fingerprint({"template": template, "inputs": inputs_fp})
    if stamp_path.is_file() and out.is_dir():
        try:
            stamp = json.loads(stamp_path.read_text())
        except json.JSONDecodeError:
            stamp = {}
        if stamp.get("key") == key and stamp.get("outputs") == _digest_tree(out):
            found = finder(out)
            if found:
                return found, stamp["outputs"], None
    stamp_path.unlink(missing_ok=True)
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    cmd = render_command(template, values)
    t0 = time.monotonic()
    with open(log_path, "w") as log:
        log.write(f"$ {cmd}\n")
        log.flush()
        proc = subprocess.Popen(cmd, shell=True, executable=shutil.which("bash") or None, stdout=log,
                                stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True)
        try:
            rc = proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)  # the command's own process group (start_new_session)
            proc.wait()
            raise ToolError(f"{clip_id}: {tool} command timed out after {timeout_s:g} s; see {log_path}") from None
    seconds = time.monotonic() - t0
    if rc != 0:
        raise ToolError(f"{clip_id}: {tool} command failed (exit {rc}); see {log_path}")
    try:
        found = finder(out)
    except io.DataError as exc:
        raise io.DataError(f"{clip_id}: {tool}: {exc}") from exc
    if not found:
        raise ToolError(f"{clip_id}: {tool} wrote nothing at {out} (expected {EXPECTED[tool]}); check its command and {log_path}")
    digest = _digest_tree(out)
    io.write_json(stamp_path, {"key": key, "outputs": digest, "seconds": round(seconds, 3), "command": cmd})
    return found, digest, seconds


# ----------------------------------------------------------------------------- frames
def load_source_frames(source: str | os.PathLike, max_frames: int | None = None) -> tuple[list[np.ndarray], float | None]:
    """A video file or a folder of PNG/JPEG frames -> (uint8 RGB frames, fps of the video or None)."""
    import imageio.v3 as iio

    source = Path(source)
    if source.is_file():
        frames, fps = io.read_video(source, max_frames=max_frames)
        return list(frames), fps
    if not source.is_dir():
        raise io.DataError(f"{source}: neither a video file nor a folder of frames; check the clip's source path")
    files = sorted(p for p in source.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if max_frames is not None:
        files = files[:max_frames]
    if not files:
        raise io.DataError(f"{source}: no .png/.jpg frames; put the video's frames there or give a video file")
    frames = []
    for p in files:
        try:
            im = np.asarray(iio.imread(p))
        except Exception as exc:
            raise io.DataError(f"{p}: unreadable frame ({type(exc).__name__}); replace or remove it") from exc
        if im.dtype != np.uint8:
            raise io.DataError(f"{p}: frames must be 8-bit, got {im.dtype}; convert the video's frames to 8-bit RGB")
        if im.ndim == 2:
            im = np.repeat(im[..., None], 3, axis=-1)
        if im.ndim != 3 or im.shape[2] not in (3, 4):
            raise io.DataError(f"{p}: frame must be (H, W, 3) RGB, got shape {im.shape}")
        im = im[..., :3]
        if frames and im.shape != frames[0].shape:
            raise io.DataError(f"{p}: frame is {im.shape[1]}x{im.shape[0]} but the first is "
                               f"{frames[0].shape[1]}x{frames[0].shape[0]}; all frames must share one size")
        frames.append(im)
    return frames, None


def _write_png(path: Path, rgb: np.ndarray) -> None:
    import imageio.v3 as iio

    with io.atomic_path(path) as tmp:
        iio.imwrite(tmp, np.ascontiguousarray(rgb), extension=".png")


def _frames_fingerprint(frames: list[np.ndarray], fps: float) -> str:
    h = hashlib.sha256(f"{len(frames)} {fps!r}".encode())
    for f in frames:
        h.update(str(f.shape).encode())
        h.update(np.ascontiguousarray(f).tobytes())
    return h.hexdigest()[:16]


def _rank_corr(a: np.ndarray, b: np.ndarray) -> float | None:
    """Spearman rank correlation of two equal-length samples (None if too few)."""
    if a.size < 16:
        return None
    ra = np.argsort(np.argsort(a, kind="stable"), kind="stable").astype(np.float64)
    rb = np.argsort(np.argsort(b, kind="stable"), kind="stable").astype(np.float64)
    ra -= ra.mean()
    rb -= rb.mean()
    den = np.sqrt((ra * ra).sum() * (rb * rb).sum())
    return float((ra * rb).sum() / den) if den > 0 else None


# ----------------------------------------------------------------------------- the backend
def reconstruct_paper_stack(source: str | os.PathLike, out_clip_dir: str | os.PathLike, commands: dict, *,
                            scene_static: bool, fps: float | None = None, camera_static: bool = False,
                            clip_id: str | None = None, timeouts: dict | float | None = None,
                            work_dir: str | os.PathLike | None = None, max_frames: int | None = None,
                            dr_resize=None, dr_overlap_frames: int = 0,
                            dr_lsb_offset: float = diffusion_renderer.DEFAULT_LSB_OFFSET,
                            basecolor_encoding: str = "srgb", normal_axes: str = "opengl",
                            dr_unstretch_normals: bool = True,
                            megasam_far_clip: float = megasam.DEFAULT_FAR_CLIP,
                            dl_supersample: int = diffusion_light.DEFAULT_SUPERSAMPLE,
                            envmap_height: int | None = None, cleanup_work: bool = False) -> dict:
    """Reconstruct one video with the paper's stack and write a clip to ``out_clip_dir``.

    source: a video file or a folder of PNG/JPEG frames (then ``fps`` is required).
    commands: {tool: shell template} for megasam, diffusion_renderer, diffusion_light (module doc).
    scene_static / camera_static: the clip's flags (a reconstruction cannot know them).
    timeouts: seconds per tool ({tool: s}) or one number for all (default 6 h each).
    work_dir: where frames, tool outputs and logs go (default ``out_clip_dir/.work``).
    dr_resize, dr_overlap_frames, dr_lsb_offset, basecolor_encoding, normal_axes: how the
    DiffusionRenderer run was configured and how to read it (see :mod:`.diffusion_renderer`);
    dr_unstretch_normals: correct its normals for a stretch of the frame's aspect (default on).
    megasam_far_clip: depths at or beyond are invalid. dl_supersample: ball2envmap.py's --scale.
    envmap_height: height of envmap_init.exr (default: DiffusionLight's).
    Returns the clip manifest. Raises ToolError / io.DataError with one line naming the clip.
    """
    commands = check_commands(commands)
    out = Path(out_clip_dir)
    clip_id = re.sub(r"[^A-Za-z0-9_.-]", "_", clip_id or out.name) or "clip"
    work = Path(work_dir) if work_dir is not None else out / ".work"
    if isinstance(timeouts, (int, float)):
        timeouts = {t: float(timeouts) for t in TOOLS}
    timeouts = {t: float((timeouts or {}).get(t, DEFAULT_TIMEOUT_S)) for t in TOOLS}

    (out / clipmod.MANIFEST).unlink(missing_ok=True)      # nothing from an earlier run is trusted
    frames, video_fps = load_source_frames(source, max_frames)
    fps = float(fps if fps is not None else (video_fps or 0.0))
    if fps <= 0:
        raise ValueError(f"{source}: a folder of frames needs fps; give the clip's frame rate")
    T = len(frames)
    H0, W0 = frames[0].shape[:2]
    static = T == 1      # MegaSAM's tracker needs a warm-up of moving frames: the static-camera path

    frames_root, first_dir = work / "frames", work / "first"
    frames_dir, frame0 = frames_root / clip_id, first_dir / f"{clip_id}.png"
    inputs_fp = _frames_fingerprint(frames, fps)
    stamp = work / "frames.json"
    try:
        have = io.read_json(stamp) if stamp.is_file() else {}
    except io.DataError:
        have = {}
    if have.get("fingerprint") != inputs_fp or not frame0.is_file():
        stamp.unlink(missing_ok=True)
        shutil.rmtree(frames_root, ignore_errors=True)
        shutil.rmtree(first_dir, ignore_errors=True)
        for i, f in enumerate(frames):
            _write_png(frames_dir / f"{i:05d}.png", f)
        _write_png(frame0, frames[0])
        io.write_json(stamp, {"fingerprint": inputs_fp, "num_frames": T})

    base = {"frames": frames_dir, "frames_root": frames_root, "frame0": frame0, "frame0_dir": first_dir,
            "work": work, "clip": clip_id, "fps": f"{fps:g}", "num_frames": T, "width": W0, "height": H0}
    finders = {
        "megasam": megasam.find_unidepth if static else megasam.find_output,
        "diffusion_renderer": lambda d: diffusion_renderer.find_frames(d, T, dr_overlap_frames) or None,
        "diffusion_light": diffusion_light.find_output,
    }
    found, digests, seconds = {}, {}, {}
    for tool in TOOLS:
        values = dict(base, out=work / tool / "out")
        found[tool], digests[tool], seconds[tool] = run_tool(
            tool, commands[tool], values, clip_id=clip_id, work=work, inputs_fp=inputs_fp,
            finder=finders[tool], timeout_s=timeouts[tool])

    def adapt(tool, fn, *a, **kw):
        try:
            return fn(*a, **kw)
        except io.DataError as exc:
            raise io.DataError(f"{clip_id}: {tool}: {exc}") from exc

    if static:
        ms = adapt("megasam", megasam.load_unidepth, found["megasam"], frames[0])
        grid = megasam.unidepth_map(W0, H0)
    else:
        ms = adapt("megasam", megasam.load, found["megasam"], far_clip=megasam_far_clip)
        grid = megasam.working_map(W0, H0)
    if ms.num_frames != T:
        raise io.DataError(f"{clip_id}: megasam: {ms.path} has {ms.num_frames} frames but the video has {T}; rerun MegaSAM on {frames_dir}")
    if (grid.height, grid.width) != (ms.height, ms.width):
        raise io.DataError(f"{clip_id}: megasam: {ms.path} is {ms.width}x{ms.height} but MegaSAM's working grid of a "
                           f"{W0}x{H0} video is {grid.width}x{grid.height}; run the released test_demo.py/cvd_opt.py")
    env = adapt("diffusion_light", diffusion_light.load, found["diffusion_light"])
    env_world = diffusion_light.to_world(env, ms.c2w[0], envmap_height, dl_supersample)

    decode_kw = dict(lsb_offset=dr_lsb_offset, basecolor_encoding=basecolor_encoding, normal_axes=normal_axes,
                     unstretch_normals=dr_unstretch_normals)
    settings = {"dr_resize": dr_resize, "dr_overlap_frames": dr_overlap_frames, "megasam_far_clip": megasam_far_clip,
                "dl_supersample": dl_supersample, "envmap_height": envmap_height, **decode_kw}
    inputs = {"backend": "paper_stack", "frames": inputs_fp, "tools": digests, "settings": settings}
    content_id = io.fingerprint(inputs)
    dr_paths = found["diffusion_renderer"]

    def gbuffers(i):
        return adapt("diffusion_renderer", diffusion_renderer.read_frame, {p: dr_paths[p][i] for p in diffusion_renderer.PASSES},
                     ms.c2w[i], src_size=(W0, H0), target=grid, resize=dr_resize, **decode_kw)

    ff = clipmod.buffer_frames(out, inputs)
    for i in ff.missing(range(T), io.read_buffers):
        ff.stamp()
        g = gbuffers(i)
        valid = ms.valid[i] & g.valid
        io.write_buffers(clipmod.buffer_path(out, i), io.Buffers(
            depth=np.where(valid, ms.depth[i], np.inf).astype(np.float32),
            normal=np.where(valid[..., None], g.normal, 0.0).astype(np.float32),
            albedo=g.albedo, roughness=g.roughness, metallic=g.metallic, mask=valid.astype(np.float32)))

    # Diagnostic: does DiffusionRenderer's relative depth order pixels like MegaSAM's depth?
    # (+1: near is dark, -1: near is bright; near 0: the two grids or frames do not line up.)
    corr, valid_share = [], []
    for i in sorted({0, T // 2, T - 1}):
        g = gbuffers(i)
        m = ms.valid[i] & g.valid
        valid_share.append(float(m.mean()))
        c = _rank_corr(ms.depth[i][m], g.depth_rel[m])
        if c is not None:
            corr.append(round(c, 4))

    source_rel = []
    shutil.rmtree(out / "source", ignore_errors=True)
    for i in range(T):
        rel = f"source/{i:04d}.png"
        _write_png(out / rel, ms.rgb[i])
        source_rel.append(rel)
    io.write_rgb_exr(out / "envmap_init.exr", env_world)

    producer = {
        "stage": "phi", "backend": "paper_stack", "commands": commands, "settings": settings,
        "tool_outputs": {t: str(found[t] if t != "diffusion_renderer" else Path(dr_paths["basecolor"][0]).parent) for t in TOOLS},
    }
    extra = {
        "clip_id": clip_id,
        "source": {"path": str(source), "width": W0, "height": H0, "num_frames": T},
        "source_frames": source_rel,
        "source_encoding": "8-bit sRGB display frames on the clip grid (MegaSAM's images)",
        "envmap_init": "envmap_init.exr",
        "source_map": {"sx": grid.sx, "ox": grid.ox, "sy": grid.sy, "oy": grid.oy,
                       "note": "x_clip = sx x_source + ox (pixel centres at integers); the clip grid is "
                               + ("UniDepth's (one frame, static camera)" if static else "MegaSAM's working grid")},
        "world_frame": "X = x, Y = z, Z = -y of MegaSAM's first (OpenCV) camera: Z up if that camera is level",
        "diagnostics": {
            "megasam_far_fraction": round(ms.far_fraction, 4),
            "valid_fraction": round(float(np.mean(valid_share)), 4),
            "dr_depth_rank_corr": corr,
        },
    }
    manifest = clipmod.write_clip(out, serve=list(range(T)), K=ms.K, c2w=ms.c2w, width=ms.width, height=ms.height,
                                  fps=fps, camera_static=camera_static or static, scene_static=scene_static,
                                  units="metres" if static else "arbitrary",
                                  producer=producer, content_id=content_id, extra=extra)
    # Run times vary between runs: kept out of the manifest (consumers fingerprint it), beside it.
    io.write_json(out / "timing.json", {"tool_seconds": {t: (round(v, 3) if v is not None else None) for t, v in seconds.items()},
                                        "note": "null = outputs of an earlier run reused"})
    if cleanup_work:
        shutil.rmtree(work, ignore_errors=True)
    return manifest
