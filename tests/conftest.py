import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))


@pytest.fixture(scope="session")
def repo() -> Path:
    return REPO


@pytest.fixture(scope="session")
def default_config(repo):
    import yaml

    return yaml.safe_load((repo / "config" / "config.yaml").read_text())


@pytest.fixture(scope="session")
def paper_config(repo):
    import yaml

    return yaml.safe_load((repo / "config" / "paper.yaml").read_text())
