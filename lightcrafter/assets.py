"""Assets: a procedural source of "Objaverse-style" GLBs, and curation of any GLB folder.

Objaverse-style means: binary glTF files with PBR metallic-roughness materials and base-colour
textures, at arbitrary scale and orientation. The procedural generator makes such files offline
(revolved profiles, superquadrics, star extrusions and concave compounds); a user points
``assets.dir`` at a folder of real Objaverse GLBs instead.

Curation (:func:`curate_folder`) loads each file, rejects it with a recorded reason (unreadable,
empty, degenerate), decimates heavy meshes with pymeshlab instead of dropping them, puts the asset
on its most stable resting pose, normalises its size and ground contact, and writes a manifest.

Frames: glTF is Y-up (metres); Blender's importer turns it into Z-up. Curated GLBs are therefore
normalised in the glTF frame: base on y = 0, centred on x = z = 0, largest extent ``target_size_m``.
"""

from __future__ import annotations

import hashlib
import io as _io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lightcrafter.config.models import Curation
from .io import atomic_path, write_json

# ----------------------------------------------------------------------------- generation
SHAPE_KINDS = ("revolve", "superquadric", "extrusion", "compound")


def _uv_cylindrical(vertices: np.ndarray) -> np.ndarray:
    """Cylindrical UVs about the local Y axis: u = azimuth / 2pi, v = normalised height."""
    c = vertices - vertices.mean(axis=0)
    u = (np.arctan2(c[:, 2], c[:, 0]) / (2 * np.pi)) % 1.0
    y = c[:, 1]
    v = (y - y.min()) / max(float(np.ptp(y)), 1e-9)
    return np.stack([u, v], axis=1)


def _texture(rng: np.random.Generator, size: int = 64):
    """A small base-colour texture (sRGB-encoded PNG, as glTF requires): stripes, checks or dots."""
    from PIL import Image

    c1, c2 = rng.uniform(0.05, 0.95, 3), rng.uniform(0.05, 0.95, 3)
    yy, xx = np.mgrid[0:size, 0:size] / size
    kind = rng.integers(3)
    freq = rng.integers(2, 8)
    if kind == 0:
        t = (np.sin(2 * np.pi * freq * (xx + 0.3 * yy)) > 0).astype(float)
    elif kind == 1:
        t = ((np.floor(xx * freq) + np.floor(yy * freq)) % 2).astype(float)
    else:
        t = ((((xx * freq) % 1 - 0.5) ** 2 + ((yy * freq) % 1 - 0.5) ** 2) < 0.08).astype(float)
    img = c1[None, None] * (1 - t[..., None]) + c2[None, None] * t[..., None]
    return Image.fromarray((img * 255).round().astype(np.uint8), "RGB")


def _revolve(rng):
    import trimesh

    n = int(rng.integers(5, 10))
    heights = np.sort(rng.uniform(0, 1, n))
    heights[0], heights[-1] = 0.0, 1.0
    radii = rng.uniform(0.15, 0.5, n)
    profile = np.column_stack([radii, heights])
    profile = np.vstack([[0.0, 0.0], profile, [0.0, 1.0]])
    mesh = trimesh.creation.revolve(profile, sections=int(rng.integers(24, 64)))
    return mesh  # revolve() spins about Z


def _superquadric(rng, res: int):
    import trimesh

    e1, e2 = rng.uniform(0.2, 2.5, 2)
    a = rng.uniform(0.3, 1.0, 3)

    def f(w, m):
        return np.sign(np.cos(w)) * np.abs(np.cos(w)) ** m, np.sign(np.sin(w)) * np.abs(np.sin(w)) ** m

    eta = np.linspace(-np.pi / 2, np.pi / 2, res)
    om = np.linspace(-np.pi, np.pi, 2 * res, endpoint=False)
    E, O = np.meshgrid(eta, om, indexing="ij")
    ce, se = f(E, e1)
    co, so = f(O, e2)
    verts = np.stack([a[0] * ce * co, a[1] * ce * so, a[2] * se], axis=-1).reshape(-1, 3)
    faces = []
    nw = 2 * res
    for i in range(res - 1):
        for j in range(nw):
            p, q = i * nw + j, i * nw + (j + 1) % nw
            faces += [[p, p + nw, q], [q, p + nw, q + nw]]
    mesh = trimesh.Trimesh(verts, np.array(faces), process=True)
    mesh.merge_vertices()
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.fix_normals()
    return mesh


