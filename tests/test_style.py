"""The code base is ruff-clean (configuration in pyproject.toml)."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_ruff_clean():
    exe = shutil.which("ruff")
    cmd = [exe, "check", str(ROOT)] if exe else [sys.executable, "-m", "ruff", "check", str(ROOT)]
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=ROOT)
    except FileNotFoundError:  # pragma: no cover - ruff is in the test extra
        pytest.fail("ruff is not installed: pip install -e '.[test]'")
    assert p.returncode == 0, p.stdout + p.stderr
