"""Scene sampling: a pure function of (config, seed, scene index) -> declarative ``scene.json``.

Two levels, so the workflow can build its DAG without touching any file:

* :func:`plan_scene` decides everything the job graph depends on — split, trajectories, motion
  configs, which lightings each trajectory uses (source and targets) and how many buffer frames it
  needs. It reads no file and is cheap enough to call for every scene at parse time.
* :func:`sample_scene` adds the content: assets from the curation manifest, primitives, ground
  material, lightings (HDRIs) and the per-frame camera / object / light poses. It calls
  :func:`plan_scene`, so the spec always agrees with the DAG.

Conventions: world Z up, metres, radians (see docs/architecture.md). Object ``location_m`` is the
centre of its base on the ground (z = 0). The camera looks at ``cam_target_m`` from
``cam_location_m`` with horizontal field of view ``camera.fov_x_rad``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .camera import intrinsics, opencv_c2w  # noqa: F401  (used by checks and tests)
from .errors import ConfigError  # noqa: F401  (defined there, so that scripts/_cli.py imports nothing else)
from .io import DataError

FORMAT = "lightcrafter.scene/1"
MOTIONS = ("orbit_static", "dynamic_moving", "static_rotating_light")
ELEVATION_GROUPS = ("upper", "middle", "lower", "random")
SPLITS = ("train", "test", "recon")
PRIMITIVE_SHAPES = ("cube", "sphere", "cylinder", "cone", "torus")
GROUND_PATTERNS = ("checker", "noise", "bricks", "voronoi")


def scene_ids(scfg: dict) -> list[str]:
    return [f"s{i:04d}" for i in range(int(scfg["count"]))]


def renders_recon_split(cfg: dict) -> bool:
    """Whether a run renders its recon-split scenes: they only feed the G-buffer estimator's training, so
    only a default-backend run with ``recon.estimator.weights: train`` needs them."""
    r = cfg.get("recon", {})
    return r.get("backend") == "default" and r.get("estimator", {}).get("weights") == "train"


def rendered_plans(cfg: dict) -> list[dict]:
    """Plans (:func:`plan_scene`) of the scenes a run renders (every scene but the recon split's unless
    :func:`renders_recon_split`)."""
    s = cfg["scenes"]
    plans = [plan_scene(s, cfg["seed"], i) for i in range(s["count"])]
    return plans if renders_recon_split(cfg) else [p for p in plans if p["split"] != "recon"]


def scene_index(scene_id: str) -> int:
    return int(scene_id.lstrip("s"))


def _rng(seed: int, index: int, stream: int, redraw: int = 0) -> np.random.Generator:
    """Independent, reproducible random streams per (seed, scene, purpose); ``redraw`` > 0 gives the
    stream's k-th sub-stream (redraw 0 is the stream itself)."""
    return np.random.default_rng([int(seed), int(index), int(stream), *([int(redraw)] if redraw else [])])


# ----------------------------------------------------------------------------- splits
def split_counts(count: int, fractions: dict[str, float]) -> dict[str, int]:
    """Largest-remainder rounding of split fractions to scene counts (sums to ``count``)."""
    total = sum(fractions.get(s, 0.0) for s in SPLITS)
    if total <= 0:
        raise ConfigError("scenes.splits: fractions must sum to a positive number")
    raw = {s: count * fractions.get(s, 0.0) / total for s in SPLITS}
    counts = {s: int(math.floor(v)) for s, v in raw.items()}
    left = count - sum(counts.values())
    for s in sorted(SPLITS, key=lambda s: (-(raw[s] - counts[s]), SPLITS.index(s)))[:left]:
        counts[s] += 1
    return counts


def split_of(scfg: dict, seed: int, index: int) -> str:
    """Split of scene ``index``: a seeded permutation of scene indices cut by the split counts."""
    n = int(scfg["count"])
    if not 0 <= index < n:
        raise ValueError(f"scene index {index} outside 0..{n - 1} (scenes.count = {n})")
    counts = split_counts(n, scfg["splits"])
    order = np.random.default_rng([int(seed), 0x5B117]).permutation(n)
    position = int(np.nonzero(order == index)[0][0])
    edge = 0
    for s in SPLITS:
        edge += counts[s]
        if position < edge:
            return s
    raise AssertionError("unreachable")