def _extrusion(rng):
    import trimesh

    k = int(rng.integers(4, 9))
    ang = np.linspace(0, 2 * np.pi, 2 * k, endpoint=False)
    r = np.where(np.arange(2 * k) % 2 == 0, 1.0, rng.uniform(0.35, 0.75))
    poly = np.column_stack([r * np.cos(ang), r * np.sin(ang)]) * 0.5
    verts2 = np.vstack([[0.0, 0.0], poly])
    faces2 = np.array([[0, 1 + i, 1 + (i + 1) % (2 * k)] for i in range(2 * k)])
    return trimesh.creation.extrude_triangulation(verts2, faces2, height=float(rng.uniform(0.2, 1.0)))


def _compound(rng):
    """A concave compound: a base block with a handle (torus) and a post (cylinder)."""
    import trimesh

    base = trimesh.creation.box(extents=rng.uniform(0.4, 1.0, 3))
    torus = trimesh.creation.torus(major_radius=0.3, minor_radius=0.06, major_sections=32, minor_sections=12)
    torus.apply_translation([0.45, 0, 0.2])
    post = trimesh.creation.cylinder(radius=0.08, height=0.8, sections=20)
    post.apply_translation([-0.25, 0.1, 0.6])
    return trimesh.util.concatenate([base, torus, post])


def generate_asset(seed: int, index: int, heavy: bool = False):
    """Build one procedural asset as a ``trimesh.Scene`` (pure function of seed and index).

    Each asset has a PBR metallic-roughness material with a base-colour texture and cylindrical
    UVs, a random overall scale (0.02 to 50 units, as Objaverse files come) and a random rotation.
    ``heavy`` makes a dense superquadric (>100k faces) to exercise decimation.
    """
    import trimesh

    rng = np.random.default_rng([seed, index, 0xA55E7])
    kind = "superquadric" if heavy else SHAPE_KINDS[index % len(SHAPE_KINDS)]
    if kind == "revolve":
        mesh = _revolve(rng)
    elif kind == "superquadric":
        mesh = _superquadric(rng, res=240 if heavy else int(rng.integers(20, 40)))
    elif kind == "extrusion":
        mesh = _extrusion(rng)
    else:
        mesh = _compound(rng)
    metallic = float(rng.uniform(0.8, 1.0)) if rng.random() < 0.25 else float(rng.uniform(0.0, 0.1))
    material = trimesh.visual.material.PBRMaterial(
        name=f"mat_{index}",
        baseColorTexture=_texture(rng),
        baseColorFactor=[255, 255, 255, 255],
        metallicFactor=metallic,
        roughnessFactor=float(rng.uniform(0.1, 0.9)),
    )
    mesh.visual = trimesh.visual.TextureVisuals(uv=_uv_cylindrical(mesh.vertices), material=material)
    rot = trimesh.transformations.random_rotation_matrix(rng.random(3))
    scale = float(10 ** rng.uniform(np.log10(0.02), np.log10(50.0)))
    mesh.apply_transform(rot)
    mesh.apply_scale(scale)
    scene = trimesh.Scene()
    scene.add_geometry(mesh, geom_name=f"{kind}_{index}")
    return scene, kind


