"""Shared entry-point helpers: import the library from the repo, one-line errors, exit codes."""

from __future__ import annotations

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))


def run(main) -> None:
    """Run ``main()``; known input errors become one line on stderr and exit code 1."""
    from lightcrafter.io import DataError
    from lightcrafter.scenes import ConfigError

    try:
        main()
    except (DataError, ConfigError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(1)
