"""Where the vendor device files are (see conftest.py of this folder)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

_HERE = Path(__file__).resolve()


def vendor_dir() -> Path | None:
    """The folder holding the vendor files, or None."""
    env = os.environ.get("HIL_VENDOR_DEVICES")
    if env:
        return Path(env) if Path(env).is_dir() else None
    for parent in _HERE.parents:
        cand = parent / "shared" / "data" / "devices"
        if cand.is_dir():
            return cand
    return None


def vendor_file(name: str) -> Path:
    """Path of vendor file ``name``; skips the test (with the reason) when it is not available."""
    d = vendor_dir()
    if d is None:
        pytest.skip(f"vendor device files not found (set HIL_VENDOR_DEVICES to the folder holding {name})")
    p = d / name
    if not p.is_file():
        pytest.skip(f"vendor file {name} not in {d}")
    return p
