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


# ----------------------------------------------------------------------------- work units for pytest-xdist
# `make test` runs the tests on 2 workers (-n 2 --dist loadscope --no-loadscope-reorder), with the scheduler
# below: the tests of a module form one unit (a module-scoped fixture such as the SLURM cluster or the paper
# dry run is built once), and the tests that use the tiny end-to-end run (e2e_run, about 12 minutes on 2
# cores) form one unit across modules, so that only one worker builds it; that unit goes first, as the
# longest chain. Without xdist (`pytest`, `-p no:xdist`) the tests run in one process in the same order.
# (xdist's own loadgroup does not group under pytest 9: it renames test ids through an attribute pytest 9
# no longer reads.)
E2E_FIXTURE = "e2e_run"


def requesting_tests(fixture: str, test_dir: Path = Path(__file__).parent, prefix: str = "tests") -> set[str]:
    """Node ids (``prefix/file::[Class::]test``, without parameters) of the tests in ``test_dir`` that request
    ``fixture`` -- as an argument, through ``pytest.mark.usefixtures`` (on the test, its class or the
    module's ``pytestmark``), or through fixtures of the same file or conftest.py that do -- read from the
    source, since the xdist controller collects nothing. tests/test_suite_units.py checks it against what
    pytest collects."""
    import ast

    files = sorted(test_dir.glob("test_*.py"))
    trees = {f: ast.parse(f.read_text()) for f in files + [test_dir / "conftest.py"]}

    def requested(node) -> set[str]:
        names = {a.arg for a in node.args.args + node.args.kwonlyargs} if hasattr(node, "args") else set()
        for dec in getattr(node, "decorator_list", []):
            names |= usefixtures(dec)
        return names

    def usefixtures(expr) -> set[str]:
        out = set()
        for call in ast.walk(expr):
            if isinstance(call, ast.Call) and getattr(call.func, "attr", "") == "usefixtures":
                out |= {a.value for a in call.args if isinstance(a, ast.Constant) and isinstance(a.value, str)}
        return out

    def fixtures(tree) -> dict[str, set[str]]:
        return {fn.name: requested(fn) for fn in ast.walk(tree)
                if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)) and not fn.name.startswith("test_")}

    shared = fixtures(trees[test_dir / "conftest.py"])
    out = set()
    for f in files:
        tree = trees[f]
        local = {**shared, **fixtures(tree)}
        module_marks = set().union(*(usefixtures(n.value) for n in tree.body if isinstance(n, ast.Assign)
                                     and any(getattr(t, "id", "") == "pytestmark" for t in n.targets)))

        def needs(name, seen=()) -> bool:
            return name == fixture or (name in local and name not in seen
                                       and any(needs(a, seen + (name,)) for a in local[name]))

        def visit(body, ids: str, inherited: set[str]):
            for node in body:
                if isinstance(node, ast.ClassDef) and node.name.startswith("Test"):
                    visit(node.body, f"{ids}::{node.name}", inherited | requested(node))
                elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.name.startswith("test_"):
                    if any(needs(a) for a in requested(node) | inherited):
                        out.add(f"{ids}::{node.name}")

        visit(tree.body, f"{prefix}/{f.name}", module_marks)
    return out


@pytest.hookimpl(optionalhook=True)  # a hook of pytest-xdist: pytest runs without it too
def pytest_xdist_make_scheduler(config, log):
    """Only for ``--dist loadscope`` (what `make test` uses); other modes keep xdist's own scheduler."""
    if config.getvalue("dist") != "loadscope":
        return None
    from xdist.scheduler import LoadScopeScheduling

    tests_dir = Path(__file__).parent
    e2e = requesting_tests(E2E_FIXTURE, tests_dir, tests_dir.relative_to(config.rootpath).as_posix())

    class WorkUnits(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return "e2e" if nodeid.split("[")[0] in e2e else nodeid.split("::")[0]

    return WorkUnits(config, log)


def _work_unit(item) -> str:
    return "e2e" if E2E_FIXTURE in item.fixturenames else item.module.__name__


def pytest_collection_modifyitems(config, items):
    """The end-to-end unit first, then the slow modules, then the rest in collection order (the order xdist
    sends units in when its reordering is off; without xdist, the order the tests run in)."""
    items.sort(key=lambda it: (_work_unit(it) != "e2e", getattr(it.module, "pytestmark", None) is None))
