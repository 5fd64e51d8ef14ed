"""Fit the source environment map of a video and render its pseudo-input video (real pseudo-pairs).

  fit_envmap.py --clip CLIP_DIR --frames FRAMES_DIR --out OUT_DIR [--settings-json @envfit.json] [--proxy @proxy.json]

CLIP_DIR: the video's recovered scene state (lightcrafter.clip: buffers.json, cameras.json, buffers/);
FRAMES_DIR: the video's linear EXR frames 0000.exr ... (one per clip frame, clip resolution).
Writes OUT_DIR/envmap.exr (fitted 64x128 map, world frame, yaw/pitch/exposure baked in),
lighting.json (lighting file R renders with), params.npz, loss_curve.json, pseudo/####.exr +
pseudo.mp4 + pseudo.json (R(S, L_hat) of every frame) and fit.json (manifest, last).
Defaults are the paper's (config envfit, lightcrafter.config.models.Envfit); a killed run resumes.
"""

import argparse

import _cli


def main():
    from pathlib import Path

    from lightcrafter.clip import is_skipped
    from lightcrafter.config import validate_section
    from lightcrafter.config.models import Envfit
    from lightcrafter.envfit.fit import FitSettings, fit_envmap
    from lightcrafter.io import write_json
    from lightcrafter.proxy import render_settings

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--clip", required=True, help="clip folder (buffers.json, cameras.json, buffers/)")
    ap.add_argument("--frames", required=True, help="folder of the video's linear EXR frames {i:04d}.exr")
    ap.add_argument("--out", required=True, help="output folder")
    ap.add_argument("--settings-json", default=None,
                    help="the fit's settings: JSON or @file of config envfit (lightcrafter.config.models.Envfit; "
                    "default: its defaults, the paper's)")
    ap.add_argument("--proxy", default=None, help="R's settings: JSON or @file of config proxy")
    ap.add_argument("--init-map", default=None,
                    help="initial lat-long EXR (e.g. DiffusionLight's); default constant grey")
    ap.add_argument("--threads", type=int, default=None, help="CPU threads (Dr.Jit)")
    a = ap.parse_args()

    reason = is_skipped(a.clip)
    if reason:  # the reconstruction stack left the clip out: so is its pseudo-pair (datasets count it)
        out = Path(a.out)
        write_json(out / "pseudo.json", {"format": "lightcrafter.proxy/1", "skipped": reason})
        write_json(out / "fit.json", {"skipped": reason, "clip": a.clip})
        print(f"{a.out}: left out ({reason})")
        return
    fit = validate_section(Envfit, _cli.json_arg(a.settings_json, {}), "envfit").model_dump()
    if a.init_map is None and (Path(a.clip) / "envmap_init.exr").is_file():  # the paper stack's DiffusionLight map
        a.init_map = str(Path(a.clip) / "envmap_init.exr")
    settings = FitSettings(**{k: tuple(v) if k == "betas" else v for k, v in fit.items()}, threads=a.threads)
    render = render_settings(_cli.json_arg(a.proxy, {}))
    m = fit_envmap(a.clip, a.frames, a.out, settings, render, init_map=a.init_map)
    print(f"{a.out}: {settings.solver} fit in {m['fit']['fit_seconds']:.1f} s, yaw {m['fit']['yaw_rad']:+.3f} rad, "
          f"pitch {m['fit']['pitch_rad']:+.3f} rad, exposure {m['fit']['exposure_ev']:+.2f} EV, "
          f"pseudo-input PSNR {m['pseudo_psnr_db']['mean'] if m['pseudo_psnr_db'] else float('nan'):.2f} dB")


if __name__ == "__main__":
    _cli.run(main)