def write_procedural_assets(out_dir: str | Path, seed: int, count: int, heavy_every: int = 0,
                            include_faulty: bool = False) -> list[Path]:
    """Write ``count`` procedural GLBs to ``out_dir`` (``proc_0000.glb`` ...).

    ``heavy_every`` = k makes every k-th asset a dense mesh (0 = none). ``include_faulty`` adds two
    files a real download folder also has: a truncated GLB and a GLB whose mesh is flat
    (zero thickness), so that curation's rejection path runs in every pipeline run.
    """
    import trimesh

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for i in range(count):
        heavy = heavy_every > 0 and (i + 1) % heavy_every == 0
        scene, _ = generate_asset(seed, i, heavy=heavy)
        path = out_dir / f"proc_{i:04d}.glb"
        data = scene.export(file_type="glb")
        with atomic_path(path) as tmp:
            tmp.write_bytes(data)
        paths.append(path)
    if include_faulty:
        good = paths[0].read_bytes() if paths else b"glTF"
        bad = out_dir / "faulty_truncated.glb"
        with atomic_path(bad) as tmp:
            tmp.write_bytes(good[: len(good) // 3])
        gx, gy = np.meshgrid(np.linspace(0, 1, 5), np.linspace(0, 1, 5))
        grid = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(25)])
        quads = [(r * 5 + c, r * 5 + c + 1, (r + 1) * 5 + c) for r in range(4) for c in range(4)]
        quads += [(r * 5 + c + 1, (r + 1) * 5 + c + 1, (r + 1) * 5 + c) for r in range(4) for c in range(4)]
        flat = trimesh.Trimesh(grid, np.array(quads))
        flat_path = out_dir / "faulty_flat.glb"
        data = trimesh.Scene(flat).export(file_type="glb")
        with atomic_path(flat_path) as tmp:
            tmp.write_bytes(data)
        paths += [bad, flat_path]
    return paths


# ----------------------------------------------------------------------------- curation
# The curation settings are config assets.curation (one definition of keys and defaults).
CurationSettings = Curation


class AssetRejected(Exception):
    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


def load_glb(path: str | Path):
    """Load a GLB as a ``trimesh.Scene``; raise :class:`AssetRejected` with a reason on failure."""
    import trimesh

    path = Path(path)
    if path.stat().st_size == 0:
        raise AssetRejected("unreadable: empty file")
    try:
        scene = trimesh.load(str(path), force="scene", process=False)
    except Exception as exc:  # trimesh raises many types on corrupt input
        raise AssetRejected(f"unreadable: {type(exc).__name__}: {str(exc).splitlines()[0][:120] if str(exc) else ''}")
    meshes = [g for g in scene.geometry.values() if isinstance(g, trimesh.Trimesh)]
    if not meshes or sum(len(m.faces) for m in meshes) == 0:
        raise AssetRejected("empty: no triangles")
    return scene


def _decimate(mesh, target_faces: int):
    """Quadric edge-collapse decimation with pymeshlab; per-vertex UVs of kept vertices survive."""
    import pymeshlab
    import trimesh

    uv = getattr(mesh.visual, "uv", None)
    kwargs = {}
    if uv is not None and len(uv) == len(mesh.vertices):
        kwargs["v_tex_coords_matrix"] = np.asarray(uv, dtype=np.float64)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.asarray(mesh.vertices, np.float64),
                               face_matrix=np.asarray(mesh.faces, np.int32), **kwargs))
    ms.apply_filter("meshing_decimation_quadric_edge_collapse", targetfacenum=int(target_faces),
                    preservenormal=True, preserveboundary=True, optimalplacement=False)
    ms.apply_filter("meshing_remove_unreferenced_vertices")
    m = ms.current_mesh()
    out = trimesh.Trimesh(m.vertex_matrix(), m.face_matrix(), process=False)
    if "v_tex_coords_matrix" in kwargs and m.has_vertex_tex_coord():
        out.visual = trimesh.visual.TextureVisuals(uv=m.vertex_tex_coord_matrix(), material=mesh.visual.material)
    elif hasattr(mesh.visual, "material"):
        out.visual = trimesh.visual.TextureVisuals(material=mesh.visual.material)
    return out


