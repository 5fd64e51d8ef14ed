"""Print the effective configuration as JSON: exactly what the workflow's rules get.

  python -m lightcrafter.config                                  # the laptop default (config/config.yaml)
  python -m lightcrafter.config --configfile config/paper.yaml   # the paper's run
  python -m lightcrafter.config --configfile config/paper.yaml --key refiner.train
  python -m lightcrafter.config --configfile config/ci.yaml --set scenes.count=4
  python -m lightcrafter.config --write-docs | --check-docs      # config/README.md and the JSON schema

``--no-disk-checks`` validates without checking the folders the config names (to read a site's config
elsewhere). Errors are one line naming the key and the fix; the exit code is 1.
"""

from __future__ import annotations

import argparse
import json
import sys

import yaml

from . import deep_merge, raw_config, validate
from ..scenes import ConfigError


def _set(spec: str) -> dict:
    key, sep, value = spec.partition("=")
    if not sep or not key:
        raise ConfigError(f"--set {spec!r}: write KEY.PATH=VALUE (the value is YAML)")
    out: dict = {}
    node = out
    parts = key.split(".")
    for p in parts[:-1]:
        node = node.setdefault(p, {})
    node[parts[-1]] = yaml.safe_load(value)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m lightcrafter.config", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--configfile", nargs="+", default=None, help="config files, merged in order (as Snakemake's)")
    ap.add_argument("--set", action="append", default=[], help="KEY.PATH=VALUE override (after the files)")
    ap.add_argument("--key", default=None, help="print only this dotted key")
    ap.add_argument("--no-disk-checks", action="store_true", help="skip the start-up checks of folders on disk")
    ap.add_argument("--write-docs", action="store_true", help="regenerate config/README.md and the JSON schema")
    ap.add_argument("--check-docs", action="store_true", help="exit 1 if they are stale")
    a = ap.parse_args(argv)
    try:
        if a.write_docs or a.check_docs:
            from .docs import stale_docs, write_docs

            if a.write_docs:
                for p in write_docs():
                    print(f"wrote {p}")
                return 0
            stale = stale_docs()
            for p in stale:
                print(f"stale: {p}; run python -m lightcrafter.config --write-docs", file=sys.stderr)
            return 1 if stale else 0
        overrides: dict = {}
        for s in a.set:
            overrides = deep_merge(overrides, _set(s))
        files = a.configfile or []
        cfg = validate(raw_config(files, overrides), " + ".join(files) or "config/config.yaml")
        if not a.no_disk_checks:
            from . import check_startup

            check_startup(cfg, " + ".join(files) or "config/config.yaml")
        if a.key:
            for part in a.key.split("."):
                if not isinstance(cfg, dict) or part not in cfg:
                    raise ConfigError(f"--key {a.key}: no key {part!r}; known: {sorted(cfg) if isinstance(cfg, dict) else []}")
                cfg = cfg[part]
        print(json.dumps(cfg, indent=1))
        return 0
    except ConfigError as exc:
        print(f"ConfigError: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