# ----------------------------------------------------------------------------- plan
def plan_scene(scfg: dict, seed: int, index: int) -> dict:
    """What the DAG needs to know about scene ``index`` (no file access).

    Returns ``{"scene_id", "split", "lighting_ids", "trajectories": [{"id", "motion",
    "elevation_group", "quadrant", "oscillating", "camera_static", "scene_static",
    "light_rotating", "source_light", "target_lights", "render_lights", "buffer_frames"}]}``.
    Motion configs cycle over ``scenes.motions`` across (scene, trajectory) so they stay balanced.
    Scenes of split ``recon`` (training data of the reconstruction stack) get no target lightings: their
    buffers are rendered, with their source video and the videos under ``scenes.recon_lightings`` - 1 other
    lightings (``render_lights``), all of which the G-buffer estimator trains on.
    """
    rng = _rng(seed, index, 1)
    n_light = int(scfg["lightings_per_scene"])
    n_targets = int(scfg["targets_per_trajectory"])
    n_recon = int(scfg["recon_lightings"])
    for key, value, needs in (("targets_per_trajectory", n_targets, n_targets + 1),
                              ("recon_lightings", n_recon, n_recon)):
        if needs > n_light:
            raise ConfigError(f"scenes.{key}={value} needs at least {needs} lightings; raise "
                              f"scenes.lightings_per_scene (now {n_light})")
    motions = list(scfg["motions"])
    lights = [f"L{k}" for k in range(n_light)]
    n_traj = int(scfg["trajectories_per_scene"])
    split = split_of(scfg, seed, index)
    trajs = []
    for t in range(n_traj):
        motion = motions[(index * n_traj + t) % len(motions)]
        src = int(rng.integers(n_light))
        others = [k for k in range(n_light) if k != src]
        tgts = sorted(int(k) for k in rng.choice(others, size=n_targets, replace=False))
        extra = []
        if split == "recon":  # reconstruction-stack training data: buffers + videos under recon_lightings lights
            tgts = []
            if n_recon > 1:  # a stream of its own: the plans of a run with one lighting stay as they were
                draw = _rng(seed, index, 3, redraw=t + 1).choice(others, size=n_recon - 1, replace=False)
                extra = sorted(int(k) for k in draw)
        camera_static = motion == "static_rotating_light"
        scene_static = motion != "dynamic_moving"
        trajs.append({
            "id": f"t{t}",
            "motion": motion,
            "elevation_group": ELEVATION_GROUPS[int(rng.integers(len(ELEVATION_GROUPS)))],
            "quadrant": int(rng.integers(4)),
            "oscillating": bool(rng.random() < float(scfg["oscillation_prob"])) and not camera_static,
            "camera_static": camera_static,
            "scene_static": scene_static,
            "light_rotating": motion == "static_rotating_light",
            "source_light": lights[src],
            "target_lights": [lights[k] for k in tgts],
            "render_lights": sorted({lights[src], *(lights[k] for k in tgts + extra)}),
            "buffer_frames": 1 if (camera_static and scene_static) else int(scfg["num_frames"]),
        })
    return {"scene_id": f"s{index:04d}", "split": split, "lighting_ids": lights, "trajectories": trajs}


# ----------------------------------------------------------------------------- content
@dataclass
class _Placed:
    id: str
    x: float
    y: float
    r: float  # footprint radius (metres)
    h: float  # height (metres)