def curate_asset(path: str | Path, settings: CurationSettings):
    """Load, validate, decimate and normalise one GLB. Returns (scene, record) or raises AssetRejected.

    The record holds face counts before/after, the footprint radius (max horizontal distance of a
    vertex from the vertical axis, metres) and height (metres) in the normalised glTF (Y-up) frame.
    """
    import trimesh

    scene = load_glb(path)
    meshes = []
    for node in scene.graph.nodes_geometry:
        transform, geom_name = scene.graph[node]
        g = scene.geometry[geom_name]
        if not isinstance(g, trimesh.Trimesh) or len(g.faces) == 0:
            continue
        g = g.copy()
        g.apply_transform(transform)
        meshes.append(g)
    if not meshes:
        raise AssetRejected("empty: no triangles")
    verts = np.concatenate([m.vertices for m in meshes])
    if not np.isfinite(verts).all():
        raise AssetRejected("degenerate: non-finite vertex coordinates")
    faces_in = int(sum(len(m.faces) for m in meshes))
    if faces_in < settings.min_faces:
        raise AssetRejected(f"degenerate: {faces_in} faces < min_faces {settings.min_faces}")
    ext = np.ptp(verts, axis=0)
    if ext.max() <= 0 or ext.min() / ext.max() < settings.min_thickness_ratio:
        raise AssetRejected(
            f"degenerate: flat or thin (extent ratio {ext.min() / max(ext.max(), 1e-30):.2g} "
            f"< min_thickness_ratio {settings.min_thickness_ratio})")
    if sum(float(m.area) for m in meshes) <= 0:
        raise AssetRejected("degenerate: zero surface area")

    # Decimate heavy meshes, each in proportion to its share of the faces.
    decimated = faces_in > settings.max_faces
    if decimated:
        meshes = [_decimate(m, max(settings.min_faces, int(settings.max_faces * len(m.faces) / faces_in)))
                  for m in meshes]

    # Most stable resting pose of the whole asset (convex hull), expressed Y-up for glTF.
    combined = trimesh.util.concatenate([trimesh.Trimesh(m.vertices, m.faces, process=False) for m in meshes])
    hull = combined.convex_hull
    poses, probs = trimesh.poses.compute_stable_poses(hull, n_samples=1)
    rest = poses[int(np.argmax(probs))] if len(poses) else np.eye(4)  # rests on z = 0 (Z-up)
    z_up_to_y_up = np.array([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]], dtype=float)
    T = z_up_to_y_up @ rest
    for m in meshes:
        m.apply_transform(T)
    verts = np.concatenate([m.vertices for m in meshes])
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    centre = np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])
    scale = settings.target_size_m / float(np.max(hi - lo))
    out = trimesh.Scene()
    for k, m in enumerate(meshes):
        m.apply_translation(-centre)
        m.apply_scale(scale)
        out.add_geometry(m, geom_name=f"part_{k}")
    verts = np.concatenate([m.vertices for m in meshes])
    record = {
        "faces_in": faces_in,
        "faces_out": int(sum(len(m.faces) for m in meshes)),
        "decimated": bool(decimated),
        "height_m": round(float(verts[:, 1].max()), 6),
        "footprint_radius_m": round(float(np.sqrt(verts[:, 0] ** 2 + verts[:, 2] ** 2).max()), 6),
        "source_scale": round(float(1.0 / scale), 6),
    }
    return out, record


def list_glbs(src_dir: str | Path) -> list[Path]:
    """Every ``*.glb`` under ``src_dir`` at any depth (Objaverse: ``glbs/000-xxx/<uid>.glb``), sorted by
    relative path; hidden files (a writer's temporaries) are left out. Asset ids are file stems: two
    files of one name are an error, as is a folder without any GLB."""
    from .io import DataError

    src_dir = Path(src_dir)
    if not src_dir.is_dir():
        raise DataError(f"{src_dir}: asset folder not found; set assets.dir to a folder of .glb files")
    files = sorted((f for f in src_dir.rglob("*.glb")
                    if not any(part.startswith(".") for part in f.relative_to(src_dir).parts)),
                   key=lambda f: f.relative_to(src_dir).as_posix())
    if not files:
        raise DataError(f"{src_dir}: no .glb file at any depth; set assets.dir to a folder of .glb files")
    stems: dict[str, Path] = {}
    for f in files:
        if f.stem in stems:
            raise DataError(f"{src_dir}: two assets are named {f.stem!r} ({stems[f.stem]} and {f}); asset ids are "
                            "file names, rename one")
        stems[f.stem] = f
    return files


