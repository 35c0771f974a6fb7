"""The suite's hang guards are scaled for a loaded machine (tests/conftest.py, issue 26)."""

from __future__ import annotations

import pytest
from simtime import TIMEOUT_SCALE


@pytest.mark.timeout(7)
def test_a_timeout_marker_is_scaled_for_a_loaded_box(request: pytest.FixtureRequest) -> None:
    """A test marked ``timeout(7)`` gets 7 x TIMEOUT_SCALE s before pytest-timeout calls it hung."""
    assert TIMEOUT_SCALE >= 4  # two CPU-bound processes beside two workers on 2 cores: ~4x slower
    assert request.node.get_closest_marker("timeout").args[0] == 7 * TIMEOUT_SCALE


def test_the_default_timeout_is_scaled_too(pytestconfig: pytest.Config) -> None:
    """An unmarked test's guard (pyproject.toml ``timeout``) is 300 s of an idle machine, scaled."""
    assert float(pytestconfig.getini("timeout")) == 300 * TIMEOUT_SCALE
