"""Curate a folder of GLB assets: validate, reject with reasons, decimate, normalise, manifest.

  curate_assets.py --src-dir D --out-dir C --manifest shard_k.json --settings @params.json [--shard K --shards N]
  curate_assets.py --merge shard_0.json shard_1.json ... --manifest manifest.json
"""

import argparse

import _cli


def main():
    from lightcrafter.assets import CurationSettings, curate_folder, merge_manifests

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--src-dir")
    ap.add_argument("--out-dir")
    ap.add_argument("--manifest", required=True)
    ap.add_argument("--settings", help="JSON of config['assets']['curation']")
    ap.add_argument("--shard", type=int, default=0, help="this job's index k: every n-th GLB from the k-th")
    ap.add_argument("--shards", type=int, default=1, help="n, the number of curation jobs")
    ap.add_argument("--merge", nargs="+", help="shard manifests to join into --manifest")
    a = ap.parse_args()
    if a.merge:
        m = merge_manifests(a.merge, a.manifest)
    else:
        if not (a.src_dir and a.out_dir and a.settings):
            ap.error("--src-dir, --out-dir and --settings are required unless --merge is given")
        m = curate_folder(a.src_dir, a.out_dir, a.manifest, CurationSettings(**_cli.json_arg(a.settings)),
                          shard=(a.shard, a.shards))
    print(f"accepted {len(m['accepted'])}, rejected {len(m['rejected'])}")


if __name__ == "__main__":
    _cli.run(main)
