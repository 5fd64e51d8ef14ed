"""Write the procedural "Objaverse-style" GLB assets and a listing (written last)."""

import argparse
import json

import _cli


def main():
    from lightcrafter.assets import write_procedural_assets
    from lightcrafter.io import write_json

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out-dir", required=True)
    ap.add_argument("--listing", required=True, help="JSON listing written when all files exist")
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--settings", required=True, help="JSON of config['assets']['procedural']")
    a = ap.parse_args()
    s = _cli.json_arg(a.settings)
    paths = write_procedural_assets(a.out_dir, a.seed, s["count"], s.get("heavy_every", 0), s.get("include_faulty", False))
    write_json(a.listing, {"files": [str(p) for p in paths]})
    print(f"wrote {len(paths)} GLB files to {a.out_dir}")


if __name__ == "__main__":
    _cli.run(main)
