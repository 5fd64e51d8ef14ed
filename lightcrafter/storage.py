"""Expected files and bytes per product of a configuration, from its plans alone (no rendering).

Each product is a set of per-frame EXRs in the storage precision of lightcrafter.io (ZIP-compressed,
lossless): video frames 3 half-float channels (6 bytes per pixel uncompressed), buffers 9 half-float
channels plus float32 depth (22 bytes per pixel; 40 before the half-float change). The uncompressed
size is an upper bound; with ``measured`` (a results folder of a run of any config) each product's
compressed-to-uncompressed ratio is measured on its files there and applied to the projection.
The paper stack's tool images (~(2 + 5) images per frame and MegaSAM's npz) live only while their
clip's job runs (removed when the clip is written) and are listed as per-clip transients.

  python -m lightcrafter.storage [--configfile F ...] [--measured results/]
"""

from __future__ import annotations

from pathlib import Path

from .scenes import rendered_plans

FRAME_BPP = 3 * 2                    # R, G, B half float
BUFFER_BPP = 4 + 9 * 2               # depth float32, normal/albedo (3 + 3), roughness, metallic, mask half
BUFFER_BPP_FLOAT32 = 10 * 4          # all float32 (before)
FRAME_BPP_FLOAT32 = 3 * 4
EXR_OVERHEAD_BYTES = 400             # header and line-offset table of a small scanline EXR (ZIP, 16-line blocks)

# product: (folder glob under a results folder, kind)
PRODUCTS = {
    "gt_rgb": ("gt/*/*/rgb/*", "frame"),
    "gt_buffers": ("gt/*/*/buffers", "buffers"),
    "proxy_gt": ("proxy_gt/*/*/*", "frame"),
    "proxy": ("proxy/*/*/*", "frame"),
    "phi_synthetic": ("recon/synthetic/*/buffers", "buffers"),
    "aligned_synthetic": ("aligned/*/*/buffers", "buffers"),
    "real_frames": ("real/*/rgb", "frame"),
    "phi_real": ("recon/real/*/buffers", "buffers"),
    "pseudo_input": ("envfit/*/pseudo", "frame"),
}


def plan_counts(cfg: dict) -> dict[str, tuple[int, int]]:
    """{product: (files, pixels per file)} of a configuration (plans only)."""
    from .ingest import real_clips

    s = cfg["scenes"]
    px, n = int(s["width"]) * int(s["height"]), int(s["num_frames"])
    plans = rendered_plans(cfg)
    trajs = [(p["split"], t) for p in plans for t in p["trajectories"]]
    pairs = sum(len(t["target_lights"]) for sp, t in trajs if sp in ("train", "test"))
    refiner_trajs = [t for sp, t in trajs if sp in ("train", "test")]
    real_cfg = dict(cfg.get("real", {}))
    d = real_cfg.pop("dl3dv", None) or {}
    real = len(real_clips(real_cfg, n, int(cfg.get("seed", 0))))
    if d.get("root"):
        from .ingest import dl3dv_scenes

        # a DL3DV folder not mounted where this runs: plan from the config's numbers
        scenes = len(dl3dv_scenes(d["root"])) if Path(d["root"]).is_dir() else int(d.get("max_scenes") or 0)
        real += min(scenes, int(d.get("max_scenes") or scenes)) * int(d.get("clips_per_scene", 1))
    return {
        "gt_rgb": (sum(len(t["render_lights"]) for _, t in trajs) * n, px),
        "gt_buffers": (sum(int(t["buffer_frames"]) for _, t in trajs), px),
        "proxy_gt": (pairs * n, px),
        "proxy": (pairs * n, px),
        "phi_synthetic": (len(refiner_trajs) * n, px),
        "aligned_synthetic": (len(refiner_trajs) * n, px),
        "real_frames": (real * n, px),
        "phi_real": (real * n, px),
        "pseudo_input": (real * n, px),
    }


def _bpp(kind: str) -> int:
    return FRAME_BPP if kind == "frame" else BUFFER_BPP


