"""Sample one declarative scene spec (scene.json) as a pure function of (config, seed, scene id)."""

import argparse
import json

import _cli


def main():
    from lightcrafter import scenes
    from lightcrafter.io import read_json, write_json

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--scene-id", required=True)
    ap.add_argument("--manifest", required=True, help="curated asset manifest")
    ap.add_argument("--config", required=True, help="JSON with keys seed, scenes, render")
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    cfg = _cli.json_arg(a.config)
    spec = scenes.sample_scene(cfg["scenes"], cfg["render"], cfg["seed"], scenes.scene_index(a.scene_id),
                               read_json(a.manifest), scenes.hdri_pool(cfg["scenes"]))
    write_json(a.out, spec)


if __name__ == "__main__":
    _cli.run(main)
