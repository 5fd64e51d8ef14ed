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

# `make test` runs the suite on two pytest-xdist workers (-n 2 --no-loadscope-reorder, scheduler below).
# Each test module is one work unit, so its module-scoped fixtures (a SLURM cluster, a rendered scene, a
# paper dry run) are built once per run; the modules that use the session fixture e2e_run (the tiny
# end-to-end run, the longest fixture) form one unit, so that run happens once. The two longest units go
# first, one per worker; the rest are handed out in collection order as workers free up.
E2E_MODULES = ("test_pipeline_e2e", "test_kill_resume", "test_config", "test_refiner_paper_preset", "test_relight")
FIRST_UNITS = ("e2e", "test_slurm")


def work_unit(nodeid: str) -> str:
    """The xdist work unit of a test: its module's name, or "e2e" for the modules in E2E_MODULES."""
    module = Path(nodeid.split("::", 1)[0]).stem
    return "e2e" if module in E2E_MODULES else module


def pytest_collection_modifyitems(config, items):
    for item in items:
        if "e2e_run" in getattr(item, "fixturenames", ()) and work_unit(item.nodeid) != "e2e":
            raise pytest.UsageError(f"{item.nodeid} uses e2e_run: add its module to E2E_MODULES in tests/conftest.py "
                                    "so that the end-to-end run happens once per test run")
    rank = {u: i for i, u in enumerate(FIRST_UNITS)}
    items.sort(key=lambda it: rank.get(work_unit(it.nodeid), len(rank)))  # stable: collection order otherwise


@pytest.hookimpl(optionalhook=True)  # a pytest-xdist hook: unknown (and unused) without it
def pytest_xdist_make_scheduler(config, log):
    from xdist.scheduler import LoadScopeScheduling

    class ModuleUnits(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return work_unit(nodeid)

    return ModuleUnits(config, log)


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
