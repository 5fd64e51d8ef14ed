"""Fit the source environment map of a video and render its pseudo-input video (real pseudo-pairs).

  fit_envmap.py --clip CLIP_DIR --frames FRAMES_DIR --out OUT_DIR [--solver fast|reference] [--init-map MAP.exr]

CLIP_DIR: the video's recovered scene state (lightcrafter.clip: buffers.json, cameras.json, buffers/);
FRAMES_DIR: the video's linear EXR frames 0000.exr ... (one per clip frame, clip resolution).
Writes OUT_DIR/envmap.exr (fitted 64x128 map, world frame, yaw/pitch/exposure baked in),
lighting.json (lighting file R renders with), params.npz, loss_curve.json, pseudo/####.exr +
pseudo.mp4 + pseudo.json (R(S, L_hat) of every frame) and fit.json (manifest, last).
Defaults are the paper's (lightcrafter.envfit.fit.FitSettings); a killed run resumes.
"""

import argparse

import _cli


def main():
    from lightcrafter.envfit.fit import SOLVERS, FitSettings, fit_envmap
    from lightcrafter.proxy.renderer import RenderSettings
    from lightcrafter.proxy.visibility import VisibilitySettings

    d = FitSettings()
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--clip", required=True, help="clip folder (buffers.json, cameras.json, buffers/)")
    ap.add_argument("--frames", required=True, help="folder of the video's linear EXR frames {i:04d}.exr")
    ap.add_argument("--out", required=True, help="output folder")
    ap.add_argument("--solver", choices=SOLVERS, default=d.solver)
    ap.add_argument("--init-map", default=None,
                    help="initial lat-long EXR (e.g. DiffusionLight's); default constant grey")
    ap.add_argument("--no-init-match-mean", action="store_true", help="keep the initial map's scale as given")
    ap.add_argument("--iterations", type=int, default=d.iterations)
    ap.add_argument("--lr", type=float, default=d.lr)
    ap.add_argument("--lambda-tv", type=float, default=d.lambda_tv)
    ap.add_argument("--data-reduction", choices=["sum", "mean"], default=d.data_reduction)
    ap.add_argument("--frame-stride", type=int, default=d.frame_stride, help="fit frames 0, s, 2s, ...")
    ap.add_argument("--env-height", type=int, default=d.env_height)
    ap.add_argument("--env-width", type=int, default=d.env_width)
    ap.add_argument("--no-rotation", action="store_true", help="do not optimise yaw and pitch")
    ap.add_argument("--no-exposure", action="store_true", help="do not optimise the exposure")
    ap.add_argument("--saturation-level", type=float, default=None,
                    help="linear level at which the video clips (default: detect a plateau at the maximum; 0: off)")
    ap.add_argument("--no-background", action="store_true", help="fit surface pixels only")
    ap.add_argument("--transport-pixels", type=int, default=d.transport_pixels,
                    help="fast: pixels per fitted frame (0 = all)")
    ap.add_argument("--transport-spp", type=int, default=d.transport_spp, help="fast: lanes per pixel")
    ap.add_argument("--ref-spp", type=int, default=d.ref_spp, help="reference: lanes per pixel per iteration")
    ap.add_argument("--ref-pixels", type=int, default=d.ref_pixels, help="reference: pixels per iteration (0 = all)")
    ap.add_argument("--seed", type=int, default=d.seed)
    ap.add_argument("--checkpoint-every", type=int, default=d.checkpoint_every)
    ap.add_argument("--spp", type=int, default=16, help="R's samples per pixel for the pseudo-input video")
    ap.add_argument("--rel-threshold", type=float, default=0.05, help="R: depth-discontinuity tolerance (relative)")
    ap.add_argument("--visibility", choices=["auto", "aggregate", "frame", "none"], default="auto",
                    help="R's shadow mesh: auto = aggregate for static scenes, frame when objects move")
    ap.add_argument("--visibility-max-faces", type=int, default=50000)
    ap.add_argument("--threads", type=int, default=None, help="CPU threads (Dr.Jit)")
    ap.add_argument("--settings-json", default=None,
                    help="FitSettings overrides as JSON (the workflow passes config envfit); win over the flags")
    a = ap.parse_args()
    import json
    from pathlib import Path

    from lightcrafter.clip import is_skipped
    from lightcrafter.io import write_json

    reason = is_skipped(a.clip)
    if reason:  # the reconstruction stack left the clip out: so is its pseudo-pair (datasets count it)
        out = Path(a.out)
        write_json(out / "pseudo.json", {"format": "lightcrafter.proxy/1", "skipped": reason})
        write_json(out / "fit.json", {"skipped": reason, "clip": a.clip})
        print(f"{a.out}: left out ({reason})")
        return
    over = json.loads(a.settings_json) if a.settings_json else {}
    if a.init_map is None and (Path(a.clip) / "envmap_init.exr").is_file():  # the paper stack's DiffusionLight map
        a.init_map = str(Path(a.clip) / "envmap_init.exr")
    settings = FitSettings(
        solver=a.solver, env_height=a.env_height, env_width=a.env_width, iterations=a.iterations, lr=a.lr,
        lambda_tv=a.lambda_tv, data_reduction=a.data_reduction, frame_stride=a.frame_stride,
        fit_rotation=not a.no_rotation, fit_exposure=not a.no_exposure, seed=a.seed,
        init_match_mean=not a.no_init_match_mean, saturation_level=a.saturation_level,
        use_background=not a.no_background, ref_spp=a.ref_spp, ref_pixels=a.ref_pixels,
        transport_spp=a.transport_spp, transport_pixels=a.transport_pixels, threads=a.threads,
        checkpoint_every=a.checkpoint_every)
    if over:
        from dataclasses import fields, replace

        known = {f.name for f in fields(FitSettings)}
        unknown = sorted(set(over) - known)
        if unknown:
            raise ValueError(f"unknown envfit key(s) {unknown}; known: {sorted(known)}")
        settings = replace(settings, **{k: tuple(v) if k == "betas" else v for k, v in over.items()})
    render = RenderSettings(spp=a.spp, seed=a.seed, rel_threshold=a.rel_threshold, visibility=a.visibility,
                            visibility_mesh=VisibilitySettings(rel_threshold=a.rel_threshold,
                                                               max_faces=a.visibility_max_faces))
    m = fit_envmap(a.clip, a.frames, a.out, settings, render, init_map=a.init_map)
    print(f"{a.out}: {settings.solver} fit in {m['fit']['fit_seconds']:.1f} s, yaw {m['fit']['yaw_rad']:+.3f} rad, "
          f"pitch {m['fit']['pitch_rad']:+.3f} rad, exposure {m['fit']['exposure_ev']:+.2f} EV, "
          f"pseudo-input PSNR {m['pseudo_psnr_db']['mean'] if m['pseudo_psnr_db'] else float('nan'):.2f} dB")


if __name__ == "__main__":
    _cli.run(main)
