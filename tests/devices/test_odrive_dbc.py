"""The ODrive adapter and twin against ODrive's own CAN databases (``odrive-cansimple-0.5.6.dbc`` and
``-0.6.10.dbc``, decoded with cantools): both firmware lines (issue 29, items 5 and 7).

What the DBCs define is the expectation, not the project's codec: error bit names, message lengths,
signal layouts and scaling, cycle times (``GenMsgCycleTime``)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

can = pytest.importorskip("can")
cantools = pytest.importorskip("cantools")

from hil.errors import DeviceFault  # noqa: E402
from hil.mocks.can_devices import SIM_WATCHDOG_ENDPOINTS, SimODrive  # noqa: E402
from hil.mocks.faults import FaultPlan  # noqa: E402
from hil.mocks.interfaces import FreeJoints  # noqa: E402
from hil.protocols.can_odrive import ODriveCAN  # noqa: E402
from hil.protocols.codecs import odrive as od  # noqa: E402

pytestmark = pytest.mark.timeout(60)
_chan = itertools.count()


def _line(version: str) -> str:
    return "0.6" if version.startswith("0.6") else "0.5"


def _db(path):
    return cantools.database.load_file(str(path))


def test_axis_error_names_are_the_dbc_tables(odrive_dbc):
    version, path = odrive_dbc
    line = _line(version)
    choices = {int(k): str(v) for k, v in _db(path).get_message_by_name("Axis0_Heartbeat")
               .get_signal_by_name("Axis_Error").choices.items() if int(k)}
    assert od.AXIS_ERRORS[line] == choices
    for bit, name in choices.items():
        assert od.describe_axis_error(bit, line) == name


@pytest.mark.parametrize(("injected", "line", "name"), [
    (0x4000, "0.5", "ESTOP_REQUESTED"), (0x800, "0.5", "WATCHDOG_TIMER_EXPIRED"),
    (0x4000, "0.6", "INVERTER_OVER_TEMP"), (0x800, "0.6", "DC_BUS_OVER_REGEN_CURRENT")])
def test_the_firmware_read_from_the_drive_names_its_errors(injected, line, name):
    """The adapter is not told the firmware: it asks (Get_Version) and names the error from the
    table of the line that answered (0.5.x does not answer)."""
    ch = f"odrive-fw-{next(_chan)}"
    plan = FaultPlan(error_code=injected, error_at_tick=0)
    with SimODrive(FreeJoints(), ch, node_id=0, sync=True, firmware=line, faults=plan), \
            pytest.raises(DeviceFault) as e:
        ODriveCAN(0, ch, "virtual")
    assert e.value.code == injected and f"({name})" in str(e.value)


def test_get_version_selects_the_line_and_reports_the_version():
    for line, version in (("0.6", (0, 6, 10)), ("0.5", None)):
        ch = f"odrive-fw-{next(_chan)}"
        with SimODrive(FreeJoints(), ch, node_id=2, sync=True, firmware=line), \
                ODriveCAN(2, ch, "virtual", enable=False, timeout=0.05) as dev:
            assert dev.firmware == line and dev.firmware_version == version
            assert dev.info.firmware == ("0.6.10" if version else "0.5 (no Get_Version answer)")


def test_every_host_frame_has_its_dbc_length_and_decodes(odrive_dbc):
    """Every frame the adapter sends (open, torque, state, mode, clear errors, estop, watchdog over
    RxSdo on 0.6) is a message of the DBC of the drive's line with exactly its length (cantools
    decodes it strictly), or an RTR request of one of its Get_* messages."""
    version, path = odrive_dbc
    line = _line(version)
    db = _db(path)
    ch = f"odrive-dbc-{next(_chan)}"
    spy = can.Bus(interface="virtual", channel=ch)
    with SimODrive(FreeJoints(), ch, node_id=0, sync=True, firmware=line) as node, \
            ODriveCAN(0, ch, "virtual", watchdog_s=0.05, watchdog_endpoints=dict(SIM_WATCHDOG_ENDPOINTS)) as dev:
        dev.command_effort(np.array([1.5]))
        dev.read()
        dev.clear_errors()
        dev.estop()
        assert node.input_torque == pytest.approx(1.5)
    host = [m for m in iter(lambda: spy.recv(0.05), None) if m.arbitration_id in _host_ids(db)]
    spy.shutdown()
    assert host
    sent = set()
    for m in host:
        if m.is_remote_frame:
            assert db.get_message_by_frame_id(m.arbitration_id).senders == ["ODrive_Axis0"]
            continue
        msg = db.get_message_by_frame_id(m.arbitration_id)
        assert len(m.data) == msg.length, msg.name
        decoded = msg.decode(bytes(m.data), decode_choices=False)
        sent.add(msg.name)
        if msg.name == "Axis0_Set_Input_Torque" and decoded["Input_Torque"]:
            assert decoded["Input_Torque"] == pytest.approx(1.5)
    expected = {"Axis0_Set_Input_Torque", "Axis0_Set_Axis_State", "Axis0_Set_Controller_Mode", "Axis0_Clear_Errors"}
    if line == "0.6":
        expected |= {"Axis0_Estop", "Axis0_RxSdo"}  # 0.5.6's DBC has no Estop (id 2) nor RxSdo
    assert expected <= sent


def _host_ids(db) -> set[int]:
    """Frame ids a host sends to axis 0 (Master's messages) or asks for by RTR (the drive's)."""
    return {m.frame_id for m in db.messages if m.frame_id < 0x20}


def test_watchdog_over_rxsdo_is_not_sent_to_a_05_drive():
    ch = f"odrive-fw-{next(_chan)}"
    with SimODrive(FreeJoints(), ch, node_id=1, sync=True, firmware="0.5") as node, \
            ODriveCAN(1, ch, "virtual", watchdog_s=0.05, watchdog_endpoints=dict(SIM_WATCHDOG_ENDPOINTS)) as dev:
        assert dev.firmware == "0.5" and not dev.watchdog_armed and not node.watchdog_configured
        assert math.isfinite(dev.read().position[0])
