"""Fit a source environment map to a video (paper appendix, "Real-World Video Pseudo-Pairs").

    min_L  sum_i || T(R(S^i, L)) - T(I^i) ||_1 + lambda_TV TV(log L),    T(x) = x / (1 + x)

over a 64x128 log-space lat-long map and a global yaw, pitch and exposure (:mod:`.model`), with
Adam (lr 2e-3, default betas) for 2000 iterations, each on one frame drawn uniformly from
{0, 4, 8, ...}; the scene state S (buffers + cameras, lightcrafter.clip) stays fixed. Solvers:
``reference`` (:mod:`.reference`: R differentiated with Mitsuba AD every iteration) and ``fast``
(:mod:`.fast`: the same objective on a sparse transport traced once).

Initialisation: a given map (e.g. DiffusionLight's) resized to the fit's size, else a constant
grey map; either way scaled by one factor so that the first render's mean over the used pixels of
the fitted frames equals the video's (``init_match_mean``; a map's absolute exposure is arbitrary
and Adam at lr 2e-3 moves exposure by at most about 4 EV in 2000 steps). The scale is measured
with R's estimator (:class:`.tracing.Tracer`, ``init_spp`` lanes per pixel, fixed seed), the same
for both solvers. yaw = pitch = exposure = 0 initially.

Outputs of :func:`fit_envmap` (``out_dir``)::

    envmap.exr        fitted map, *baked*: 2**exposure * rotate(exp(log_map), yaw, pitch), (64, 128, 3)
                      linear RGB, world frame, lightcrafter.envmap convention
    lighting.json     lighting file (lightcrafter.lighting/1) naming envmap.exr with yaw = pitch =
                      exposure = 0 (already baked); the fitted values are recorded under "fit"
    params.npz        log_map (unrotated), yaw_rad, pitch_rad, exposure_ev, fingerprint
    loss_curve.json   [{iteration, seconds, loss}]: each iteration's own objective estimate (its
                      sampled frame), seconds since the fit started (set-up included)
    pseudo/####.exr   R(S, L_hat) for ALL frames, rendered by lightcrafter.proxy.clip.render_clip with
    pseudo.mp4/.json  lighting.json (standard renderer, resumable frames); with ``fit_response``, through
                      the camera response fitted on the fitted frames (:mod:`.response`, recorded in
                      fit.json and pseudo.json)
    fit.json          manifest, written last (the declared output of a workflow rule)

Every file is written atomically. A killed fit resumes: the optimiser state is checkpointed every
``checkpoint_every`` iterations (``.checkpoint.pt``, with the fingerprint of inputs and settings)
and a rerun continues from it; frames and Monte Carlo seeds are functions of (seed, iteration), so
a resumed fit retraces the same path (up to floating-point summation order in Dr.Jit's parallel
reductions). A finished fit (params.npz of the same fingerprint) is not redone; pseudo frames are
re-rendered only when missing. Other inputs or settings start from scratch.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from lightcrafter import clip as clipmod
from lightcrafter import envmap, io
from lightcrafter.clip import read_clip
from lightcrafter.proxy.clip import render_clip, resolve_visibility
from lightcrafter.proxy.renderer import RenderSettings

from . import video as videomod
from .model import EnvParams, MapHead, log_of_map, make_adam, resize_map, tv_log
from .tracing import Tracer, bilinear_taps

SOLVERS = ("fast", "reference")
# R's settings for fitting and for the pseudo-input video: visibility 'auto' = the clip's aggregate
# mesh for static scenes, each frame's own mesh when objects move (lightcrafter.proxy.clip).
DEFAULT_RENDER = RenderSettings(visibility="auto")


@dataclass(frozen=True)
class FitSettings:
    """Every knob of the fit, paper values as defaults (see the module docs of :mod:`.fit`, :mod:`.model`).

    * solver: 'fast' or 'reference'; env_height, env_width: map size (64 x 128);
    * iterations, lr, betas: Adam (2000, 2e-3, torch defaults); lambda_tv: TV weight (1e-3);
    * data_reduction: 'sum' (the paper's L1 norm summed over frames, pixels and channels) or 'mean'
      (mean over pixels and channels, frames averaged), see :mod:`.model`;
    * frame_stride: fitted frames {0, stride, 2 stride, ...} (4);
    * fit_rotation / fit_exposure / fit_map: optimise yaw + pitch / exposure / the log map (False:
      it stays at its initial value, e.g. fit_map=False aligns a known map by yaw/pitch/exposure);
    * seed: frame sequence, pixel samples and Monte Carlo seeds;
    * init_match_mean, init_spp: initial scale (module doc) and its lanes per pixel;
    * saturation_level: clip level of the video (None = detect a plateau, <= 0 = off);
    * use_background: fit the background pixels R shows (with R's show_background);
    * ref_spp, ref_pixels: reference lanes per pixel and pixels per iteration (0 = all used pixels);
    * transport_spp, transport_pixels: fast solver's lanes per pixel and pixels per fitted frame (0 = all);
    * threads: Dr.Jit threads (None = its default); checkpoint_every: iterations between checkpoints (0 = off);
    * fit_response: after the map, fit the camera's tone curve (:mod:`.response`) on the fitted frames and
      render the pseudo-input through it (not in the paper; off by default).
    """

    solver: str = "fast"
    env_height: int = 64
    env_width: int = 128
    iterations: int = 2000
    lr: float = 2e-3
    betas: tuple[float, float] = (0.9, 0.999)
    lambda_tv: float = 1e-3
    data_reduction: str = "sum"
    frame_stride: int = 4
    fit_rotation: bool = True
    fit_exposure: bool = True
    fit_map: bool = True
    seed: int = 0
    init_match_mean: bool = True
    init_spp: int = 4
    saturation_level: float | None = None
    use_background: bool = True
    ref_spp: int = 8
    ref_pixels: int = 0
    transport_spp: int = 64
    transport_pixels: int = 2048
    threads: int | None = None
    checkpoint_every: int = 200
    fit_response: bool = False

    def fingerprint_dict(self) -> dict:
        d = asdict(self)
        for k in ("threads", "checkpoint_every"):
            d.pop(k)
        return d


@dataclass
class FitResult:
    """params: final EnvParams as numpy (log_map, yaw_rad, pitch_rad, exposure_ev); env: baked map;
    curve: [{iteration, seconds, loss}]; seconds: total fit time; setup_seconds; stats: solver facts."""

    params: dict
    env: np.ndarray
    curve: list
    seconds: float
    setup_seconds: float
    stats: dict = field(default_factory=dict)


@dataclass
class Problem:
    """Everything the solvers need: views and info of the clip, the video selection, R's settings
    (visibility resolved), the tracer and the initial log map."""

    views: list
    info: object
    video: videomod.Video
    render: RenderSettings
    tracer: Tracer
    init_log_map: np.ndarray
    init_scale: float
    frames_dir: Path


def set_threads(threads: int | None) -> None:
    """Dr.Jit's worker threads (ray tracing). torch always runs single-threaded in the optimisation
    loop (see :func:`optimize`): its tensors are tiny and a thread pool only adds contention."""
    if threads:
        import drjit as dr

        dr.set_thread_count(int(threads))


def frame_sequence(fitted: list[int], iterations: int, seed: int) -> np.ndarray:
    """The frame of every iteration: uniform over ``fitted``, a pure function of (seed, fitted)."""
    rng = np.random.default_rng([int(seed), 0x5EED])
    return np.asarray(fitted)[rng.integers(0, len(fitted), size=int(iterations))]


def data_weights(video, reduction: str) -> dict[int, float]:
    """Factor turning a frame's mean |T(R) - T(I)| (over its used pixels and channels) into this
    iteration's estimate of the data term: 'sum' -> F * 3 * used pixels (an unbiased estimate of the
    sum over the F fitted frames, pixels and channels); 'mean' -> 1."""
    f = len(video.fitted)
    return {i: (3.0 * f * len(video.used[i]) if reduction == "sum" else 1.0) for i in video.fitted}


def _initial_scale(tracer: Tracer, views, video, env: np.ndarray, spp: int, seed: int, where: str,
                   max_pixels: int = 20000) -> float:
    """video mean / render mean over the used pixels of the fitted frames, render under ``env``."""
    h, w = env.shape[:2]
    flat = np.asarray(env, np.float64).reshape(-1, 3)
    num = den = 0.0
    rng = np.random.default_rng([int(seed), 0x1417])
    for i in video.fitted:
        px = video.used[i]
        if len(px) > max_pixels:
            px = np.sort(rng.choice(px, size=max_pixels, replace=False))
        lanes = tracer.lanes(views[i], px, spp, seed=seed * 31 + i)
        d = np.stack([np.asarray(lanes.d.x), np.asarray(lanes.d.y), np.asarray(lanes.d.z)], -1)
        wl = np.stack([np.asarray(lanes.w.x), np.asarray(lanes.w.y), np.asarray(lanes.w.z)], -1).astype(np.float64)
        idx, bw = bilinear_taps(d.astype(np.float64), h, w)
        look = (flat[idx] * bw[..., None]).sum(axis=1)
        den += float((wl * look).sum()) / lanes.spp
        num += float(video.frames[i].reshape(-1, 3)[px].astype(np.float64).sum())
    if not den > 0:
        raise io.DataError(f"{where}: no environment light reaches any used pixel (every surface is shadowed "
                           "and no background is shown); check the clip's geometry")
    return num / den


def prepare(clip: str | Path, frames_dir: str | Path, settings: FitSettings,
            render: RenderSettings = DEFAULT_RENDER, init_map: np.ndarray | str | Path | None = None,
            cache_frames: bool | None = None) -> Problem:
    """Load and check the inputs, build R's visibility and the initial map (see module doc)."""
    if settings.solver not in SOLVERS:
        raise ValueError(f"solver={settings.solver!r}: use one of {SOLVERS}")
    if settings.data_reduction not in ("sum", "mean"):
        raise ValueError(f"data_reduction={settings.data_reduction!r}: use 'sum' or 'mean'")
    views, info = read_clip(clip)
    frames = videomod.read_frames(frames_dir, info)
    render = resolve_visibility(render, info.scene_static, info.consistent_depth)
    vid = videomod.select(frames, views, info, frames_dir, settings.frame_stride, settings.saturation_level,
                          settings.use_background and render.show_background)
    if cache_frames is None:
        cache_frames = settings.solver == "reference"
    tracer = Tracer(views, render, cache_frames=cache_frames)
    h, w = settings.env_height, settings.env_width
    where = "<init map>"
    if init_map is None:
        env0 = np.ones((h, w, 3), np.float32)
    else:
        if isinstance(init_map, (str, Path)):
            where = str(init_map)
            init_map = envmap.load(init_map)
        env0 = resize_map(envmap.validate(init_map, where), h, w)
        log_of_map(env0, where)  # all-zero / non-finite check
    where_clip = str(clipmod.manifest_path(info.root))
    scale = (_initial_scale(tracer, views, vid, env0, settings.init_spp, settings.seed, where_clip)
             if settings.init_match_mean else 1.0)
    log_map = log_of_map(env0 * np.float32(scale), where)
    return Problem(views=views, info=info, video=vid, render=render, tracer=tracer, init_log_map=log_map,
                   init_scale=float(scale), frames_dir=Path(frames_dir))


def build_objective(problem: Problem, settings: FitSettings):
    from .fast import build_fast_objective
    from .reference import ReferenceObjective

    if settings.solver == "fast":
        return build_fast_objective(problem.tracer, problem.views, problem.video, settings.transport_pixels,
                                    settings.transport_spp, settings.seed, settings.env_height, settings.env_width)
    return ReferenceObjective(problem.tracer, problem.views, problem.video, settings.ref_spp, settings.ref_pixels,
                              settings.seed)


def optimize(problem: Problem, settings: FitSettings, *, checkpoint: Path | None = None, fingerprint: str = "",
             snapshot=None, snapshot_at=(), t_start: float | None = None) -> FitResult:
    """Run the solver; ``snapshot(iteration, seconds, params_numpy)`` is called (outside the timed
    span) before the iterations listed in ``snapshot_at`` (``iterations`` = after the last)."""
    t0 = time.perf_counter() if t_start is None else t_start
    set_threads(settings.threads)
    torch_threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return _optimize(problem, settings, checkpoint, fingerprint, snapshot, snapshot_at, t0)
    finally:
        torch.set_num_threads(torch_threads)


def _optimize(problem, settings, checkpoint, fingerprint, snapshot, snapshot_at, t0) -> FitResult:
    objective = build_objective(problem, settings)
    head = MapHead(settings.env_height, settings.env_width)
    params = EnvParams.create(problem.init_log_map)
    opt = make_adam(params, settings.lr, settings.betas, settings.fit_rotation, settings.fit_exposure,
                    settings.fit_map)
    seq = frame_sequence(problem.video.fitted, settings.iterations, settings.seed)
    weight = data_weights(problem.video, settings.data_reduction)
    start, curve, offset = 0, [], 0.0
    if checkpoint is not None and checkpoint.is_file():
        try:
            ck = torch.load(checkpoint, weights_only=False)
        except Exception:  # noqa: BLE001 - an unreadable checkpoint is ignored (atomic writes make it rare)
            ck = None
        if ck and ck.get("fingerprint") == fingerprint:
            with torch.no_grad():
                params.log_map.copy_(torch.from_numpy(ck["params"]["log_map"]))
                params.yaw.fill_(ck["params"]["yaw_rad"])
                params.pitch.fill_(ck["params"]["pitch_rad"])
                params.exposure.fill_(ck["params"]["exposure_ev"])
            opt.load_state_dict(ck["optimizer"])
            start, curve = int(ck["iteration"]), list(ck["curve"])
            offset = float(ck["elapsed"]) - (time.perf_counter() - t0)
    setup_seconds = time.perf_counter() - t0
    snaps = set(int(s) for s in snapshot_at)
    paused = 0.0

    def now():
        return time.perf_counter() - t0 - paused + offset

    for it in range(start, settings.iterations):
        if snapshot is not None and it in snaps:
            tp = time.perf_counter()
            snapshot(it, now(), params.numpy())
            paused += time.perf_counter() - tp
        env = head(params)
        loss = weight[int(seq[it])] * objective.data_loss(env, int(seq[it]), it)
        if settings.lambda_tv:
            loss = loss + settings.lambda_tv * tv_log(params.log_map)
        value = float(loss.detach())
        if not np.isfinite(value):  # never seen; a guard so a fit can not silently write NaN maps
            raise FloatingPointError(f"envfit iteration {it} (frame {int(seq[it])}): objective is {value}; "
                                     "check the frames and buffers for extreme values")
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        curve.append({"iteration": it, "seconds": round(now(), 4), "loss": value})
        if checkpoint is not None and settings.checkpoint_every and (it + 1) % settings.checkpoint_every == 0 \
                and it + 1 < settings.iterations:
            tp = time.perf_counter()
            with io.atomic_path(checkpoint) as tmp:
                torch.save({"fingerprint": fingerprint, "iteration": it + 1, "params": params.numpy(),
                            "optimizer": opt.state_dict(), "curve": curve, "elapsed": now()}, tmp)
            paused += time.perf_counter() - tp
    total = now()
    if snapshot is not None and settings.iterations in snaps:
        snapshot(settings.iterations, total, params.numpy())
    stats = {"solver": settings.solver, "fitted_frames": problem.video.fitted,
             "dropped_black_frames": problem.video.dropped_black,
             "saturation_level": problem.video.saturation_level, "saturated_pixels": problem.video.saturated_pixels,
             "used_pixels": {str(k): int(len(v)) for k, v in problem.video.used.items()},
             "init_scale": problem.init_scale, "resumed_from": start or None}
    if settings.solver == "fast":
        stats.update(transport_bytes=objective.nbytes, transport_nnz=objective.nnz,
                     transport_matrices=len({id(t) for t in objective.transports.values()}))
    return FitResult(params=params.numpy(), env=head.baked(params), curve=curve, seconds=total,
                     setup_seconds=setup_seconds, stats=stats)


# ----------------------------------------------------------------------------- outputs
def fit_camera_response(problem: Problem, lighting_path: Path, seed: int = 0):
    """R renders the fitted frames under the fitted map (the same renderer settings and visibility as
    the pseudo-input) and :func:`.response.fit_response` fits the tone curve from them to the video
    on their used pixels. Returns (CameraResponse, stats with the seconds it took)."""
    from lightcrafter.proxy.lighting import lighting_from_file
    from lightcrafter.proxy.renderer import ProxyRenderer

    from .response import fit_response

    t0 = time.perf_counter()
    renderer = ProxyRenderer(lighting_from_file(lighting_path), problem.render)
    renderer.prepare(problem.views, like=problem.tracer.renderer)
    rendered, observed = [], []
    for i in problem.video.fitted:
        frame = renderer.render(problem.views[i], frame=i)
        rendered.append(frame.reshape(-1, 3)[problem.video.used[i]])
        observed.append(problem.video.observed(i))
    response, stats = fit_response(rendered, observed, seed=seed)
    return response, {**stats, "seconds": round(time.perf_counter() - t0, 3)}


def _digest_array(a: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(a, np.float32).tobytes()).hexdigest()[:16]


def fit_fingerprint(clip: Path, frames: np.ndarray, settings: FitSettings, render: RenderSettings,
                    init_map_digest: str | None) -> str:
    from lightcrafter.proxy.clip import _settings_dict

    return io.product_fingerprint({"what": "envfit", "clip": clipmod.identity(clip), "frames": _digest_array(frames),
                           "settings": settings.fingerprint_dict(), "render": _settings_dict(render),
                           "init": init_map_digest})


def fit_envmap(clip: str | Path, frames_dir: str | Path, out_dir: str | Path, settings: FitSettings = FitSettings(),
               render: RenderSettings = DEFAULT_RENDER, init_map: str | Path | np.ndarray | None = None,
               extra: dict | None = None, render_pseudo: bool = True) -> dict:
    """Fit, write the outputs listed in the module doc, and return the manifest (fit.json)."""
    t0 = time.perf_counter()
    out_dir = Path(out_dir)
    set_threads(settings.threads)
    if isinstance(init_map, (str, Path)):
        init_src = str(init_map)
        init_digest = _digest_array(envmap.load(init_map))
    else:
        init_src = None if init_map is None else "<array>"
        init_digest = None if init_map is None else _digest_array(init_map)
    problem = prepare(clip, frames_dir, settings, render, init_map)
    render = problem.render
    fp = fit_fingerprint(problem.info.root, problem.video.frames, settings, render, init_digest)
    params_path = out_dir / "params.npz"
    manifest_path = out_dir / "fit.json"
    if manifest_path.is_file():
        try:
            old = io.read_json(manifest_path)
        except io.DataError:
            old = {}
        if old.get("fingerprint") == fp and all((out_dir / f).exists() for f in old.get("files", {}).values()):
            return old
    head = MapHead(settings.env_height, settings.env_width)
    done = None
    if params_path.is_file():
        try:
            with np.load(params_path) as z:
                if str(z["fingerprint"]) == fp:
                    done = {k: z[k] for k in z.files}
        except Exception:  # noqa: BLE001 - unreadable: refit
            done = None
    checkpoint = out_dir / ".checkpoint.pt"
    if done is None:
        result = optimize(problem, settings, checkpoint=checkpoint, fingerprint=fp, t_start=t0)
        p = result.params
        out_dir.mkdir(parents=True, exist_ok=True)
        io.write_json(out_dir / "loss_curve.json", {
            "format": "lightcrafter.envfit_curve/1", "solver": settings.solver,
            "loss": "per-iteration objective estimate on the sampled frame: mean |T(R)-T(I)| + lambda_tv TV(log L)",
            "points": result.curve})
        with io.atomic_path(params_path) as tmp:
            with open(tmp, "wb") as fh:
                np.savez(fh, log_map=p["log_map"], yaw_rad=p["yaw_rad"], pitch_rad=p["pitch_rad"],
                         exposure_ev=p["exposure_ev"], fingerprint=fp, seconds=result.seconds,
                         setup_seconds=result.setup_seconds, stats=json.dumps(result.stats))
        if checkpoint.is_file():
            checkpoint.unlink()
        fit_seconds, setup_seconds, stats = result.seconds, result.setup_seconds, result.stats
        params = p
    else:
        params = {"log_map": done["log_map"], "yaw_rad": float(done["yaw_rad"]), "pitch_rad": float(done["pitch_rad"]),
                  "exposure_ev": float(done["exposure_ev"])}
        fit_seconds, setup_seconds = float(done["seconds"]), float(done["setup_seconds"])
        stats = json.loads(str(done["stats"]))
    env = head.baked(EnvParams.create(params["log_map"], params["yaw_rad"], params["pitch_rad"], params["exposure_ev"]))
    env = envmap.validate(env, out_dir / "envmap.exr")
    io.write_rgb_exr(out_dir / "envmap.exr", env)
    fit_info = {"solver": settings.solver, "yaw_rad": params["yaw_rad"], "pitch_rad": params["pitch_rad"],
                "exposure_ev": params["exposure_ev"], "baked": True, "fingerprint": fp}
    from lightcrafter.proxy.lighting import write_lighting_file

    write_lighting_file(out_dir / "lighting.json", env="envmap.exr", extra={"fit": fit_info})
    response = None
    if settings.fit_response:
        response, response_stats = fit_camera_response(problem, out_dir / "lighting.json", settings.seed)
        fit_info["response"] = {**response.as_dict(), **response_stats}
    files = {"envmap": "envmap.exr", "lighting": "lighting.json", "params": "params.npz",
             "loss_curve": "loss_curve.json"}
    pseudo = None
    if render_pseudo:
        pseudo = render_clip(problem.info.root, out_dir / "lighting.json", out_dir / "pseudo", settings=render,
                             extra={"kind": "real_pseudo_input", **(extra or {})},
                             visibility_from=problem.tracer.renderer,  # same clip, same geometry settings
                             response=response)
        from lightcrafter.metrics import display_psnr_db

        frames = [io.read_rgb_exr(out_dir / f) for f in pseudo["frames"]]
        psnr = [display_psnr_db(a, b) for a, b in zip(frames, problem.video.frames)]
        files.update(pseudo_frames="pseudo", pseudo_manifest="pseudo.json", pseudo_preview="pseudo.mp4")
    manifest = {
        "format": "lightcrafter.envfit/1", "fingerprint": fp,
        "clip": str(clipmod.manifest_path(problem.info.root)), "frames_dir": str(Path(frames_dir)),
        "init_map": init_src, "files": files,
        "fit": {**fit_info, "fit_seconds": round(fit_seconds, 3), "setup_seconds": round(setup_seconds, 3),
                "final_loss": None},
        "settings": {**asdict(settings), "render": asdict(render)},
        "stats": stats,
        "pseudo_psnr_db": None if pseudo is None else {"mean": round(float(np.mean(np.minimum(psnr, 100.0))), 3),
                                                        "per_frame": [round(min(x, 100.0), 3) for x in psnr]},
        "total_seconds": round(time.perf_counter() - t0, 3), "cores": os.cpu_count(),
        **(extra or {}),
    }
    curve = io.read_json(out_dir / "loss_curve.json")["points"] if (out_dir / "loss_curve.json").is_file() else []
    if curve:
        tail = [p["loss"] for p in curve[-50:]]
        manifest["fit"]["final_loss"] = round(float(np.mean(tail)), 6)
        manifest["fit"]["final_loss_note"] = "mean of the last 50 per-iteration objective estimates"
    io.write_json(manifest_path, manifest)
    return io.read_json(manifest_path)
