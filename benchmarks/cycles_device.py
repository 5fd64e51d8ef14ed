"""One ground-truth frame at the paper's size and settings (720x480, 64 spp, 6 bounces, OIDN) on each
Cycles device: seconds per frame, and the GPU frames' display PSNR against the CPU frame.

Renders frame 0 of lightcrafter.blender.testing.tiny_spec (a textured GLB, primitives, HDRI; the
scene the render tests use) resized to 720x480. Devices are measured in interleaved repeats (cpu,
optix, cuda, cpu, ...; a device the node lacks is reported as not run, with Cycles' reason) and each
reports the median seconds with its range, each GPU device also its speed ratio to the CPU per repeat (a GPU
device renders once untimed first: kernel loading is not the frame's cost). Seconds are the wall time of posing
the frame and one render call (path tracing, denoising, EXR write/read) with Cycles' default threads.

    .venv/bin/python benchmarks/cycles_device.py [--repeats 3] [--devices cpu optix cuda]
    -> results/bench/cycles_device.json
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lightcrafter import io  # noqa: E402
from lightcrafter.blender import build, render, testing  # noqa: E402
from lightcrafter.metrics import psnr_db  # noqa: E402
from lightcrafter.speed import median_range, ratio_median_range  # noqa: E402

PAPER = {"width": 720, "height": 480, "spp": 64, "max_bounces": 6, "denoiser": "oidn"}


def render_once(built, spec: dict) -> tuple[np.ndarray, float]:
    build.configure_render(spec, samples=PAPER["spp"], max_bounces=PAPER["max_bounces"],
                           filter_width_px=render.RGB_FILTER_WIDTH_PX, film_transparent=False, buffers=False,
                           denoiser=PAPER["denoiser"], clamp_indirect=0.0)
    t0 = time.perf_counter()
    build.set_frame(built, spec["trajectories"][0]["frames"][0])
    ch = render.render_layers()
    return np.stack([ch[f"Combined.{c}"] for c in "RGB"], axis=-1), time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--devices", nargs="+", default=["cpu", "optix", "cuda"])
    ap.add_argument("--out", type=Path, default=Path("results/bench/cycles_device.json"))
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="lc_bench_") as tmp:
        spec = testing.tiny_spec(Path(tmp), width=PAPER["width"], height=PAPER["height"], num_frames=1)
        spec["render"] = dict(spec["render"], spp=PAPER["spp"], max_bounces=PAPER["max_bounces"])
        built = build.build_scene(spec, light_id="L0")
        usable, not_run = [], {}
        for dev in a.devices:
            try:
                used = build.select_device(dev)
            except io.DataError as exc:
                not_run[dev] = str(exc)
                continue
            if used.lower() != dev:
                not_run[dev] = f"asked for {dev}, Cycles used {used}"
                continue
            usable.append(dev)
        for dev in usable:  # an untimed render on each GPU device first: it loads the device's kernels
            if dev != "cpu":
                build.select_device(dev)
                render_once(built, spec)
        seconds = {d: [] for d in usable}
        frames = {}
        for r in range(a.repeats):
            for dev in usable:                     # interleaved: cpu, optix, cuda, cpu, ...
                build.select_device(dev)
                img, s = render_once(built, spec)
                seconds[dev].append(s)
                frames.setdefault(dev, img)
                print(f"repeat {r}: {dev}: {s:.2f} s", flush=True)
    cpu = io.linear_to_display(frames["cpu"]) if "cpu" in frames else None
    results = {}
    for dev, ss in seconds.items():
        results[dev] = {"seconds_per_frame": median_range(ss)}
        if dev != "cpu" and "cpu" in seconds:  # the same repeat of each device: an interleaved pair
            results[dev]["speed_ratio_cpu_over_this"] = ratio_median_range(seconds["cpu"], ss)
        if cpu is not None and dev != "cpu":
            results[dev]["psnr_db_vs_cpu_frame"] = round(psnr_db(io.linear_to_display(frames[dev]), cpu), 2)
    out = {"name": "cycles_device", "settings": PAPER, "scene": "lightcrafter.blender.testing.tiny_spec frame 0, L0",
           "machine": {"cores": os.cpu_count(), "platform": platform.platform()},
           "devices": results, "not_run": not_run,
           "method": "interleaved repeats per device, median and range of wall seconds per frame (lightcrafter.speed); "
                     "PSNR on display values"}
    io.write_json(a.out, out)
    print(f"wrote {a.out}: {results}; not run: {list(not_run)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
