"""A tiny hand-built scene spec with known materials, for tests and the spp benchmark.

Three primitives and one textured GLB (made here with trimesh: PBR metallic-roughness material
with a uniform base-colour texture) on a checker ground, two lightings (bundled HDRIs) and two
trajectories: ``orbit`` (moving camera, static scene, one buffer frame per frame) and ``static``
(static camera and scene, rotating light, one buffer frame). Every material triple
(linear albedo, roughness, metallic) is distinct, so each surface pixel can be attributed.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

GLB_TEXTURE_SRGB8 = (230, 150, 40)  # uniform base-colour texture of the GLB (sRGB-encoded 8-bit)
GLB_ROUGHNESS, GLB_METALLIC = 0.25, 0.6


def srgb8_to_linear(rgb8) -> np.ndarray:
    """sRGB-encoded 8-bit values -> linear [0, 1] (IEC 61966-2-1), as Blender decodes sRGB textures."""
    c = np.asarray(rgb8, float) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def known_materials() -> dict[str, tuple[tuple[float, float, float], float, float]]:
    """Surface name -> (linear base colour RGB, roughness, metallic) of every surface in :func:`tiny_spec`."""
    return {
        "ground_a": ((0.8, 0.8, 0.8), 0.6, 0.0),
        "ground_b": ((0.1, 0.1, 0.1), 0.6, 0.0),
        "cube": ((0.8, 0.1, 0.1), 0.3, 0.0),
        "sphere": ((0.1, 0.7, 0.2), 0.7, 1.0),
        "cylinder": ((0.2, 0.3, 0.9), 0.5, 0.5),
        "glb": (tuple(srgb8_to_linear(GLB_TEXTURE_SRGB8).tolist()), GLB_ROUGHNESS, GLB_METALLIC),
    }


def write_textured_glb(path: Path, size_m: float = 0.6) -> Path:
    """A cube-ish GLB, normalised like curated assets (glTF Y-up: base on y = 0, centred on x = z = 0)."""
    import trimesh
    from PIL import Image

    mesh = trimesh.creation.box(extents=(size_m, size_m, size_m))
    mesh.apply_translation((0.0, size_m / 2.0, 0.0))
    uv = (mesh.vertices[:, [0, 2]] / size_m + 0.5).clip(0.0, 1.0)
    texture = Image.new("RGB", (8, 8), GLB_TEXTURE_SRGB8)
    material = trimesh.visual.material.PBRMaterial(
        baseColorTexture=texture, metallicFactor=GLB_METALLIC, roughnessFactor=GLB_ROUGHNESS
    )
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, material=material)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(mesh.export(file_type="glb"))
    return path


def tiny_spec(
    work_dir: Path,
    *,
    width: int = 96,
    height: int = 64,
    num_frames: int = 3,
    spp: int = 8,
    orbit_step_rad: float = math.radians(8.0),
) -> dict:
    """The test scene spec (``lightcrafter.scene/1``); writes its GLB into ``work_dir``."""
    glb = write_textured_glb(Path(work_dir) / "glb_box.glb")
    m = known_materials()

    def prim(oid, shape, loc, dims, name, yaw=0.0):
        base, rough, metal = m[name]
        return {
            "id": oid,
            "kind": "primitive",
            "shape": shape,
            "location_m": [*loc, 0.0],
            "rotation_euler_rad": [0.0, 0.0, yaw],
            "dimensions_m": dims,
            "footprint_radius_m": max(dims[:2]) / 2,
            "height_m": dims[2],
            "material": {"base_color": list(base), "roughness": rough, "metallic": metal},
        }

    target = [0.0, 0.0, 0.3]

    def orbit_frame(k):
        a = math.radians(30.0) + k * orbit_step_rad
        return {
            "cam_location_m": [3.2 * math.cos(a), 3.2 * math.sin(a), 1.8],
            "cam_target_m": target,
            "light_rotation_z_rad": 0.0,
            "objects": {},
        }

    static = orbit_frame(0)
    return {
        "format": "lightcrafter.scene/1",
        "scene_id": "test0",
        "seed": 0,
        "split": "test",
        "resolution": {"width": width, "height": height},
        "num_frames": num_frames,
        "fps": 24,
        "camera": {"fov_x_rad": 0.87},
        "render": {"spp": spp, "seed": 0, "max_bounces": 4},
        "ground": {
            "size_m": 12.0,
            "material": {
                "type": "procedural",
                "pattern": "checker",
                "color_a": list(m["ground_a"][0]),
                "color_b": list(m["ground_b"][0]),
                "scale": 1.5,
                "roughness": 0.6,
                "metallic": 0.0,
            },
        },
        "objects": [
            prim("p0", "cube", [0.7, -0.2], [0.5, 0.4, 0.6], "cube", yaw=0.4),
            prim("p1", "sphere", [-0.6, 0.4], [0.6, 0.6, 0.6], "sphere"),
            prim("p2", "cylinder", [-0.2, -0.8], [0.4, 0.4, 0.7], "cylinder"),
            {
                "id": "a0",
                "kind": "asset",
                "asset_id": "glb_box",
                "path": str(glb),
                "location_m": [0.3, 0.7, 0.0],
                "rotation_euler_rad": [0.0, 0.0, 0.3],
                "scale": 1.0,
                "footprint_radius_m": 0.43,
                "height_m": 0.6,
            },
        ],
        "lightings": [
            {"id": "L0", "hdri": "builtin:forest.exr", "rotation_z_rad": 0.5, "strength": 1.0},
            {"id": "L1", "hdri": "builtin:sunset.exr", "rotation_z_rad": 2.0, "strength": 1.0},
            {"id": "L2", "hdri": "builtin:city.exr", "rotation_z_rad": 0.0, "strength": 1.0},
        ],
        "trajectories": [
            {
                "id": "orbit",
                "motion": "orbit_static",
                "camera_static": False,
                "scene_static": True,
                "light_rotating": False,
                "source_light": "L0",
                "target_lights": ["L1"],
                "render_lights": ["L0", "L1"],
                "buffer_frames": num_frames,
                "frames": [orbit_frame(k) for k in range(num_frames)],
            },
            {
                "id": "static",
                "motion": "static_camera_rotating_light",
                "camera_static": True,
                "scene_static": True,
                "light_rotating": True,
                "source_light": "L0",
                "target_lights": ["L0"],
                "render_lights": ["L0"],
                "buffer_frames": 1,
                "frames": [dict(static, light_rotation_z_rad=k * math.radians(15.0)) for k in range(num_frames)],
            },
        ],
    }
