"""Type checking is part of the test suite: mypy over the package ``hil``, configured by pyproject.toml.

The package is laid out by pyproject's ``package-dir`` (``hil.identify`` is the folder identify/,
``hil.protocols`` protocols/, ``hil.mocks`` mocks/); an editable install reaches them through an
import hook that mypy cannot follow. So the check builds the installed layout as a tree of symbolic
links (``.mypy_cache/hil-tree/hil/...``, kept between runs so mypy's cache stays valid), runs
``python -m mypy --config-file pyproject.toml -p hil`` in it and maps the paths in its messages back
to the repository's. ``python tests/test_types.py`` prints mypy's messages the same way.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tomllib
from collections import Counter
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: installed subpackage -> folder of the repository (pyproject.toml [tool.setuptools] package-dir)
PACKAGE_DIRS = {"hil": "hil", "hil.identify": "identify", "hil.protocols": "protocols", "hil.mocks": "mocks"}


def _package_dirs_from_pyproject() -> dict[str, str]:
    conf = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    return dict(conf["tool"]["setuptools"]["package-dir"])


def build_tree(root: Path = ROOT) -> Path:
    """The installed layout of ``hil`` as links under ``root/.mypy_cache/hil-tree``; returns the tree."""
    tree = root / ".mypy_cache" / "hil-tree"
    pkg = tree / "hil"
    pkg.mkdir(parents=True, exist_ok=True)
    want: dict[str, Path] = {p.name: p for p in (root / "hil").iterdir() if p.name != "__pycache__"}
    for sub, folder in PACKAGE_DIRS.items():
        if sub != "hil":
            want[sub.split(".", 1)[1]] = root / folder
    for link in pkg.iterdir():  # drop links to files that are gone (a module was moved or deleted)
        if link.name not in want or not link.is_symlink() or link.resolve() != want[link.name].resolve():
            link.unlink()
    for name, target in want.items():
        if not (pkg / name).is_symlink():
            (pkg / name).symlink_to(target, target_is_directory=target.is_dir())
    return tree


def _repo_path(tree_path: str) -> str:
    """``hil/identify/api.py`` (a path in the tree) -> ``identify/api.py`` (the repository's)."""
    for sub, folder in PACKAGE_DIRS.items():
        prefix = sub.replace(".", "/") + "/"
        if sub != "hil" and tree_path.startswith(prefix):
            return folder + "/" + tree_path[len(prefix):]
    return tree_path


def run_mypy(root: Path = ROOT) -> tuple[int, list[str]]:
    """mypy's exit status and its message lines (paths relative to the repository)."""
    tree = build_tree(root)
    env = {k: v for k, v in os.environ.items() if k not in ("MYPYPATH", "PYTHONPATH")}
    cp = subprocess.run([sys.executable, "-m", "mypy", "--config-file", str(root / "pyproject.toml"),
                         "--cache-dir", str(root / ".mypy_cache" / "cache"), "--no-color-output",
                         "--no-error-summary", "-p", "hil"],
                        cwd=tree, env=env, capture_output=True, text=True, timeout=900, check=False)
    lines = [ln for ln in (cp.stdout + cp.stderr).splitlines() if ln.strip()]
    return cp.returncode, [re.sub(r"^(\S+?\.py)(?=:)", lambda m: _repo_path(m.group(1)), ln) for ln in lines]


def error_counts(lines: list[str]) -> Counter[str]:
    """Errors per file (``note:`` lines are not errors)."""
    return Counter(m.group(1) for ln in lines if (m := re.match(r"^(\S+\.py):\d+: error:", ln)))


def test_package_dirs_match_pyproject() -> None:
    # the tree must lay out exactly what setuptools installs
    assert _package_dirs_from_pyproject() == PACKAGE_DIRS


def test_py_typed_is_installed() -> None:
    # PEP 561: each top-level folder carries py.typed and pyproject ships it as package data
    conf = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    data = conf["tool"]["setuptools"]["package-data"]
    for sub, folder in PACKAGE_DIRS.items():
        assert (ROOT / folder / "py.typed").is_file(), folder
        assert "py.typed" in data.get(sub, []), sub


def test_mypy_config_is_the_documented_one() -> None:
    conf = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    mypy = conf["tool"]["mypy"]
    assert mypy["python_version"] == "3.11"
    strict = [o for o in mypy["overrides"] if o.get("disallow_untyped_defs")]
    assert strict and {"hil.stability.*", "hil.protocols.*"} <= set(strict[0]["module"])
    assert any(dep.startswith("mypy") for dep in conf["project"]["optional-dependencies"]["test"])


def test_tree_maps_paths_back() -> None:
    assert _repo_path("hil/identify/api.py") == "identify/api.py"
    assert _repo_path("hil/mocks/physics.py") == "mocks/physics.py"
    assert _repo_path("hil/stability/exact.py") == "hil/stability/exact.py"
    tree = build_tree()
    assert (tree / "hil" / "protocols" / "base.py").resolve() == (ROOT / "protocols" / "base.py").resolve()
    assert (tree / "hil" / "cli" / "main.py").resolve() == (ROOT / "hil" / "cli" / "main.py").resolve()


@pytest.mark.slow  # mypy over ~90 modules: about a minute without its cache
def test_mypy_finds_no_errors() -> None:
    code, lines = run_mypy()
    counts = error_counts(lines)
    summary = ", ".join(f"{f}: {n}" for f, n in counts.most_common())
    assert code == 0 and not counts, (f"mypy: {sum(counts.values())} errors ({summary})\n"
                                      + "\n".join(lines[:60]))


if __name__ == "__main__":  # pragma: no cover
    status, out = run_mypy()
    print("\n".join(out))
    c = error_counts(out)
    print(f"{sum(c.values())} errors in {len(c)} files", file=sys.stderr)
    sys.exit(status)
