"""Render the PBR proxy of a clip with the forward renderer R (Mitsuba 3) under one scene lighting.

Writes OUT/{frame:04d}.exr (linear HDR RGB), OUT.mp4 (display preview) and OUT.json (manifest, last).
"""

import argparse

import _cli


def main():
    from lightcrafter.proxy.clip import render_clip
    from lightcrafter.proxy.renderer import RenderSettings
    from lightcrafter.proxy.visibility import VisibilitySettings

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--buffers", required=True, help="folder with buffers.json and cameras.json (or buffers.json)")
    ap.add_argument("--scene", required=True, help="scene.json (lightings, trajectories)")
    ap.add_argument("--light", required=True, help="lighting id in scene.json, e.g. L1")
    ap.add_argument("--out", required=True, help="frame folder; OUT.mp4 and OUT.json are written beside it")
    ap.add_argument("--traj", default=None, help="trajectory id (default: from buffers.json or the folder name)")
    ap.add_argument("--spp", type=int, default=16, help="samples per pixel")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--exposure-ev", type=float, default=0.0, help="global envmap exposure in EV")
    ap.add_argument("--rel-threshold", type=float, default=0.05, help="depth-discontinuity tolerance (relative)")
    ap.add_argument("--border-px", type=int, default=0, help="image border masked from the per-frame mesh")
    ap.add_argument("--bilateral-sigma-px", type=float, default=0.0, help="depth bilateral filter sigma (0 = off)")
    ap.add_argument("--visibility", choices=["auto", "aggregate", "frame", "primary", "none"], default="auto",
                    help="shadow mesh: auto = aggregate for static scenes, frame when objects move")
    ap.add_argument("--visibility-max-faces", type=int, default=50000, help="decimation target of the clip mesh")
    ap.add_argument("--sampler", default="multijitter", help="Mitsuba sampler plugin (multijitter, ldsampler, independent)")
    ap.add_argument("--threads", type=int, default=None, help="Dr.Jit LLVM worker threads")
    a = ap.parse_args()
    if a.threads:
        import drjit as dr

        dr.set_thread_count(a.threads)
    settings = RenderSettings(spp=a.spp, seed=a.seed, rel_threshold=a.rel_threshold, border_px=a.border_px,
                              bilateral_sigma_px=a.bilateral_sigma_px, visibility=a.visibility, sampler=a.sampler,
                              visibility_mesh=VisibilitySettings(rel_threshold=a.rel_threshold,
                                                                 max_faces=a.visibility_max_faces))
    render_clip(a.buffers, a.scene, a.light, a.out, traj_id=a.traj, settings=settings, exposure_ev=a.exposure_ev)


if __name__ == "__main__":
    _cli.run(main)
