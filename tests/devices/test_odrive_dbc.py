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

from vendor_files import vendor_file  # noqa: E402

from hil.errors import DeviceFault  # noqa: E402
from hil.mocks.faults import FaultPlan  # noqa: E402
from hil.mocks.interfaces import FreeJoints  # noqa: E402
from hil.mocks.odrive_device import SIM_ENDPOINTS, SIM_WATCHDOG_ENDPOINTS, SimODrive  # noqa: E402
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


# -- the twin's traffic (item 7) ------------------------------------------------------------------

class _Joints:
    """A joint held at a known state (rad, rad/s); records the effort applied."""

    dof = 1

    def __init__(self, q: float = 0.0, v: float = 0.0) -> None:
        self.q, self.v, self.effort = q, v, 0.0

    def position(self) -> np.ndarray:
        return np.array([self.q])

    def velocity(self) -> np.ndarray:
        return np.array([self.v])

    def apply_effort(self, effort: np.ndarray) -> None:
        self.effort = float(np.asarray(effort).reshape(-1)[0])

    def measured_force(self) -> np.ndarray:
        return np.array([self.effort])


def _drain(bus) -> list:
    return list(iter(lambda: bus.recv(0.0), None))


def _decode_strict(db, m):
    msg = db.get_message_by_frame_id(m.arbitration_id)
    assert len(m.data) == msg.length, (msg.name, len(m.data))
    return msg, msg.decode(bytes(m.data), decode_choices=False)


def test_factory_cyclic_messages_are_the_dbcs(odrive_dbc):
    """A factory twin, left alone for 1 s of 1 ms ticks, sends exactly the DBC's cyclic messages at
    its GenMsgCycleTime (Heartbeat 100 ms, Get_Encoder_Estimates 10 ms, and Get_Version 100 ms on
    0.6.10), each decoding strictly."""
    version, path = odrive_dbc
    db = _db(path)
    cyclic = {m.frame_id: m.cycle_time for m in db.messages if m.frame_id < 0x20 and m.cycle_time}
    ch = f"odrive-cyc-{next(_chan)}"
    ticks: dict[int, list[int]] = {}
    with SimODrive(_Joints(), ch, node_id=0, dt=0.001, firmware=_line(version)) as node, \
            can.Bus(interface="virtual", channel=ch) as host:
        for k in range(1, 1001):
            node.tick()
            for m in _drain(host):
                _decode_strict(db, m)
                ticks.setdefault(m.arbitration_id, []).append(k)
    assert set(ticks) == set(cyclic)
    for fid, period_ms in cyclic.items():
        assert np.all(np.diff(ticks[fid]) == period_ms), (fid, ticks[fid][:5])
        assert len(ticks[fid]) == 1000 // period_ms


