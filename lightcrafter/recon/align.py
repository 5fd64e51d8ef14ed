"""Align(S~, S_gt): bring a reconstruction into the ground-truth world frame (synthetic clips only).

Monocular reconstruction has an arbitrary world frame and scale, and its depth maps may carry a scale
of their own; rendered as is, lighting directions and shadow lengths would not match the Blender
target. Align estimates a LOW-DIMENSIONAL correction from the ground truth and applies it, leaving
every local error (holes, blur, wrong materials, per-frame depth errors, camera drift) in place:

* a global similarity x_gt = s R x_est + t (7 numbers) from the cameras:
  - R: the rotation closest (chordal L2, via SVD) to the mean of R_gt_i R_est_i^T over frames. On the
    short, nearly straight camera paths of these clips the camera centres alone constrain rotation
    poorly (Umeyama on centres of a 16-degree arc was off by 5-15 degrees where this is off by the
    cameras' own error), so the orientations fix R;
  - s: the ratio of the RMS spreads of the camera centres about their means (exact for a similarity,
    and positive however wrong R is, where the least-squares scale given R can turn negative on a
    poorly reconstructed path); t = mean(c_gt) - s R mean(c_est); a static camera (all centres equal,
    in the ground truth or the estimate) takes s from the depth maps instead;
* a depth-scale correction k (1 number): the median over surface pixels of d_gt / (s d_est), applied
  to every depth map, so depth and camera units agree.

Poses become c2w_aligned = [[R c2w_R, s R c_est + t]] (OpenCV camera axes kept), depth s k d_est,
normals R n. Albedo, roughness, metallic and masks are untouched.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lightcrafter import io


@dataclass
class Similarity:
    """x_gt = scale * R @ x_est + t (world metres); depth_scale multiplies depth maps after ``scale``."""

    R: np.ndarray
    t: np.ndarray
    scale: float
    depth_scale: float = 1.0

    def as_dict(self) -> dict:
        return {"R": np.asarray(self.R).round(12).tolist(), "t": np.asarray(self.t).round(12).tolist(),
                "scale": float(self.scale), "depth_scale": float(self.depth_scale)}


def closest_rotation(M: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def estimate(c2w_est: np.ndarray, c2w_gt: np.ndarray, depth_est: list[np.ndarray] | None = None,
             depth_gt: list[np.ndarray] | None = None, where: str = "clip") -> Similarity:
    """Similarity + depth scale from per-frame cameras (N,4,4) and optionally depth maps (for k, and for
    s when the camera is static). Depth maps: z-depth, invalid = non-finite or <= 0."""
    c2w_est, c2w_gt = np.asarray(c2w_est, np.float64), np.asarray(c2w_gt, np.float64)
    if c2w_est.shape != c2w_gt.shape or c2w_est.ndim != 3:
        raise io.DataError(f"{where}: {len(c2w_est)} estimated and {len(c2w_gt)} ground-truth cameras; they must match")
    R = closest_rotation(sum(g[:3, :3] @ e[:3, :3].T for e, g in zip(c2w_est, c2w_gt)))
    ce, cg = c2w_est[:, :3, 3], c2w_gt[:, :3, 3]
    ce_c, cg_c = ce - ce.mean(0), cg - cg.mean(0)
    spread, spread_gt = float((ce_c ** 2).sum()), float((cg_c ** 2).sum())
    ratio = _depth_ratio(depth_est, depth_gt)
    moving = (spread > 1e-12 * max(1.0, float((ce ** 2).sum()))
              and spread_gt > 1e-12 * max(1.0, float((cg ** 2).sum())))
    if moving:
        s = float(np.sqrt(spread_gt / spread))  # RMS spread ratio: positive whatever the error of R
    else:  # a static camera (in the ground truth or the estimate; an estimate's jitter about a static
        # camera has no scale to match): the depth maps carry the scale
        if ratio is None:
            raise io.DataError(f"{where}: static camera and no depth to scale the reconstruction; cannot align")
        s = ratio
    if not np.isfinite(s) or s <= 0:
        raise io.DataError(f"{where}: alignment scale {s} is not positive; the reconstruction is degenerate")
    t = cg.mean(0) - s * R @ ce.mean(0)
    k = 1.0 if ratio is None else ratio / s
    return Similarity(R=R, t=t, scale=s, depth_scale=float(k))


def _depth_ratio(depth_est, depth_gt) -> float | None:
    if depth_est is None or depth_gt is None:
        return None
    r = []
    for de, dg in zip(depth_est, depth_gt):
        ok = np.isfinite(de) & np.isfinite(dg) & (de > 0) & (dg > 0)
        if ok.any():
            r.append(dg[ok] / de[ok])
    return float(np.median(np.concatenate(r))) if r else None


def apply_pose(sim: Similarity, c2w: np.ndarray) -> np.ndarray:
    c2w = np.asarray(c2w, np.float64)
    out = c2w.copy()
    out[..., :3, :3] = sim.R @ c2w[..., :3, :3]
    out[..., :3, 3] = sim.scale * c2w[..., :3, 3] @ sim.R.T + sim.t
    return out


def apply_buffers(sim: Similarity, b: io.Buffers) -> io.Buffers:
    valid = np.isfinite(b.depth) & (b.mask > 0.5)
    depth = np.where(valid, b.depth * (sim.scale * sim.depth_scale), np.inf).astype(np.float32)
    normal = (b.normal.astype(np.float64) @ sim.R.T).astype(np.float32)
    return io.Buffers(depth=depth, normal=normal, albedo=b.albedo, roughness=b.roughness, metallic=b.metallic,
                      mask=b.mask)


def align_clip(est_clip, gt_clip, out_clip) -> dict:
    """Write the aligned copy of clip ``est_clip`` (units metres) using ground-truth clip ``gt_clip``;
    returns the manifest. The similarity and depth scale are recorded in the manifest (``align``)."""
    from lightcrafter import clip as clipmod

    views_e, info_e = clipmod.read_clip(est_clip)
    views_g, info_g = clipmod.read_clip(gt_clip)
    where = str(info_e.root)
    if info_e.num_frames != info_g.num_frames:
        raise io.DataError(f"{where}: {info_e.num_frames} frames but ground truth {info_g.root} has {info_g.num_frames}")
    if (info_e.width, info_e.height) != (info_g.width, info_g.height):
        raise io.DataError(f"{where}: {info_e.width}x{info_e.height} but ground truth is {info_g.width}x{info_g.height}")
    Ke = np.stack([v.K for v in views_e])
    sim = estimate(np.stack([v.c2w for v in views_e]), np.stack([v.c2w for v in views_g]),
                   [views_e[i].buffers.depth for i in info_e.distinct_frames],
                   [views_g[i].buffers.depth for i in info_e.distinct_frames], where)
    inputs = {"what": "aligned", "est": clipmod.identity(info_e.root), "gt": clipmod.identity(info_g.root)}
    frames = clipmod.buffer_frames(out_clip, inputs)
    distinct = info_e.distinct_frames
    todo = frames.missing(distinct, io.read_buffers)
    for i in todo:
        frames.stamp()
        io.write_buffers(frames.path(i), apply_buffers(sim, views_e[i].buffers))
    serve = [distinct[[info_e.frames[j] for j in distinct].index(rel)] for rel in info_e.frames]
    extra = {k: v for k, v in info_e.manifest.items() if k not in (
        "format", "width", "height", "num_frames", "fps", "buffer_frames", "frames", "cameras", "confidence",
        "camera_static", "scene_static", "units", "producer", "content_id")}
    return clipmod.write_clip(
        out_clip, serve=serve, K=Ke, c2w=apply_pose(sim, np.stack([v.c2w for v in views_e])),
        width=info_e.width, height=info_e.height, fps=info_e.fps, camera_static=info_e.camera_static,
        scene_static=info_e.scene_static, units="metres",
        producer={"stage": "align", "source": info_e.producer}, content_id=io.fingerprint(inputs),
        extra={**extra, "align": sim.as_dict()},
    )