def _place(rng, radii, heights, ids, layout_radius_m, clearance_m, tries=200, restarts=50) -> list[_Placed]:
    """Rejection-sample non-overlapping footprints (discs grown by ``clearance_m``) in a disc.

    Largest first; a full restart when one does not fit. Two footprints never come closer than
    their radii plus twice the clearance, which leaves room for dynamic motion (see frames).
    """
    order = np.argsort(-np.asarray(radii), kind="stable")
    for _ in range(restarts):
        placed: list[_Placed] = []
        for k in order:
            r = radii[k] + clearance_m
            for _ in range(tries):
                rho = math.sqrt(rng.random()) * max(layout_radius_m - r, 0.0)
                phi = rng.uniform(0, 2 * math.pi)
                x, y = rho * math.cos(phi), rho * math.sin(phi)
                if all(math.hypot(x - p.x, y - p.y) >= r + p.r + clearance_m for p in placed):
                    placed.append(_Placed(ids[k], x, y, radii[k], heights[k]))
                    break
            else:
                break
        if len(placed) == len(radii):
            return sorted(placed, key=lambda p: ids.index(p.id))
    raise ConfigError(
        f"scenes.layout_radius_m={layout_radius_m} is too small to place {len(radii)} objects "
        f"without overlap; raise it or lower objects_per_scene/primitives_per_scene")


def _look_at_distance(bound_radius_m: float, fov_x: float, aspect_hw: float, margin: float) -> float:
    """Distance at which a sphere of ``bound_radius_m`` fits the narrower field of view."""
    fov_y = 2 * math.atan(math.tan(fov_x / 2) * aspect_hw)
    return margin * bound_radius_m / math.sin(min(fov_x, fov_y) / 2)


_ELEV_RANGES_DEG = {"upper": (45.0, 65.0), "middle": (25.0, 45.0), "lower": (8.0, 25.0), "random": (8.0, 65.0)}


def _trajectory_frames(rng, plan_t, scfg, centre, bound_r, fov_x, aspect_hw, placed, dynamic_ids):
    n = int(scfg["num_frames"])
    t = np.arange(n, dtype=float)
    lo, hi = _ELEV_RANGES_DEG[plan_t["elevation_group"]]
    elev0 = rng.uniform(lo, hi)
    az0 = math.radians(90.0 * plan_t["quadrant"] + rng.uniform(0.0, 90.0))
    direction = 1.0 if rng.random() < 0.5 else -1.0
    step = math.radians(float(scfg["orbit_deg_per_frame"]))
    if plan_t["camera_static"]:
        az = np.full(n, az0)
        elev = np.full(n, math.radians(elev0))
        dist_scale = np.full(n, 1.0 + 0.15 * rng.random())
    else:
        if plan_t["oscillating"]:
            # Non-monotonic: sway back and forth around the start azimuth.
            amp = math.radians(rng.uniform(8.0, 20.0))
            period = rng.uniform(0.5, 1.0) * max(n, 8)
            az = az0 + amp * np.sin(2 * math.pi * t / period)
        else:
            az = az0 + direction * step * t
        # Smoothly varying elevation and distance (random phase and frequency), kept in group range.
        ph1, ph2 = rng.uniform(0, 2 * math.pi, 2)
        f1, f2 = rng.uniform(0.5, 1.5, 2) / max(n, 1)
        e_amp = rng.uniform(0.0, (hi - lo) / 2)
        elev = np.radians(np.clip(elev0 + e_amp * np.sin(2 * math.pi * f1 * t + ph1), lo, hi))
        d_amp = float(scfg["distance_jitter"]) * rng.random()
        dist_scale = 1.0 + d_amp * (0.5 + 0.5 * np.sin(2 * math.pi * f2 * t + ph2))
    d0 = _look_at_distance(bound_r, fov_x, aspect_hw, float(scfg["framing_margin"]))
    frames = []
    rot_rate = math.radians(float(scfg["light_rotation_deg_per_frame"])) * direction
    move_amp = float(scfg["clearance_m"]) * 0.45  # stays inside the clearance ring: no contact
    for i in range(n):
        d = d0 * dist_scale[i]
        loc = centre + d * np.array([math.cos(elev[i]) * math.cos(az[i]),
                                     math.cos(elev[i]) * math.sin(az[i]), math.sin(elev[i])])
        fr = {"cam_location_m": np.round(loc, 6).tolist(), "cam_target_m": np.round(centre, 6).tolist(),
              "light_rotation_z_rad": round(rot_rate * i, 6) if plan_t["light_rotating"] else 0.0}
        if dynamic_ids:
            objs = {}
            for p, (ph, w, spin) in dynamic_ids.items():
                obj = placed[p]
                dx, dy = move_amp * math.cos(w * i + ph) - move_amp * math.cos(ph), \
                    move_amp * math.sin(w * i + ph) - move_amp * math.sin(ph)
                objs[obj["id"]] = {
                    "location_m": [round(obj["location_m"][0] + dx, 6), round(obj["location_m"][1] + dy, 6), 0.0],
                    "rotation_euler_rad": [0.0, 0.0, round(obj["rotation_euler_rad"][2] + spin * i, 6)],
                }
            fr["objects"] = objs
        frames.append(fr)
    return frames