def test_every_get_message_of_the_dbc_is_answered_with_its_values(odrive_dbc):
    """Every message the DBC gives the drive as sender, but the cyclic-only Heartbeat's data and the
    SDO/Address replies, asked for as the line does (RTR; 0.5.x Get_ADC_Voltage: a data frame with
    the GPIO number), is answered once with the DBC's length, and its signals are the drive's state
    computed here from the twin's documented telemetry model."""
    version, path = odrive_dbc
    line = _line(version)
    db = _db(path)
    q, v, tau = 3.0, -1.5, 0.25  # joint rad, rad/s, motor N.m (gear ratio 2: motor turns = 2 q / 2 pi)
    joints = _Joints(q, v)
    ch = f"odrive-get-{next(_chan)}"
    turns, tps = 2 * q / (2 * math.pi), 2 * v / (2 * math.pi)
    kt = 8.27 / 270.0
    power = tau * 2 * math.pi * tps
    expect = {
        "Get_Encoder_Estimates": {"Pos_Estimate": turns, "Vel_Estimate": tps},
        "Get_Iq": {"Iq_Setpoint": tau / kt, "Iq_Measured": tau / kt},
        "Get_Bus_Voltage_Current": {"Bus_Voltage": 24.0, "Bus_Current": power / 24.0},
        "Heartbeat": {"Axis_Error": 0, "Axis_State": 8},
        "Get_Version": {"Fw_Version_Major": 0, "Fw_Version_Minor": 6, "Fw_Version_Revision": 10},
        "Get_Error": {"Active_Errors": 0, "Disarm_Reason": 0},
        "Get_Temperature": {"FET_Temperature": 35.0, "Motor_Temperature": 30.0},
        "Get_Torques": {"Torque_Target": tau, "Torque_Estimate": tau},
        "Get_Powers": {"Electrical_Power": power, "Mechanical_Power": power},
        "Get_Motor_Error": {"Motor_Error": 0}, "Get_Encoder_Error": {"Encoder_Error": 0},
        "Get_Sensorless_Error": {"Sensorless_Error": 0}, "Get_Controller_Error": {"Controller_Error": 0},
        "Get_Encoder_Count": {"Shadow_Count": round(turns * 8192), "Count_in_CPR": round(turns * 8192) % 8192},
        "Get_Sensorless_Estimates": {"Sensorless_Pos_Estimate": turns, "Sensorless_Vel_Estimate": tps},
        "Get_ADC_Voltage": {"ADC_Voltage": 1.25},
    }
    asked = [m for m in db.messages if m.frame_id < 0x20 and m.senders == ["ODrive_Axis0"]
             and m.name not in ("Axis0_TxSdo",)]
    with SimODrive(joints, ch, node_id=0, sync=True, firmware=line, gear_ratio=2.0, adc_voltage=1.25,
                   cyclic_ms={"Heartbeat": 0, "Get_Encoder_Estimates": 0, "Get_Version": 0}
                   if line == "0.6" else {"Heartbeat": 0, "Get_Encoder_Estimates": 0}) as node, \
            can.Bus(interface="virtual", channel=ch) as host:
        node.control_mode, node.axis_state, node.input_torque = 1, 8, tau  # armed, torque control
        answered = set()
        for msg in asked:
            name = msg.name.removeprefix("Axis0_")
            if name == "Get_ADC_Voltage":
                host.send(can.Message(arbitration_id=msg.frame_id, data=b"\x05", is_extended_id=False))
            else:
                host.send(can.Message(arbitration_id=msg.frame_id, is_remote_frame=True, dlc=msg.length,
                                      is_extended_id=False))
            got = [m for m in _drain(host) if not m.is_remote_frame]
            assert len(got) == 1 and got[0].arbitration_id == msg.frame_id, name
            _, sig = _decode_strict(db, got[0])
            answered.add(name)
            if name == "Address":
                assert sig["Node_ID"] == 0
                continue
            for k, want in expect[name].items():
                assert sig[k] == pytest.approx(want, rel=1e-6, abs=1e-6), (name, k)
    gets = {m.name.removeprefix("Axis0_") for m in asked}
    assert answered == gets and {n for n in gets if n.startswith("Get_")} <= set(expect)
    assert ("Get_Version" in answered) == (line == "0.6") and ("Get_ADC_Voltage" in answered) == (line == "0.5")


