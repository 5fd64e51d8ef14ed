"""Shared entry-point helpers: import the library from the repo, one-line errors, exit codes."""

from __future__ import annotations

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))


def run(main, name: str | None = None, errors: tuple = ()) -> None:
    """Run ``main()`` and exit with its return value (None = 0). Known input errors (DataError, which includes
    the refiner's CheckpointError, ConfigError, FileNotFoundError, NoGPUError and ``errors``) become one line on
    stderr, ``<name>: <message>`` (``error: <message>`` without a name), and exit code 1: the one error path of
    every entry point. Imports here count in every script's code fingerprint (lightcrafter.codeversion).
    Calls :func:`set_code_version` first."""
    from lightcrafter.errors import ConfigError, DataError, NoGPUError

    set_code_version()

    try:
        rc = main()
    except (DataError, ConfigError, FileNotFoundError, NoGPUError, *errors) as exc:
        print(f"{name or 'error'}: {exc}", file=sys.stderr)
        sys.exit(1)
    sys.exit(int(rc or 0))


def set_code_version(script: Path | None = None) -> None:
    """The running script's code fingerprint (lightcrafter.codeversion) becomes the library's code version
    (lightcrafter.io.CODE_VERSION): what this process resumes or reuses (frame folders, fits, checkpoints) must
    have been made by the same code, and the clips it writes name that code in their content id. ``script``: another
    entry point's file instead, for a product that process will resume."""
    from lightcrafter import io
    from lightcrafter.codeversion import code_fingerprint

    script = Path(script or sys.argv[0])
    if script.suffix == ".py" and script.is_file():
        io.CODE_VERSION = code_fingerprint(script.resolve())


def json_arg(text: str | None, default=None):
    """A JSON command-line value: literal JSON, or ``@path`` of a JSON file (what the workflow passes:
    settings and plans travel in files it writes, never on the command line). One-line error if bad."""
    import json

    from lightcrafter.errors import DataError

    if text is None:
        return default
    try:
        if text.startswith("@"):
            return json.loads(Path(text[1:]).read_text())
        return json.loads(text)
    except FileNotFoundError:
        raise DataError(f"{text[1:]}: settings file not found; rerun the workflow, which writes it") from None
    except json.JSONDecodeError as exc:
        where = text[1:] if text.startswith("@") else "a command-line JSON value"
        raise DataError(f"{where}: not valid JSON ({exc.msg} at line {exc.lineno}); fix it") from None
