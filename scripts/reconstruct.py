#!/usr/bin/env python
"""Run the reconstruction stack Phi on a video (a folder of linear frames {i:04d}.exr) and write a clip.

  reconstruct.py --frames results/gt/s0000/t0/rgb/L1 --out results/recon/synthetic/s0000_t0 \
      --estimator results/recon/estimator/model.pt --fps 24 --scene-static 1 --settings-json '{...}' \
      [--name s0000_t0] [--skip-failed]

With --skip-failed, a video Phi cannot reconstruct (too little texture or parallax) gets a manifest
that records ``skipped`` and the reason (downstream stages leave it out and count it) instead of
stopping the run.
"""

import argparse
import shutil
import sys
from pathlib import Path

import _cli  # noqa: F401  (puts the repository on sys.path)

from lightcrafter import io


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", required=True, help="folder of linear EXR frames (or its manifest .json)")
    ap.add_argument("--out", required=True, help="clip folder to write")
    from lightcrafter.recon import BACKENDS

    ap.add_argument("--backend", default="default", choices=sorted(BACKENDS))
    ap.add_argument("--estimator", default=None, help="G-buffer estimator weights (default backend)")
    ap.add_argument("--fps", type=float, default=24.0)
    ap.add_argument("--scene-static", type=int, choices=[0, 1], default=1, help="1: no object moves (video metadata)")
    ap.add_argument("--settings-json", default="{}", help="backend settings")
    ap.add_argument("--name", default=None, help="clip id for messages")
    ap.add_argument("--skip-failed", action="store_true")
    a = ap.parse_args()
    frames = Path(a.frames)
    frames = frames.with_suffix("") if frames.suffix == ".json" else frames
    out = Path(a.out)
    name = a.name or out.name
    from lightcrafter.clip import write_skipped
    from lightcrafter.recon.cameras import ReconstructionError
    from lightcrafter.recon.paper_stack import ToolError

    try:
        man = io.read_json(frames.with_suffix(".json")) if frames.with_suffix(".json").is_file() else {}
        if man.get("skipped"):
            write_skipped(out, f"source video skipped: {man['skipped']}", {"clip_id": name})
            print(f"reconstruct: {name}: left out (source video skipped)")
            return 0
        settings = _cli.json_arg(a.settings_json)
        if a.backend == "default":
            from lightcrafter.recon.default import DefaultSettings, reconstruct_default

            if not a.estimator:
                raise io.DataError("--estimator is required by the default backend")
            m = reconstruct_default(frames, out, estimator_path=a.estimator, fps=a.fps, scene_static=bool(a.scene_static),
                                    settings=DefaultSettings.from_dict(settings), name=name, extra={"clip_id": name})
        else:  # the paper's stack: 8-bit frames in, its clip on MegaSAM's grid, then onto the video's grid
            from lightcrafter.recon.default import read_video_frames
            from lightcrafter.recon.paper_stack import reconstruct_paper_stack
            from lightcrafter.recon.resample import onto_video_grid

            _, u8 = read_video_frames(frames)
            # The tools' frames are written by the backend under .work/frames (frames_root holds this
            # clip only); the display frames handed to it go to .work/input, apart, so that a retry
            # never shows the tools a second clip.
            png = out / ".work" / "input"
            shutil.rmtree(png, ignore_errors=True)
            png.mkdir(parents=True)
            import imageio.v3 as iio

            for i, f in enumerate(u8):
                iio.imwrite(png / f"{i:05d}.png", f)
            cleanup = bool(settings.pop("cleanup_work", True))
            reconstruct_paper_stack(png, out / "tool_grid", settings.pop("commands", {}), scene_static=bool(a.scene_static),
                                    fps=a.fps, clip_id=name, work_dir=out / ".work", cleanup_work=False, **settings)
            if (out / "tool_grid" / "envmap_init.exr").is_file():
                shutil.copyfile(out / "tool_grid" / "envmap_init.exr", out / "envmap_init.exr")
            m = onto_video_grid(out / "tool_grid", out, u8.shape[2], u8.shape[1])
            if cleanup:  # the clip is written: the tools' frames, outputs and the tool-grid copy go
                for d in (".work", "tool_grid"):
                    shutil.rmtree(out / d, ignore_errors=True)
    except (ReconstructionError, ToolError) as exc:  # the video, or a paper-stack tool on it, failed
        if not a.skip_failed:
            print(f"reconstruct: {exc}", file=sys.stderr)
            return 1
        shutil.rmtree(out / "buffers", ignore_errors=True)
        reason = str(exc)
        if _drop_tool_work(out):  # the tool logs the reason names now live in tool_logs/
            reason = reason.replace(str(out / ".work") + "/", str(out / "tool_logs") + "/")
        write_skipped(out, reason, {"clip_id": name})
        print(f"reconstruct: {name}: left out: {exc}")
        return 0
    except (io.DataError, ValueError) as exc:
        print(f"reconstruct: {exc}", file=sys.stderr)
        return 1
    phi = m.get("phi", {})
    print(f"reconstruct: {name}: {m['num_frames']} frames, {m['buffer_frames']} buffer frame(s), "
          f"cameras {phi.get('method')} ({phi.get('registered')}/{phi.get('frames')} registered) -> {out}")
    return 0


def _drop_tool_work(out: Path) -> bool:
    """A skipped paper-stack clip keeps only its tools' logs (out/tool_logs/), not their outputs.
    Returns whether there were any."""
    work = out / ".work"
    logs = sorted(work.glob("*.log")) if work.is_dir() else []
    if logs:
        (out / "tool_logs").mkdir(exist_ok=True)
        for log in logs:
            shutil.copyfile(log, out / "tool_logs" / log.name)
    for d in (".work", "tool_grid"):
        shutil.rmtree(out / d, ignore_errors=True)
    return bool(logs)


if __name__ == "__main__":
    from _cli import set_code_version

    set_code_version()
    sys.exit(main())
