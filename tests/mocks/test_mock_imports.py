"""Import direction: the simulated devices (mocks/) reach the protocols only through their wire
formats (hil.protocols.codecs and the pure link-budget arithmetic), never an adapter or a transport
module, so a simulated device cannot lean on the code it is meant to test."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

MOCKS = Path(__file__).resolve().parents[2] / "mocks"
#: ``hil mock serve``'s command line (scene loading, the bench's SimulatedScene, the CLI parser)
COMMAND_LINE = {"serve.py"}
ALLOWED = ("hil.errors", "hil.lti", "hil.mocks", "hil.protocols.codecs", "hil.protocols.link_budget")


def _hil_imports(path: Path) -> list[tuple[int, str]]:
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            mod = node.module if node.module != "hil.protocols" else names[1]
            out.append((node.lineno, mod))
        elif isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
    return [(n, m) for n, m in out if m == "hil" or m.startswith("hil.")]


@pytest.mark.parametrize("path", sorted(p for p in MOCKS.glob("*.py") if p.name not in COMMAND_LINE),
                         ids=lambda p: p.name)
def test_mocks_import_only_errors_and_codecs(path: Path) -> None:
    bad = [f"{path.name}:{n}: {m}" for n, m in _hil_imports(path)
           if not any(m == a or m.startswith(a + ".") for a in ALLOWED)]
    assert not bad, bad


def test_the_check_sees_a_forbidden_import(tmp_path: Path) -> None:
    probe = tmp_path / "probe.py"
    probe.write_text("from hil.protocols import can_odrive\nfrom hil.protocols.codecs import odrive\n"
                     "def f():\n    from hil.protocols.serial_bota import FrameParser\n", encoding="utf-8")
    found = [m for _, m in _hil_imports(probe)]
    assert found == ["hil.protocols.can_odrive", "hil.protocols.codecs", "hil.protocols.serial_bota"]
