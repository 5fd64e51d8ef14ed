"""Curate a folder of GLB assets: validate, reject with reasons, decimate, normalise, manifest."""

import argparse
import json

import _cli


def main():
    from lightcrafter.assets import CurationSettings, curate_folder

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--src-dir", required=True)
    ap.add_argument("--out-dir", required=True)
    ap.add_argument("--manifest", required=True)
    ap.add_argument("--settings", required=True, help="JSON of config['assets']['curation']")
    a = ap.parse_args()
    m = curate_folder(a.src_dir, a.out_dir, a.manifest, CurationSettings(**_cli.json_arg(a.settings)))
    print(f"accepted {len(m['accepted'])}, rejected {len(m['rejected'])}")


if __name__ == "__main__":
    _cli.run(main)