def _ground_material(rng, scfg):
    tex_dir = scfg.get("ground_textures_dir")
    if tex_dir:
        from pathlib import Path

        sets = sorted(p for p in Path(tex_dir).iterdir() if p.is_dir()) if Path(tex_dir).is_dir() else []
        if not sets:
            raise ConfigError(f"scenes.ground_textures_dir={tex_dir}: no texture-set folders found; "
                              "point it at a folder of PBR texture sets or set it to null")
        return {"type": "texture_set", "dir": str(sets[int(rng.integers(len(sets)))]),
                "scale_m": round(float(rng.uniform(0.5, 2.0)), 4)}
    # Two colours of clearly different brightness (b is 2.5-5x darker than a, hue jittered), at a
    # pattern scale whose features span a few pixels to a few tens of pixels at the cameras'
    # distances: texture that a structure-from-motion front end can track, as scanned ground
    # textures give in the paper's scenes.
    lo_s, hi_s = scfg.get("ground_pattern_scale_range", [2.0, 10.0])
    color_a = rng.uniform(0.35, 0.85, 3)
    color_b = color_a / rng.uniform(2.5, 5.0) * rng.uniform(0.7, 1.3, 3)
    return {
        "type": "procedural",
        "pattern": GROUND_PATTERNS[int(rng.integers(len(GROUND_PATTERNS)))],
        "color_a": np.round(color_a, 4).tolist(),
        "color_b": np.round(np.clip(color_b, 0.02, 0.85), 4).tolist(),
        "scale": round(float(rng.uniform(lo_s, hi_s)), 4),
        "roughness": round(float(rng.uniform(0.3, 0.95)), 4),
        "metallic": 0.0,
    }


def hdri_pool(scfg: dict) -> list[str]:
    """HDRI references to sample lightings from: the bpy wheel's eight, or a user folder."""
    from pathlib import Path

    d = scfg.get("hdri_dir")
    if d:
        from .lights import HDRI_SUFFIXES

        files = sorted(str(p) for p in Path(d).iterdir() if p.suffix.lower() in HDRI_SUFFIXES) if Path(d).is_dir() else []
        if not files:
            raise ConfigError(f"scenes.hdri_dir={d}: no {'/'.join(HDRI_SUFFIXES)} files found; point it at a folder of "
                              "HDR environment maps or set it to null for the built-in ones")
        return files
    from .lights import builtin_hdris

    return [f"builtin:{name}" for name in builtin_hdris()]


LAYOUT_REDRAWS = 8  # content redraws of one scene before its layout counts as infeasible