def test_rate_settings_over_rxsdo_are_honoured():
    """0.6: the host sets heartbeat_msg_rate_ms = 20 and iq_msg_rate_ms = 5 with RxSdo writes
    (encoded from the DBC), reads one back (TxSdo decoded with the DBC); the twin's cyclic traffic
    follows."""
    db = _db(vendor_file("odrive-cansimple-0.6.10.dbc"))
    rx, tx = db.get_message_by_name("Axis0_RxSdo"), db.get_message_by_name("Axis0_TxSdo")
    ep = SIM_ENDPOINTS
    ch = f"odrive-rate-{next(_chan)}"
    with SimODrive(_Joints(), ch, node_id=0, sync=True, dt=0.001) as node, \
            can.Bus(interface="virtual", channel=ch) as host:
        for name, ms in (("heartbeat_msg_rate_ms", 20), ("iq_msg_rate_ms", 5), ("version_msg_rate_ms", 0),
                         ("encoder_msg_rate_ms", 0)):
            data = rx.encode({"Opcode": 1, "Endpoint_ID": ep[name], "Reserved": 0, "Value": ms})
            host.send(can.Message(arbitration_id=rx.frame_id, data=data, is_extended_id=False))
        host.send(can.Message(arbitration_id=rx.frame_id, is_extended_id=False,
                              data=rx.encode({"Opcode": 0, "Endpoint_ID": ep["iq_msg_rate_ms"], "Reserved": 0,
                                              "Value": 0})))
        (back,) = [m for m in _drain(host) if m.arbitration_id == tx.frame_id]
        assert tx.decode(bytes(back.data))["Value"] == 5 and tx.decode(bytes(back.data))["Endpoint_ID"] == ep[
            "iq_msg_rate_ms"]
        seen: dict[int, int] = {}
        for _ in range(100):
            node.tick()
            for m in _drain(host):
                seen[m.arbitration_id] = seen.get(m.arbitration_id, 0) + 1
    assert seen == {0x01: 5, 0x14: 20}


def test_05_estop_and_watchdog_latch_the_05_bits():
    db = _db(vendor_file("odrive-cansimple-0.5.6.dbc"))
    hb = db.get_message_by_name("Axis0_Heartbeat")
    ch = f"odrive-05-{next(_chan)}"
    with SimODrive(_Joints(), ch, node_id=0, sync=True, firmware="0.5", watchdog_ticks=3, heartbeat_every=1,
                   encoder_every=0) as node, can.Bus(interface="virtual", channel=ch) as host:
        for cmd, data in ((0x0B, od.encode_controller_mode(1, 1)), (0x07, od.encode_u32(8))):
            host.send(can.Message(arbitration_id=cmd, data=data, is_extended_id=False))
        for _ in range(5):  # silent host: the watchdog expires
            node.tick()
        last = [m for m in _drain(host) if m.arbitration_id == hb.frame_id][-1]
        assert hb.decode(bytes(last.data))["Axis_Error"] == "WATCHDOG_TIMER_EXPIRED"
        host.send(can.Message(arbitration_id=0x18, data=b"", is_extended_id=False))  # 0.5 Clear_Errors: empty
        host.send(can.Message(arbitration_id=0x02, data=b"", is_extended_id=False))  # Estop
        node.tick()
        last = [m for m in _drain(host) if m.arbitration_id == hb.frame_id][-1]
        assert hb.decode(bytes(last.data))["Axis_Error"] == "ESTOP_REQUESTED"


def test_odrives_can_simple_example_flow_against_the_twin():
    """ODrive's own ``can_simple`` example (docs "CAN Bus Guide"): Set_Axis_State CLOSED_LOOP_CONTROL as
    4 data bytes, wait for a heartbeat showing state 8, send a setpoint, then read the *cyclic*
    Get_Encoder_Estimates a factory drive broadcasts (it never requests them)."""
    joints = _Joints(q=2 * math.pi * 0.75, v=2 * math.pi * 0.5)  # 0.75 turn, 0.5 turn/s
    ch = f"odrive-example-{next(_chan)}"
    with SimODrive(joints, ch, node_id=0, dt=0.001) as node, can.Bus(interface="virtual", channel=ch) as bus:
        bus.send(can.Message(arbitration_id=0 << 5 | 0x07, data=(8).to_bytes(4, "little"), is_extended_id=False))
        state = None
        for _ in range(200):
            node.tick()
            for m in _drain(bus):
                if m.arbitration_id == 0 << 5 | 0x01:
                    state = m.data[4]
            if state == 8:
                break
        assert state == 8
        bus.send(can.Message(arbitration_id=0 << 5 | 0x0E, data=od.encode_input_torque(0.1), is_extended_id=False))
        est = []
        for _ in range(30):
            node.tick()
            est += [od.decode_f32x2(m.data) for m in _drain(bus) if m.arbitration_id == 0 << 5 | 0x09]
        assert len(est) == 3 and all(e == pytest.approx((0.75, 0.5)) for e in est)
