#!/usr/bin/env python
"""Apply one scene edit to a clip (lightcrafter.editing) so that R can render it like any clip.

  edit_scene.py --kind light    --clip CLIP --scene scene.json --traj t0 --light L1 --out DIR --settings-json '{...}'
  edit_scene.py --kind material --clip CLIP --scene scene.json --traj t0 --light L1 --out DIR --settings-json '{...}'
  edit_scene.py --kind object   --clip CLIP --scene scene.json --traj t0 --light L1 --out DIR --settings-json '{...}'

Writes DIR/lighting.json (the target lighting of the scene, plus the inserted lights for ``light``) and,
for ``material`` and ``object``, the edited clip DIR/clip/ (lightcrafter.clip contract); DIR/edit.json
(what was edited, last).
"""

import argparse
import json
from pathlib import Path

import _cli  # puts the repository on sys.path; run() is the one error path

from lightcrafter import io


def scene_lighting_file(spec: dict, light_id: str, traj_id: str, path: Path, extra_lights: dict | None = None) -> dict:
    from lightcrafter.proxy.lighting import write_lighting_file
    from lightcrafter.scenes import lighting, trajectory

    lt = lighting(spec, light_id)
    frames = trajectory(spec, traj_id)["frames"]
    extra_lights = extra_lights or {}
    return write_lighting_file(path, env=lt["hdri"], strength=float(lt.get("strength", 1.0)),
                               rotation_z_rad=float(lt.get("rotation_z_rad", 0.0)),
                               frame_rotation_z_rad=[float(f.get("light_rotation_z_rad", 0.0)) for f in frames],
                               point_lights=list(lt.get("point_lights", [])) + list(extra_lights.get("point_lights", [])),
                               area_lights=list(lt.get("area_lights", [])) + list(extra_lights.get("area_lights", [])),
                               extra={"scene_id": spec.get("scene_id"), "light": light_id})


def _unused_asset(spec: dict, manifest: str | None) -> str:
    used = {o.get("asset_id") for o in spec["objects"]}
    if manifest:
        for a in sorted(io.read_json(manifest)["accepted"], key=lambda a: a["id"]):
            if a["id"] not in used:
                return a["path"]
    return next(o["path"] for o in spec["objects"] if o["kind"] == "asset")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kind", required=True, choices=["light", "material", "object"])
    ap.add_argument("--clip", required=True)
    ap.add_argument("--scene", required=True)
    ap.add_argument("--traj", required=True)
    ap.add_argument("--light", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--settings-json", default="{}")
    ap.add_argument("--manifest", default=None, help="curated asset manifest (object insertion picks an asset "
                                                      "the scene does not use)")
    a = ap.parse_args()
    from lightcrafter import clip as clipmod
    from lightcrafter import editing

    out = Path(a.out)
    s = _cli.json_arg(a.settings_json)
    spec = io.read_json(a.scene)
    reason = clipmod.is_skipped(a.clip)
    if reason:
        raise io.DataError(f"{a.clip}: the clip to edit was left out by the reconstruction stack ({reason}); "
                           "choose another clip in edits")
    record = {"kind": a.kind, "clip": a.clip, "scene_id": spec.get("scene_id"), "trajectory": a.traj,
              "light": a.light}
    if a.kind == "light":
        lights = {"point_lights": s.get("point_lights", []), "area_lights": s.get("area_lights", [])}
        scene_lighting_file(spec, a.light, a.traj, out / "lighting.json", lights)
        record.update(lights)
    else:
        scene_lighting_file(spec, a.light, a.traj, out / "lighting.json")
        views, info = clipmod.read_clip(a.clip)
        if a.kind == "material":
            obj = next((o for o in spec["objects"] if o["id"] == (s.get("object") or spec["objects"][0]["id"])), None)
            if obj is None:
                raise io.DataError(f"{a.scene}: no object {s.get('object')!r} to edit; fix edits.material.object")
            centre = [obj["location_m"][0], obj["location_m"][1], 0.5 * obj["height_m"]]
            radius = float(s.get("radius_scale", 1.2)) * max(obj["footprint_radius_m"], 0.5 * obj["height_m"])
            edit = {k: s[k] for k in s if k.endswith(("_override", "_multiplier")) and s[k] is not None}
            views, frac = editing.material_edit_views(views, centre, radius, edit)
            record.update({"object": obj["id"], "centre_m": centre, "radius_m": radius, "edit": edit,
                           "pixels_edited": frac})
        else:
            glb = s.get("asset") or _unused_asset(spec, a.manifest)
            loc = s.get("location_m") or editing.free_ground_spot(spec).tolist()
            views, frac = editing.insert_object(views, glb, loc, float(s.get("yaw_rad", 0.0)), float(s.get("scale", 1.0)))
            record.update({"asset": str(glb), "location_m": loc, "pixels_covered": frac})
        inputs = {"what": "edit", "kind": a.kind, "clip": clipmod.identity(a.clip), "settings": s}
        ff = clipmod.buffer_frames(out / "clip", inputs)
        for i in ff.missing(range(len(views)), io.read_buffers):
            ff.stamp()
            io.write_buffers(ff.path(i), views[i].buffers)
        clipmod.write_clip(out / "clip", serve=list(range(len(views))), K=[v.K for v in views],
                           c2w=[v.c2w for v in views], width=info.width, height=info.height, fps=info.fps,
                           camera_static=info.camera_static, scene_static=info.scene_static, units=info.units,
                           producer={"stage": "edit", "kind": a.kind, "source": info.producer},
                           content_id=io.fingerprint(inputs))
    io.write_json(out / "edit.json", record)
    print(f"edit_scene: {a.kind}: {json.dumps(record)[:300]}")
    return 0


if __name__ == "__main__":
    _cli.run(main, "edit_scene", (io.DataError,))
