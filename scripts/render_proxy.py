"""Render the PBR proxy of a clip with the forward renderer R (Mitsuba 3) under one lighting.

  render_proxy.py --clip CLIP_DIR --lighting LIGHTING.json --out OUT
  render_proxy.py --clip CLIP_DIR --scene scene.json --light L1 [--traj t0] --out OUT

The lighting is a lighting file (lightcrafter.lighting/1) or a scene spec's lighting (with the
trajectory's per-frame rotation when --traj is given). Writes OUT/{frame:04d}.exr (linear HDR RGB),
OUT.mp4 (display preview) and OUT.json (manifest, last).
"""

import argparse

import _cli


def main():
    from lightcrafter.io import read_json
    from lightcrafter.proxy.clip import render_clip
    from lightcrafter.proxy import render_settings
    from lightcrafter.proxy.lighting import lighting_from_spec

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--clip", required=True, help="clip folder (buffers.json, cameras.json, buffers/)")
    ap.add_argument("--lighting", default=None, help="lighting file (lightcrafter.lighting/1)")
    ap.add_argument("--scene", default=None, help="scene.json whose lighting --light is used (instead of --lighting)")
    ap.add_argument("--light", default=None, help="lighting id in scene.json, e.g. L1")
    ap.add_argument("--traj", default=None, help="trajectory id in scene.json: its per-frame light rotation")
    ap.add_argument("--out", required=True, help="frame folder; OUT.mp4 and OUT.json are written beside it")
    ap.add_argument("--proxy", default=None,
                    help="R's settings: JSON or @file of config proxy (lightcrafter.config.models.Proxy; default: its "
                    "defaults)")
    ap.add_argument("--exposure-ev", type=float, default=0.0, help="global envmap exposure in EV")
    ap.add_argument("--threads", type=int, default=None, help="Dr.Jit LLVM worker threads")
    a = ap.parse_args()
    if bool(a.lighting) == bool(a.scene and a.light):
        ap.error("give either --lighting FILE or --scene SCENE.json with --light ID")
    if a.threads:
        import drjit as dr

        dr.set_thread_count(a.threads)
    settings = render_settings(_cli.json_arg(a.proxy, {}))
    from lightcrafter.clip import is_skipped
    from lightcrafter.io import write_json

    reason = is_skipped(a.clip)
    if reason:  # a clip the reconstruction stack left out: so is its proxy (datasets count it)
        write_json(f"{a.out}.json", {"format": "lightcrafter.proxy/1", "skipped": reason, "clip": a.clip})
        print(f"render_proxy: {a.clip} was left out ({reason})")
        return
    if a.lighting:
        lighting = a.lighting
        if a.exposure_ev:
            ap.error("--exposure-ev applies to --scene lightings; a lighting file carries its own exposure")
        extra = {}
    else:
        spec = read_json(a.scene)
        lighting = lighting_from_spec(spec, a.light, a.traj, exposure_ev=a.exposure_ev, where=a.scene)
        extra = {"scene_id": spec.get("scene_id"), "trajectory": a.traj, "light": a.light}
    render_clip(a.clip, lighting, a.out, settings=settings, extra=extra)


if __name__ == "__main__":
    _cli.run(main)