def _draw_content(scfg: dict, rng, accepted: list[dict], n_assets: int, n_prims: int):
    """Objects (assets + primitives, sizes in metres) and their placement on the ground disc."""
    chosen = rng.choice(len(accepted), size=n_assets, replace=len(accepted) < n_assets) if n_assets else []

    objects, radii, heights, ids = [], [], [], []
    for k, ai in enumerate(chosen):
        a = accepted[int(ai)]
        s = float(rng.uniform(*scfg["asset_scale_range"]))
        objects.append({"id": f"a{k}", "kind": "asset", "asset_id": a["id"], "path": a["path"], "scale": round(s, 6),
                        "footprint_radius_m": round(a["footprint_radius_m"] * s, 6),
                        "height_m": round(a["height_m"] * s, 6)})
    lo, hi = scfg["primitive_size_range_m"]
    for k in range(n_prims):
        shape = PRIMITIVE_SHAPES[int(rng.integers(len(PRIMITIVE_SHAPES)))]
        if shape in ("sphere",):
            d = rng.uniform(lo, hi)
            dims = [d, d, d]
        elif shape in ("cylinder", "cone", "torus"):
            d = rng.uniform(lo, hi)
            dims = [d, d, rng.uniform(lo, hi) * (0.4 if shape == "torus" else 1.0)]
        else:
            dims = list(rng.uniform(lo, hi, 3))
        metallic = 1.0 if rng.random() < float(scfg["metallic_prob"]) else 0.0
        objects.append({
            "id": f"p{k}", "kind": "primitive", "shape": shape,
            "dimensions_m": np.round(dims, 6).tolist(),
            "footprint_radius_m": round(0.5 * math.hypot(dims[0], dims[1]), 6),
            "height_m": round(float(dims[2]), 6),
            "material": {"base_color": np.round(rng.uniform(0.05, 0.95, 3), 4).tolist(),
                         "roughness": round(float(rng.uniform(0.05, 1.0)), 4), "metallic": metallic},
        })
    for o in objects:
        radii.append(o["footprint_radius_m"])
        heights.append(o["height_m"])
        ids.append(o["id"])
    placed = _place(rng, radii, heights, ids, float(scfg["layout_radius_m"]), float(scfg["clearance_m"]))
    for o, p in zip(objects, placed):
        o["location_m"] = [round(p.x, 6), round(p.y, 6), 0.0]
        o["rotation_euler_rad"] = [0.0, 0.0, round(float(rng.uniform(0, 2 * math.pi)), 6)]
    return objects, placed


def denoise_networks(render_cfg: dict) -> tuple[str, str]:
    """(OIDN network of the videos Phi sees, network of target-only videos) from a ``render`` config section or a
    spec's ``render``: ``denoise_quality`` (default high) and ``target_denoise_quality``, which falls back to it."""
    quality = str(render_cfg.get("denoise_quality") or "high")
    return quality, str(render_cfg.get("target_denoise_quality") or quality)


