import sys
from pathlib import Path

import pytest

# bpy and mitsuba each bundle an Embree library with the same soname; whichever loads first is
# shared by both. bpy needs the newer one (its import fails with "undefined symbol
# rtcGetSceneTraversable" after mitsuba), while mitsuba works with bpy's. Test modules import
# mitsuba at collection, so load bpy first. The pipeline itself never mixes them in one process.
try:
    import bpy  # noqa: F401
except ImportError:  # pragma: no cover - bpy is a pinned requirement
    pass

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))


@pytest.fixture(scope="session")
def repo() -> Path:
    return REPO


@pytest.fixture(scope="session")
def default_config(repo):
    """The effective laptop config (config/config.yaml over the models' defaults), as the rules get it."""
    from lightcrafter.config import raw_config, validate

    return validate(raw_config())


@pytest.fixture(scope="session")
def paper_config(repo):
    """The effective paper config (validated; its site folders are not checked on disk)."""
    from lightcrafter.config import raw_config, validate

    return validate(raw_config([repo / "config" / "paper.yaml"]))


@pytest.fixture(scope="session")
def paper_site(tmp_path_factory):
    """A stand-in site for config/paper.yaml (tests/paper_site.py): {name: path}, 'site' the site file that
    extends config/paper.yaml with the folders' paths only."""
    from paper_site import make_site

    return make_site(tmp_path_factory.mktemp("paper-site"))


@pytest.fixture(scope="session")
def e2e_run(tmp_path_factory):
    """One uninterrupted run of the whole default target on the tiny config (config/ci.yaml), shared by the
    end-to-end, kill/resume and SLURM tests. Returns the working directory."""
    import subprocess

    from workflow_util import venv_env

    wd = tmp_path_factory.mktemp("e2e")
    cmd = [sys.executable, "-m", "snakemake", "--cores", "2", "-d", str(wd), "--configfile",
           str(REPO / "config" / "ci.yaml")]
    res = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=3600, env=venv_env())
    assert res.returncode == 0, res.stderr[-5000:]
    return wd
