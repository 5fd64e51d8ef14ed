"""Cameras of a video from its pixels: static-camera detection, then COLMAP (pycolmap) structure from motion.

Conventions
-----------
* Input frames: display 8-bit RGB (N, H, W, 3) -- what a camera records (lightcrafter.io.linear_to_display
  of linear frames).
* Intrinsics come from a documented prior (pinhole, square pixels, horizontal field of view in
  radians, principal point at the image centre ((W-1)/2, (H-1)/2) in the OpenCV pixel-centre
  convention) and are held fixed in bundle adjustment: on short clips self-calibration is far less
  accurate than the prior (measured: 0.06 deg rotation error with a fixed focal vs 3.4 deg
  self-calibrated on 49 frames at 320x240).
* Output poses: per-frame c2w (4x4) with OpenCV camera axes in the reconstruction's own world
  frame and units (COLMAP's: an arbitrary similarity of the true world). COLMAP's pixel-centre
  convention (top-left pixel centre at (0.5, 0.5)) is converted here; nothing outside this module
  sees it.

Far cameras: structure from motion sometimes registers a frame with its centre far off the clip's path (in a
study run, 3.6e3 and 1.9e8 times the median camera's distance from the path's median centre, where every other
moving clip of the run stayed under 10x); such a frame is counted as unregistered
(:func:`drop_far_cameras`, ``FAR_CAMERA_FACTOR``) and is posed like a frame SfM did not register
(:func:`fill_unregistered_poses`, ``recon.sfm.fill_unregistered``). So is a
frame whose depth scale (its SfM points' depths over the G-buffer estimator's, when Phi gives them) is more than
``recon.sfm.max_depth_scale_ratio`` times off the clip's median frame (:func:`depth_scale_outliers`), a check of the
model against a cue SfM does not use. Of the study config's 42 moving clips one sets it off (``s0023_t1``: one frame
13x off; without the check its aligned depth was 4.25 off the truth (AbsRel), with it 0.034); the others spread
1.02-1.57 between their frames, the default's 12 moving clips 1.02-1.37.

Static camera: when the typical motion of SIFT matches between consecutive frames (median over pairs
of the per-pair median; keypoints on the G-buffer estimator's surface only, when Phi gives it, since a
background at infinity turns with a rotating environment light) stays under ``static_motion_px`` pixels, the
camera is taken as static and structure from motion is not run (it cannot: a pure rotation or a static camera
gives no two-view geometry). All frames then get the identity pose. When SfM fails on a clip whose motion is
under twice that threshold, the camera is taken as static too (little image motion and no two-view geometry);
the clip's ``method`` records ``static (fallback)``.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lightcrafter.config.models import SfM
from lightcrafter.camera import intrinsics
from lightcrafter.io import DataError


class ReconstructionError(DataError):
    """The video cannot be reconstructed (too little texture, parallax or registered frames)."""


# The structure-from-motion settings are config recon.sfm (one definition of keys and defaults).
SfMSettings = SfM


@dataclass
class CameraTrack:
    """K (N,3,3 px, OpenCV), c2w (N,4,4, OpenCV axes, reconstruction world), registered (N,) bool,
    points (P,3) sparse structure in the same world, observations: per frame (uv_px (M,2) in the
    OpenCV pixel-centre convention, point index (M,)), static: camera detected static, info: counts
    and seconds."""

    K: np.ndarray
    c2w: np.ndarray
    registered: np.ndarray
    points: np.ndarray
    observations: list[tuple[np.ndarray, np.ndarray]]
    static: bool
    info: dict = field(default_factory=dict)


FAR_CAMERA_FACTOR = 50.0  # far off the path: > 50x the median distance (study: outliers 3.6e3x, others < 10x)
DEPTH_SCALE_MIN_POINTS = 8  # SfM points a frame needs for its own depth scale (also recon.default's min_points)


def drop_far_cameras(c2w: np.ndarray, registered: np.ndarray, factor: float = FAR_CAMERA_FACTOR) -> np.ndarray:
    """``registered`` (N,) without the frames whose camera centre (of ``c2w``, (N, 4, 4)) lies more than
    ``factor`` times the median registered camera's distance from the registered centres' median point
    (per axis); a path whose cameras all sit at one point keeps them all."""
    reg = np.asarray(registered, bool).copy()
    if reg.sum() < 3:
        return reg
    centres = np.asarray(c2w, np.float64)[:, :3, 3]
    dist = np.linalg.norm(centres - np.median(centres[reg], axis=0), axis=1)
    typical = float(np.median(dist[reg]))
    if not np.isfinite(typical) or typical <= 0.0:
        return reg
    reg &= np.isfinite(dist) & (dist <= factor * typical)
    return reg


def depth_scale_outliers(track: "CameraTrack", depth_pred: np.ndarray, factor: float,
                         min_points: int = DEPTH_SCALE_MIN_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """Registered frames whose own depth scale is more than ``factor`` times off the clip's.

    A frame's depth scale is the median, over its observed SfM points, of the point's z-depth in the frame's camera
    (reconstruction units) over the estimator's depth ``depth_pred`` (N, H, W) at the point's pixel. The estimator
    keeps about one scale over a clip and a consistent SfM model keeps one too, so the scales of a clip's frames
    stay close to their median (the default's moving clips: within 1.37x); a frame posed against points of a wrong
    part of the model departs from it. Returns (scales (N,), NaN where a frame has fewer than ``min_points``
    points or is unregistered; outliers (N,) bool, frames with |log(scale / median)| > log(factor))."""
    n, _, _ = depth_pred.shape
    scales = np.full(n, np.nan)
    for i in np.flatnonzero(track.registered):
        _, z, d = observed_depths(track, depth_pred, i)
        if len(z) >= min_points:
            scales[i] = float(np.median(z / d))
    have = np.isfinite(scales)
    if have.sum() < 3:
        return scales, np.zeros(n, bool)
    off = np.abs(np.log(np.where(have, scales, 1.0) / np.median(scales[have])))
    return scales, have & (off > np.log(factor))


def prior_intrinsics(width: int, height: int, fov_x_rad: float) -> np.ndarray:
    """The intrinsics prior: pinhole K (3x3 px) from the horizontal field of view (radians)."""
    if not 0.05 < fov_x_rad < 3.0:
        raise DataError(f"field-of-view prior {fov_x_rad:.3f} rad is not a plausible horizontal fov; fix recon.fov_x_deg")
    return intrinsics(width, height, fov_x_rad)


def median_motion_px(frames: np.ndarray, ratio: float = 0.75, surface: np.ndarray | None = None) -> float:
    """Median, over consecutive frame pairs, of the median displacement (px) of their SIFT matches
    (OpenCV SIFT, Lowe's ratio test): the typical image motion per frame, robust to the few pairs in
    which moving shadows dominate the matches. SIFT matching, unlike brightness-constancy tracking, holds
    under the strong lighting changes of a rotating environment, where moving shadows are a minority
    of the matches. Returns 0.0 for a one-frame clip and for frames that do not change (mean absolute
    difference of consecutive uint8 frames below 0.5 levels: a featureless video that does not change, e.g.
    black, has no motion to measure); inf when fewer than 8 matches are found.

    ``surface`` (N, H, W) bool: keypoints on these pixels only (the estimator's surface), so that a background
    at infinity that turns with a rotating environment light (a synthetic clip's visible HDRI, the sky) does not
    read as camera motion; when that leaves a pair of frames fewer than 8 matches, every pixel counts."""
    if len(frames) < 2:
        return 0.0
    f16 = np.asarray(frames).astype(np.int16)
    if all(np.abs(b - a).mean() < 0.5 for a, b in zip(f16[:-1], f16[1:])):
        return 0.0
    if surface is not None:
        on_surface = _sift_motion_px(frames, ratio, [np.asarray(m, bool).astype(np.uint8) * 255 for m in surface])
        if np.isfinite(on_surface):
            return on_surface
    return _sift_motion_px(frames, ratio, [None] * len(frames))


def _sift_motion_px(frames: np.ndarray, ratio: float, masks: list) -> float:
    """:func:`median_motion_px` of keypoints inside ``masks`` (uint8, 255 = use; None = every pixel)."""
    import cv2

    sift = cv2.SIFT_create(nfeatures=2000)
    matcher = cv2.BFMatcher(cv2.NORM_L2)
    feats = [sift.detectAndCompute(cv2.cvtColor(np.ascontiguousarray(f), cv2.COLOR_RGB2GRAY), m)
             for f, m in zip(frames, masks)]
    per_pair = []
    for (k0, d0), (k1, d1) in zip(feats[:-1], feats[1:]):  # consecutive frames: the smallest lighting change
        if d0 is None or d1 is None or len(k0) < 8 or len(k1) < 2:
            return float("inf")
        good = [m for m, n in (pair for pair in matcher.knnMatch(d0, d1, k=2) if len(pair) == 2)
                if m.distance < ratio * n.distance]
        if len(good) < 8:
            return float("inf")
        p0, p1 = np.array([k.pt for k in k0]), np.array([k.pt for k in k1])
        disp = np.linalg.norm(p1[[m.trainIdx for m in good]] - p0[[m.queryIdx for m in good]], axis=1)
        per_pair.append(float(np.median(disp)))
    return float(np.median(per_pair))


def static_track(n: int, K: np.ndarray) -> CameraTrack:
    return CameraTrack(K=np.repeat(K[None], n, 0), c2w=np.repeat(np.eye(4)[None], n, 0),
                       registered=np.ones(n, bool), points=np.zeros((0, 3)),
                       observations=[(np.zeros((0, 2)), np.zeros(0, np.int64)) for _ in range(n)], static=True)


def estimate_cameras(frames: np.ndarray, fov_x_rad: float, settings: SfMSettings = SfMSettings(),
                     name: str = "clip", work_dir: str | Path | None = None,
                     surface: np.ndarray | None = None, depth: np.ndarray | None = None) -> CameraTrack:
    """Cameras of display frames (N, H, W, 3) uint8: static detection (on the ``surface`` pixels, (N, H, W)
    bool, when given: :func:`median_motion_px`), else incremental SfM.

    ``depth``: the estimator's depth (N, H, W), any one unit; with ``max_depth_scale_ratio`` a frame whose depth
    scale to the SfM points is that many times off the clip's counts as unregistered (:func:`depth_scale_outliers`).

    Raises :class:`ReconstructionError` (one line naming ``name``) when SfM registers fewer than
    ``min_registered_fraction`` of the frames with the settings and with each of their ``retry`` overrides
    (tried in order; ``info["sfm_attempt"]`` is the one that succeeded, 0 = ``settings`` themselves).
    Unregistered frames of an accepted model (flagged in ``registered``) are posed by
    :func:`fill_unregistered_poses` (``settings.fill_unregistered``).
    """
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8:
        raise DataError(f"{name}: frames must be (N, H, W, 3) uint8 display RGB, got {frames.shape} {frames.dtype}")
    n, h, w, _ = frames.shape
    K = prior_intrinsics(w, h, fov_x_rad)
    t0 = time.perf_counter()
    motion = median_motion_px(frames, surface=surface)
    if motion <= settings.static_motion_px:
        track = static_track(n, K)
        track.info = {"method": "static", "median_motion_px": motion, "registered": n, "frames": n,
                      "seconds": round(time.perf_counter() - t0, 3)}
        return track
    if n < 3:
        raise ReconstructionError(f"{name}: {n} frames with camera motion; structure from motion needs at least 3")
    track, failures = None, []
    for attempt, s in enumerate(settings.attempts()):
        tmp = Path(tempfile.mkdtemp(prefix="lc_sfm_", dir=work_dir))
        try:
            track = _colmap(frames, K, s, name, tmp, depth)
            track.info["sfm_attempt"] = attempt
            break
        except ReconstructionError as exc:
            failures.append(str(exc))
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    if track is None:
        if motion > 2 * settings.static_motion_px:
            tried = f" (after {len(failures)} attempts: recon.sfm and its {len(failures) - 1} retry overrides)" \
                if len(failures) > 1 else ""
            raise ReconstructionError(failures[-1] + tried)
        track = static_track(n, K)
        track.info = {"method": "static (fallback)", "registered": n, "frames": n}
    if failures:
        track.info["sfm_failed_attempts"] = failures
    track.info.update({"median_motion_px": motion, "seconds": round(time.perf_counter() - t0, 3)})
    return track


def _colmap(frames: np.ndarray, K: np.ndarray, s: SfMSettings, name: str, tmp: Path,
            depth: np.ndarray | None = None) -> CameraTrack:
    import imageio.v3 as iio
    import pycolmap

    n, h, w, _ = frames.shape
    img_dir = tmp / "images"
    img_dir.mkdir()
    names = [f"{i:05d}.png" for i in range(n)]
    up = s.upscale_for(w)
    for f, nm in zip(frames, names):
        if up > 1:
            import cv2

            f = cv2.resize(np.ascontiguousarray(f), (w * up, h * up), interpolation=cv2.INTER_CUBIC)
        iio.imwrite(img_dir / nm, f)
    Ku = K.copy()  # COLMAP works in the enlarged pixels: pixel centres map as u' = up * (u + 0.5) - 0.5
    Ku[:2, :2] *= up
    Ku[:2, 2] = up * (K[:2, 2] + 0.5) - 0.5
    db = tmp / "database.db"
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"
    # COLMAP's pixel centres sit at +0.5 of OpenCV's.
    reader.camera_params = f"{Ku[0, 0]!r},{Ku[1, 1]!r},{Ku[0, 2] + 0.5!r},{Ku[1, 2] + 0.5!r}"
    extract = pycolmap.FeatureExtractionOptions()
    extract.num_threads = s.threads
    extract.use_gpu = False
    extract.sift.max_num_features = s.max_features
    extract.sift.peak_threshold = s.peak_threshold
    device = pycolmap.Device.cpu
    pycolmap.extract_features(db, img_dir, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
                              reader_options=reader, extraction_options=extract, device=device)
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = s.threads
    matching.use_gpu = False
    if n <= s.exhaustive_max_frames:
        pycolmap.match_exhaustive(db, matching_options=matching, device=device)
    else:
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = s.sequential_overlap
        pycolmap.match_sequential(db, matching_options=matching, pairing_options=pairing, device=device)
    opts = pycolmap.IncrementalPipelineOptions()
    opts.ba_refine_focal_length = False
    opts.ba_refine_principal_point = False
    opts.ba_refine_extra_params = False
    opts.num_threads = s.threads
    opts.random_seed = 0
    opts.mapper.init_min_tri_angle = float(s.init_min_tri_angle_deg)
    opts.mapper.abs_pose_min_num_inliers = int(s.abs_pose_min_num_inliers)
    models = pycolmap.incremental_mapping(db, img_dir, tmp / "sparse", options=opts)
    if not models:
        raise ReconstructionError(f"{name}: structure from motion found no model (too little texture or parallax); "
                                  "check the video, or mark the clip static if the camera does not move")
    rec = max(models.values(), key=lambda r: r.num_reg_images())
    index = {nm: i for i, nm in enumerate(names)}
    c2w = np.full((n, 4, 4), np.nan)
    registered = np.zeros(n, bool)
    point_ids = sorted(rec.points3D.keys())
    pid_index = {pid: k for k, pid in enumerate(point_ids)}
    points = np.array([rec.points3D[pid].xyz for pid in point_ids], dtype=np.float64).reshape(-1, 3)
    observations: list[tuple[np.ndarray, np.ndarray]] = [(np.zeros((0, 2)), np.zeros(0, np.int64))] * n
    for im in rec.images.values():
        if im.name not in index or not im.has_pose:
            continue
        i = index[im.name]
        pose = im.cam_from_world() if callable(im.cam_from_world) else im.cam_from_world
        R = np.asarray(pose.rotation.matrix(), np.float64)
        t = np.asarray(pose.translation, np.float64)
        c2w[i] = np.eye(4)
        c2w[i, :3, :3] = R.T
        c2w[i, :3, 3] = -R.T @ t
        registered[i] = True
        uv, ids = [], []
        for p2d in im.points2D:
            if p2d.has_point3D() and p2d.point3D_id in pid_index:
                uv.append((np.asarray(p2d.xy, np.float64)) / up - 0.5)
                ids.append(pid_index[p2d.point3D_id])
        observations[i] = (np.asarray(uv).reshape(-1, 2), np.asarray(ids, np.int64))
    return accept_model(K, c2w, registered, points, observations, s, name, depth,
                        {"models": len(models), "upscale": up,
                         "matching": "exhaustive" if n <= s.exhaustive_max_frames
                         else f"sequential({s.sequential_overlap})"})


#: registered frames a clip end's motion is measured over (the nearest and up to this many frames beyond it)
MOTION_BASELINE_FRAMES = 3


def _se3_power(delta: np.ndarray, t: float) -> np.ndarray | None:
    """``delta`` (4, 4) rigid motion raised to the real power ``t`` (the geodesic exp(t log delta)); None when it
    has no real logarithm (a half turn) or the result is not finite."""
    from scipy.linalg import expm, logm

    log = logm(delta)
    if np.iscomplexobj(log):
        if np.abs(log.imag).max() > 1e-8:
            return None
        log = log.real
    out = expm(t * log)
    return out if np.all(np.isfinite(out)) else None


def fill_unregistered_poses(c2w: np.ndarray, registered: np.ndarray, mode: str) -> np.ndarray:
    """Poses for the unregistered frames of a track: c2w (N, 4, 4), any axes, registered (N,) bool; returns a
    copy with every unregistered frame posed by ``mode`` (recon.sfm.fill_unregistered). ``nearest``: its nearest
    registered neighbour's pose. ``motion``: the camera's motion continued: within a gap, the geodesic in SE(3)
    between the registered frames around it (T_i = (T_b T_a^-1)^((i-a)/(b-a)) T_a, exact for an orbit or a dolly
    at constant speed); before the first or after the last registered frame, the mean motion per frame over the
    nearest registered frames (:data:`MOTION_BASELINE_FRAMES`) carried on, however far (a camera that stopped
    there is overshot; the ``min_registered_fraction`` floor bounds the gap). A motion without a real logarithm
    falls back to ``nearest``."""
    if mode not in ("nearest", "motion"):
        raise ValueError(f"recon.sfm.fill_unregistered={mode!r}: use 'nearest' or 'motion'")
    out = np.array(c2w, np.float64)
    registered = np.asarray(registered, bool)
    reg = np.flatnonzero(registered)
    if len(reg) == 0:
        raise ValueError("fill_unregistered_poses: no registered frame")
    for i in np.flatnonzero(~registered):
        near = reg[np.argmin(np.abs(reg - i))]
        pose = None
        if mode == "motion" and len(reg) >= 2:
            before, after = reg[reg < i], reg[reg > i]
            if len(before) and len(after):
                a, b = before[-1], after[0]
            elif len(after):     # before the first registered frame
                a, b = after[0], after[min(MOTION_BASELINE_FRAMES, len(after) - 1)]
            else:                # after the last
                a, b = before[-1 - min(MOTION_BASELINE_FRAMES, len(before) - 1)], before[-1]
            step = _se3_power(out[b] @ np.linalg.inv(out[a]), (i - a) / (b - a))
            pose = None if step is None else step @ out[a]
        out[i] = out[near] if pose is None else pose
    return out


def accept_model(K: np.ndarray, c2w: np.ndarray, registered: np.ndarray, points: np.ndarray,
                 observations: list[tuple[np.ndarray, np.ndarray]], s: SfMSettings, name: str,
                 depth: np.ndarray | None = None, info: dict | None = None) -> CameraTrack:
    """The track of an SfM model (K (3, 3) px; c2w (N, 4, 4), OpenCV axes, NaN where unregistered; points;
    per-frame observations): frames far off the path (:func:`drop_far_cameras`) and, with ``depth`` and
    ``s.max_depth_scale_ratio``, frames at another depth scale (:func:`depth_scale_outliers`) count as
    unregistered (their observations dropped); fewer than ``s.min_registered_fraction`` registered frames is a
    :class:`ReconstructionError` naming ``name``; an unregistered frame is posed by :func:`fill_unregistered_poses`
    (``s.fill_unregistered``). ``info`` is added to the track's."""
    n = len(c2w)
    c2w, observations = np.array(c2w, np.float64), list(observations)
    registered = np.asarray(registered, bool)
    kept = drop_far_cameras(c2w, registered)
    far = int(registered.sum() - kept.sum())
    for i in np.flatnonzero(registered & ~kept):  # its SfM points were seen from a wrong pose: as unregistered
        observations[i] = (np.zeros((0, 2)), np.zeros(0, np.int64))
    registered = kept
    Ks = np.repeat(np.asarray(K, np.float64)[None], n, 0)
    scale_info = {}
    if depth is not None and s.max_depth_scale_ratio is not None:
        scales, off = depth_scale_outliers(CameraTrack(K=Ks, c2w=c2w, registered=registered, points=points,
                                                       observations=observations, static=False),
                                           np.asarray(depth), float(s.max_depth_scale_ratio))
        for i in np.flatnonzero(off):  # posed against a wrong part of the model: as unregistered
            observations[i] = (np.zeros((0, 2)), np.zeros(0, np.int64))
        registered = registered & ~off
        have = scales[np.isfinite(scales)]
        scale_info = {"depth_scale_outliers": int(off.sum()),
                      "depth_scale_spread": round(float(have.max() / have.min()), 4) if len(have) else None}
    n_reg = int(registered.sum())
    if n_reg < max(3, s.min_registered_fraction * n):
        dropped = f"; {scale_info['depth_scale_outliers']} at another depth scale" \
            if scale_info.get("depth_scale_outliers") else ""
        raise ReconstructionError(f"{name}: structure from motion registered {n_reg}/{n} frames (needs "
                                  f"{s.min_registered_fraction:.0%}{dropped}); too little texture or parallax")
    c2w = fill_unregistered_poses(c2w, registered, s.fill_unregistered)
    return CameraTrack(K=Ks, c2w=c2w, registered=registered, points=points, observations=observations,
                       static=False, info={"method": "colmap", "registered": n_reg, "frames": n,
                                           "points": int(len(points)), "far_cameras_dropped": far, **scale_info,
                                           **(info or {})})


def pixel_indices(uv: np.ndarray, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """(row, col) integer indices of the pixels containing OpenCV pixel-centre positions ``uv`` (M, 2),
    clipped to an (h, w) image."""
    return (np.clip(np.round(uv[:, 1]).astype(int), 0, h - 1), np.clip(np.round(uv[:, 0]).astype(int), 0, w - 1))


def observed_depths(track: CameraTrack, depth_pred: np.ndarray, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(uv_px (M, 2), z (M,), d (M,)) of frame i's observed SfM points where both depths are positive and finite:
    pixel positions, z-depths in the reconstruction's units (:func:`point_depths`) and the predicted depth
    ``depth_pred`` (N, H, W) at their pixels."""
    uv, z = point_depths(track, i)
    row, col = pixel_indices(uv, *depth_pred.shape[1:])
    d = depth_pred[i, row, col]
    ok = (z > 0) & np.isfinite(d) & (d > 0)
    return uv[ok], z[ok], d[ok]


def point_depths(track: CameraTrack, i: int) -> tuple[np.ndarray, np.ndarray]:
    """(uv_px (M,2), z (M,)) of frame i's observed SfM points: pixel positions and z-depths in the
    reconstruction's units (camera OpenCV z axis)."""
    uv, ids = track.observations[i]
    if len(ids) == 0:
        return uv, np.zeros(0)
    c2w = track.c2w[i]
    pc = (track.points[ids] - c2w[:3, 3]) @ c2w[:3, :3]
    return uv, pc[:, 2]