def measured_ratios(results: str | Path) -> dict[str, dict]:
    """{product: {files, bytes, ratio}} of a results folder: on-disk bytes over the uncompressed size
    of the same EXRs in the current precision (pixels read from each file's header)."""
    import OpenEXR

    out = {}
    for name, (pattern, kind) in PRODUCTS.items():
        files = [f for d in Path(results).glob(pattern) if d.is_dir() for f in d.glob("*.exr")]
        if not files:
            continue
        size = sum(f.stat().st_size for f in files)
        raw = 0
        for f in files:
            with OpenEXR.File(str(f), header_only=True) as e:
                (x0, y0), (x1, y1) = e.header()["dataWindow"]
            raw += (x1 - x0 + 1) * (y1 - y0 + 1) * _bpp(kind) + EXR_OVERHEAD_BYTES
        out[name] = {"files": len(files), "bytes": size, "ratio": size / raw}
    return out


def project(cfg: dict, measured: dict | None = None) -> dict:
    """Expected files and bytes per product (module docstring)."""
    rows, tot_files, tot_bytes, tot_f32 = [], 0, 0.0, 0.0
    for name, (files, px) in plan_counts(cfg).items():
        kind = PRODUCTS[name][1]
        raw = files * (px * _bpp(kind) + EXR_OVERHEAD_BYTES)
        f32 = files * (px * (FRAME_BPP_FLOAT32 if kind == "frame" else BUFFER_BPP_FLOAT32) + EXR_OVERHEAD_BYTES)
        ratio = (measured or {}).get(name, {}).get("ratio")
        expected = raw * ratio if ratio else raw
        rows.append({"product": name, "kind": kind, "files": files, "uncompressed_bytes": raw,
                     "float32_uncompressed_bytes": f32, "ratio": ratio, "expected_bytes": expected})
        tot_files += files
        tot_bytes += expected
        tot_f32 += f32
    transient = {"per_clip_frames": int(cfg["scenes"]["num_frames"]),
                 "images_per_frame": 2 + 5, "note": "paper stack only: PNG frames (input, frames_root) and "
                 "DiffusionRenderer's 5 JPEG passes per frame, MegaSAM's npz; removed when the clip is written"}
    return {"rows": rows, "total_files": tot_files, "total_expected_bytes": tot_bytes,
            "total_float32_uncompressed_bytes": tot_f32, "transient": transient,
            "measured": bool(measured)}


def _fmt_bytes(b: float) -> str:
    if b < 1000:
        return f"{b:.0f} B"
    for unit in ("KB", "MB", "GB"):
        b /= 1000.0
        if b < 1000:
            return f"{b:.1f} {unit}"
    return f"{b / 1000.0:.1f} TB"


def table(p: dict) -> str:
    """The projection as text (one line per product, then the total)."""
    lines = [f"{'product':<18} {'files':>10} {'expected':>11} {'ratio':>6} {'float32 raw':>12}"]
    for r in p["rows"]:
        ratio = f"{r['ratio']:.2f}" if r["ratio"] else "n/a"
        lines.append(f"{r['product']:<18} {r['files']:>10,} {_fmt_bytes(r['expected_bytes']):>11} {ratio:>6} "
                     f"{_fmt_bytes(r['float32_uncompressed_bytes']):>12}")
    how = "ZIP ratio measured" if p["measured"] else "uncompressed (upper bound)"
    lines.append(f"{'total':<18} {p['total_files']:>10,} {_fmt_bytes(p['total_expected_bytes']):>11} "
                 f"{'':>6} {_fmt_bytes(p['total_float32_uncompressed_bytes']):>12}   ({how})")
    return "\n".join(lines)


def main(argv=None) -> int:
    import argparse

    from .config import raw_config, validate

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--configfile", nargs="*", default=[])
    ap.add_argument("--measured", help="results folder of a run, for the compression ratios")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    cfg = validate(raw_config(a.configfile or None))   # no disk checks: a site's config can be read elsewhere
    p = project(cfg, measured_ratios(a.measured) if a.measured else None)
    if a.json:
        import json

        print(json.dumps(p, indent=1))
    else:
        print(table(p))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
