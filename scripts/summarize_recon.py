#!/usr/bin/env python
"""Write results/summary/reconstruction.json: Phi's errors on synthetic clips (after Align, per motion
config), its run counts (once per trajectory vs once per pair), registration, skips and seconds.

  summarize_recon.py --est CLIP.json ... --aligned CLIP.json ... --gt CLIP.json ... --real CLIP.json ...
      --plans-json '{...}' --out results/summary/reconstruction.json
  summarize_recon.py --inputs @inputs.json --plans-json @plans.json --out ...
"""

import argparse
import json
from pathlib import Path

import _cli  # puts the repository on sys.path; run() is the one error path

from lightcrafter import io


def _timing(clip_manifest: str) -> float | None:
    f = Path(clip_manifest).parent / "timing.json"
    return io.read_json(f).get("seconds") if f.is_file() else None


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--inputs", default=None, help="JSON or @file {est, aligned, gt, real: [clip manifest, ...]} "
                    "(what the workflow passes: thousands of paths do not fit on a command line)")
    ap.add_argument("--est", nargs="*", default=[])
    ap.add_argument("--aligned", nargs="*", default=[])
    ap.add_argument("--gt", nargs="*", default=[])
    ap.add_argument("--real", nargs="*", default=[])
    ap.add_argument("--plans-json", required=True, help="JSON or @file {scene_id: scene_plan}")
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    from lightcrafter.clip import is_skipped, read_info
    from lightcrafter.recon.evaluate import clip_errors, summarize

    for key, paths in _cli.json_arg(a.inputs, {}).items():
        setattr(a, key, list(paths))
    plans = _cli.json_arg(a.plans_json)
    motions, targets, frames = {}, 0, {}
    for sid, plan in plans.items():
        for t in plan["trajectories"]:
            motions[f"{sid}_{t['id']}"] = t["motion"]
            targets += len(t["target_lights"])
    per_clip, seconds = {}, []
    for e, al, g in zip(a.est, a.aligned, a.gt):
        cid = Path(e).parent.name
        per_clip[cid] = {**clip_errors(e, al, g), "motion": motions.get(cid),
                         "split": plans.get(cid.split("_")[0], {}).get("split")}
        frames[cid] = read_info(g).num_frames
        if _timing(e) is not None:
            seconds.append((_timing(e), frames[cid]))
    out = summarize(per_clip, motions)
    moving = [c for c in per_clip if motions.get(c) != "static_rotating_light"]
    n_mov = sum(frames[c] for c in moving)
    reg = sum(per_clip[c].get("registered_fraction", 0.0) * frames[c] for c in moving)
    out["moving_camera_frames_registered_incl_skipped"] = reg / n_mov if n_mov else None
    by_split = {}
    for split in ("train", "test"):
        rows = {c: v for c, v in per_clip.items() if v.get("split") == split}
        if rows:
            by_split[split] = summarize(rows, motions)["by_motion"].get("all")
    out["by_split"] = by_split
    out["phi_runs"] = {"synthetic": len(a.est), "real": len(a.real),
                       "naive_synthetic": targets,
                       "note": "Phi runs once per trajectory on its source video; a naive pipeline would "
                               "reconstruct once per (trajectory, target light) pair"}
    out["seconds_per_frame"] = (sum(s for s, _ in seconds) / sum(n for _, n in seconds)) if seconds else None
    real = {}
    for r in a.real:
        cid = Path(r).parent.name
        reason = is_skipped(r)
        if reason:
            real[cid] = {"skipped": reason}
            continue
        info = read_info(r)
        phi = info.manifest.get("phi", {})
        real[cid] = {"camera_method": phi.get("method"), "registered": phi.get("registered"),
                     "frames": info.num_frames, "camera_static": info.camera_static, "seconds": _timing(r)}
    out["real"] = real
    out["per_clip"] = per_clip
    io.write_json(a.out, out)
    print(json.dumps({k: v for k, v in out.items() if k not in ("per_clip",)}, indent=1)[:3000])
    return 0


if __name__ == "__main__":
    _cli.run(main, "summarize_recon", (io.DataError,))
