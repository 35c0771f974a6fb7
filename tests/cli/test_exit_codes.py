"""Exit codes are defined once (hil.errors.ExitCode, EXIT_MEANINGS) and the documentation shows that table."""

from __future__ import annotations

import re
from pathlib import Path

from hil import errors
from hil.certify import fleet
from hil.cli import main as cli
from hil.errors import DECISION_EXIT, EXIT_MEANINGS, VERDICT_EXIT, ExitCode
from hil.run import realtime

ROOT = Path(__file__).resolve().parents[2]


def _table(text: str, header: str) -> list[list[str]]:
    """The rows (cells stripped) of the Markdown table that starts with ``header``."""
    lines = text.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.strip() == header)
    rows = []
    for ln in lines[start + 2:]:
        if not ln.startswith("|"):
            break
        rows.append([c.strip() for c in ln.strip().strip("|").split("|")])
    return rows


def test_guide_exit_code_table_is_the_code_table() -> None:
    guide = ROOT / "docs" / "guide" / "troubleshooting.md"
    rows = _table(guide.read_text(encoding="utf-8"), "| exit code | meaning |")
    readme = {int(code): meaning for code, meaning in rows}
    assert len(readme) == len(rows)  # no code listed twice
    assert readme == {int(k): v for k, v in EXIT_MEANINGS.items()}


def test_every_exit_code_has_a_meaning() -> None:
    assert set(EXIT_MEANINGS) == set(ExitCode)


def test_verdicts_doc_table_matches_verdict_exit() -> None:
    rows = _table((ROOT / "docs" / "VERDICTS.md").read_text(encoding="utf-8"), "| verdict | exit code | meaning |")
    assert {r[0].strip("`"): int(r[1]) for r in rows} == {k: int(v) for k, v in VERDICT_EXIT.items()}


def test_no_second_definition() -> None:
    # the CLI, the fleet and check-realtime use the one table (the same objects, not copies)
    assert cli.VERDICT_EXIT is VERDICT_EXIT and cli.DECISION_EXIT is DECISION_EXIT
    assert fleet._EXIT is DECISION_EXIT
    assert realtime.EXIT_NOT_HELD is ExitCode.NOT_HELD
    # and no module assigns an exit-code constant a number of its own (``EXIT_X = 2`` or a dict of numbers)
    pat = re.compile(r"^\s*(EXIT_[A-Z_]+(\s*,\s*EXIT_[A-Z_]+)*)\s*=\s*[\d(]|^\s*_?[A-Z_]*EXIT[A-Z_]*\s*=\s*\{\s*\"",
                     re.M)
    offenders = []
    for folder in ("hil", "identify", "protocols", "mocks"):
        for p in (ROOT / folder).rglob("*.py"):
            if pat.search(p.read_text(encoding="utf-8")) and p != Path(errors.__file__).resolve():
                offenders.append(str(p.relative_to(ROOT)))
    assert offenders == []
