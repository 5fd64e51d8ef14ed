"""The default (CPU) backend of Phi: COLMAP cameras + the learned G-buffer estimator, from pixels only.

Steps for a video of N linear frames ``{i:04d}.exr`` (converted to display values with the one display
transform, lightcrafter.io.linear_to_display, as a camera would record them):

1. cameras (:func:`lightcrafter.recon.cameras.estimate_cameras`): static detection, else COLMAP SfM
   with the intrinsics prior held fixed; SfM world and units;
2. per-frame buffers from the estimator (:mod:`.estimator`): depth in the training scenes' metres,
   camera-space normals, albedo, roughness, metallic, mask (``mask_refine: grabcut``: the mask refined by colour,
   :func:`refine_mask_grabcut`);
3. depth made consistent with the cameras: per frame, the estimator's inverse depth is fitted to the
   SfM points seen in that frame, 1/d = a/d_pred + b + p x + q y (``depth_fit: planar``, robust least
   squares; (x, y) normalised camera coordinates), 1/d = a/d_pred + b (``affine``) or 1/d = a/d_pred
   (``scale``, the median ratio); frames with fewer than ``min_points`` take their
   nearest neighbour's fit, smoothed by a 3-frame median; a static camera keeps the estimator's metres;
4. world normals: the estimator's (rotated by c2w), or derived from the depth map (config
   ``normals: depth``: cross product of the unprojected points' image-space differences);
5. a Z-up world: the dominant direction of the predicted surface normals (the ground dominates
   these scenes) is rotated onto +Z (the smallest rotation), for cameras and normals alike;
6. optionally (``ground_plane``), the dominant supporting plane: a RANSAC plane through every frame's
   unprojected upward-facing surface points; pixels on it take its depth and normal, and its normal becomes
   the world's +Z (:func:`snap_to_ground_plane`); with ``sky_beyond_ground`` > 0, surface pixels off the plane
   farther than that multiple of the frame's farthest ground pixel are background
   (:func:`cut_sky_beyond_ground`: an estimator that calls the sky a surface makes a far wall that shadows
   the whole ground);
7. holes of the mask (``max_hole_fraction``) are filled from the nearest surface pixel;
8. a static camera over a static scene gives ONE buffer frame: the per-frame predictions are averaged
   (median depth, mean normal/materials), so R builds its meshes once.

Nothing here reads ground truth. Units are "arbitrary" (SfM scale).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from lightcrafter import clip as clipmod
from lightcrafter import io
from lightcrafter.recon.cameras import (DEPTH_SCALE_MIN_POINTS, CameraTrack, ReconstructionError, SfMSettings,
                                       estimate_cameras, observed_depths, pixel_indices)


GROUND_NORMALS = ("depth", "predicted", "depth_sfm")  # recon.ground_plane_normal, besides auto


@dataclass
class DefaultSettings:
    """fov_x_deg: intrinsics prior (horizontal field of view, degrees); camera: auto (static detection,
    else SfM) | static (known fixed camera: no SfM); normals: predicted | depth; depth_fit: scale |
    affine | planar (per-frame fit of the estimator's depth to the SfM points, see :func:`depth_fits`);
    min_points: SfM points a frame needs for its own depth scale; mask_threshold: estimator mask
    probability above which a pixel is a surface; mask_refine: none | grabcut (that mask refined by colour,
    :func:`refine_mask_grabcut`); max_hole_fraction: non-surface components enclosed by
    surface or smaller than this fraction of the frame are holes, filled from the nearest surface pixel
    (:func:`hole_pixels`; 0 = off); ground_plane: snap the dominant supporting plane
    (:func:`snap_to_ground_plane`, tolerance ``ground_plane_tol_rel`` of depth, normals within
    ``ground_plane_max_tilt_deg``; ground_plane_normal: depth | predicted | depth_sfm | auto, the plane's
    orientation from the depth, the predicted normals of its pixels, or the mean of the depth's and of the SfM
    points seen on its pixels; auto = predicted for a static camera, depth_sfm for a moving one);
    ground_plane_sfm_tol_rel: how the SfM points' plane is fitted (null: least squares trimmed of the 20 %
    largest residuals three times; a number: RANSAC, a point an inlier within this fraction of its distance
    from the cameras' centroid, :func:`sfm_ground_normal`); ground_plane_sfm_weight: depth_sfm's normal is
    the normalised (1 - w) n_depth + w n_sfm (0.5: their mean; 1: the SfM points' plane alone);
    sky_beyond_ground: with the plane, surface pixels off it farther than this multiple of the frame's
    farthest ground pixel become background
    (:func:`cut_sky_beyond_ground`; 0 = off); albedo_detail_px: the input's own texture on the estimator's
    albedo, through a Gaussian of this many pixels (:func:`albedo_detail`; 0 = off); depth_multiview: a moving
    camera's depth in a static scene refined by a plane sweep against its registered neighbours
    (:func:`lightcrafter.recon.multiview.refine_depth`); sfm: SfMSettings fields; exposure_ev: display exposure
    applied before estimation."""

    fov_x_deg: float = 50.0
    camera: str = "auto"
    normals: str = "predicted"
    depth_fit: str = "scale"
    min_points: int = DEPTH_SCALE_MIN_POINTS
    mask_threshold: float = 0.5
    mask_refine: str = "none"
    max_hole_fraction: float = 0.0
    ground_plane: bool = False
    ground_plane_tol_rel: float = 0.05
    ground_plane_max_tilt_deg: float = 25.0
    ground_plane_normal: str = "depth"
    ground_plane_sfm_tol_rel: float | None = None
    ground_plane_sfm_weight: float = 0.5
    sky_beyond_ground: float = 0.0
    albedo_detail_px: float = 0.0
    depth_multiview: bool = False
    exposure_ev: float = 0.0
    sfm: dict = field(default_factory=dict)

    @classmethod
    def from_dict(cls, d: dict | None) -> "DefaultSettings":
        d = dict(d or {})
        unknown = sorted(set(d) - set(cls.__dataclass_fields__))
        if unknown:
            raise ValueError(f"unknown recon key(s) {unknown}; known: {sorted(cls.__dataclass_fields__)}")
        s = cls(**d)
        if s.camera not in ("auto", "static"):
            raise ValueError(f"recon camera={s.camera!r}: use 'auto' or 'static'")
        if s.depth_fit not in DEPTH_FIT_MODES:
            raise ValueError(f"recon.depth_fit={s.depth_fit!r}: use one of {list(DEPTH_FIT_MODES)}")
        if s.mask_refine not in MASK_REFINE_MODES:
            raise ValueError(f"recon.mask_refine={s.mask_refine!r}: use one of {list(MASK_REFINE_MODES)}")
        if s.sky_beyond_ground and s.sky_beyond_ground < 1.0:
            raise ValueError(f"recon.sky_beyond_ground={s.sky_beyond_ground!r}: use 0 (off) or a ratio >= 1")
        if s.ground_plane_normal not in GROUND_NORMALS + ("auto",):
            raise ValueError(f"recon.ground_plane_normal={s.ground_plane_normal!r}: use one of "
                             f"{list(GROUND_NORMALS + ('auto',))}")
        if s.ground_plane_sfm_tol_rel is not None and not 0.0 < s.ground_plane_sfm_tol_rel < 1.0:
            raise ValueError(f"recon.ground_plane_sfm_tol_rel={s.ground_plane_sfm_tol_rel!r}: use null or a "
                             "fraction in (0, 1)")
        if not 0.0 <= s.ground_plane_sfm_weight <= 1.0:
            raise ValueError(f"recon.ground_plane_sfm_weight={s.ground_plane_sfm_weight!r}: use a weight in [0, 1]")
        if s.normals not in ("predicted", "depth"):
            raise ValueError(f"recon.normals={s.normals!r}: use 'predicted' or 'depth'")
        from lightcrafter.config import validate_section

        s.sfm = validate_section(SfMSettings, s.sfm, "recon.sfm").model_dump()  # one line naming a bad key
        return s


def read_video_frames(frames_dir: str | Path, exposure_ev: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Linear EXR frames ``{i:04d}.exr`` (consecutive from 0) -> (display float (N,H,W,3) in [0,1], uint8)."""
    frames_dir = Path(frames_dir)
    files = []
    while (frames_dir / f"{len(files):04d}.exr").is_file():
        files.append(frames_dir / f"{len(files):04d}.exr")
    if not files:
        raise io.DataError(f"{frames_dir}: no frames 0000.exr...; run the stage that writes the video")
    disp = [io.linear_to_display(io.read_rgb_exr(f), exposure_ev) for f in files]
    shapes = {d.shape for d in disp}
    if len(shapes) > 1:
        raise io.DataError(f"{frames_dir}: frames of mixed sizes {sorted(shapes)}; re-export the video at one size")
    d = np.stack(disp)
    return d, io.to_uint8(d)


DEPTH_FIT_MODES = ("scale", "affine", "planar")


def depth_fits(track: CameraTrack, depth_pred: np.ndarray, min_points: int, mode: str = "scale") -> np.ndarray:
    """Per-frame fits (N, 4) = (a, b, p, q) taking predicted z-depth d to the cameras' units by
    1/d' = a/d + b + p x + q y, with (x, y) = ((u - c_x)/f_x, (v - c_y)/f_y) the pixel's normalised camera
    coordinates (OpenCV axes, z = 1):

    * ``scale``: b = p = q = 0, a the median ratio of the SfM points' inverse depths to the prediction's;
    * ``affine``: p = q = 0, (a, b) a robust least-squares fit in inverse depth (disparity): a monocular
      estimator's depth range is compressed, the shift restores the slope of the ground along the view;
    * ``planar``: (a, b, p, q) by the same robust fit. The inverse depth of a plane is affine in (x, y)
      (n . z(x, y, 1) = o gives 1/z = (n_x x + n_y y + n_z) / o), so the added terms are exactly a plane's:
      they turn a ground the estimator tilted (wrong shading under a low sun, self-shadowing) to the tilt
      the multi-view SfM points give it, in any direction, where ``affine`` can only steepen or flatten the
      predicted slope.

    Robust fit: three rounds of least squares keeping the 80 % smallest residuals; a fit that makes some
    observed point's inverse depth non-positive falls back to ``scale``; ``affine`` needs 2 x ``min_points``
    points and ``planar`` 4 x. Frames with fewer than ``min_points`` points take their nearest neighbour's
    fit; then a 3-frame median in time, per coefficient. A static camera keeps the prediction: (1, 0, 0, 0).
    """
    if mode not in DEPTH_FIT_MODES:
        raise ValueError(f"recon.depth_fit={mode!r}: use one of {list(DEPTH_FIT_MODES)}")
    n, _, _ = depth_pred.shape
    if track.static:
        return np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    fits = np.full((n, 4), np.nan)
    need = {"scale": 1, "affine": 2, "planar": 4}[mode] * min_points
    for i in range(n):
        uv, z, dp = observed_depths(track, depth_pred, i)
        if len(z) < min_points:
            continue
        x, y = 1.0 / dp, 1.0 / z
        fit = np.array([np.median(y / x), 0.0, 0.0, 0.0])
        if mode != "scale" and len(z) >= need and np.ptp(x) > 0:
            cols = [x, np.ones_like(x)]
            if mode == "planar":  # the points' normalised camera coordinates
                K = np.asarray(track.K[i], np.float64)
                cols += [(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1]]
            A_all = np.stack(cols, 1)
            keep = np.ones(len(x), bool)
            for _ in range(3):  # least squares with residual trimming (robust to mismatched points)
                coef = np.linalg.lstsq(A_all[keep], y[keep], rcond=None)[0]
                r = np.abs(A_all @ coef - y)
                keep = r <= max(np.percentile(r, 80), 1e-12)
            if coef[0] > 0 and np.all(A_all @ coef > 0):
                fit[: len(coef)] = coef
        fits[i] = fit
    have = np.flatnonzero(np.isfinite(fits[:, 0]))
    if not len(have):
        raise ReconstructionError("no frame sees enough SfM points to scale its depth")
    for i in np.flatnonzero(~np.isfinite(fits[:, 0])):
        fits[i] = fits[have[np.argmin(np.abs(have - i))]]
    if n >= 3:
        pad = np.concatenate([fits[:1], fits, fits[-1:]])
        fits = np.median(np.stack([pad[:-2], pad[1:-1], pad[2:]]), axis=0)
    return fits


def apply_depth_fit(depth: np.ndarray, fit: np.ndarray, K: np.ndarray | None = None) -> np.ndarray:
    """d' = 1 / (a / d + b + p x + q y) for a fit (a, b[, p, q]) of :func:`depth_fits` (the plane terms need
    the intrinsics K); pixels whose inverse depth would not be positive become invalid (inf)."""
    fit = np.asarray(fit, np.float64)
    inv = fit[0] / depth + fit[1]
    if len(fit) > 2 and (fit[2] or fit[3]):
        if K is None:
            raise ValueError("a planar depth fit needs the frame's intrinsics K")
        from lightcrafter.proxy.geometry import camera_rays

        rays = camera_rays(K, *depth.shape)
        inv = inv + fit[2] * rays[..., 0] + fit[3] * rays[..., 1]
    return np.where(inv > 0, 1.0 / np.maximum(inv, 1e-12), np.inf)


def depth_scales(track: CameraTrack, depth_pred: np.ndarray, min_points: int) -> np.ndarray:
    """Per-frame factors taking predicted depth to the cameras' units (``depth_fits`` in scale mode:
    d' = d / a, so the factor is 1 / a)."""
    return 1.0 / depth_fits(track, depth_pred, min_points, "scale")[:, 0]


def normals_from_depth(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Camera-space unit normals (H,W,3, OpenCV axes, facing the camera) from a z-depth map."""
    from lightcrafter.proxy.geometry import camera_rays

    h, w = depth.shape
    P = camera_rays(K, h, w) * depth[..., None]
    dx = np.zeros_like(P)
    dy = np.zeros_like(P)
    dx[:, 1:-1] = (P[:, 2:] - P[:, :-2]) / 2
    dx[:, 0], dx[:, -1] = P[:, 1] - P[:, 0], P[:, -1] - P[:, -2]
    dy[1:-1] = (P[2:] - P[:-2]) / 2
    dy[0], dy[-1] = P[1] - P[0], P[-1] - P[-2]
    n = np.cross(dy, dx)
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    flip = (n * P).sum(-1) > 0  # face the camera
    return np.where(flip[..., None], -n, n)


def hole_pixels(valid: np.ndarray, max_fraction: float) -> np.ndarray:
    """Boolean (H, W): non-surface pixels that are holes in the surface rather than environment: connected
    (4-neighbour) non-surface components that do not touch the image border, or that cover less than
    ``max_fraction`` of the frame. None when ``max_fraction`` <= 0."""
    from scipy import ndimage

    holes = np.zeros_like(valid, bool)
    if max_fraction <= 0 or valid.all() or not valid.any():
        return holes
    lab, n = ndimage.label(~valid)
    sizes = np.bincount(lab.ravel(), minlength=n + 1)
    edge = np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))
    small = sizes < max_fraction * valid.size
    enclosed = np.ones(n + 1, bool)
    enclosed[edge] = False
    fill = small | enclosed
    fill[0] = False
    return fill[lab]


MASK_REFINE_MODES = ("none", "grabcut")
SURE_SURFACE = 0.995  # grabcut seeds: estimator surface probability above which a pixel stays surface,
SURE_BACKGROUND = 0.1  # below which it stays background


def refine_mask_grabcut(frames_u8: np.ndarray, probability: np.ndarray, threshold: float, seed: int = 0,
                        iterations: int = 5) -> np.ndarray:
    """Surface masks (N, H, W) bool of a video: the estimator's (``probability`` > ``threshold``) less the
    pixels that OpenCV's GrabCut, run per frame on the display frame (uint8 (N, H, W, 3)), labels background.

    The estimator is unsure near the edge of the ground, where the environment behind it shows a far wall or
    trees: it calls that background a surface with probability 0.9-0.99, below the ground's own 0.998, and the
    plane snap then extends the ground into the sky. GrabCut learns one colour model for the frame's surface and
    one for its background from the sure pixels (probability above :data:`SURE_SURFACE`, below
    :data:`SURE_BACKGROUND`) and relabels the unsure ones between them by colour and image edges. It only takes
    surface off: where the estimator says background GrabCut may say surface, but filling the estimator's holes
    gave real clips surface they do not have (a street's bright car lights became surface, bikes_f32's pseudo-input
    18.6 -> 17.6 dB), and the background of a real clip shows its fitted map, which matches the video. A frame without
    a sure-background or a sure-surface pixel keeps the estimator's mask (no colour to learn). OpenCV's random
    generator is seeded per frame (``seed`` + frame index), so the same video gives the same masks."""
    import cv2

    probability = np.asarray(probability)
    out = probability > threshold
    for i in range(len(probability)):
        p = probability[i]
        labels = np.full(p.shape, cv2.GC_PR_BGD, np.uint8)
        labels[p > threshold] = cv2.GC_PR_FGD
        labels[p > SURE_SURFACE] = cv2.GC_FGD
        labels[p < SURE_BACKGROUND] = cv2.GC_BGD
        if not (labels == cv2.GC_BGD).any() or not (labels == cv2.GC_FGD).any():
            continue
        cv2.setRNGSeed(seed + i)
        bg_model, fg_model = np.zeros((1, 65)), np.zeros((1, 65))
        cv2.grabCut(np.ascontiguousarray(frames_u8[i]), labels, None, bg_model, fg_model, iterations,
                    cv2.GC_INIT_WITH_MASK)
        out[i] &= (labels == cv2.GC_FGD) | (labels == cv2.GC_PR_FGD)  # only takes surface off, never adds
    return out


DETAIL_RATIO_RANGE = (0.5, 2.0)  # bounds of the texture ratio: a highlight or a shadow edge moves the albedo 2x at most
DETAIL_EPS = 1e-3  # linear radiance added to both sides of the ratio: where a frame is black its ratio is 1


def albedo_detail(frames_linear: np.ndarray, sigma_px: float) -> np.ndarray:
    """Texture ratio (H, W, 3) of the linear frames (K, H, W, 3) of one view: each channel over its Gaussian blur
    of ``sigma_px`` pixels (``(x + eps) / (blur + eps)``, :data:`DETAIL_EPS`), clipped to :data:`DETAIL_RATIO_RANGE`,
    the median over the K frames.

    Multiplied onto the estimator's albedo (``recon.albedo_detail_px``). The estimator, a U-Net trained on 64x96
    crops, returns a smooth albedo: the ground's bricks and checks are gone, and so is their contrast in the proxy.
    Shading varies slowly over a surface, so at the scale of a pixel or two the input's variation is the albedo's
    (a cast shadow's edge or a highlight also passes, bounded by the clip). A static view's frames under a moving
    light give the median: an edge that moves with the light is in few of them."""
    import cv2

    ratios = []
    for f in np.asarray(frames_linear, np.float32):
        blur = cv2.GaussianBlur(f, (0, 0), float(sigma_px), borderType=cv2.BORDER_REFLECT)
        ratios.append(np.clip((f + DETAIL_EPS) / (blur + DETAIL_EPS), *DETAIL_RATIO_RANGE))
    return np.median(np.stack(ratios), axis=0) if len(ratios) > 1 else ratios[0]


def fill_from_nearest(values: np.ndarray, valid: np.ndarray, where: np.ndarray) -> np.ndarray:
    """``values`` (H, W[, C]) with the pixels ``where`` set to their nearest ``valid`` pixel's value."""
    from scipy import ndimage

    if not where.any():
        return values
    _, (ri, ci) = ndimage.distance_transform_edt(~valid, return_indices=True)
    out = values.copy()
    out[where] = values[ri[where], ci[where]]
    return out


def fit_ground_plane(points: np.ndarray, dist: np.ndarray, tol_rel: float, max_tilt_deg: float,
                     iters: int = 256, seed: int = 0) -> tuple[np.ndarray, float, float] | None:
    """RANSAC plane n . x = o through world points (M, 3) of a Z-up world: n a unit normal within
    ``max_tilt_deg`` of +Z (facing up); a point is an inlier when its distance to the plane is below
    ``tol_rel`` x its distance from the camera ``dist`` (M,) (depth noise grows with distance). The best
    hypothesis is refined by least squares on its inliers (SVD). Returns (n, o, inlier fraction) or None
    when fewer than 3 points. Seeded: the same points give the same plane."""
    if len(points) < 3:
        return None
    rng = np.random.default_rng(seed)
    cos_max = np.cos(np.radians(max_tilt_deg))
    tol = tol_rel * dist
    best = (-1, None)
    for _ in range(iters):
        a, b, c = points[rng.choice(len(points), 3, replace=False)]
        n = np.cross(b - a, c - a)
        ln = np.linalg.norm(n)
        if ln < 1e-12:
            continue
        n = n / ln * np.sign(n[2] or 1.0)
        if n[2] < cos_max:
            continue
        inl = np.abs(points @ n - n @ a) < tol
        if inl.sum() > best[0]:
            best = (int(inl.sum()), inl)
    if best[1] is None or best[0] < 3:
        return None
    for _ in range(2):  # least-squares refinement on the inliers, then their inliers again
        P = points[best[1]]
        c0 = P.mean(0)
        n = np.linalg.svd(P - c0, full_matrices=False)[2][-1]
        n = n * np.sign(n[2] or 1.0)
        o = float(n @ c0)
        inl = np.abs(points @ n - o) < tol
        if inl.sum() < 3:
            break
        best = (int(inl.sum()), inl)
    return n, o, best[0] / len(points)


def plane_depth(n: np.ndarray, o: float, K: np.ndarray, c2w: np.ndarray, h: int, w: int) -> np.ndarray:
    """z-depth (H, W) at which each pixel's camera ray meets the plane n . x = o (inf where it does not, in
    front of the camera)."""
    from lightcrafter.proxy.geometry import camera_rays

    rays_w = camera_rays(K, h, w) @ np.asarray(c2w)[:3, :3].T  # world direction per unit z-depth
    denom = rays_w @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        z = (o - n @ np.asarray(c2w)[:3, 3]) / denom
    return np.where(np.isfinite(z) & (z > 0), z, np.inf)


MIN_SFM_GROUND_POINTS = 20  # depth_sfm keeps the depth's plane when fewer SfM points lie on the ground


def sfm_ground_normal(points: np.ndarray, observations: list[tuple[np.ndarray, np.ndarray]], on: list[np.ndarray],
                      min_points: int = MIN_SFM_GROUND_POINTS, tol_rel: float | None = None,
                      cameras: np.ndarray | None = None,
                      max_tilt_deg: float = 89.0) -> tuple[np.ndarray, int] | None:
    """Unit normal (facing +Z) of the plane through the SfM points (P, 3, world) that some frame observes on a
    ground pixel (``on[i]`` (H, W) bool; observations: per frame (uv_px (M, 2), point index (M,)), OpenCV pixel
    centres); with the number of points. None when fewer than ``min_points`` (or RANSAC finds no plane). The SfM
    points are triangulated from several views, so their plane's tilt does not share the errors of the
    per-frame depth fits. ``tol_rel`` None: least squares, three rounds keeping the 80 % smallest residuals;
    a number: RANSAC (:func:`fit_ground_plane`, a normal within ``max_tilt_deg`` of +Z), a point an inlier
    within ``tol_rel`` of its distance from the centroid of the camera centres ``cameras`` (N, 3): mismatched
    features on a repeated texture triangulate off the plane far more than 20 % of the time."""
    ids = set()
    for (uv, idx), mask in zip(observations, on):
        if len(idx) == 0:
            continue
        row, col = pixel_indices(uv, *mask.shape)
        ids.update(np.asarray(idx)[mask[row, col]].tolist())
    if len(ids) < min_points:
        return None
    P = np.asarray(points, np.float64)[sorted(ids)]
    if tol_rel is not None:
        if cameras is None:
            raise ValueError("a RANSAC fit of the SfM ground plane needs the camera centres (cameras=)")
        dist = np.linalg.norm(P - np.asarray(cameras, np.float64).mean(0), axis=1)
        fit = fit_ground_plane(P, dist, tol_rel, max_tilt_deg)
        return None if fit is None else (fit[0], len(P))
    keep = np.ones(len(P), bool)
    for _ in range(3):
        c0 = P[keep].mean(0)
        n = np.linalg.svd(P[keep] - c0, full_matrices=False)[2][-1]
        r = np.abs((P - c0) @ n)
        keep = r <= max(np.percentile(r, 80), 1e-12)
    return n * np.sign(n[2] or 1.0), len(P)


def snap_to_ground_plane(depth: np.ndarray, n_world: np.ndarray, surface: np.ndarray, K: np.ndarray,
                         c2w: np.ndarray, tol_rel: float, max_tilt_deg: float, min_support: float = 0.25,
                         max_points: int = 20000, normal_from: str = "depth", sfm=None,
                         sfm_tol_rel: float | None = None, sfm_weight: float = 0.5):
    """The dominant supporting plane of a Z-up clip, from the depth maps of every frame (metres of the
    clip's units): pixels whose points lie within ``tol_rel`` of the plane (relative to their depth) and whose
    normals are within ``max_tilt_deg`` of the plane's take the plane's depth and normal exactly (a
    multi-view estimate of the ground replaces the per-frame monocular one: no tilt, no depth noise to cast
    self-shadows). The plane is used only when its pixels are at least ``min_support`` of the clip's
    surface pixels (info ``support_fraction``, ``used``). ``normal_from``: ``depth`` snaps to the RANSAC plane
    itself; ``predicted`` keeps its inliers (which pixels are ground) but turns the plane to the mean of their
    per-pixel normals ``n_world`` (through their median offset): where the depth's tilt is the estimator's
    guess alone (a static camera: no SfM points to fit it to), its normals may tilt the ground better;
    ``depth_sfm`` keeps the inliers too and turns the plane to the weighted mean (``sfm_weight`` w:
    (1 - w) n_depth + w n_sfm, normalised) of the RANSAC normal and the normal of the SfM points seen on them
    (:func:`sfm_ground_normal`, fitted by least squares or, with ``sfm_tol_rel``, by RANSAC; ``sfm`` = (points
    (P, 3) in the given world, per-frame observations); a points' plane beyond ``max_tilt_deg`` of +Z is not
    ground and is ignored, info ``sfm_plane_tilt_deg``). On the 6 moving-camera train clips of the 6-scene
    default the ground's tilt against the truth was 5.2 deg (mean) from the depth, 7.3 from the SfM points' least
    squares and 2.7 from their mean; on those of the 8-scene default (docs/phi.md) 5.1 deg from that mean and 3.3 from
    the SfM points' RANSAC plane alone. Without ``sfm`` or enough points it is ``depth``.
    Returns (depth, n_world, plane (n, o) or None, info) with the plane n . x = o in the given world."""
    from lightcrafter.proxy.geometry import unproject

    nf, h, w = depth.shape
    rng = np.random.default_rng(0)
    cos_max = np.cos(np.radians(max_tilt_deg))
    if normal_from not in GROUND_NORMALS:
        raise ValueError(f"recon.ground_plane_normal={normal_from!r}: use one of {list(GROUND_NORMALS)}")
    pts, dists = [], []
    for i in range(nf):
        ok = surface[i] & np.isfinite(depth[i]) & (n_world[i][..., 2] > cos_max)
        P = unproject(np.where(ok, depth[i], np.inf), K[i], c2w[i])[ok]
        dd = depth[i][ok]
        k = rng.choice(len(P), min(len(P), max(1, max_points // nf)), replace=False) if len(P) else []
        pts.append(P[k])
        dists.append(dd[k])
    P, D = np.concatenate(pts), np.concatenate(dists)
    fit = fit_ground_plane(P, D, tol_rel, max_tilt_deg)
    if fit is None:
        return depth, n_world, None, {"ground_plane": None}
    n, o, frac = fit
    ons = []
    for i in range(nf):
        zp = plane_depth(n, o, K[i], c2w[i], h, w)
        on = surface[i] & np.isfinite(zp) & (np.abs(depth[i] - zp) < tol_rel * zp) & \
            ((n_world[i] @ n) > np.cos(np.radians(max_tilt_deg)))
        ons.append((on, zp))
    tilt_change, n_new, sfm_points, sfm_tilt = 0.0, None, None, None
    if normal_from == "predicted" and any(on.any() for on, _ in ons):
        m = sum(n_world[i][on].sum(0) for i, (on, _) in enumerate(ons))
        n_new = m / max(np.linalg.norm(m), 1e-12)
    elif normal_from == "depth_sfm" and sfm is not None:
        got = sfm_ground_normal(sfm[0], sfm[1], [on for on, _ in ons], tol_rel=sfm_tol_rel, cameras=c2w[:, :3, 3],
                                max_tilt_deg=max_tilt_deg)
        if got is not None:
            n_s, sfm_points = got
            sfm_tilt = round(float(np.degrees(np.arccos(np.clip(n_s[2], -1.0, 1.0)))), 3)
            if n_s[2] >= cos_max:  # the bound the depth's plane has; points off any ground (a face) turn it far
                m = (1.0 - sfm_weight) * n + sfm_weight * n_s
                n_new = m / np.linalg.norm(m)
    if n_new is not None:
        inl = np.concatenate([unproject(np.where(on, depth[i], np.inf), K[i], c2w[i])[on]
                              for i, (on, _) in enumerate(ons)])
        tilt_change = float(np.degrees(np.arccos(np.clip(n_new @ n, -1.0, 1.0))))
        n, o = n_new, float(np.median(inl @ n_new))
        ons = [(on, plane_depth(n, o, K[i], c2w[i], h, w)) for i, (on, _) in enumerate(ons)]
        ons = [(on & np.isfinite(zp), zp) for on, zp in ons]
    support = sum(int(on.sum()) for on, _ in ons) / max(int(surface.sum()), 1)
    info = {"ground_plane": {"normal": np.round(n, 6).tolist(), "offset": round(o, 6), "inlier_fraction": round(frac, 4),
                             "support_fraction": round(support, 4), "used": support >= min_support,
                             "normal_from": normal_from, "turned_deg": round(tilt_change, 3),
                             **({"sfm_ground_points": sfm_points, "sfm_plane_tilt_deg": sfm_tilt}
                                if normal_from == "depth_sfm" else {})}}
    if support < min_support:  # no plane carries the scene (e.g. a face filling the frame): leave it alone
        return depth, n_world, None, info
    depth, n_world = depth.copy(), n_world.copy()
    for i, (on, zp) in enumerate(ons):
        depth[i][on] = zp[on]
        n_world[i][on] = n
    return depth, n_world, (n, o), info


def cut_sky_beyond_ground(depth: np.ndarray, n_world: np.ndarray, surface: np.ndarray, plane: tuple[np.ndarray, float],
                          K: np.ndarray, c2w: np.ndarray, tol_rel: float, max_tilt_deg: float,
                          ratio: float) -> tuple[np.ndarray, int]:
    """Surface mask (N, H, W) without the pixels that cannot be scene: off the ground plane n . x = o and
    farther than ``ratio`` x the frame's farthest ground pixel
    (the 99th percentile of the depths of ground pixels: within ``tol_rel`` of the plane and facing up within
    ``max_tilt_deg``, so a far wall where it meets the plane does not count). Objects standing on the
    ground are nearer than the ground behind them, so they stay; the sky and the far environment go.
    Whether a ray meets the plane is not asked: a plane tilted by a degree or two moves the horizon out of a
    downward-looking frame. Frames without ground pixels are left alone. Returns (mask, pixels cut)."""
    n, o = plane
    nf, h, w = depth.shape
    out, cut = surface.copy(), 0
    for i in range(nf):
        zp = plane_depth(n, o, K[i], c2w[i], h, w)
        ground = surface[i] & np.isfinite(zp) & (np.abs(depth[i] - zp) < tol_rel * zp) & \
            ((n_world[i] @ n) > np.cos(np.radians(max_tilt_deg)))
        if not ground.any():
            continue
        far = float(np.percentile(depth[i][ground], 99))
        sky = surface[i] & ~ground & (depth[i] > ratio * far)
        out[i] &= ~sky
        cut += int(sky.sum())
    return out, cut


def settings_from_config(cfg: dict, **overrides) -> "DefaultSettings":
    """The default backend's settings from an effective config (its ``recon`` section; the scenes' field of
    view when ``recon.fov_x_deg`` is null), then ``overrides`` (DefaultSettings fields)."""
    return DefaultSettings.from_dict({**config_settings(cfg), **overrides})


def config_settings(cfg: dict) -> dict:
    """The config keys of the default backend as a dict of DefaultSettings fields (what the workflow hands
    scripts/reconstruct.py), in a fixed order."""
    r = cfg["recon"]
    return {
        "fov_x_deg": r["fov_x_deg"] or cfg["scenes"]["fov_x_deg"],
        "normals": r["normals"],
        "depth_fit": r["depth_fit"],
        "mask_threshold": r["mask_threshold"],
        "mask_refine": r["mask_refine"],
        "max_hole_fraction": r["max_hole_fraction"],
        "ground_plane": r["ground_plane"],
        "ground_plane_tol_rel": r["ground_plane_tol_rel"],
        "ground_plane_max_tilt_deg": r["ground_plane_max_tilt_deg"],
        "ground_plane_normal": r["ground_plane_normal"],
        "ground_plane_sfm_tol_rel": r["ground_plane_sfm_tol_rel"],
        "ground_plane_sfm_weight": r["ground_plane_sfm_weight"],
        "sky_beyond_ground": r["sky_beyond_ground"],
        "albedo_detail_px": r["albedo_detail_px"],
        "depth_multiview": r["depth_multiview"],
        "sfm": r["sfm"],
    }


def up_rotation(up: np.ndarray) -> np.ndarray:
    """Smallest rotation taking unit vector ``up`` onto +Z (Rodrigues)."""
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    z = np.array([0.0, 0.0, 1.0])
    v, c = np.cross(up, z), float(up @ z)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


def reconstruct_default(frames_dir: str | Path, out_clip: str | Path, *, estimator_path: str | Path, fps: float,
                        scene_static: bool, settings: DefaultSettings = DefaultSettings(), name: str | None = None,
                        extra: dict | None = None) -> dict:
    """Run the default Phi on a folder of linear frames and write the clip; returns its manifest.

    Raises :class:`ReconstructionError` (one line naming the clip) when the cameras cannot be recovered.
    """
    from lightcrafter.recon import estimator as est

    t0 = time.perf_counter()
    name = name or str(frames_dir)
    disp, u8 = read_video_frames(frames_dir, settings.exposure_ev)
    n, h, w, _ = disp.shape
    model = est.load(estimator_path)
    pred = est.predict(model, disp)
    t_est = time.perf_counter() - t0
    if settings.camera == "static":
        from lightcrafter.recon.cameras import prior_intrinsics, static_track

        track = static_track(n, prior_intrinsics(w, h, np.radians(settings.fov_x_deg)))
        track.info = {"method": "static (given)", "registered": n, "frames": n}
    else:  # static detection looks at the surface: a background at infinity turns with a rotating light
        track = estimate_cameras(u8, np.radians(settings.fov_x_deg), SfMSettings(**settings.sfm), name=name,
                                 surface=pred["mask"] > settings.mask_threshold, depth=pred["depth"])
    t_cam = time.perf_counter() - t0 - t_est
    try:
        fits = depth_fits(track, pred["depth"], settings.min_points, settings.depth_fit)
    except ReconstructionError as exc:
        raise ReconstructionError(f"{name}: {exc}") from None
    mask = pred["mask"] > settings.mask_threshold
    mask_info = {}
    if settings.mask_refine == "grabcut":
        refined = refine_mask_grabcut(u8, pred["mask"], settings.mask_threshold)
        mask_info = {"mask_pixels_removed": int((mask & ~refined).sum())}
        mask = refined
    depth = np.stack([apply_depth_fit(pred["depth"][i], fits[i], track.K[i]) for i in range(n)])
    multiview_info = {}
    if settings.depth_multiview and not track.static and scene_static:
        from lightcrafter.recon.multiview import refine_depth

        depth, multiview_info = refine_depth(disp, depth, track.K, track.c2w, track.registered)
    if settings.normals == "depth":
        n_cam = np.stack([normals_from_depth(depth[i], track.K[i]) for i in range(n)])
    else:
        n_cam = pred["normal_cam"]
    R_c2w = track.c2w[:, :3, :3]
    n_world = np.einsum("nij,nhwj->nhwi", R_c2w, n_cam)
    up = (n_world * mask[..., None]).sum(axis=(0, 1, 2))
    Q = up_rotation(up) if np.linalg.norm(up) > 0 else np.eye(3)
    c2w = track.c2w.copy()
    c2w[:, :3, :3] = Q @ R_c2w
    c2w[:, :3, 3] = track.c2w[:, :3, 3] @ Q.T
    n_world = n_world @ Q.T
    plane_info = {}
    if settings.ground_plane:
        normal_from = settings.ground_plane_normal
        if normal_from == "auto":  # SfM points tilt the ground of a moving camera; a static one has only the estimator
            normal_from = "predicted" if track.static else "depth_sfm"
        sfm = None if track.static else (track.points @ Q.T, track.observations)  # in the Z-up world of c2w
        depth, n_world, plane, plane_info = snap_to_ground_plane(
            depth, n_world, mask, track.K, c2w, settings.ground_plane_tol_rel, settings.ground_plane_max_tilt_deg,
            normal_from=normal_from, sfm=sfm, sfm_tol_rel=settings.ground_plane_sfm_tol_rel,
            sfm_weight=settings.ground_plane_sfm_weight)
        if plane is not None and settings.sky_beyond_ground:
            mask, plane_info["sky_pixels_cut"] = cut_sky_beyond_ground(
                depth, n_world, mask, plane, track.K, c2w, settings.ground_plane_tol_rel,
                settings.ground_plane_max_tilt_deg, settings.sky_beyond_ground)
        if plane is not None:  # the plane's normal is the world's up: rotate it onto +Z exactly
            Q2 = up_rotation(plane[0])
            c2w[:, :3, :3] = Q2 @ c2w[:, :3, :3]
            c2w[:, :3, 3] = c2w[:, :3, 3] @ Q2.T
            n_world = n_world @ Q2.T
    one = track.static and scene_static
    inputs = {"what": "phi-default", "frames": _frames_identity(frames_dir, n), "settings": asdict(settings),
              "estimator": _file_digest(estimator_path), "scene_static": scene_static}
    frames = clipmod.buffer_frames(out_clip, inputs)
    distinct = [0] if one else list(range(n))
    todo = frames.missing(distinct, io.read_buffers)

    filled_per_frame: list[int] = []

    def buffers_of(idx) -> io.Buffers:
        sel = slice(None) if one else slice(idx, idx + 1)
        m = mask[sel].mean(0) > 0.5
        d = np.median(depth[sel], axis=0)
        nn_ = n_world[sel].mean(0)
        nn_ /= np.maximum(np.linalg.norm(nn_, axis=-1, keepdims=True), 1e-9)
        ok = m & np.isfinite(d) & (d > 0)
        holes = hole_pixels(ok, settings.max_hole_fraction)
        if holes.any():  # surface the estimator's mask missed: nearest surface pixel's buffers
            d = fill_from_nearest(np.where(ok, d, 0.0), ok, holes)
            nn_ = fill_from_nearest(np.where(ok[..., None], nn_, 0.0), ok, holes)
            albedo = fill_from_nearest(pred["albedo"][sel].mean(0), ok, holes)
            rough = fill_from_nearest(pred["roughness"][sel].mean(0), ok, holes)
            metal = fill_from_nearest(pred["metallic"][sel].mean(0), ok, holes)
            ok = ok | holes
        else:
            albedo, rough, metal = (pred[k][sel].mean(0) for k in ("albedo", "roughness", "metallic"))
        if settings.albedo_detail_px > 0:
            lin = io.display_to_linear(disp[sel], settings.exposure_ev)
            albedo = np.clip(albedo * albedo_detail(lin, settings.albedo_detail_px), 0.0, 1.0)
        filled_per_frame.append(int(holes.sum()))
        return io.Buffers(depth=np.where(ok, d, np.inf).astype(np.float32),
                          normal=np.where(ok[..., None], nn_, 0.0).astype(np.float32),
                          albedo=np.where(ok[..., None], albedo, 0.0).astype(np.float32),
                          roughness=np.where(ok, rough, 0.0).astype(np.float32),
                          metallic=np.where(ok, metal, 0.0).astype(np.float32),
                          mask=ok.astype(np.float32))

    for i in distinct:  # every distinct frame is built (cheap next to the estimator), so counts do not depend on
        b = buffers_of(i)  # which frames a resumed run still had to write
        if i in todo:
            frames.stamp()
            io.write_buffers(frames.path(i), b)
    info = {**track.info, **plane_info, **mask_info, **multiview_info,
            "depth_fit_per_frame": np.round(fits, 6).tolist(),
            "hole_pixels_filled": sum(filled_per_frame), "registered_per_frame": track.registered.tolist()}
    timing = {"cameras_seconds": round(t_cam, 3), "estimator_seconds": round(t_est, 3),
              "seconds": round(time.perf_counter() - t0, 3), "frames": n}
    io.write_json(Path(out_clip) / "timing.json", timing)  # beside the manifest: run times vary between runs
    return clipmod.write_clip(
        out_clip, serve=[0] * n if one else list(range(n)), K=track.K, c2w=c2w, width=w, height=h, fps=fps,
        camera_static=track.static, scene_static=scene_static, units="arbitrary",
        producer={"stage": "phi", "backend": "default", "settings": asdict(settings)},
        content_id=io.fingerprint(inputs), extra={**(extra or {}), "phi": _without_times(info)},
    )


def _frames_identity(frames_dir, n) -> list:
    d = Path(frames_dir)
    manifest = d.with_suffix(".json")
    if manifest.is_file():
        return [manifest.read_text()]
    return [(f"{i:04d}.exr", (d / f"{i:04d}.exr").stat().st_size) for i in range(n)]


def _without_times(info: dict) -> dict:
    """Diagnostics without run times (those go to timing.json): equal inputs, byte-identical manifests."""
    return {k: v for k, v in info.items() if k != "seconds"}


def _file_digest(path) -> str:
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]
