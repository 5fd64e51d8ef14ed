"""Bytes and files per clip before and after the half-float storage change, and the paper projection.

For every product of a results folder (lightcrafter.storage.PRODUCTS) the same frames are written
twice into a scratch folder, as before (float32 everywhere, ZIP) and as now (lightcrafter.io: half
float, depth float32, ZIP), and their sizes compared on identical content. The measured
compressed-to-uncompressed ratios of the current encoding then scale the paper config's projection
(lightcrafter.storage.project).

    .venv/bin/python benchmarks/storage.py [--results results] [--configfile config/paper.yaml]
    -> results/bench/storage.json
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lightcrafter import io, storage  # noqa: E402
from lightcrafter.config import raw_config, validate  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def reencode(files: list[Path], kind: str, scratch: Path) -> tuple[int, int]:
    """(bytes as float32, bytes as now) of ``files`` written both ways."""
    before = after = 0
    for i, f in enumerate(files):
        a, b = scratch / f"{i}_f32.exr", scratch / f"{i}_now.exr"
        if kind == "frame":
            rgb = io.read_rgb_exr(f, allow_nonfinite=True)
            io.write_rgb_exr(a, rgb)
            io.write_frame_exr(b, rgb)
        else:
            ch = io.read_exr(f, io.BUFFER_CHANNELS)
            io.write_exr(a, ch)
            io.write_buffers(b, io.read_buffers(f))
        before += a.stat().st_size
        after += b.stat().st_size
        a.unlink()
        b.unlink()
    return before, after


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", type=Path, default=REPO / "results")
    ap.add_argument("--configfile", default=str(REPO / "config" / "paper.yaml"))
    ap.add_argument("--out", type=Path, default=REPO / "results" / "bench" / "storage.json")
    a = ap.parse_args(argv)
    rows = {}
    with tempfile.TemporaryDirectory(prefix="lc_storage_") as tmp:
        for name, (pattern, kind) in storage.PRODUCTS.items():
            clips = [d for d in sorted(a.results.glob(pattern)) if d.is_dir() and any(d.glob("*.exr"))]
            files = [f for d in clips for f in sorted(d.glob("*.exr"))]
            if not files:
                continue
            before, after = reencode(files, kind, Path(tmp))
            rows[name] = {"clips": len(clips), "files": len(files), "files_per_clip": round(len(files) / len(clips), 2),
                          "bytes_per_clip_float32": round(before / len(clips)), "bytes_per_clip_now": round(after / len(clips)),
                          "ratio_now_over_float32": round(after / before, 3)}
            print(f"{name:18s} {len(clips):3d} clips  {before / len(clips) / 1e3:9.1f} kB -> {after / len(clips) / 1e3:9.1f} kB per clip "
                  f"({after / before:.2f})", flush=True)
    measured = storage.measured_ratios(a.results)
    cfg = validate(raw_config([a.configfile]))
    projection = storage.project(cfg, measured)
    print(storage.table(projection))
    io.write_json(a.out, {"name": "storage", "results": str(a.results), "per_product": rows,
                          "projection_config": a.configfile, "projection": projection,
                          "note": "same frames written both ways; the projection uses the measured ZIP ratios of the "
                                  "current encoding, at this run's resolution (compression depends on content)"})
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
