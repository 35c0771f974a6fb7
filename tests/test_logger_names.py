"""One logger convention: a module that logs has ``logger = logging.getLogger(__name__)`` and nothing else.

So every record of the suite is named after its module (``hil.run.realtime``, ``hil.protocols.cia402``),
``hil --debug`` turns all of them on through the ``hil`` parent logger, and a reader finds the
logger under the same name in every file. Modules still on the older name ``log`` are listed in
:data:`KNOWN_OTHER_NAMES`; the list may only shrink (a listed module that follows the convention fails
the test, so whoever renames it removes its line).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("hil", "identify", "protocols", "mocks")

#: modules (paths) that still bind another logger name (none left: every module follows the convention)
KNOWN_OTHER_NAMES: set[str] = set()


def _get_logger_calls(path: Path) -> list[tuple[str | None, str | None, int]]:
    """(bound name or None, argument source, line) of every ``logging.getLogger(...)`` call in the file."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    bound: dict[int, str] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            bound[id(node.value)] = node.targets[0].id
    out = []
    for node in ast.walk(tree):
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "getLogger"
                and isinstance(node.func.value, ast.Name) and node.func.value.id == "logging"):
            arg = ast.unparse(node.args[0]) if node.args else None
            out.append((bound.get(id(node)), arg, node.lineno))
    return out


def _configures_another_logger(arg: str | None) -> bool:
    """The root logger (no argument) or a third-party library's logger named by a literal (e.g.
    ``'distributed.client'`` to quiet it): configured, never logged to, so not a module logger."""
    if arg is None:
        return True
    if not (arg[:1] in "'\"" and arg[-1:] == arg[:1]):
        return False
    return arg[1:-1].split(".")[0] not in {"hil", *FOLDERS}


def _offenders() -> dict[str, list[str]]:
    bad: dict[str, list[str]] = {}
    for folder in FOLDERS:
        for p in sorted((ROOT / folder).rglob("*.py")):
            rel = str(p.relative_to(ROOT))
            for name, arg, line in _get_logger_calls(p):
                if name is None and rel == "hil/cli/main.py" and arg == "'hil'":
                    continue  # hil --debug sets the level of the package's parent logger (not a module logger)
                if _configures_another_logger(arg):
                    continue
                if (name, arg) != ("logger", "__name__"):
                    bad.setdefault(rel, []).append(f"line {line}: {name} = logging.getLogger({arg})")
    return bad


def test_reader_sees_the_binding(tmp_path: Path) -> None:
    p = tmp_path / "m.py"
    p.write_text("import logging\nlog = logging.getLogger(__name__)\nlogger = logging.getLogger('x')\n"
                 "def f():\n    return logging.getLogger(__name__)\n", encoding="utf-8")
    assert _get_logger_calls(p) == [("log", "__name__", 2), ("logger", "'x'", 3), (None, "__name__", 5)]


def test_only_other_libraries_and_the_root_are_configured_by_name() -> None:
    assert _configures_another_logger(None) and _configures_another_logger("'distributed.client'")
    assert not _configures_another_logger("'hil.run'") and not _configures_another_logger("'identify'")
    assert not _configures_another_logger("__name__") and not _configures_another_logger("name")


def test_module_loggers_follow_the_convention() -> None:
    bad = _offenders()
    new = {k: v for k, v in bad.items() if k not in KNOWN_OTHER_NAMES}
    assert not new, f"use logger = logging.getLogger(__name__): {new}"


def test_known_other_names_only_shrink() -> None:
    fixed = sorted(KNOWN_OTHER_NAMES - set(_offenders()))
    assert not fixed, f"these follow the convention now: remove them from KNOWN_OTHER_NAMES: {fixed}"
