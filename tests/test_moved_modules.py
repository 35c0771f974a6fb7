"""Old import paths of the modules that moved when hil/ was split into subpackages (issue 13):
``hil.MOVED_MODULES`` aliases give the same module object (so a monkeypatch reaches the code) with a
DeprecationWarning; a package that took an old module's name gives that module's names."""

from __future__ import annotations

import importlib
import subprocess
import sys
import warnings

import pytest

import hil


def test_every_alias_names_an_existing_module() -> None:
    for old, new in hil.MOVED_MODULES.items():
        assert importlib.util.find_spec(new) is not None, (old, new)
        assert old not in {m for m in hil.MOVED_INTO_PACKAGE}
    for pkg, mod in hil.MOVED_INTO_PACKAGE.items():
        assert importlib.import_module(pkg).__path__, pkg  # a package now
        assert importlib.util.find_spec(mod) is not None


@pytest.mark.parametrize("old", sorted(hil.MOVED_MODULES))
def test_old_path_is_the_same_module_with_a_warning(old: str) -> None:
    # a fresh interpreter: the alias must work as the first import of the old name, and warn
    code = (f"import warnings, importlib\nwarnings.simplefilter('error', DeprecationWarning)\n"
            f"new = importlib.import_module({hil.MOVED_MODULES[old]!r})\n"
            f"try:\n    importlib.import_module({old!r})\nexcept DeprecationWarning as w:\n    print('WARN', w)\n"
            f"warnings.simplefilter('ignore', DeprecationWarning)\n"
            f"old = importlib.import_module({old!r})\n"
            f"assert old is new, (old, new)\nassert old.__spec__.name == {hil.MOVED_MODULES[old]!r}, old.__spec__\n"
            f"print('SAME')\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert f"WARN {old} moved to {hil.MOVED_MODULES[old]}" in out.stdout and "SAME" in out.stdout


def test_a_monkeypatch_on_the_old_path_reaches_the_code(monkeypatch: pytest.MonkeyPatch) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        old = importlib.import_module("hil.certify_stages")
    import hil.certify.stages as new

    monkeypatch.setattr(old, "_probe_attribute", 42, raising=False)
    assert new._probe_attribute == 42  # type: ignore[attr-defined]


def test_package_facade_gives_the_old_names_and_refuses_others() -> None:
    from hil.scene.spec import load_scene

    with pytest.warns(DeprecationWarning, match=r"hil\.scene\.load_scene moved to hil\.scene\.spec\.load_scene"):
        from hil.scene import load_scene as old_load
    assert old_load is load_scene
    with pytest.raises(AttributeError, match="no attribute 'no_such_name'"):
        hil.scene.no_such_name  # type: ignore[attr-defined]  # noqa: B018
    with pytest.raises(ImportError):
        from hil.bench import no_such_name  # type: ignore[attr-defined]  # noqa: F401


def _is_module(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except ModuleNotFoundError:
        return False


def test_the_suite_itself_uses_the_new_paths() -> None:
    """Code, tests and benchmarks import the moved modules by their new paths (an old path works for
    outside code, but it would hide a dependency from tests/test_import_rules.py)."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    old_names = set(hil.MOVED_MODULES)
    old_facade = {f"{pkg}.{n}" for pkg in hil.MOVED_INTO_PACKAGE for n in dir(importlib.import_module(
        hil.MOVED_INTO_PACKAGE[pkg])) if not n.startswith("__")}
    bad = []
    for folder in ("hil", "identify", "protocols", "mocks", "tests", "benchmarks"):
        for p in sorted((root / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"), str(p))):
                mods: list[str] = []
                if isinstance(node, ast.Import):
                    mods = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                    mods = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
                for m in mods:
                    if m in old_names or (m in old_facade and p.name != "test_moved_modules.py"
                                          and importlib.util.find_spec(m.rpartition(".")[0]) is not None
                                          and not _is_module(m)):
                        bad.append(f"{p.relative_to(root)}:{node.lineno}: {m}")
    assert not bad, "old import paths (use hil.MOVED_MODULES' new ones): " + ", ".join(bad)
