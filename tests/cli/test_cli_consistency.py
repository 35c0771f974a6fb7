"""One command line (issue 28, item 8): ``hil --version``; every option of every command says what it
does; experiments are selected by name everywhere (``hil run``, ``hil plan``, the certification);
tables are not cut at 80 columns when stdout is a pipe; ``hil certify`` names the experiment running
and its ticks; the adequacy lines of ``hil identify`` state the threshold their verdict used."""

from __future__ import annotations

import argparse
import subprocess
import sys
from types import SimpleNamespace

import pytest

from hil import __version__
from hil.cli.common import PIPE_COLUMNS, UsageError, console
from hil.cli.main import build_parser, main
from hil.cli.run import select_experiments
from hil.scene.spec import load_scene


def test_version(capsys):
    try:
        code = main(["--version"])
    except SystemExit as e:
        code = e.code
    assert code == 0
    assert capsys.readouterr().out.strip() == f"hil-certify {__version__}"


def _undocumented(parser: argparse.ArgumentParser, prefix: list[str]) -> list[str]:
    out = []
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            for name, sp in a.choices.items():
                out += _undocumented(sp, [*prefix, name])
        elif a.help != argparse.SUPPRESS and not (a.help or "").strip() and a.dest != "rest":
            out.append(" ".join([*prefix, *(a.option_strings or [a.dest])]))
    return out


def test_every_option_of_every_command_has_help():
    assert _undocumented(build_parser(None), ["hil"]) == []


def test_every_option_of_hil_identify_has_help(monkeypatch):
    """``hil identify`` parses its own arguments: its parser is checked the same way."""
    import hil.cli.identify as ident

    captured = {}
    real = argparse.ArgumentParser.parse_args

    def grab(self, *a, **k):
        captured["p"] = self
        raise SystemExit(0)

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", grab)
    with pytest.raises(SystemExit):
        ident.main(["x.h5"])
    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", real)
    assert _undocumented(captured["p"], ["hil", "identify"]) == []


def test_experiments_are_selected_by_name():
    sc = load_scene("sdea_bench")
    names = [e["name"] for e in sc.experiment_configs()]
    assert names == ["chirp_locked", "chirp_free", "static_hold"]
    assert select_experiments(sc, ["chirp_locked"]) == [0]
    assert select_experiments(sc, ["static_hold", "chirp_free"]) == [2, 1]
    # the certification names its identification experiment the same way
    assert [i.experiment for i in sc.certification.identify] == ["chirp_locked"]
    with pytest.raises(UsageError, match=r"no experiment named 'chirp_lockd'.*names: chirp_locked, chirp_free"):
        select_experiments(sc, ["chirp_lockd"])


def test_hil_run_and_hil_plan_take_the_same_name(capsys):
    assert main(["plan", "sdea_bench", "--experiment", "chirp_locked", "--json"]) == 0
    capsys.readouterr()
    # hil run with a name it does not know: one line listing the names (nothing written)
    assert main(["run", "sdea_bench", "--experiment", "locked"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "names: chirp_locked, chirp_free, static_hold" in err[0]


def test_tables_are_not_cut_at_80_columns_in_a_pipe(monkeypatch):
    monkeypatch.delenv("COLUMNS", raising=False)
    monkeypatch.setattr(sys.stdout, "isatty", lambda: False)
    assert console().width == PIPE_COLUMNS
    monkeypatch.setenv("COLUMNS", "132")  # a width the user asks for is kept
    assert console().width == 132
    p = subprocess.run([sys.executable, "-m", "hil", "scenes"], capture_output=True, text=True, timeout=120,
                       env={"PATH": "/usr/bin:/bin"})
    assert p.returncode == 0, p.stderr
    widths = [len(line) for line in p.stdout.splitlines()]
    assert max(widths) > 80, max(widths)  # wider than rich's default for a pipe
    assert max(widths) <= PIPE_COLUMNS


def test_certify_names_the_experiment_running(monkeypatch, tmp_path, capsys):
    """The progress line of a long run names the stage, the experiment and its ticks (it said
    "run … (still running)" for the whole run)."""
    import hil.certify.pipeline as pl

    seen: list[str] = []
    real = pl.certify_scene

    def fake(scene, out, **kw):
        kw["tick_progress"]("00_chirp_locked", 1600, 32000)
        seen.append(beat_message())
        return real(scene, out, run_experiments=False, progress=kw["progress"])

    import hil.cli.common as common

    made: list = []
    real_init = common.StepProgress.__init__

    def init(self, *a, **k):
        real_init(self, *a, **k)
        made.append(self)

    def beat_message() -> str:
        return made[-1].message

    monkeypatch.setattr(common.StepProgress, "__init__", init)
    monkeypatch.setattr(pl, "certify_scene", fake)
    main(["certify", "mcet_trilateral", "--out", str(tmp_path / "c")])
    capsys.readouterr()
    assert seen == ["run 00_chirp_locked: 1600/32000 ticks (5 %)"]


def test_adequacy_lines_state_their_threshold(capsys):
    from hil.cli.identify import _print_table

    t = SimpleNamespace(name="whiteness", channel="velocity", statistic=25.7, expected=None, p_value=0.0017,
                        alpha=0.0005, passed=True)
    res = SimpleNamespace(model=SimpleNamespace(names=[], units=[], name="mbk"), method="frf", converged=True,
                          misfit=False, misfit_accepted=False, record={}, summary=dict, derived_summary=dict,
                          adequacy=SimpleNamespace(tests=[t]))
    _print_table(res)
    line = capsys.readouterr().out.splitlines()[-1]
    assert line.endswith("p=0.0017 ok (ok when p ≥ 0.0005)"), line
