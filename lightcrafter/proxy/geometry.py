"""Geometry from buffers: unprojection, depth-discontinuity cuts, per-pixel meshes (numpy only).

Conventions
-----------
* Pixel (row i, col j) has its centre at image coordinates (u, v) = (j, i) (OpenCV, the convention
  of ``K`` written by ``lightcrafter.blender``); its footprint is [j - 0.5, j + 0.5] x [i - 0.5, i + 0.5].
* ``depth`` is z-depth along the optical axis in metres; invalid pixels are +inf / NaN / <= 0 or
  mask 0. Camera frame OpenCV (x right, y down, z forward); ``c2w`` maps it to the world (Z up).
* Two 4-neighbour pixels are *continuous* (same surface) if their depths differ by at most
  ``rel_threshold`` times the nearer depth, or if the far one lies within that tolerance of the
  plane through the near one with its buffer normal (so grazing planes are not cut).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def valid_depth(depth: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Boolean (H, W): finite, positive depth (and mask >= 0.5 if given)."""
    d = np.asarray(depth)
    ok = np.isfinite(d) & (d > 0)
    if mask is not None:
        ok &= np.asarray(mask) >= 0.5
    return ok


def camera_rays(K: np.ndarray, height: int, width: int, offset_px: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """Camera-frame rays (H, W, 3) with z = 1 through pixel centres shifted by ``offset_px`` (du, dv)."""
    Kinv = np.linalg.inv(np.asarray(K, dtype=np.float64))
    v, u = np.meshgrid(np.arange(height, dtype=np.float64), np.arange(width, dtype=np.float64), indexing="ij")
    pix = np.stack([u + offset_px[0], v + offset_px[1], np.ones_like(u)], axis=-1)
    rays = pix @ Kinv.T
    return rays / rays[..., 2:3]


def unproject(depth: np.ndarray, K: np.ndarray, c2w: np.ndarray) -> np.ndarray:
    """World points (H, W, 3) of pixel centres at z-depth ``depth`` (NaN where depth is invalid)."""
    h, w = depth.shape
    d = np.where(valid_depth(depth), depth, np.nan).astype(np.float64)
    pc = camera_rays(K, h, w) * d[..., None]
    c2w = np.asarray(c2w, dtype=np.float64)
    return pc @ c2w[:3, :3].T + c2w[:3, 3]


def project(points_world: np.ndarray, K: np.ndarray, c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World points (..., 3) -> (u_px, v_px, z_m) in the OpenCV pixel-centre convention."""
    c2w = np.asarray(c2w, dtype=np.float64)
    pc = (np.asarray(points_world, dtype=np.float64) - c2w[:3, 3]) @ c2w[:3, :3]
    z = pc[..., 2]
    uvw = pc @ np.asarray(K, dtype=np.float64).T
    with np.errstate(divide="ignore", invalid="ignore"):
        return uvw[..., 0] / z, uvw[..., 1] / z, z


def bilateral_depth(depth: np.ndarray, valid: np.ndarray, sigma_px: float, sigma_rel: float = 0.02,
                    radius_px: int | None = None) -> np.ndarray:
    """Edge-preserving smoothing of valid depths (spatial sigma in pixels, range sigma relative to depth).

    Invalid pixels neither contribute nor change; ``sigma_px <= 0`` returns a copy.
    """
    out = np.array(depth, dtype=np.float64)
    if sigma_px <= 0:
        return out.astype(np.float32)
    r = int(radius_px if radius_px is not None else max(1, round(2 * sigma_px)))
    h, w = depth.shape
    d0 = np.where(valid, out, 0.0)
    pad_d = np.pad(d0, r)
    pad_v = np.pad(valid.astype(np.float64), r)
    num = np.zeros_like(d0)
    den = np.zeros_like(d0)
    safe = np.where(valid, d0, 1.0)
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            dn = pad_d[r + dy:r + dy + h, r + dx:r + dx + w]
            vn = pad_v[r + dy:r + dy + h, r + dx:r + dx + w]
            ws = np.exp(-(dx * dx + dy * dy) / (2 * sigma_px**2))
            wr = np.exp(-(((dn - d0) / (sigma_rel * safe)) ** 2) / 2)
            wgt = ws * wr * vn
            num += wgt * dn
            den += wgt
    out = np.where(valid & (den > 0), num / np.maximum(den, 1e-300), out)
    return out.astype(np.float32)


def continuity(depth: np.ndarray, valid: np.ndarray, K: np.ndarray, normal_cam: np.ndarray | None,
               rel_threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """Continuity of horizontal (H, W-1) and vertical (H-1, W) neighbour pairs (see module doc)."""
    h, w = depth.shape
    d = np.where(valid, depth, np.nan).astype(np.float64)
    rays = camera_rays(K, h, w)

    def pair(a, b, ra, rb, na):
        near = np.fmin(a, b)
        with np.errstate(invalid="ignore", divide="ignore"):
            ok = np.abs(a - b) <= rel_threshold * near
            if na is not None:
                # depth b predicted by the plane through a with normal na: n.(rb zb - ra za) = 0
                zb = a * np.sum(na * ra, -1) / np.sum(na * rb, -1)
                ok_a = np.abs(zb - b) <= rel_threshold * near
                ok |= ok_a & np.isfinite(zb) & (zb > 0)
        return ok & np.isfinite(a) & np.isfinite(b)

    nh = normal_cam[:, :-1] if normal_cam is not None else None
    nv = normal_cam[:-1, :] if normal_cam is not None else None
    horiz = pair(d[:, :-1], d[:, 1:], rays[:, :-1], rays[:, 1:], nh)
    vert = pair(d[:-1, :], d[1:, :], rays[:-1, :], rays[1:, :], nv)
    if normal_cam is not None:  # symmetric: also predict from the other side
        horiz |= pair(d[:, 1:], d[:, :-1], rays[:, 1:], rays[:, :-1], normal_cam[:, 1:])
        vert |= pair(d[1:, :], d[:-1, :], rays[1:, :], rays[:-1, :], normal_cam[1:, :])
    return horiz, vert


def border_mask(height: int, width: int, border_px: int) -> np.ndarray:
    """True inside the image, False on the outer ``border_px`` pixels."""
    m = np.ones((height, width), dtype=bool)
    if border_px > 0:
        m[:border_px] = m[-border_px:] = False
        m[:, :border_px] = m[:, -border_px:] = False
    return m


@dataclass
class PixelMesh:
    """Triangle mesh in world metres: ``vertices`` (V, 3) float32, ``faces`` (F, 3) uint32,
    ``face_pixel`` (F,) flat pixel index (row * W + col) each face belongs to (-1: none)."""

    vertices: np.ndarray
    faces: np.ndarray
    face_pixel: np.ndarray


def _normal_cam(normal_world: np.ndarray | None, c2w: np.ndarray) -> np.ndarray | None:
    if normal_world is None:
        return None
    return np.asarray(normal_world, dtype=np.float64) @ np.asarray(c2w, dtype=np.float64)[:3, :3]


def pixel_quad_mesh(depth: np.ndarray, valid: np.ndarray, K: np.ndarray, c2w: np.ndarray,
                    normal_world: np.ndarray | None = None, rel_threshold: float = 0.05,
                    border_px: int = 0) -> PixelMesh:
    """One quad (two triangles, four own vertices) per valid pixel covering exactly its footprint.

    Each quad corner lies on the corner's camera ray. Its inverse depth is the mean over the four
    pixels sharing the corner when all are continuous with this pixel (exact for planes and
    watertight inside a surface); otherwise it is extrapolated from this pixel's inverse-depth
    gradient over continuous neighbours. No face ever joins pixels across a discontinuity.
    """
    h, w = depth.shape
    valid = valid & valid_depth(depth) & border_mask(h, w, border_px)
    horiz, vert = continuity(depth, valid, K, _normal_cam(normal_world, c2w), rel_threshold)
    inv = np.where(valid, 1.0 / np.where(valid, depth, 1.0), 0.0).astype(np.float64)

    # continuity of pixel p with its 8 neighbours (via 4-neighbour chains for diagonals)
    def shifted(a, dy, dx, fill=False):
        out = np.full(a.shape, fill, dtype=a.dtype)
        ys = slice(max(dy, 0), h + min(dy, 0))
        yd = slice(max(-dy, 0), h + min(-dy, 0))
        xs = slice(max(dx, 0), w + min(dx, 0))
        xd = slice(max(-dx, 0), w + min(-dx, 0))
        out[yd, xd] = a[ys, xs]
        return out

    right = np.zeros((h, w), bool); right[:, :-1] = horiz
    left = np.zeros((h, w), bool); left[:, 1:] = horiz
    down = np.zeros((h, w), bool); down[:-1, :] = vert
    up = np.zeros((h, w), bool); up[1:, :] = vert
    # gradients of inverse depth per pixel (one-sided where a neighbour is cut)
    inv_r, inv_l, inv_d, inv_u = shifted(inv, 0, 1, 0.0), shifted(inv, 0, -1, 0.0), shifted(inv, 1, 0, 0.0), shifted(inv, -1, 0, 0.0)
    gx = np.where(right & left, (inv_r - inv_l) / 2, np.where(right, inv_r - inv, np.where(left, inv - inv_l, 0.0)))
    gy = np.where(down & up, (inv_d - inv_u) / 2, np.where(down, inv_d - inv, np.where(up, inv - inv_u, 0.0)))

    corners = []  # (sx, sy) in {-1, +1}: TL, TR, BR, BL
    for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
        side_x = right if sx > 0 else left
        side_y = down if sy > 0 else up
        # the diagonal neighbour is continuous with both side neighbours
        diag_x = shifted(down if sy > 0 else up, 0, sx, False)   # side-x neighbour continuous vertically
        diag_y = shifted(right if sx > 0 else left, sy, 0, False)  # side-y neighbour continuous horizontally
        all4 = side_x & side_y & diag_x & diag_y
        inv_diag = shifted(inv, sy, sx, 0.0)
        mean4 = (inv + shifted(inv, 0, sx, 0.0) + shifted(inv, sy, 0, 0.0) + inv_diag) / 4
        extrap = inv + 0.5 * sx * gx + 0.5 * sy * gy
        ci = np.where(all4, mean4, extrap)
        ci = np.where(ci > 1e-12, ci, inv)  # never behind the camera / at infinity
        corners.append(ci)

    idx = np.flatnonzero(valid.ravel())
    n = len(idx)
    rows, cols = np.divmod(idx, w)
    Kinv = np.linalg.inv(np.asarray(K, dtype=np.float64))
    c2w = np.asarray(c2w, dtype=np.float64)
    verts = np.empty((n, 4, 3), dtype=np.float64)
    for k, (sx, sy) in enumerate(((-1, -1), (1, -1), (1, 1), (-1, 1))):
        pix = np.stack([cols + 0.5 * sx, rows + 0.5 * sy, np.ones(n)], axis=-1)
        ray = pix @ Kinv.T
        ray /= ray[:, 2:3]
        z = 1.0 / corners[k].ravel()[idx]
        verts[:, k] = (ray * z[:, None]) @ c2w[:3, :3].T + c2w[:3, 3]
    base = (np.arange(n, dtype=np.uint32) * 4)[:, None]
    # winding TL, BR, TR / TL, BL, BR: geometric normals face the camera
    faces = np.concatenate([base + np.array([0, 2, 1], np.uint32), base + np.array([0, 3, 2], np.uint32)], axis=1)
    return PixelMesh(
        vertices=verts.reshape(-1, 3).astype(np.float32),
        faces=faces.reshape(-1, 3).astype(np.uint32),
        face_pixel=np.repeat(idx, 2).astype(np.int64),
    )


def pixel_grid_mesh(depth: np.ndarray, valid: np.ndarray, K: np.ndarray, c2w: np.ndarray,
                    normal_world: np.ndarray | None = None, rel_threshold: float = 0.05,
                    border_px: int = 0) -> PixelMesh:
    """Mesh with one vertex per valid pixel centre and two triangles per 2x2 block, keeping only
    triangles whose three edges are continuous (used for the aggregated visibility mesh)."""
    h, w = depth.shape
    valid = valid & valid_depth(depth) & border_mask(h, w, border_px)
    horiz, vert = continuity(depth, valid, K, _normal_cam(normal_world, c2w), rel_threshold)
    pts = unproject(np.where(valid, depth, np.inf), K, c2w).reshape(-1, 3)
    ids = np.arange(h * w).reshape(h, w)
    a, b = ids[:-1, :-1], ids[:-1, 1:]
    c, d = ids[1:, :-1], ids[1:, 1:]
    top, bottom = horiz[:-1, :], horiz[1:, :]
    lft, rgt = vert[:, :-1], vert[:, 1:]
    # diagonal b-c continuity approximated by the two paths around the block
    diag = (top & rgt) | (lft & bottom)
    t1 = top & lft & diag  # a, c, b
    t2 = rgt & bottom & diag  # b, c, d
    faces = np.concatenate([np.stack([a[t1], c[t1], b[t1]], -1), np.stack([b[t2], c[t2], d[t2]], -1)])
    used = np.unique(faces)
    remap = -np.ones(h * w, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return PixelMesh(
        vertices=pts[used].astype(np.float32),
        faces=remap[faces].astype(np.uint32).reshape(-1, 3),
        face_pixel=-np.ones(len(faces), dtype=np.int64),
    )
