"""Suite-wide test configuration.

Tests marked ``slow`` (calibration over many datasets, long sweeps) are skipped unless the ``-m``
expression mentions ``slow``: ``pytest`` runs the fast suite, ``pytest -m "slow or not slow"``
(what CI runs) runs everything, ``pytest -m slow`` only the slow checks.
"""

from __future__ import annotations

import pytest


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if "slow" in (config.getoption("-m") or ""):
        return
    skip = pytest.mark.skip(reason="slow: run with -m 'slow or not slow'")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)
