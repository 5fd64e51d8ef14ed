"""Code fingerprints (lightcrafter.codeversion): a job reruns when its script or the library code it imports
changes, and only then."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from lightcrafter.codeversion import code_fingerprint, covered_files
from workflow_util import REPO, venv_env

TREE = {
    "scripts/_cli.py": "from lightcrafter.io import DataError\n",
    "scripts/job.py": "import _cli\nfrom lightcrafter import io\n\ndef main():\n"
                      "    from lightcrafter.recon.align import align\n    return align\n",
    "scripts/lazy_job.py": "from lightcrafter.refiner import train\n",
    "scripts/package_job.py": "from lightcrafter import refiner\n",
    "scripts/config_job.py": "from lightcrafter.config import validate\n",
    "lightcrafter/io.py": "class DataError(ValueError):\n    pass\n",
    "lightcrafter/recon/__init__.py": "",
    "lightcrafter/recon/align.py": "from ..io import DataError\nfrom .cameras import pose\n\ndef align():\n    pass\n",
    "lightcrafter/recon/cameras.py": "def pose():\n    pass\n",
    "lightcrafter/recon/weights/net.pt": "weights v1",
    "lightcrafter/recon/weights/net.json": "{}",
    "lightcrafter/refiner/__init__.py": "import importlib\n_WHERE = {'train': 'training'}\n\n"
                                        "def __getattr__(name):\n"
                                        "    return getattr(importlib.import_module('.' + _WHERE[name], __name__), name)\n",
    "lightcrafter/refiner/training.py": "def train():\n    pass\n",
    "lightcrafter/refiner/model.py": "class Refiner:\n    pass\n",
    "lightcrafter/config/__init__.py": "from ..recon import align\n\ndef validate():\n    pass\n",
}


@pytest.fixture
def tree(tmp_path) -> Path:
    root = tmp_path / "repo"
    for rel, text in TREE.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    return root


def _edit(path: Path) -> None:
    """A change of code (a new statement at the end)."""
    path.write_text(path.read_text() + "\nEDITED = 1\n")


def _edit_text(path: Path) -> None:
    """A change of comments and of the module's docstring only."""
    text = path.read_text()
    text = '"""Edited. ' + text[3:] if text.startswith('"""') else '"""A new docstring."""\n' + text
    path.write_text("# a comment\n" + text + "\n# edited\n")


def test_a_script_covers_what_it_imports_through_every_kind_of_import(tree):
    names = {f.relative_to(tree).as_posix() for f in covered_files(tree / "scripts/job.py", tree)}
    assert names == {"scripts/job.py", "scripts/_cli.py", "lightcrafter/io.py", "lightcrafter/recon/__init__.py",
                     "lightcrafter/recon/align.py", "lightcrafter/recon/cameras.py"}


@pytest.mark.parametrize("rel", ["scripts/job.py", "scripts/_cli.py", "lightcrafter/io.py",
                                 "lightcrafter/recon/cameras.py"])
def test_editing_a_covered_file_changes_the_fingerprint(tree, rel):
    before = code_fingerprint(tree / "scripts/job.py", tree)
    _edit(tree / rel)
    assert code_fingerprint(tree / "scripts/job.py", tree) != before


@pytest.mark.parametrize("rel", ["lightcrafter/refiner/model.py", "lightcrafter/config/__init__.py",
                                 "scripts/lazy_job.py", "lightcrafter/recon/weights/net.pt"])
def test_editing_code_the_script_does_not_import_keeps_the_fingerprint(tree, rel):
    before = code_fingerprint(tree / "scripts/job.py", tree)
    _edit(tree / rel)
    assert code_fingerprint(tree / "scripts/job.py", tree) == before


@pytest.mark.parametrize("rel", ["scripts/job.py", "lightcrafter/io.py", "lightcrafter/recon/cameras.py"])
def test_editing_only_comments_and_docstrings_keeps_the_fingerprint(tree, rel):
    before = code_fingerprint(tree / "scripts/job.py", tree)
    _edit_text(tree / rel)
    assert code_fingerprint(tree / "scripts/job.py", tree) == before


def test_a_file_that_does_not_parse_counts_by_its_bytes(tree):
    (tree / "lightcrafter/recon/cameras.py").write_text("def pose(:\n")
    before = code_fingerprint(tree / "scripts/job.py", tree)
    _edit_text(tree / "lightcrafter/recon/cameras.py")
    assert code_fingerprint(tree / "scripts/job.py", tree) != before


@pytest.mark.parametrize("script", ["lazy_job.py", "package_job.py"])
def test_a_package_that_loads_names_on_first_use_is_covered_whole(tree, script):
    before = code_fingerprint(tree / "scripts" / script, tree)
    _edit(tree / "lightcrafter/refiner/training.py")
    assert code_fingerprint(tree / "scripts" / script, tree) != before


def test_the_config_package_is_not_followed(tree):
    """Its effects reach jobs as config values (settings files), so a job importing it does not depend on
    every module it validates."""
    names = {f.relative_to(tree).as_posix() for f in covered_files(tree / "scripts/config_job.py", tree)}
    assert names == {"scripts/config_job.py"}


