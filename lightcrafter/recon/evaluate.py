"""Errors of the reconstruction stack against ground truth, per clip and per motion config.

For a synthetic trajectory: the Phi clip (its cameras' registration), the aligned clip (lightcrafter.recon.align)
and the ground-truth clip. All errors are on the ALIGNED reconstruction (the one R renders):

* depth_abs_rel: mean |d - d_gt| / d_gt over pixels that are surface in both (no further rescaling);
* normal_deg: mean angle between world normals (degrees);
* ground_tilt_deg: angle (degrees) between world +Z and the mean aligned normal over the ground-truth ground
  (:func:`ground_pixels`, all distinct frames): the tilt of the plane Phi snaps its ground to, which decides
  the shading of most of a frame under a low sun (NaN when no frame sees ground);
* albedo_psnr_db: PSNR of linear albedo, peak 1; roughness_mae, metallic_mae;
* albedo_psnr_db_colour_fit: the same after the clip's per-channel least-squares gain
  (:func:`albedo_colour_gain`, also reported as ``albedo_colour_gain``): the albedo's error up to one colour
  for the whole clip, which one video cannot tell from the light's colour (a pink ground under white light and
  a grey one under pink light give the same frames); the gap to ``albedo_psnr_db`` is what the clip's colour
  costs;
* rotation_deg: median over frames of the angle of R_gt^T R_aligned (camera orientation error, degrees);
* translation_m: median distance between aligned and true camera centres (metres);
* registered_fraction: frames the SfM registered (static cameras count as registered);
* mask_iou of surface masks.
"""

from __future__ import annotations

import numpy as np

from lightcrafter import clip as clipmod
from lightcrafter import io
from lightcrafter.recon.estimator import buffer_errors

GROUND_DEG = 2.0  # a ground-truth normal within this angle of world +Z is ground


def ground_pixels(gt: io.Buffers, max_deg: float = GROUND_DEG) -> np.ndarray:
    """(H, W) bool: surface pixels of ground-truth buffers whose world normal is within ``max_deg`` degrees of
    world +Z (the Z-up world of the scenes)."""
    return (gt.mask > 0.5) & np.isfinite(gt.depth) & (gt.normal[..., 2] > np.cos(np.radians(max_deg)))


def ground_tilt_deg(pred: list[io.Buffers], gt: list[io.Buffers]) -> float:
    """Angle (degrees) between +Z and the mean of ``pred``'s world normals over the pixels that are ground in
    ``gt`` (:func:`ground_pixels`) and surface in ``pred``, over all frames; NaN when there are none."""
    total = np.zeros(3)
    for p, g in zip(pred, gt):
        on = ground_pixels(g) & (p.mask > 0.5)
        total += p.normal[on].astype(np.float64).sum(0)
    norm = np.linalg.norm(total)
    return float(np.degrees(np.arccos(np.clip(total[2] / norm, -1.0, 1.0)))) if norm > 0 else float("nan")


def albedo_colour_gain(pred: list[io.Buffers], gt: list[io.Buffers]) -> np.ndarray:
    """(3,) per-channel gain g minimising the squared error of g * pred albedo against ``gt``'s (linear) over the
    pixels that are surface in both, all frames together; ones when no pixel is (or a channel is black)."""
    num, den = np.zeros(3), np.zeros(3)
    for p, g in zip(pred, gt):
        both = (p.mask > 0.5) & (g.mask > 0.5)
        a, b = p.albedo[both].astype(np.float64), g.albedo[both].astype(np.float64)
        num += (a * b).sum(0)
        den += (a * a).sum(0)
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), 1.0)