def sample_scene(scfg: dict, render_cfg: dict, seed: int, index: int, manifest: dict,
                 hdris: list[str]) -> dict:
    """The full declarative scene spec for scene ``index`` (see docs/architecture.md)."""
    plan = plan_scene(scfg, seed, index)
    accepted = sorted(manifest["accepted"], key=lambda a: a["id"])
    n_assets, n_prims = int(scfg["objects_per_scene"]), int(scfg["primitives_per_scene"])
    if n_assets and len(accepted) < 1:
        raise ConfigError("assets: the curation manifest accepted no assets; see its 'rejected' list")
    if not hdris:
        raise ConfigError("scenes: no HDRIs to sample lightings from")
    # A draw whose objects do not fit the layout disc (rejection sampling jams near 55 % area cover) is
    # redrawn from the next sub-stream; scenes whose first draw fits are unchanged by this.
    for attempt in range(LAYOUT_REDRAWS + 1):
        rng = _rng(seed, index, 2, redraw=attempt)
        try:
            objects, placed = _draw_content(scfg, rng, accepted, n_assets, n_prims)
            break
        except ConfigError:
            if attempt == LAYOUT_REDRAWS:
                raise

    # Bounding sphere of the layout (incl. motion slack) around a target at mid-height.
    max_h = max((p.h for p in placed), default=0.5)
    centre = np.array([0.0, 0.0, 0.4 * max_h])
    slack = float(scfg["clearance_m"])
    bound_r = max(math.sqrt((math.hypot(p.x, p.y) + p.r + slack) ** 2 + max(p.h - centre[2], centre[2]) ** 2)
                  for p in placed) if placed else 1.0

    lightings = []
    pool_idx = rng.permutation(len(hdris))
    white = scfg.get("white_radiance")
    for k, lid in enumerate(plan["lighting_ids"]):
        ref = hdris[int(pool_idx[k % len(hdris)])]
        strength = float(rng.uniform(*scfg["light_strength_range"]))
        if white:  # exposure-normalised: a white ground would reflect `white` x strength
            from .lights import hdri_white_radiance

            strength *= float(white) / hdri_white_radiance(ref)
        lightings.append({"id": lid, "hdri": ref, "rotation_z_rad": round(float(rng.uniform(0, 2 * math.pi)), 6),
                          "strength": round(strength, 4)})

    width, height = int(scfg["width"]), int(scfg["height"])
    fov_x = math.radians(float(scfg["fov_x_deg"]))
    trajectories = []
    for t in plan["trajectories"]:
        trng = _rng(seed, index, 100 + int(t["id"][1:]))
        dynamic = {}
        if not t["scene_static"]:
            for k, o in enumerate(objects):
                if o["kind"] == "asset" or trng.random() < 0.5:
                    dynamic[k] = (float(trng.uniform(0, 2 * math.pi)), float(trng.uniform(0.1, 0.3)),
                                  float(trng.uniform(-0.05, 0.05)))
        frames = _trajectory_frames(trng, t, scfg, centre, bound_r, fov_x, height / width, objects, dynamic)
        trajectories.append({**t, "frames": frames})

    return {
        "format": FORMAT,
        "scene_id": plan["scene_id"],
        "seed": int(seed),
        "split": plan["split"],
        "resolution": {"width": width, "height": height},
        "num_frames": int(scfg["num_frames"]),
        "fps": int(scfg["fps"]),
        "camera": {"fov_x_rad": round(fov_x, 9)},
        "render": {"spp": int(render_cfg["spp"]), "seed": int(render_cfg["seed"]),
                   "max_bounces": int(render_cfg["max_bounces"]),
                   "denoiser": str(render_cfg.get("denoiser", "none")),
                   **dict(zip(("denoise_quality", "target_denoise_quality"), denoise_networks(render_cfg))),
                   "clamp_indirect": float(render_cfg.get("clamp_indirect", 0.0))},
        "ground": {"size_m": float(scfg["ground_size_m"]), "material": _ground_material(rng, scfg)},
        "objects": objects,
        "lightings": lightings,
        "trajectories": trajectories,
    } | ({"layout_redraws": attempt} if attempt else {})


# ----------------------------------------------------------------------------- spec lookups
def trajectory(spec: dict, traj_id: str, where: str | None = None) -> dict:
    """The trajectory ``traj_id`` of a spec, checked for a frame list of ``num_frames`` entries.

    ``where`` names the spec file in error messages (default: the scene id).
    """
    where = where or f"scene {spec.get('scene_id')!r}"
    for t in spec.get("trajectories", []):
        if t.get("id") == traj_id:
            frames = t.get("frames", [])
            if not frames or len(frames) != int(spec["num_frames"]):
                raise DataError(f"{where}: trajectory {traj_id!r} has {len(frames)} frames but "
                                f"num_frames={spec['num_frames']}; re-sample the scene")
            return t
    ids = [t.get("id") for t in spec.get("trajectories", [])]
    raise DataError(f"{where}: no trajectory {traj_id!r} (has {ids}); fix the trajectory id")


def lighting(spec: dict, light_id: str, where: str | None = None) -> dict:
    """The lighting entry ``light_id`` of a spec (``where`` as in :func:`trajectory`)."""
    where = where or f"scene {spec.get('scene_id')!r}"
    for lt in spec.get("lightings", []):
        if lt.get("id") == light_id:
            return lt
    ids = [lt.get("id") for lt in spec.get("lightings", [])]
    raise DataError(f"{where}: no lighting {light_id!r} (has {ids}); fix the lighting id")


# ----------------------------------------------------------------------------- geometry checks
def object_corners_world(obj: dict, pose: dict | None = None) -> np.ndarray:
    """8 corners (metres, world) of the object's bounding cylinder's enclosing box."""
    pose = pose or obj
    x, y, _ = pose["location_m"]
    r, h = obj["footprint_radius_m"], obj["height_m"]
    return np.array([[x + sx * r, y + sy * r, z] for sx in (-1, 1) for sy in (-1, 1) for z in (0.0, h)])
