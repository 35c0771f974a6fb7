"""What a person sees from the CLI: output folders that never overwrite (issue 10 item 6), progress
on long steps, and 80-column output where no value or path is split across lines (issue 9 item 6)."""

from __future__ import annotations

import datetime as dt
import hashlib
import io
import json
import re
import sys
import time
from pathlib import Path

import pytest
from malformed_helpers import assert_one_line_error, run_cli

from hil.record import outdir
from hil.record.outdir import OutputPathError, check_out_file, prepare_out_dir, remove_if_empty


class _FrozenClock(dt.datetime):
    @classmethod
    def now(cls, tz=None):
        return dt.datetime(2026, 1, 2, 3, 4, 5, tzinfo=dt.UTC)


@pytest.fixture
def same_second(monkeypatch):
    """Every default folder name gets the same UTC time stamp, as two runs in one second would."""

    class _Dt:
        datetime = _FrozenClock
        UTC = dt.UTC

    monkeypatch.setattr(outdir, "_dt", _Dt)


def _digest(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


# ------------------------------------------------------------------------------------------ hil.record.outdir


def test_default_folders_in_the_same_second_differ(tmp_path, same_second):
    a = prepare_out_dir(None, default_stem=str(tmp_path / "runs" / "scene"))
    b = prepare_out_dir(None, default_stem=str(tmp_path / "runs" / "scene"))
    assert a != b and a.is_dir() and b.is_dir()
    for p in (a, b):
        assert re.fullmatch(r"scene-20260102T030405Z-[0-9a-f]{6}", p.name), p.name


def test_explicit_folder_rules(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert prepare_out_dir(empty, default_stem="x") == empty  # an existing empty folder is fine
    (empty / "a.h5").write_text("old")
    with pytest.raises(OutputPathError, match="exists and is not empty; use --overwrite"):
        prepare_out_dir(empty, default_stem="x")
    assert prepare_out_dir(empty, default_stem="x", overwrite=True) == empty
    assert (empty / "a.h5").read_text() == "old"  # --overwrite replaces files as they are written, deletes nothing
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(OutputPathError, match="is a file, not a folder"):
        prepare_out_dir(f / "sub", default_stem="x")
    with pytest.raises(OutputPathError, match="exists and is not a folder"):
        prepare_out_dir(f, default_stem="x", overwrite=True)
    new = prepare_out_dir(tmp_path / "a" / "b", default_stem="x")
    assert new.is_dir()


def test_output_file_rules(tmp_path):
    f = tmp_path / "r.h5"
    assert check_out_file(f) == f
    f.write_text("old")
    with pytest.raises(OutputPathError, match="use --overwrite"):
        check_out_file(f)
    assert check_out_file(f, overwrite=True) == f
    with pytest.raises(OutputPathError, match="is a folder"):
        check_out_file(tmp_path)
    with pytest.raises(OutputPathError, match="is a file"):
        check_out_file(f / "x.h5")


def test_remove_if_empty_keeps_folders_with_files(tmp_path):
    (tmp_path / "a" / "records").mkdir(parents=True)
    assert remove_if_empty(tmp_path / "a") and not (tmp_path / "a").exists()
    (tmp_path / "b" / "records").mkdir(parents=True)
    (tmp_path / "b" / "records" / "x").write_text("1")
    assert not remove_if_empty(tmp_path / "b") and (tmp_path / "b" / "records" / "x").exists()


# ------------------------------------------------------------------------------------------ hil run


@pytest.mark.timeout(240)
def test_two_runs_into_one_out_keep_the_first(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("HIL_PROGRESS_SECONDS", "600")
    out = tmp_path / "today"
    argv = ["run", "sdea_bench", "--experiment", "static_hold", "--out", str(out), "--json"]
    code, stdout, _ = run_cli(argv, capsys)
    assert code == 0, stdout
    first = _digest(out)
    assert list(first) == ["02_static_hold.h5"]
    assert_one_line_error(argv, capsys, [str(out), "--overwrite"])
    assert _digest(out) == first  # the refused run touched nothing
    code, stdout, _ = run_cli([*argv, "--overwrite", "--seed", "3"], capsys)
    assert code == 0
    assert json.loads(stdout)["out"] == str(out)
    assert _digest(out) != first  # replaced on request (another seed, another record)


@pytest.mark.timeout(240)
def test_two_runs_in_the_same_second_get_their_own_folders(tmp_path, capsys, monkeypatch, same_second):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("HIL_PROGRESS_SECONDS", "600")
    outs = []
    for _ in range(2):
        code, stdout, _ = run_cli(["run", "sdea_bench", "--experiment", "static_hold", "--json"], capsys)
        assert code == 0
        outs.append(Path(json.loads(stdout)["out"]))
    assert outs[0] != outs[1]
    assert all(p.parent == Path("runs") and p.name.startswith("sdea_bench-20260102T030405Z-") for p in outs)
    assert all((tmp_path / p / "02_static_hold.h5").is_file() for p in outs)


def test_a_refused_run_leaves_no_folder(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert_one_line_error(["run", "sdea_bench", "--experiment", "nosuch"], capsys, "--experiment nosuch")
    assert_one_line_error(["run", "sdea_bench", "--seed", "-1", "--out", "new"], capsys, ["--seed", "got -1"])
    assert list(tmp_path.iterdir()) == []


def test_a_failing_run_removes_the_empty_folder_it_made(tmp_path, capsys, monkeypatch):
    import hil.run.runner

    def broken(self, select=None):  # e.g. a bench that cannot open (a missing extra)
        from hil.errors import DeviceError

        raise DeviceError("the simulated ODrive needs python-can")

    monkeypatch.setattr(hil.run.runner.Runner, "run", broken)
    out = tmp_path / "runs" / "x"
    assert_one_line_error(["run", "sdea_bench", "--out", str(out)], capsys, "python-can")
    assert not out.exists()
    keep = tmp_path / "mine"
    keep.mkdir()  # an empty folder the user made stays
    assert_one_line_error(["run", "sdea_bench", "--out", str(keep)], capsys, "python-can")
    assert keep.is_dir()


# ------------------------------------------------------------------------------------------ 80 columns


def _assert_whole_on_one_line(text: str, pieces: list[str]) -> None:
    lines = text.splitlines()
    for piece in pieces:
        assert any(piece in ln for ln in lines), f"{piece!r} is split across lines in:\n{text}"


@pytest.mark.timeout(240)
def test_run_output_at_80_columns_keeps_paths_whole(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")
    monkeypatch.setenv("HIL_PROGRESS_SECONDS", "600")
    out = tmp_path / "a-rather-long-folder-name-for-the-records-of-today" / "and-one-more-level"
    code, stdout, _ = run_cli(["run", "sdea_bench", "--experiment", "static_hold", "--out", str(out)], capsys)
    assert code == 0
    assert len(str(out / "02_static_hold.h5")) > 80
    _assert_whole_on_one_line(stdout, [str(out / "02_static_hold.h5"), "02_static_hold", "completed"])
    table = [ln for ln in stdout.splitlines() if ln.startswith(("┏", "│", "└"))]
    assert table and all(len(ln) <= 80 for ln in table)


@pytest.mark.timeout(300)
def test_certify_output_at_80_columns_keeps_values_and_paths_whole(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")
    out = tmp_path / "reports" / "certify-at-eighty-columns"
    code, stdout, _ = run_cli(["certify", "--no-experiments", "--out", str(out)], capsys)
    assert code in (0, 10, 11, 13)
    cert = json.loads((out / "certificate.json").read_text())
    pieces = [str(out / "certificate.json"), str(out / "report.html"), str(out / "report.pdf")]
    pieces += [r for r in cert["reasons"]]  # reasons hold values ("margin ... > 0") that must stay whole
    for m in cert["measurements"]:
        v = m["value"]
        pieces.append(f"{v:.4g}" if isinstance(v, float) else str(v))
        if m["lower"] is not None:
            pieces.append(f"≥ {m['lower']:g}")
    _assert_whole_on_one_line(stdout, pieces)


def test_stability_output_at_80_columns_keeps_values_whole(capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")
    code, stdout, _ = run_cli(["stability", "--model", "bilateral_2dof", "--set", "gains=B", "-v", "--json"], capsys)
    res = json.loads(stdout)
    code, stdout, _ = run_cli(["stability", "--model", "bilateral_2dof", "--set", "gains=B", "-v"], capsys)
    assert code == 11
    pieces = [c["name"] for c in res["conditions"]]
    pieces += [f"{c['margin']:.3g}" for c in res["conditions"] if isinstance(c["margin"], float)]
    _assert_whole_on_one_line(stdout, pieces)
    assert all(len(ln) <= 80 for ln in stdout.splitlines() if ln.startswith("│"))


# ------------------------------------------------------------------------------------------ progress


def test_progress_prints_plain_lines_when_not_a_tty(monkeypatch):
    from hil.cli.common import StepProgress

    buf = io.StringIO()
    monkeypatch.setattr(sys, "stderr", buf)
    with StepProgress("hil design", interval=0.01) as p:
        p.update("alpha = 0.5")
        deadline = time.monotonic() + 30
        while "alpha = 0.5" not in buf.getvalue() and time.monotonic() < deadline:
            time.sleep(0.01)
    lines = buf.getvalue().splitlines()
    assert lines and all(re.fullmatch(r"hil design: \d+ s: .+", ln) for ln in lines), lines
    assert "alpha = 0.5" in lines[-1] or any("alpha = 0.5" in ln for ln in lines)


def test_progress_is_silent_for_short_steps(monkeypatch):
    from hil.cli.common import StepProgress

    buf = io.StringIO()
    monkeypatch.setattr(sys, "stderr", buf)
    with StepProgress("hil stability", interval=600) as p:
        p.update("checking")
    assert buf.getvalue() == ""


def test_design_search_reports_progress():
    from hil.models.design import optimize_coupler

    msgs: list[str] = []
    r = optimize_coupler("passivity", 1.0, progress=msgs.append)
    assert msgs and all("k22_max" in m and "exact verdicts" in m for m in msgs)
    best = max(float(re.search(r"best so far ([0-9.e+-]+)", m)[1]) for m in msgs)
    assert best == pytest.approx(r.k22_max, rel=1e-4)  # the best value reported is the result (5 digits)
