"""Code fingerprints for the workflow's rerun triggers.

The rules run their entry points as shell commands (``python scripts/X.py ...``), so Snakemake's own
``code`` trigger, which covers ``script:`` and ``run:`` directives only, does not see them: a job whose
script or library code changed would not rerun, and a working copy could keep products of old code
without any sign of it. Each rule therefore passes ``code=code_fingerprint(script)`` among its params
(``workflow/rules/common.smk: script_params``), and Snakemake's default ``params`` trigger reruns a job
when it changes ("Params have changed since last execution").

What a fingerprint covers, found by reading the code (nothing is imported or run):

* the script itself and the helpers of ``scripts/`` it imports (``_cli``);
* every ``lightcrafter`` module it imports, directly or through covered modules (a function-level
  import counts as well), with the ``__init__.py`` of each package on the way;
* every module of a package whose ``__init__.py`` resolves names on first use (PEP 562 ``__getattr__``,
  as ``lightcrafter.refiner``) when the package itself or a name from it is imported.

A file counts by its syntax tree without docstrings, so that editing a comment, a docstring or the layout
reruns nothing; a file that does not parse counts by its bytes.

Not followed: ``lightcrafter.codeversion`` itself (every entry point imports it through ``scripts/_cli.py`` to
know its own code version, lightcrafter.io.CODE_VERSION; an edit of how fingerprints are computed changes them
all anyway), ``lightcrafter.config`` (what it changes reaches jobs as config values, which the workflow
writes into the settings files the jobs read, so a changed value reruns them through those files) and
modules loaded by a name in a string (``lightcrafter.recon.BACKENDS``: ``scripts/reconstruct.py`` imports
both backends itself). Following the config package would tie every job to the code of every section it
validates, so that adding a key to Phi's settings would rerun the asset curation and, through its new
outputs, every render. Not covered: third-party packages (pinned in requirements.txt; conda envs have the
``software-env`` trigger), data files (the shipped estimator weights are an input of the rules that read
them) and files the code opens by a path from the config (rule inputs as well). To rerun on input files
and timestamps only, pass ``--rerun-triggers mtime input`` to Snakemake.
"""

from __future__ import annotations

import ast
import hashlib
import json
import os
import tempfile
from pathlib import Path

PACKAGE = "lightcrafter"
REPO = Path(__file__).resolve().parents[1]


def _module_name(path: Path, repo: Path) -> str:
    parts = list(path.relative_to(repo).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


NOT_FOLLOWED = (f"{PACKAGE}.config", f"{PACKAGE}.codeversion")


CACHE = Path(".snakemake") / "codeversion-cache.json"  # under the repository: what each file imports, its digest
_MEMO: dict[Path, dict] = {}  # repository -> {relative path: entry}, loaded from CACHE once per process
_DIRTY: set[Path] = set()


def _scan(path: Path, repo: Path, data: bytes) -> dict:
    """{"names": the dotted names the file imports, "lazy": whether it has a module ``__getattr__``, "digest":
    SHA-256 of its syntax tree without docstrings (of its bytes when it does not parse)}, for ``data``, the
    bytes of ``path``. For ``from a import b``: ``a`` and ``a.b`` (``b`` may be a submodule); relative imports
    are resolved against the file's package. One pass over the tree."""
    try:
        tree = ast.parse(data, filename=str(path))
    except (SyntaxError, ValueError):
        return {"names": [], "lazy": False, "digest": hashlib.sha256(data).hexdigest()}
    own = _module_name(path, repo).split(".") if path.is_relative_to(repo / PACKAGE) else []
    package = own if path.name == "__init__.py" else own[:-1]
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                if node.level > len(package):
                    continue
                base = ".".join(package[: len(package) - node.level + 1] + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            names.add(base)
            names.update(f"{base}.{alias.name}" for alias in node.names if alias.name != "*")
        elif isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]  # its docstring, if any, is left out of the digest (children are already queued)
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str):
                node.body = node.body[1:] or [ast.Pass()]
    lazy = any(isinstance(n, ast.FunctionDef) and n.name == "__getattr__" for n in tree.body)
    digest = hashlib.sha256(ast.dump(tree, include_attributes=False).encode()).hexdigest()
    return {"names": sorted(n for n in names if n), "lazy": lazy, "digest": digest}


