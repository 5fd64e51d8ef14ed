"""Generated documentation of the configuration: ``config/README.md`` and the JSON schema
``workflow/schemas/config.schema.json``, both from the models of :mod:`.models` (the only place keys,
defaults and doc lines are written). ``python -m lightcrafter.config --write-docs`` rewrites them;
``--check-docs`` (and a test) fails when they are stale.
"""

from __future__ import annotations

import json
import typing
from pathlib import Path

from pydantic import BaseModel

from . import REPO, _model_in, raw_config, validate

README = REPO / "config" / "README.md"
SCHEMA = REPO / "workflow" / "schemas" / "config.schema.json"

INTRO = """\
# Configuration keys

*Generated from `lightcrafter/config/models.py` by `python -m lightcrafter.config --write-docs`; do not
edit by hand (a test fails when this file is stale).*

The typed models in `lightcrafter/config/models.py` are the only definition of every key, default,
allowed value and doc line; this page and the JSON schema `workflow/schemas/config.schema.json` are
generated from them. **The defaults are the paper's run.**

| file | what it is |
| --- | --- |
| `config/paper.yaml` | the paper's run: the defaults plus the paths a site provides (data folders, the CogVideoX-5B-I2V folder, the paper stack's commands); each paper number with its section: `docs/paper_numbers.md` |
| `config/config.yaml` | the laptop rehearsal (`make run`, no `--configfile`): sets the smaller sizes and the CPU code paths explicitly |
| `config/ci.yaml`, `config/study.yaml` | `extends: config.yaml`, then smaller (CI) or larger (the study) sizes |

A config file may name another with `extends:` (a path relative to its folder): that file is read
first and this one deep-merged over it (mappings key by key; lists are replaced). Several
`--configfile` files are merged in order, then Snakemake's `--config`. A file without `extends`
starts from the defaults, i.e. the paper's values.
`python -m lightcrafter.config [--configfile FILE ...]` prints the effective config as JSON: exactly
what the rules get. At start-up the workflow validates it (an unknown or misspelt key at any depth, a
wrong type or an out-of-range value is one line naming the key) and checks what the run needs on disk
(data folders, the refiner's model folder and its subfolders, the paper stack's command templates and
their placeholders), so a mistake fails in seconds, before any job starts.

Units are in the key names: `_m` metres, `_deg` degrees, `_rad` radians, `_s` seconds, `_mb`
megabytes, `_px` pixels; radiance is linear and relative. Columns: **default** is the paper's value
(what a config file that does not set the key gets); **laptop** is `config/config.yaml`'s effective
value where it differs (blank: the same).
"""

PLACEHOLDER_DOC = """\
The paper stack's command templates (`recon.paper_stack.commands.*`) are shell commands with
placeholders, replaced by shell-quoted values: {placeholders}. Each must name its input (MegaSAM and
DiffusionRenderer: `{{frames}}` or `{{frames_root}}`; DiffusionLight: `{{frame0}}` or `{{frame0_dir}}`) and
`{{out}}`; literal braces are written `{{{{` and `}}}}`. What each tool must leave under `{{out}}`:
`lightcrafter/recon/paper_stack/backend.py`.
"""


def _fmt(v) -> str:
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f"`{v}`"
    text = json.dumps(v, separators=(", ", ": "))
    return f"`{text}`" if len(text) <= 60 else f"`{text[:57]}...`"


def _allowed(annotation) -> str:
    args = [a for a in typing.get_args(annotation) if a is not type(None)]
    lits = [a for a in (annotation, *args) if typing.get_origin(a) is typing.Literal]
    if lits:
        return " (" + " \\| ".join(str(x) for x in typing.get_args(lits[0])) + ")"
    return ""


def _rows(model: type[BaseModel], paper: dict, laptop: dict, prefix: str = "") -> tuple[list[str], list]:
    rows, lists = [], []
    for name, f in model.model_fields.items():
        key = prefix + name
        sub = _model_in(f.annotation)
        pv, lv = paper.get(name), laptop.get(name)
        if sub is not None and isinstance(pv, dict):  # a section: its keys as rows
            r, l2 = _rows(sub, pv, lv if isinstance(lv, dict) else {}, key + ".")
            rows += r
            lists += l2
            continue
        if sub is not None:  # a list of entries: a table of the entry's keys below
            lists.append((key, sub))
        doc = (f.description or "").replace("|", "\\|") + _allowed(f.annotation)
        lap = "" if lv == pv else _fmt(lv)
        rows.append(f"| `{key}` | {_fmt(pv)} | {lap} | {doc} |")
    return rows, lists


def readme_text() -> str:
    from ..recon.paper_stack.backend import PLACEHOLDERS
    from .models import Config

    paper = Config.model_validate({"assets": {"source": "folder", "dir": "<site>"}}).model_dump(mode="json")
    paper["assets"]["dir"] = None
    laptop = validate(raw_config(), "config/config.yaml")
    out = [INTRO]
    for name, f in Config.model_fields.items():
        sub = _model_in(f.annotation)
        if sub is None:
            continue
        out.append(f"\n## `{name}`\n")
        if sub.__doc__ and not sub.__doc__.startswith(("A config section", "Usage docs")):
            out.append(" ".join(sub.__doc__.split()) + "\n")
        if name == "refiner":
            out.append("The section is `lightcrafter.refiner.config.RefinerSettings`: the model's defaults, then the "
                       "preset named by `preset` (`lightcrafter.refiner.config.PRESETS`), then the section's own keys. "
                       "The default column shows the `paper` preset, the laptop column the `tiny` preset with "
                       "`config/config.yaml`'s keys.\n")
        if name == "recon":
            out.append(PLACEHOLDER_DOC.format(placeholders=", ".join(f"`{{{p}}}`" for p in PLACEHOLDERS)))
        rows, lists = _rows(sub, paper[name], laptop[name], name + ".")
        out.append("| key | default (paper) | laptop | meaning |\n| --- | --- | --- | --- |")
        out += rows
        for key, item in lists:
            out.append(f"\nEach entry of `{key}`:\n")
            out.append("| key | default | meaning |\n| --- | --- | --- |")
            for n, f2 in item.model_fields.items():
                d = "required" if f2.is_required() else _fmt(f2.get_default(call_default_factory=True))
                doc = (f2.description or "").replace("|", "\\|") + _allowed(f2.annotation)
                out.append(f"| `{n}` | {d} | {doc} |")
    return "\n".join(out) + "\n"


def schema_text() -> str:
    from .models import Config

    schema = Config.model_json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["description"] = ("LightCrafter pipeline configuration, generated from lightcrafter/config/models.py "
                             "(python -m lightcrafter.config --write-docs); documented key by key in config/README.md")
    return json.dumps(schema, indent=1, sort_keys=True) + "\n"


def write_docs() -> list[Path]:
    SCHEMA.parent.mkdir(parents=True, exist_ok=True)
    README.write_text(readme_text())
    SCHEMA.write_text(schema_text())
    return [README, SCHEMA]


def stale_docs() -> list[Path]:
    """Generated files whose content differs from what the models give now."""
    want = {README: readme_text(), SCHEMA: schema_text()}
    return [p for p, text in want.items() if not p.is_file() or p.read_text() != text]