def _curate_resumable(f: Path, out_dir: Path, settings: CurationSettings, logger) -> tuple[str, dict]:
    """("accepted" | "rejected", entry) for one GLB, reusing ``out_dir/<id>.record.json`` when it was
    written for this file (path, size, mtime) and these settings, and its curated GLB is intact."""
    from .io import fingerprint, read_json

    aid = f.stem
    st = f.stat()
    key = fingerprint({"settings": settings.model_dump(), "source": str(f), "size": st.st_size, "mtime_ns": st.st_mtime_ns})
    rec_path = out_dir / f"{aid}.record.json"
    if rec_path.is_file():
        try:
            rec = read_json(rec_path)
        except Exception:
            rec = {}
        if rec.get("key") == key:
            kind, entry = rec.get("kind"), rec.get("entry", {})
            if kind == "rejected" or (kind == "accepted" and Path(entry.get("path", "")).is_file()
                                      and hashlib.sha256(Path(entry["path"]).read_bytes()).hexdigest() == entry.get("sha256")):
                return kind, entry
    try:
        scene, record = curate_asset(f, settings)
    except AssetRejected as rej:
        logger(f"rejected {f}: {rej.reason}")
        kind, entry = "rejected", {"id": aid, "source": str(f), "reason": rej.reason}
    else:
        data = scene.export(file_type="glb")
        dst = out_dir / f"{aid}.glb"
        with atomic_path(dst) as tmp:
            tmp.write_bytes(data)
        logger(f"accepted {f}: {record['faces_in']} -> {record['faces_out']} faces")
        kind, entry = "accepted", {"id": aid, "source": str(f), "path": str(dst),
                                   "sha256": hashlib.sha256(data).hexdigest(), **record}
    write_json(rec_path, {"key": key, "kind": kind, "entry": entry})
    return kind, entry


def curate_folder(src_dir: str | Path, out_dir: str | Path, manifest_path: str | Path,
                  settings: CurationSettings, logger=print, shard: tuple[int, int] = (0, 1)) -> dict:
    """Curate the GLBs under ``src_dir`` (:func:`list_glbs`) into ``out_dir`` and write the manifest (JSON).

    Manifest: ``{"settings": ..., "accepted": [{id, path, sha256, ...record}], "rejected":
    [{id, source, reason}]}``, sorted by id so equal inputs give identical manifests. ``shard`` = (k, n):
    only every n-th file from the k-th (one job of an array; :func:`merge_manifests` joins them). Each
    asset's result is kept beside its GLB (``<id>.record.json``), so a rerun after a kill or a timeout
    redoes only the assets not finished.
    """
    k, n = (int(v) for v in shard)
    if not (n >= 1 and 0 <= k < n):
        raise ValueError(f"shard {k} of {n}: need 0 <= k < n")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    accepted, rejected = [], []
    for f in list_glbs(src_dir)[k::n]:
        kind, entry = _curate_resumable(f, out_dir, settings, logger)
        (accepted if kind == "accepted" else rejected).append(entry)
    manifest = {"settings": settings.model_dump(), "accepted": sorted(accepted, key=lambda e: e["id"]),
                "rejected": sorted(rejected, key=lambda e: e["id"])}
    write_json(manifest_path, manifest)
    return manifest


def merge_manifests(shard_manifests, manifest_path: str | Path) -> dict:
    """One manifest from the shard manifests of one curation (equal settings), sorted by id."""
    from .io import DataError, read_json

    parts = [read_json(p) for p in shard_manifests]
    if not parts:
        raise DataError(f"{manifest_path}: no shard manifests to merge")
    if any(p["settings"] != parts[0]["settings"] for p in parts):
        raise DataError(f"{manifest_path}: shard manifests were curated with different settings; rerun the curation")
    manifest = {"settings": parts[0]["settings"],
                "accepted": sorted((e for p in parts for e in p["accepted"]), key=lambda e: e["id"]),
                "rejected": sorted((e for p in parts for e in p["rejected"]), key=lambda e: e["id"])}
    write_json(manifest_path, manifest)
    return manifest
