"""Vendor definitions of real devices (ODrive CAN databases, a Technosoft iPOS EDS) for the device
conformance tests of this folder.

The files are not part of the project (their makers publish them; see SOURCE.txt next to them): the
tests read them where the workspace keeps them, ``HIL_VENDOR_DEVICES`` (a folder) or the first
``shared/data/devices`` folder found beside the repository or one of its parent folders, and skip
with the reason when they are absent."""

from __future__ import annotations

from pathlib import Path

import pytest
from vendor_files import vendor_file


@pytest.fixture
def technosoft_eds() -> Path:
    """Technosoft iPOS CiA 402 EDS (ros_canopen's canopen_402_driver/config/technosoft.eds)."""
    return vendor_file("technosoft_iPOS.eds")


@pytest.fixture(params=["0.5.6", "0.6.10"])
def odrive_dbc(request: pytest.FixtureRequest) -> tuple[str, Path]:
    """(firmware, ODrive CANSimple DBC of that firmware) for both firmware lines."""
    return request.param, vendor_file(f"odrive-cansimple-{request.param}.dbc")