def _memo(repo: Path) -> dict:
    if repo not in _MEMO:
        try:
            _MEMO[repo] = json.loads((repo / CACHE).read_text())
        except (OSError, ValueError):
            _MEMO[repo] = {}
    return _MEMO[repo]


def _scan_file(path: Path, repo: Path) -> dict:
    """:func:`_scan`, kept in CACHE under a hash of the file's bytes, so that a Snakemake process (one per
    cluster job) parses only the files that changed."""
    data = path.read_bytes()
    rel = path.relative_to(repo).as_posix() if path.is_relative_to(repo) else str(path)
    memo, key = _memo(repo), hashlib.sha256(data).hexdigest()
    entry = memo.get(rel)
    if entry is None or entry.get("bytes") != key:
        entry = memo[rel] = {"bytes": key, **_scan(path, repo, data)}
        _DIRTY.add(repo)
    return entry


def _save(repo: Path) -> None:
    """Writes CACHE (temporary name, then rename); a read-only checkout just keeps no cache."""
    if repo not in _DIRTY:
        return
    _DIRTY.discard(repo)
    try:
        (repo / CACHE).parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=repo / CACHE.parent, prefix=".codeversion-", suffix=".tmp")
        with os.fdopen(fd, "w") as f:
            json.dump(_MEMO[repo], f)
        os.replace(tmp, repo / CACHE)
    except OSError:
        pass


def _module_files(name: str, repo: Path) -> list[Path]:
    """Files that importing dotted ``name`` runs: each package's ``__init__.py`` and the module itself; for a
    name that is not a module (a function imported from its package) those of the package."""
    parts, files = name.split("."), []
    for i in range(1, len(parts) + 1):
        stem = repo.joinpath(*parts[:i])
        if (stem / "__init__.py").is_file():
            files.append(stem / "__init__.py")
        elif stem.with_suffix(".py").is_file():
            files.append(stem.with_suffix(".py"))
            break
        elif not stem.is_dir():  # a directory without __init__.py is a namespace package
            break
    return files


def covered_files(script: str | Path, repo: str | Path = REPO) -> list[Path]:
    """The files whose contents make up ``script``'s fingerprint (see the module docstring), sorted."""
    repo = Path(repo).resolve()
    script = Path(script).resolve()
    if not script.is_file():
        raise FileNotFoundError(f"{script}: no such script")
    files: set[Path] = {script}
    todo = [script]
    while todo:
        path = todo.pop()
        names = _scan_file(path, repo)["names"]
        new: list[Path] = []
        for name in names:
            top = name.split(".")[0]
            if any(name == n or name.startswith(n + ".") for n in NOT_FOLLOWED):
                continue
            if top == PACKAGE:
                mods = _module_files(name, repo)
                new += mods
                is_module = bool(mods) and _module_name(mods[-1], repo) == name
                package = name if is_module else name.rsplit(".", 1)[0]
                init = repo.joinpath(*package.split(".")) / "__init__.py"
                if init.is_file() and _scan_file(init, repo)["lazy"]:  # names resolved on first use: all of it
                    new += [f for f in init.parent.rglob("*.py") if "__pycache__" not in f.parts]
            elif "." not in name and path.parent == script.parent and (script.parent / f"{name}.py").is_file():
                new.append(script.parent / f"{name}.py")
        for f in new:
            if f not in files:
                files.add(f)
                if f.suffix == ".py":
                    todo.append(f)
    return sorted(files)


def code_fingerprint(script: str | Path, repo: str | Path = REPO) -> str:
    """16 hex digits of SHA-256 over the paths (relative to ``repo``) and contents (syntax trees without
    docstrings) of :func:`covered_files`; moving the checkout does not change it, editing code in any covered
    file does."""
    repo = Path(repo).resolve()
    h = hashlib.sha256()
    for f in covered_files(script, repo):
        rel = f.relative_to(repo).as_posix() if f.is_relative_to(repo) else f.name
        h.update(f"{rel}\0{_scan_file(f, repo)['digest']}\0".encode())
    _save(repo)
    return h.hexdigest()[:16]