def rotation_angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    c = (np.trace(np.asarray(Ra).T @ np.asarray(Rb)) - 1) / 2
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def clip_errors(est_clip, aligned_clip, gt_clip) -> dict:
    """Errors of one synthetic clip (see module docstring); ``skipped`` when Phi left it out."""
    reason = clipmod.is_skipped(est_clip)
    if reason:
        return {"skipped": reason}
    views_a, info_a = clipmod.read_clip(aligned_clip)
    views_g, info_g = clipmod.read_clip(gt_clip)
    est = clipmod.read_info(est_clip)
    frames = list(info_g.distinct_frames)
    pred_frames, gt_frames = [views_a[i].buffers for i in frames], [views_g[i].buffers for i in frames]
    gain = albedo_colour_gain(pred_frames, gt_frames)
    rows = []
    for a, g in zip(pred_frames, gt_frames):
        pred = {"depth": a.depth, "normal": a.normal, "albedo": a.albedo, "roughness": a.roughness,
                "metallic": a.metallic, "mask": a.mask}
        rows.append(buffer_errors(pred, g, None, align_depth_scale=False))
        fit = buffer_errors({**pred, "albedo": np.clip(a.albedo * gain, 0.0, 1.0)}, g, None, align_depth_scale=False)
        rows[-1]["albedo_psnr_db_colour_fit"] = fit["albedo_psnr_db"]
    keys = [k for k in rows[0] if k != "pixels"]
    out = {k: float(np.nanmean([r[k] for r in rows])) for k in keys}
    out["albedo_colour_gain"] = np.round(gain, 4).tolist()
    out["ground_tilt_deg"] = ground_tilt_deg(pred_frames, gt_frames)
    rot = [rotation_angle_deg(va.c2w[:3, :3], vg.c2w[:3, :3]) for va, vg in zip(views_a, views_g)]
    trans = [float(np.linalg.norm(va.c2w[:3, 3] - vg.c2w[:3, 3])) for va, vg in zip(views_a, views_g)]
    phi = est.manifest.get("phi", {})
    reg = phi.get("registered_per_frame")
    out.update({
        "rotation_deg": float(np.median(rot)), "rotation_deg_max": float(np.max(rot)),
        "translation_m": float(np.median(trans)),
        "registered_fraction": float(np.mean(reg)) if reg else 1.0,
        "camera_method": phi.get("method"), "camera_static_detected": bool(est.camera_static),
        "buffer_frames": int(est.manifest.get("buffer_frames", 0)), "frames": info_g.num_frames,
        "align": info_a.manifest.get("align"),
    })
    return out


def summarize(per_clip: dict[str, dict], motions: dict[str, str]) -> dict:
    """Means per motion config and overall; counts of registered frames and skipped clips."""
    out = {"clips": len(per_clip), "skipped": {k: v["skipped"] for k, v in per_clip.items() if "skipped" in v},
           "by_motion": {}}
    keys = ("depth_abs_rel", "normal_deg", "albedo_psnr_db", "albedo_psnr_db_colour_fit", "roughness_mae",
            "metallic_mae", "mask_iou", "rotation_deg", "translation_m", "registered_fraction")
    groups: dict[str, list[dict]] = {}
    for cid, e in per_clip.items():
        if "skipped" not in e:
            groups.setdefault(motions.get(cid, "unknown"), []).append(e)
            groups.setdefault("all", []).append(e)
    for motion, rows in sorted(groups.items()):
        out["by_motion"][motion] = {"clips": len(rows), **{k: float(np.mean([r[k] for r in rows])) for k in keys}}
        out["by_motion"][motion]["rotation_deg_median"] = float(np.median([r["rotation_deg"] for r in rows]))
        tilts = [r["ground_tilt_deg"] for r in rows if np.isfinite(r.get("ground_tilt_deg", np.nan))]
        out["by_motion"][motion]["ground_tilt_deg_median"] = float(np.median(tilts)) if tilts else None
    moving = [e for cid, e in per_clip.items() if "skipped" not in e and not e["camera_static_detected"]]
    n_mov = sum(e["frames"] for e in moving)
    out["moving_camera_frames_registered"] = (float(sum(e["registered_fraction"] * e["frames"] for e in moving) / n_mov)
                                             if n_mov else None)
    return out
