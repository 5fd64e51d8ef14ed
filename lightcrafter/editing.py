"""Scene edits on the same path as relighting (the paper's "Scene Editing"): P' = R(S', L'_target).

Every edit changes the recovered scene state S (buffers of a clip) or the lighting L, then the SAME
renderer R renders the edited proxy and the SAME trained refiner refines it:

* light insertion (:func:`insert_lights`): point and area lights added to the target lighting
  (world frame, metres; additive with the environment);
* material edit (:func:`material_edit_views`): albedo / roughness / metallic overridden inside a
  world-space region (a sphere around an object, so the edit sticks to the surface as the camera moves);
* object insertion (:func:`insert_object`): a GLB mesh ray-cast into every frame's buffers at a world
  pose, composited by depth (the nearer surface wins, so existing objects occlude it correctly).

Conventions: world right-handed Z up, metres; camera OpenCV; buffers in the lightcrafter.io contract.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from lightcrafter import io
from lightcrafter.clip import FrameView
from lightcrafter.proxy.edits import MaterialEdit, apply_edits
from lightcrafter.proxy.geometry import camera_rays, unproject
from lightcrafter.proxy.lighting import AreaLight, Lighting, PointLight


# ----------------------------------------------------------------------------- lights
def insert_lights(lighting: Lighting, point_lights: list[dict] = (), area_lights: list[dict] = ()) -> Lighting:
    """The lighting plus local lights: point {position_m, intensity_w_sr}, area {center_m, normal, size_m, radiance}."""
    pts = [PointLight(tuple(map(float, p["position_m"])), tuple(map(float, p["intensity_w_sr"]))) for p in point_lights]
    areas = [AreaLight(tuple(map(float, a["center_m"])), tuple(map(float, a["normal"])), tuple(map(float, a["size_m"])),
                       tuple(map(float, a["radiance"]))) for a in area_lights]
    return replace(lighting, point_lights=list(lighting.point_lights) + pts,
                   area_lights=list(lighting.area_lights) + areas)


# ----------------------------------------------------------------------------- materials
def region_mask(view: FrameView, centre_m, radius_m: float) -> np.ndarray:
    """(H, W) 1 where the pixel's surface point lies within ``radius_m`` of world point ``centre_m``."""
    P = unproject(view.buffers.depth, view.K, view.c2w)
    d = np.linalg.norm(P - np.asarray(centre_m, np.float64), axis=-1)
    return ((d < radius_m) & (view.buffers.mask > 0.5)).astype(np.float32)


def material_edit_views(views: list[FrameView], centre_m, radius_m: float, edit: dict) -> tuple[list[FrameView], float]:
    """Views with ``edit`` (MaterialEdit fields: albedo_override, roughness_override, ...) applied in the
    region; returns (views, mean fraction of pixels edited)."""
    out, frac = [], []
    for v in views:
        m = region_mask(v, centre_m, radius_m)
        frac.append(float(m.mean()))
        out.append(FrameView(apply_edits(v.buffers, [MaterialEdit.from_dict(edit, m)]), v.K, v.c2w, v.key + "#material"))
    return out, float(np.mean(frac))


# ----------------------------------------------------------------------------- objects
def load_glb(path: str | Path):
    """(vertices (V,3) metres in the GLB's normalised frame, glTF Y up -> our Z up; faces (F,3); uv (V,2) or
    None; base colour texture (h,w,3 linear) or None; base colour factor (3, linear); roughness; metallic)."""
    import trimesh

    try:
        scene = trimesh.load(str(path), force="scene")
    except Exception as exc:  # trimesh raises many types on corrupt files
        raise io.DataError(f"{path}: cannot load GLB ({type(exc).__name__}: {exc}); use a curated asset") from exc
    meshes = [g for g in scene.dump() if isinstance(g, trimesh.Trimesh)] if hasattr(scene, "dump") else [scene]
    if not meshes:
        raise io.DataError(f"{path}: GLB has no triangle mesh; use a curated asset")
    m = meshes[0] if len(meshes) == 1 else trimesh.util.concatenate(meshes)
    yup_to_zup = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], np.float64)
    verts = np.asarray(m.vertices, np.float64) @ yup_to_zup.T
    uv, tex, factor, rough, metal = None, None, None, 0.5, 0.0
    vis = getattr(m, "visual", None)
    mat = getattr(vis, "material", None)
    if mat is not None:
        if getattr(mat, "baseColorFactor", None) is not None:
            factor = _srgb_to_linear(np.asarray(mat.baseColorFactor, np.float64)[:3] / (255.0 if np.max(mat.baseColorFactor) > 1 else 1.0))
        if getattr(mat, "baseColorTexture", None) is not None and getattr(vis, "uv", None) is not None:
            tex = _srgb_to_linear(np.asarray(mat.baseColorTexture.convert("RGB"), np.float64) / 255.0)
            uv = np.asarray(vis.uv, np.float64)
        rough = float(mat.roughnessFactor) if getattr(mat, "roughnessFactor", None) is not None else rough
        metal = float(mat.metallicFactor) if getattr(mat, "metallicFactor", None) is not None else metal
    if factor is None:  # glTF: the factor defaults to 1 (times the texture); no material at all -> light grey
        factor = np.ones(3) if tex is not None else np.full(3, 0.8)
    return verts, np.asarray(m.faces, np.int64), uv, tex, factor, rough, metal


