"""Visibility (shadow-casting) mesh from the aggregated depth maps of a clip.

Every distinct (buffer, camera) of the clip is meshed at pixel centres (continuity cuts, image
border masked, see :mod:`.geometry`); the meshes are merged in world space and cleaned and decimated
with pymeshlab: close vertices merged, duplicate faces and unreferenced vertices removed, tiny
isolated pieces dropped, quadric edge collapse down to ``max_faces``. Occluders seen in any frame
of the clip therefore shadow every frame, also outside the current view.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lightcrafter.proxy.geometry import PixelMesh, pixel_grid_mesh


@dataclass(frozen=True)
class VisibilitySettings:
    """rel_threshold: depth-discontinuity tolerance (relative); border_px: masked image border;
    max_faces: decimation target (0 = no decimation); min_component_faces: smaller pieces dropped;
    merge_rel: vertex merge distance as a fraction of the bounding-box diagonal; max_views: at most this
    many distinct views (evenly spaced, first and last included; 0 = all) are merged: consecutive
    frames of a clip see nearly the same surfaces, and merging all 17 views cost about 15 s of CPU per
    clip, most of the proxy's render time."""

    rel_threshold: float = 0.05
    border_px: int = 1
    max_faces: int = 50000
    min_component_faces: int = 8
    merge_rel: float = 1e-4
    max_views: int = 6


def spread_subset(items: list, k: int) -> list:
    """At most ``k`` items evenly spaced over ``items`` (first and last kept); all when k <= 0."""
    if k <= 0 or len(items) <= k:
        return list(items)
    idx = np.unique(np.round(np.linspace(0, len(items) - 1, k)).astype(int))
    return [items[i] for i in idx]


def merge_meshes(meshes: list[PixelMesh]) -> tuple[np.ndarray, np.ndarray]:
    verts, faces, off = [], [], 0
    for m in meshes:
        verts.append(m.vertices.astype(np.float64))
        faces.append(m.faces.astype(np.int64) + off)
        off += len(m.vertices)
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    return np.concatenate(verts), np.concatenate(faces)


def clean_and_decimate(vertices: np.ndarray, faces: np.ndarray, s: VisibilitySettings) -> tuple[np.ndarray, np.ndarray]:
    """pymeshlab cleanup + quadric decimation; returns (V, 3) float32 and (F, 3) uint32."""
    if len(faces) == 0:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint32)
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.ascontiguousarray(vertices, np.float64),
                               face_matrix=np.ascontiguousarray(faces, np.int32)))
    diag = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    if diag > 0 and s.merge_rel > 0:
        ms.meshing_merge_close_vertices(threshold=pymeshlab.PureValue(s.merge_rel * diag))
    ms.meshing_remove_duplicate_faces()
    ms.meshing_remove_null_faces()
    if s.min_component_faces > 0:
        ms.meshing_remove_connected_component_by_face_number(mincomponentsize=s.min_component_faces)
    ms.meshing_remove_unreferenced_vertices()
    if s.max_faces > 0 and ms.current_mesh().face_number() > s.max_faces:
        ms.meshing_decimation_quadric_edge_collapse(targetfacenum=int(s.max_faces), preserveboundary=True,
                                                    preservenormal=True, planarquadric=True, autoclean=True)
    m = ms.current_mesh()
    return m.vertex_matrix().astype(np.float32), m.face_matrix().astype(np.uint32)


def visibility_mesh(views: list[tuple], s: VisibilitySettings = VisibilitySettings()) -> tuple[np.ndarray, np.ndarray]:
    """views: (depth, valid, K, c2w, normal_world or None) of each distinct frame of the clip."""
    meshes = [pixel_grid_mesh(d, v, K, c, n, rel_threshold=s.rel_threshold, border_px=s.border_px)
              for d, v, K, c, n in spread_subset(views, s.max_views)]
    return clean_and_decimate(*merge_meshes(meshes), s)