def test_moving_the_checkout_keeps_the_fingerprint(tree, tmp_path):
    moved = tmp_path / "elsewhere" / "repo"
    shutil.copytree(tree, moved)
    assert code_fingerprint(moved / "scripts/job.py", moved) == code_fingerprint(tree / "scripts/job.py", tree)


def test_a_missing_script_is_named(tree):
    with pytest.raises(FileNotFoundError, match="nothing.py"):
        covered_files(tree / "scripts/nothing.py", tree)


def test_the_repository_scripts_cover_their_own_stages_only():
    def covered(script):
        return {f.relative_to(REPO).as_posix() for f in covered_files(REPO / "scripts" / script, REPO)}

    render, recon, train = covered("render_gt.py"), covered("reconstruct.py"), covered("train_refiner.py")
    assert "lightcrafter/blender/render.py" in render and not any(f.startswith("lightcrafter/refiner/") for f in render)
    assert {"lightcrafter/recon/default.py", "lightcrafter/recon/estimator.py"} <= recon
    assert not any(f.startswith(("lightcrafter/refiner/", "lightcrafter/blender/")) for f in recon)
    assert "lightcrafter/refiner/training.py" in train and not any(f.startswith("lightcrafter/blender/") for f in train)
    for script in ("refine_clip.py", "longform.py"):  # they write a side-by-side video, not a report
        assert not any(f.startswith("lightcrafter/report/") for f in covered(script)), script
    assert covered("generate_assets.py") == {"scripts/generate_assets.py", "scripts/_cli.py", "lightcrafter/errors.py",
                                             "lightcrafter/assets.py", "lightcrafter/io.py"}
    for script in ("curate_assets.py", "sample_scene.py"):
        assert not any(f.startswith(("lightcrafter/recon/", "lightcrafter/refiner/", "lightcrafter/proxy/"))
                       or f == "lightcrafter/devices.py" for f in covered(script)), script


def test_every_rule_that_runs_a_script_passes_its_code_fingerprint():
    """Rules take `script` and `code` together from script_params; a rule with only a script path would not
    rerun when its code changes."""
    for smk in sorted((REPO / "workflow" / "rules").glob("*.smk")):
        text = smk.read_text()
        assert "script=script_path(" not in text, f"{smk.name}: use **script_params(NAME) in params"
        assert text.count("{params.script}") <= text.count("**script_params("), smk.name


# ----------------------------------------------------------------------------- in the workflow
def _snakemake(code: Path, wd: Path, *args: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "snakemake", "--cores", "2", "-d", str(wd), *args,
           "--configfile", str(code / "config" / "ci.yaml")]
    return subprocess.run(cmd, cwd=code, capture_output=True, text=True, timeout=600, env=venv_env())


@pytest.mark.slow
def test_editing_library_code_reruns_the_jobs_that_import_it_and_no_others(tmp_path):
    """A copy of the repository runs the asset and scene-spec jobs of the tiny config; after an edit of the
    asset code the dry run reruns the asset jobs (their params changed: the code fingerprint) and what reads
    their outputs; after an edit of the refiner, the config package, the renderer (not run here) or only
    the comments of the asset code nothing is to be done."""
    files = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True, check=True).stdout
    code = tmp_path / "code"
    for rel in filter(None, files.decode().split("\0")):
        if (REPO / rel).is_file():
            (code / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / rel, code / rel)
    wd, target = tmp_path / "wd", "results/scenes/s0000/scene.json"
    res = _snakemake(code, wd, target)
    assert res.returncode == 0, res.stderr[-3000:]

    _edit_text(code / "lightcrafter" / "assets.py")
    for rel in ("lightcrafter/refiner/model.py", "lightcrafter/config/models.py", "lightcrafter/blender/render.py"):
        _edit(code / rel)
    dry = _snakemake(code, wd, target, "-n")
    assert dry.returncode == 0 and "Nothing to be done" in dry.stdout, dry.stdout[-2000:]

    _edit(code / "lightcrafter" / "assets.py")
    dry = _snakemake(code, wd, target, "-n")
    assert dry.returncode == 0, dry.stderr[-2000:]
    assert "Params have changed since last execution" in dry.stdout, dry.stdout[-3000:]
    for rule in ("generate_assets", "curate_assets", "sample_scene"):
        assert f"rule {rule}:" in dry.stdout, (rule, dry.stdout[-3000:])


def test_the_cache_of_parsed_files_follows_their_bytes(tree):
    """Each Snakemake process (one per cluster job) reads the parsed files from .snakemake/codeversion-cache.json;
    an edit is seen through it, whatever the file's timestamp."""
    import os

    from lightcrafter import codeversion

    first = code_fingerprint(tree / "scripts/job.py", tree)
    assert (tree / codeversion.CACHE).is_file()
    codeversion._MEMO.clear()  # as a new process
    assert code_fingerprint(tree / "scripts/job.py", tree) == first
    cameras = tree / "lightcrafter/recon/cameras.py"
    stat = cameras.stat()
    cameras.write_text(cameras.read_text().replace("pass", "return 1"))
    os.utime(cameras, ns=(stat.st_atime_ns, stat.st_mtime_ns))  # same timestamp
    codeversion._MEMO.clear()
    assert code_fingerprint(tree / "scripts/job.py", tree) != first