def _srgb_to_linear(c):
    c = np.clip(np.asarray(c, np.float64), 0, 1)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def raycast(vertices: np.ndarray, faces: np.ndarray, K: np.ndarray, c2w: np.ndarray, width: int, height: int):
    """Ray-cast a triangle mesh (world metres) through every pixel centre (Mitsuba): z-depth (H,W, inf where
    missed), geometric world normal facing the camera (H,W,3), barycentric-interpolated hit (face (H,W), b1, b2)."""
    import drjit as dr
    import mitsuba as mi

    from lightcrafter.proxy.mitsuba_setup import ensure_variant

    ensure_variant()
    props = mi.Properties()
    props["bsdf"] = mi.load_dict({"type": "diffuse"})
    mesh = mi.Mesh("inserted", len(vertices), len(faces), props, False, False)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(np.ascontiguousarray(vertices, np.float32).ravel())
    params["faces"] = mi.UInt32(np.ascontiguousarray(faces, np.uint32).ravel())
    params.update()
    scene = mi.load_dict({"type": "scene", "obj": mesh})
    rays_c = camera_rays(K, height, width).reshape(-1, 3)  # z = 1: t along it is z-depth
    d_w = rays_c @ np.asarray(c2w)[:3, :3].T
    o = np.asarray(c2w)[:3, 3]
    ray = mi.Ray3f(mi.Point3f(*[mi.Float(np.full(len(d_w), o[k], np.float32)) for k in range(3)]),
                   mi.Vector3f(*[mi.Float(np.ascontiguousarray(d_w[:, k], np.float32)) for k in range(3)]))
    si = scene.ray_intersect(ray)
    dr.eval(si.t, si.n, si.prim_index, si.uv)
    t = np.asarray(si.t, np.float64)
    valid = np.isfinite(t) & np.asarray(si.is_valid())
    n = np.stack([np.asarray(si.n.x), np.asarray(si.n.y), np.asarray(si.n.z)], -1).astype(np.float64)
    flip = (n * d_w).sum(-1) > 0
    n[flip] *= -1
    bary = np.stack([np.asarray(si.uv.x), np.asarray(si.uv.y)], -1)  # Mitsuba's barycentrics on a triangle
    depth = np.where(valid, t, np.inf).reshape(height, width)
    return depth, n.reshape(height, width, 3), np.asarray(si.prim_index, np.int64).reshape(height, width), \
        bary.reshape(height, width, 2), valid.reshape(height, width)


def free_ground_spot(spec: dict, ring_m: tuple[float, float] = (0.6, 1.4), samples: int = 72) -> np.ndarray:
    """A point on the ground (z = 0) at least as far as possible from every object's footprint, on a ring
    around the scene centre (deterministic)."""
    objs = spec.get("objects", [])
    best, best_gap = None, -np.inf
    for r in np.linspace(*ring_m, 5):
        for a in np.linspace(0, 2 * np.pi, samples, endpoint=False):
            p = np.array([r * np.cos(a), r * np.sin(a)])
            gap = min((np.linalg.norm(p - np.asarray(o["location_m"][:2])) - o["footprint_radius_m"] for o in objs),
                      default=np.inf)
            if gap > best_gap:
                best, best_gap = p, gap
    return np.array([best[0], best[1], 0.0])


def insert_object(views: list[FrameView], glb_path, location_m, yaw_rad: float = 0.0, scale: float = 1.0
                  ) -> tuple[list[FrameView], float]:
    """Views with the GLB rendered into their buffers (depth test against the existing surfaces);
    returns (views, mean fraction of pixels where the object is visible)."""
    verts, faces, uv, tex, factor, rough, metal = load_glb(glb_path)
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    world = (verts * scale) @ Rz.T + np.asarray(location_m, np.float64)
    out, frac = [], []
    for v in views:
        h, w = v.buffers.shape
        depth, normal, face, bary, hit = raycast(world, faces, v.K, v.c2w, w, h)
        old = np.where(v.buffers.mask > 0.5, v.buffers.depth, np.inf)
        take = hit & (depth < old)
        albedo = np.broadcast_to(factor, (h, w, 3)).copy()
        if tex is not None and uv is not None:
            f = faces[np.clip(face, 0, len(faces) - 1)]
            b1, b2 = bary[..., 0:1], bary[..., 1:2]
            uvp = (1 - b1 - b2) * uv[f[..., 0]] + b1 * uv[f[..., 1]] + b2 * uv[f[..., 2]]
            th, tw = tex.shape[:2]
            tx = np.clip((uvp[..., 0] % 1.0) * tw, 0, tw - 1).astype(int)
            ty = np.clip((1 - uvp[..., 1] % 1.0) * th, 0, th - 1).astype(int)
            albedo = tex[ty, tx] * factor
        b = v.buffers
        nb = io.Buffers(
            depth=np.where(take, depth, b.depth).astype(np.float32),
            normal=np.where(take[..., None], normal, b.normal).astype(np.float32),
            albedo=np.where(take[..., None], albedo, b.albedo).astype(np.float32),
            roughness=np.where(take, rough, b.roughness).astype(np.float32),
            metallic=np.where(take, metal, b.metallic).astype(np.float32),
            mask=np.where(take, 1.0, b.mask).astype(np.float32))
        frac.append(float(take.mean()))
        out.append(FrameView(nb, v.K, v.c2w, v.key + "#object"))
    return out, float(np.mean(frac))
