"""One command-line parser family: only the package hil.cli builds argument parsers (docs/ARCHITECTURE.md,
"Exit codes and the one parser"). Each command's module there adds its options (``add_arguments``) to
the parser hil.cli.main gives it; modules elsewhere contribute options through a function
(``hil.bench.probe.add_arguments``) and run from the parsed namespace."""

from __future__ import annotations

import argparse
import ast
from pathlib import Path

from hil.bench.serve import MOCK_KINDS
from hil.cli.main import build_parser, main

ROOT = Path(__file__).resolve().parents[2]
#: modules outside hil/cli/ that still build a parser of their own: may only shrink (empty: keep it so)
KNOWN_OWN_PARSERS: set[str] = set()


def _builds_parser(path: Path) -> bool:
    """The file calls ``ArgumentParser(...)`` / ``OneLineArgumentParser(...)`` or subclasses one."""
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Call):
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""
            if name.endswith("ArgumentParser"):
                return True
        if isinstance(node, ast.ClassDef):
            for b in node.bases:
                name = b.attr if isinstance(b, ast.Attribute) else b.id if isinstance(b, ast.Name) else ""
                if name.endswith("ArgumentParser"):
                    return True
    return False


def _parser_modules() -> set[str]:
    return {str(p.relative_to(ROOT)) for folder in ("hil", "identify", "protocols", "mocks")
            for p in (ROOT / folder).rglob("*.py") if _builds_parser(p) and not p.is_relative_to(ROOT / "hil" / "cli")}


def test_the_scan_sees_a_parser(tmp_path: Path) -> None:
    p = tmp_path / "m.py"
    p.write_text("import argparse\nclass P(argparse.ArgumentParser):\n    pass\n", encoding="utf-8")
    q = tmp_path / "n.py"
    q.write_text("def f(add):\n    add('--x')\n", encoding="utf-8")
    assert _builds_parser(p) and not _builds_parser(q)
    assert _builds_parser(ROOT / "hil" / "cli" / "common.py") and _builds_parser(ROOT / "hil" / "cli" / "identify.py")


def test_only_the_cli_builds_parsers() -> None:
    extra = _parser_modules() - KNOWN_OWN_PARSERS
    assert not extra, f"build the options in hil.cli (an add_arguments function), not a parser: {sorted(extra)}"


def test_known_own_parsers_only_shrink() -> None:
    gone = KNOWN_OWN_PARSERS - _parser_modules()
    assert not gone, f"no parser of their own any more: remove from KNOWN_OWN_PARSERS: {sorted(gone)}"


def _subparser(parser: argparse.ArgumentParser, *names: str) -> argparse.ArgumentParser:
    for name in names:
        action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = action.choices[name]
    return parser


def test_mock_serve_device_help_names_every_kind() -> None:
    # the parser does not import hil.mocks (start-up time), so the kinds are written in the help text
    serve = _subparser(build_parser(), "mock", "serve")
    dev = next(a for a in serve._actions if "--device" in a.option_strings)
    listed = {k.strip() for k in dev.help.split(":", 1)[1].split(",")}
    assert listed == set(MOCK_KINDS)


def test_unknown_device_kind_is_one_line(capsys) -> None:
    assert main(["mock", "serve", "--device", "nope"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("hil mock serve: error: argument --device") and "odrive" in err[0]


def test_mock_needs_serve(capsys) -> None:
    assert main(["mock"]) == 2
    assert "serve" in capsys.readouterr().err
