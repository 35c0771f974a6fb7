"""Start-up of the ``hil`` command (issue 15): the lazily built parser parses as the full one, and
``hil stability --model NAME`` imports none of the modules other commands need.

No wall-clock assertion (benchmarks/bench_speed.py times it): what is asserted is which modules a
process imports and that the parser :func:`hil.cli.main.main` builds for one command is the full parser's
subparser for that command, option for option and help text for help text.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

import pytest

from hil.cli.main import build_parser


def _subparsers(p: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


FULL = build_parser()
COMMANDS = list(_subparsers(FULL))


def _options(p: argparse.ArgumentParser) -> list[tuple]:
    return [(tuple(a.option_strings), a.dest, a.nargs, a.default, a.help, a.required, a.metavar,
             tuple(a.choices) if a.choices is not None and not isinstance(a.choices, dict) else a.choices is None)
            for a in p._actions]


@pytest.mark.parametrize("cmd", COMMANDS)
def test_the_parser_of_one_command_is_the_full_parsers(cmd: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("COLUMNS", "100")  # the same help layout for both
    lazy = build_parser(cmd)
    assert list(_subparsers(lazy)) == COMMANDS  # every command still listed (hil --help, "invalid choice")
    full_sub, lazy_sub = _subparsers(FULL)[cmd], _subparsers(lazy)[cmd]
    assert _options(lazy_sub) == _options(full_sub)
    assert lazy_sub.format_help() == full_sub.format_help()
    assert lazy.format_help() == FULL.format_help()
    if cmd == "mock":  # the nested subcommand too
        assert _subparsers(lazy_sub)["serve"].format_help() == _subparsers(full_sub)["serve"].format_help()


def test_the_other_commands_have_no_arguments_in_a_lazy_parser() -> None:
    """The point of build_parser(command): the commands that do not run get no options (and
    ``hil probe``'s module is not needed to build them)."""
    lazy = _subparsers(build_parser("stability"))
    assert len(_options(lazy["probe"])) == 0 < len(_options(_subparsers(FULL)["probe"]))
    assert len(_options(lazy["stability"])) > 5


def test_hil_stability_imports_no_scene_schema_probe_or_plotting() -> None:
    """``hil stability --model sdea`` in a fresh interpreter: the verdict is printed and none of
    the modules of other commands (scene schema / pydantic, probe, codecs, plotting, HDF5, emcee,
    scipy, yaml) was imported."""
    code = ("import sys, json, contextlib, io\n"
            "from hil.cli.main import main\n"
            "buf = io.StringIO()\n"
            "with contextlib.redirect_stdout(buf):\n"
            "    rc = main(['stability', '--model', 'sdea'])\n"
            "print(json.dumps({'rc': rc, 'out': buf.getvalue(), 'mods': sorted(sys.modules)}))\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    got = json.loads(r.stdout)
    assert got["rc"] == 0 and "verdict: stable" in got["out"]
    mods = set(got["mods"])
    assert "hil.stability.criteria" in mods  # the test sees the imports of the run
    for heavy in ("pydantic", "hil.schema", "hil.scene.spec", "hil.models.scene_params", "hil.bench.probe",
                  "hil.protocols.codecs.bota", "matplotlib", "h5py", "emcee", "scipy", "yaml",
                  "importlib.metadata"):  # entry points are read on a name that is not built in, or --help
        assert heavy not in mods, heavy
