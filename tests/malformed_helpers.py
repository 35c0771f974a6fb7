"""Shared check for malformed-input tests: a bad input through ``hil.cli.main.main`` must end with one
line on stderr naming the offending file or flag, the documented exit code, and no traceback.

Used by tests/cli/test_malformed_inputs.py (files, records, flags) and tests/scene/test_malformed_scenes.py
(scenes)::

    from malformed_helpers import assert_one_line_error

    def test_x(capsys, tmp_path):
        assert_one_line_error(["stability", str(tmp_path / "net.yaml")], capsys, "net.yaml")
"""

from __future__ import annotations

from collections.abc import Sequence

import pytest

__all__ = ["assert_one_line_error", "run_cli"]


def run_cli(argv: Sequence[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    """``hil.cli.main.main(argv)`` in-process: (exit code, stdout, stderr); earlier captured output is dropped."""
    from hil.cli.main import main

    capsys.readouterr()
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def assert_one_line_error(argv: Sequence[str], capsys: pytest.CaptureFixture[str],
                          must_contain: str | Sequence[str], *, code: int = 2) -> str:
    """Run ``hil ARGV`` and assert: exit ``code`` (2: input error), exactly one non-empty stderr line,
    containing every string of ``must_contain`` (the file name or the flag), no ``Traceback``, and
    no Python object reprs (``np.float64(``). Returns the line."""
    got, _out, err = run_cli(argv, capsys)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    shown = f"hil {' '.join(map(str, argv))}: exit {got}, stderr:\n{err}"
    assert "Traceback" not in err, shown
    assert got == code, shown
    assert len(lines) == 1, shown
    line = lines[0]
    for s in [must_contain] if isinstance(must_contain, str) else must_contain:
        assert s in line, f"{s!r} not in the message; {shown}"
    assert "np.float64(" not in line and "np.int64(" not in line, shown
    return line
