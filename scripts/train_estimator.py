#!/usr/bin/env python
"""Train the G-buffer estimator of the default reconstruction stack on ground-truth clips (recon split).

  train_estimator.py --clips gt/s0004/t0/buffers.json ... --videos gt/s0004/t0/rgb/L1.json ... \
      --config-json '{"steps": 600}' --out results/recon/estimator/model.pt --curve results/recon/estimator/curve.json

Clip k is paired with video k (Cycles frames of the trajectory under one of the lightings it is rendered
under, scenes.recon_lightings: a clip repeats for each). Validation for the error-against-training-time
curve (and the step kept): the last eighth of the scenes when there are 8 or more, else the last trajectory
under all its lights (all are used when there is only one trajectory).
"""

import argparse
from pathlib import Path

import _cli  # puts the repository on sys.path; run() is the one error path

from lightcrafter.io import DataError


def validation_split(pairs: list[tuple[str, str]]) -> tuple[list, list]:
    """(validation, training) pairs: with 8 or more scenes, every trajectory of the last eighth of the scenes
    (whole scenes held out: no layout seen in training); with fewer, the last trajectory under every light it
    comes with; with one trajectory, it is both."""
    scenes = sorted({Path(c).parent.parent.name for c, _ in pairs})
    if len(scenes) >= 8:
        held = set(scenes[-(len(scenes) // 8):])
        return [p for p in pairs if Path(p[0]).parent.parent.name in held], \
            [p for p in pairs if Path(p[0]).parent.parent.name not in held]
    last = max(c for c, _ in pairs)
    val, train = [p for p in pairs if p[0] == last], [p for p in pairs if p[0] != last]
    return (val, train) if train else (pairs, pairs)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--clips", nargs="+", required=True, help="ground-truth clip manifests (buffers.json)")
    ap.add_argument("--videos", nargs="+", required=True, help="source-video manifests, one per clip")
    ap.add_argument("--config-json", default="{}")
    ap.add_argument("--out", required=True)
    ap.add_argument("--curve", required=True)
    a = ap.parse_args()
    from lightcrafter.clip import read_clip
    from lightcrafter.recon import estimator as est

    if len(a.clips) != len(a.videos):
        raise DataError(f"{len(a.clips)} clips but {len(a.videos)} videos; pass one source video per clip")
    cfg = est.EstimatorConfig.from_dict(_cli.json_arg(a.config_json))
    pairs = sorted(zip(a.clips, a.videos))
    val_pairs, train_pairs = validation_split(pairs)
    train = [s for c, v in train_pairs for s in est.load_clip_samples(Path(c).parent, Path(v).with_suffix(""))]
    val = []
    for c, v in val_pairs:
        views, _ = read_clip(Path(c).parent)
        samples = est.load_clip_samples(Path(c).parent, Path(v).with_suffix(""))
        val += [(s.rgb.numpy().transpose(1, 2, 0), views[i].buffers, views[i].c2w)
                for i, s in enumerate(samples)][::2]
    model, curve = est.train_estimator(train, val, cfg, log=lambda m: print(m, flush=True))
    est.save(model, cfg, a.out, {"train_frames": len(train), "val_frames": len(val), "clips": [c for c, _ in pairs]})
    est.write_curve(a.curve, curve, cfg)
    print(f"train_estimator: {len(train)} frames, {cfg.steps} steps -> {a.out}")
    return 0


if __name__ == "__main__":
    _cli.run(main, "train_estimator", (DataError, ValueError))
