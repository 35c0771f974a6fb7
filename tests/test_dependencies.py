"""Every module the code imports is declared in pyproject.toml (base dependencies or an extra).

The imports are read from the source (the AST of every .py file, top-level and lazy imports
alike, so an import inside a function that no test reaches is still checked), not from what
happens to be installed: a package installed by hand cannot hide a missing declaration. Import
names are mapped to distributions with importlib.metadata, and with the explicit table below for
optional packages that may not be installed where the test runs.
"""

from __future__ import annotations

import ast
import functools
import importlib.metadata as md
import re
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE_DIRS = ("hil", "identify", "protocols", "mocks")  # the installed `hil` namespace
DEV_DIRS = ("tests", "benchmarks")  # run with the `test` extra installed

#: import name -> distribution, for names importlib.metadata cannot resolve (not installed here)
KNOWN: dict[str, str] = {
    "can": "python-can",
    "canopen": "canopen",
    "pymodbus": "pymodbus",
    "serial": "pyserial",
    "dynamixel_sdk": "dynamixel-sdk",
    "matplotlib": "matplotlib",
    "jinja2": "jinja2",
    "corner": "corner",
    "flint": "python-flint",
    "yaml": "pyyaml",
    "cryptography": "cryptography",
    "pytest": "pytest",
    "hypothesis": "hypothesis",
    "jsonschema": "jsonschema",
    "cantools": "cantools",
    "pydantic_core": "pydantic-core",
}

#: (file, import name) -> why it may use a distribution of the `test` extra
TEST_EXTRA_USERS: dict[tuple[str, str], str] = {
    ("hil/pytest_plugin.py", "pytest"): "the pytest11 entry point: only pytest itself loads this module",
}


def _norm(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _declared() -> dict[str, set[str]]:
    """Declared distribution (normalized) -> the groups declaring it ("base" or the extra's name)."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    own = _norm(project["name"])
    groups = {"base": project.get("dependencies", []), **project.get("optional-dependencies", {})}
    out: dict[str, set[str]] = {}
    for group, reqs in groups.items():
        for req in reqs:
            m = re.match(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*)", req)
            assert m, f"pyproject.toml: cannot read requirement {req!r}"
            if _norm(m.group(1)) != own:  # hil-certify[...] refers to other extras
                out.setdefault(_norm(m.group(1)), set()).add(group)
    return out


def _imports(path: Path) -> set[str]:
    """Top-level names of the absolute imports in one file (anywhere in it)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name.partition(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.partition(".")[0])
    return names


def _third_party(dirs: tuple[str, ...], local: set[str]) -> dict[str, list[str]]:
    """Import name -> files importing it, stdlib, the project's own `hil` and ``local`` dropped."""
    found: dict[str, list[str]] = {}
    for d in dirs:
        for path in sorted((ROOT / d).rglob("*.py")):
            if any(part.startswith(".") for part in path.relative_to(ROOT).parts):
                continue
            for name in _imports(path):
                if name in sys.stdlib_module_names or name in ("hil", "__future__") or name in local:
                    continue
                found.setdefault(name, []).append(str(path.relative_to(ROOT)))
    return found


@functools.cache
def _installed() -> dict[str, list[str]]:
    return md.packages_distributions()


def _distributions(name: str) -> list[str]:
    dists = _installed().get(name, [])
    return [_norm(d) for d in dists] or ([_norm(KNOWN[name])] if name in KNOWN else [])


def _undeclared(found: dict[str, list[str]], allowed_groups: set[str] | None) -> list[str]:
    declared = _declared()
    problems = []
    for name, files in sorted(found.items()):
        dists = _distributions(name)
        if not dists:
            problems.append(f"{name} (imported by {files[0]}): not installed and not in KNOWN; declare its "
                            "distribution in pyproject.toml and add it to KNOWN")
            continue
        groups = set().union(*(declared.get(d, set()) for d in dists))
        if allowed_groups is not None and not all((f, name) in TEST_EXTRA_USERS for f in files):
            groups &= allowed_groups
        if not groups:
            problems.append(f"{name} (distribution {', '.join(dists)}, imported by {', '.join(files[:3])}) "
                            "is not declared in pyproject.toml")
    return problems


def test_package_imports_only_declared_distributions():
    found = _third_party(PACKAGE_DIRS, local=set())
    assert "numpy" in found and "flint" in found  # the walk sees the code (a vacuous pass is a failure)
    groups = set().union(*_declared().values()) - {"test"}  # the `test` extra does not count for the package
    problems = _undeclared(found, allowed_groups=groups)
    assert not problems, "\n".join(problems)


def test_tests_and_benchmarks_import_only_declared_distributions():
    local = {p.stem for d in DEV_DIRS for p in (ROOT / d).rglob("*.py")}  # e.g. `from conftest import ...`
    problems = _undeclared(_third_party(DEV_DIRS, local), allowed_groups=None)
    assert not problems, "\n".join(problems)


def test_sympy_is_gone():
    """The exact conversions use python-flint; nothing imports sympy any more."""
    users = _third_party(PACKAGE_DIRS + DEV_DIRS, local=set()).get("sympy", [])
    assert not users, users


@pytest.mark.parametrize("snippet,expected", [
    ("import can.interfaces.virtual\n", {"can"}),
    ("def f():\n    from dynamixel_sdk import PortHandler\n", {"dynamixel_sdk"}),
    ("try:\n    import corner\nexcept ImportError:\n    corner = None\n", {"corner"}),
    ("from . import sibling\nfrom .x import y\n", set()),
])
def test_the_walk_sees_lazy_and_guarded_imports(tmp_path, snippet, expected):
    p = tmp_path / "m.py"
    p.write_text(snippet, encoding="utf-8")
    assert _imports(p) == expected


def test_an_undeclared_import_is_reported(tmp_path):
    assert _undeclared({"sympy": ["hil/x.py"]}, allowed_groups=None)
    assert _undeclared({"no_such_module_xyz": ["hil/x.py"]}, allowed_groups=None)
    assert not _undeclared({"serial": ["hil/x.py"]}, allowed_groups=None)


def _readme_commands() -> list[str]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text.split("## Two commands on a fresh machine", 1)[1].split("\n## ", 1)[0]
    return [b.strip() for b in re.findall(r"```bash\n(.*?)```", section, flags=re.S)]


def test_ci_runs_the_readme_test_command_in_a_fresh_venv_of_its_own():
    certify, tests = _readme_commands()[:2]
    prefix = 'python3 -m venv .venv && . .venv/bin/activate && '
    assert certify.startswith(prefix) and certify.endswith("hil certify")
    assert tests.startswith(prefix) and "pytest" in tests
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()
    venv = ci.index("rm -rf .ci-venv")
    activate = ci.index(". .ci-venv/bin/activate")
    assert venv < activate and any(line.strip() == "python3 -m venv .ci-venv" for line in ci[venv:activate])
    assert not any("system-site-packages" in line for line in ci)
    # after the activation, the README's command verbatim (its own venv prefix replaced by .ci-venv)
    assert tests[len(prefix):] in ci[activate:]
    assert ".ci-venv/" in (ROOT / ".gitignore").read_text(encoding="utf-8").splitlines()
