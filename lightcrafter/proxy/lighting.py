"""Lighting for the forward renderer: an environment map fixed in the world frame plus local lights.

Everything is in the Blender world frame (Z up, metres) and additive: the rendered radiance is
the sum of the environment term and one term per local light, so any combination renders.

* Environment: lat-long linear HDR map in the convention of :mod:`lightcrafter.envmap`; global
  ``strength`` (Blender Background strength) and ``exposure_ev`` scale it, global fitted
  ``yaw_rad``/``pitch_rad`` resample it once; the per-frame Z rotation (scene ``rotation_z_rad`` +
  trajectory ``light_rotation_z_rad``) is applied exactly by rotating directions at render time.
* Point light: ``position_m``, radiant intensity ``intensity_w_sr`` (RGB, W/sr; irradiance
  I cos / d^2).
* Area light: one-sided rectangle, centre ``center_m``, emitting along unit ``normal``,
  ``size_m`` = (width, height), constant radiance ``radiance`` (RGB, W/(m^2 sr)).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lightcrafter import envmap
from lightcrafter.io import DataError
from lightcrafter.scenes import lighting, trajectory


@dataclass(frozen=True)
class PointLight:
    position_m: tuple[float, float, float]
    intensity_w_sr: tuple[float, float, float]


@dataclass(frozen=True)
class AreaLight:
    center_m: tuple[float, float, float]
    normal: tuple[float, float, float]
    size_m: tuple[float, float]
    radiance: tuple[float, float, float]

    def frame(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(unit normal, tangent u scaled by width, tangent v scaled by height) in world metres."""
        n = np.asarray(self.normal, dtype=np.float64)
        n = n / np.linalg.norm(n)
        helper = np.array([0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        t = np.cross(helper, n)
        t /= np.linalg.norm(t)
        b = np.cross(n, t)
        return n, t * self.size_m[0], b * self.size_m[1]


@dataclass
class Lighting:
    """env: (H, W, 3) linear radiance (scaled, yaw/pitch applied) or None.
    rotation_z_rad: base Z rotation; frame_rotation_z_rad: per-frame additions (radians)."""

    env: np.ndarray | None = None
    rotation_z_rad: float = 0.0
    frame_rotation_z_rad: list[float] = field(default_factory=list)
    point_lights: list[PointLight] = field(default_factory=list)
    area_lights: list[AreaLight] = field(default_factory=list)

    def env_rotation_rad(self, frame: int) -> float:
        extra = self.frame_rotation_z_rad[frame] if frame < len(self.frame_rotation_z_rad) else 0.0
        return float(self.rotation_z_rad + extra)

    @property
    def has_local_lights(self) -> bool:
        return bool(self.point_lights or self.area_lights)


def _vec(d: dict, key: str, n: int, where: str) -> tuple:
    v = d.get(key)
    if v is None or len(v) != n or not all(np.isfinite(float(x)) for x in v):
        raise DataError(f"{where}: light needs finite {key!r} with {n} numbers, got {v!r}")
    return tuple(float(x) for x in v)


def local_lights_from_spec(entry: dict, where: str) -> tuple[list[PointLight], list[AreaLight]]:
    points = [PointLight(_vec(p, "position_m", 3, where), _vec(p, "intensity_w_sr", 3, where))
              for p in entry.get("point_lights", [])]
    areas = [AreaLight(_vec(a, "center_m", 3, where), _vec(a, "normal", 3, where), _vec(a, "size_m", 2, where),
                       _vec(a, "radiance", 3, where)) for a in entry.get("area_lights", [])]
    for light in points + areas:
        vals = light.intensity_w_sr if isinstance(light, PointLight) else light.radiance
        if min(vals) < 0:
            raise DataError(f"{where}: negative light emission {vals}")
    return points, areas


def lighting_from_spec(spec: dict, light_id: str, traj_id: str | None = None, *, exposure_ev: float = 0.0,
                       yaw_rad: float = 0.0, pitch_rad: float = 0.0, where: str = "scene.json") -> Lighting:
    """Build the lighting ``light_id`` of a ``lightcrafter.scene/1`` spec (per-frame rotation from
    trajectory ``traj_id`` if given). The HDRI is resolved with ``lightcrafter.lights.resolve_hdri``."""
    entry = lighting(spec, light_id, where)
    env = None
    if entry.get("hdri"):
        from lightcrafter.lights import resolve_hdri

        env = envmap.load(resolve_hdri(entry["hdri"]))
        env = envmap.rotate(env, yaw_rad, pitch_rad)
        env = envmap.apply_exposure(env, exposure_ev, float(entry.get("strength", 1.0)))
    frame_rot: list[float] = []
    if traj_id is not None:
        frame_rot = [float(f.get("light_rotation_z_rad", 0.0)) for f in trajectory(spec, traj_id, where)["frames"]]
    points, areas = local_lights_from_spec(entry, where)
    return Lighting(env=env, rotation_z_rad=float(entry.get("rotation_z_rad", 0.0)),
                    frame_rotation_z_rad=frame_rot, point_lights=points, area_lights=areas)


# ----------------------------------------------------------------------------- lighting files
LIGHTING_FORMAT = "lightcrafter.lighting/1"


def write_lighting_file(path, *, env: str | None, strength: float = 1.0, exposure_ev: float = 0.0,
                        rotation_z_rad: float = 0.0, yaw_rad: float = 0.0, pitch_rad: float = 0.0,
                        frame_rotation_z_rad: list[float] | None = None, point_lights: list[dict] | None = None,
                        area_lights: list[dict] | None = None, extra: dict | None = None) -> dict:
    """Write a lighting file (``lightcrafter.lighting/1``, JSON) that :func:`lighting_from_file` reads.

    ``env`` is a lat-long EXR path (relative paths are relative to the file's folder), a
    ``builtin:NAME.exr`` reference, or None (local lights only). Radiance = map x strength x 2**exposure_ev,
    resampled once by yaw (about +Z) then pitch (about +Y), then rotated per frame about +Z by
    rotation_z_rad + frame_rotation_z_rad[i] (radians, world frame; lightcrafter.envmap convention).
    """
    from lightcrafter.io import write_json

    data = {
        "format": LIGHTING_FORMAT,
        "env": None if env is None else {"map": str(env), "strength": float(strength), "exposure_ev": float(exposure_ev),
                                         "rotation_z_rad": float(rotation_z_rad), "yaw_rad": float(yaw_rad),
                                         "pitch_rad": float(pitch_rad)},
        "frame_rotation_z_rad": [float(x) for x in (frame_rotation_z_rad or [])],
        "point_lights": list(point_lights or []), "area_lights": list(area_lights or []),
        **(extra or {}),
    }
    write_json(path, data)
    return data


def lighting_from_file(path) -> Lighting:
    """Build a :class:`Lighting` from a lighting file (see :func:`write_lighting_file`)."""
    from pathlib import Path

    from lightcrafter.io import read_json

    path = Path(path)
    data = read_json(path)
    if data.get("format") != LIGHTING_FORMAT:
        raise DataError(f"{path}: format {data.get('format')!r}, expected {LIGHTING_FORMAT!r}; rewrite the lighting file")
    env = None
    e = data.get("env")
    rot = 0.0
    if e:
        from lightcrafter.lights import BUILTIN_PREFIX, resolve_hdri

        ref = str(e["map"])
        src = resolve_hdri(ref) if ref.startswith(BUILTIN_PREFIX) else (path.parent / ref if not Path(ref).is_absolute() else Path(ref))
        if not Path(src).is_file():
            raise DataError(f"{path}: environment map {src} not found; rerun the stage that writes it")
        env = envmap.load(src)
        env = envmap.rotate(env, float(e.get("yaw_rad", 0.0)), float(e.get("pitch_rad", 0.0)))
        env = envmap.apply_exposure(env, float(e.get("exposure_ev", 0.0)), float(e.get("strength", 1.0)))
        rot = float(e.get("rotation_z_rad", 0.0))
    points, areas = local_lights_from_spec(data, str(path))
    return Lighting(env=env, rotation_z_rad=rot, frame_rotation_z_rad=[float(x) for x in data.get("frame_rotation_z_rad", [])],
                    point_lights=points, area_lights=areas)


def lighting_identity(lighting: Lighting) -> dict:
    """JSON-able identity of a lighting (the map as a digest): equal identity, equal renders."""
    import hashlib
    from dataclasses import asdict

    env = None
    if lighting.env is not None:
        arr = np.ascontiguousarray(lighting.env, np.float32)
        env = {"shape": list(arr.shape), "sha256": hashlib.sha256(arr.tobytes()).hexdigest()}
    return {"env": env, "rotation_z_rad": lighting.rotation_z_rad, "frame_rotation_z_rad": lighting.frame_rotation_z_rad,
            "point_lights": [asdict(p) for p in lighting.point_lights], "area_lights": [asdict(a) for a in lighting.area_lights]}
