"""Configuration checks: JSON-schema validation with one-line errors, then semantic checks."""

from __future__ import annotations

import math
from pathlib import Path

from ..scenes import ConfigError


def _key_path(err) -> str:
    parts = [str(p) for p in err.absolute_path]
    if err.validator == "additionalProperties":
        # jsonschema reports the parent; name the offending key itself.
        extra = sorted(set(err.instance) - set(err.schema.get("properties", {})))
        parts.append(extra[0] if extra else "?")
        return ".".join(parts)
    if err.validator == "required":
        return ".".join(parts + [err.message.split("'")[1]])
    return ".".join(parts) or "<top level>"


def check_config(config: dict, schema_path: str | Path, source: str = "config") -> None:
    """Raise :class:`ConfigError` with a one-line message naming the first bad key and the fix."""
    import jsonschema
    import yaml

    schema = yaml.safe_load(Path(schema_path).read_text())
    validator = jsonschema.Draft7Validator(schema)
    errors = sorted(validator.iter_errors(config), key=lambda e: (len(list(e.absolute_path)), str(e.path)))
    if errors:
        err = errors[0]
        key = _key_path(err)
        if err.validator == "additionalProperties":
            raise ConfigError(f"{source}: unknown key '{key}'; remove it or fix its spelling (see config/README.md)")
        msg = err.message.splitlines()[0]
        raise ConfigError(f"{source}: key '{key}': {msg}; fix it (see config/README.md)")
    check_semantics(config, source)


def check_semantics(config: dict, source: str = "config") -> None:
    """Checks a schema cannot express: combinations of keys that make a scene impossible,
    and the refiner's own key-by-key validation."""
    if "refiner" in config:
        from ..refiner.config import resolve_config

        try:
            resolve_config({k: v for k, v in config["refiner"].items() if k != "resources"})
        except (KeyError, ValueError) as exc:
            msg = exc.args[0] if exc.args else str(exc)
            raise ConfigError(f"{source}: refiner: {msg}; fix it (see config/README.md)") from None
    a, s = config.get("assets", {}), config.get("scenes", {})
    if a.get("source") == "folder" and not a.get("dir"):
        raise ConfigError(f"{source}: key 'assets.dir' must name a folder of .glb files when assets.source is 'folder'")
    if a.get("source") == "folder" and a.get("dir") and not Path(a["dir"]).is_dir():
        raise ConfigError(f"{source}: key 'assets.dir': folder {a['dir']} not found; point it at a folder of .glb files")
    if s:
        if s["targets_per_trajectory"] > s["lightings_per_scene"] - 1:
            raise ConfigError(
                f"{source}: key 'scenes.targets_per_trajectory'={s['targets_per_trajectory']} needs "
                f"lightings_per_scene >= {s['targets_per_trajectory'] + 1}; lower it or add lightings")
        for key in ("asset_scale_range", "primitive_size_range_m", "light_strength_range"):
            lo, hi = s[key]
            if lo > hi:
                raise ConfigError(f"{source}: key 'scenes.{key}'=[{lo}, {hi}] is not an increasing range; swap the ends")
        # Can the objects fit on the layout disc at all? Compare the expected footprint area
        # (asset footprints are about half their normalised size; primitives' half-diagonal)
        # with the disc: above 0.9 of it, rejection sampling cannot succeed.
        size = a.get("curation", {}).get("target_size_m", 0.8)
        r_asset = 0.5 * size * sum(s["asset_scale_range"]) / 2 + s["clearance_m"]
        r_prim = sum(s["primitive_size_range_m"]) / 2 * math.sqrt(2) / 2 + s["clearance_m"]
        need = s["objects_per_scene"] * r_asset**2 + s["primitives_per_scene"] * r_prim**2
        if need > 0.9 * s["layout_radius_m"] ** 2:
            raise ConfigError(
                f"{source}: key 'scenes.layout_radius_m'={s['layout_radius_m']} cannot hold "
                f"{s['objects_per_scene']} assets + {s['primitives_per_scene']} primitives; raise it to at least "
                f"{math.sqrt(need / 0.9):.2f} or place fewer objects")
        for d, what in ((s.get("hdri_dir"), "HDR environment maps"), (s.get("ground_textures_dir"), "texture sets")):
            if d and not Path(d).is_dir():
                raise ConfigError(f"{source}: folder {d} not found; point it at a folder of {what} or set it to null")
