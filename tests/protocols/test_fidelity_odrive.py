"""ODrive simulator and adapter against the real drive's documented behaviour (issue 14, item 1).

Specs followed: ODrive docs "CAN Protocol" (CANSimple: heartbeat_msg_rate_ms = 100 by default,
RTR requests), firmware sources ``Firmware/communication/can/can_simple.cpp`` (every message of
the node feeds the watchdog), ``Firmware/MotorControl/axis.cpp`` (watchdog expiry sets
ERROR_WATCHDOG_TIMER_EXPIRED = 0x01000000 and disarms), ``odrive-interface``
``axis.config.enable_watchdog`` = False by default, ``can_simple.hpp`` of the 0.5 branch
(0x1C = Get_ADC_Voltage).
"""

from __future__ import annotations

import itertools
import struct

import can
import numpy as np
import pytest

from hil.errors import DeviceFault
from hil.mocks.can_devices import SIM_WATCHDOG_ENDPOINTS, SimODrive
from hil.mocks.faults import FaultPlan
from hil.mocks.interfaces import FreeJoints
from hil.protocols import can_odrive as od
from hil.protocols.can_odrive import ODriveCAN

pytestmark = pytest.mark.timeout(20)
_chan = itertools.count()


def channel() -> str:
    return f"test-odrive-fid-{next(_chan)}"


def _raw(bus: can.BusABC, node: int, cmd: int, data: bytes = b"", remote: bool = False) -> None:
    bus.send(can.Message(arbitration_id=(node << 5) | cmd, data=data, is_extended_id=False,
                         is_remote_frame=remote, dlc=8 if remote else len(data)))


def _frames(bus: can.BusABC) -> list[can.Message]:
    out = []
    while (m := bus.recv(timeout=0.0)) is not None:
        out.append(m)
    return out


def test_factory_defaults_watchdog_off_and_heartbeat_every_100_ms():
    """Spec: enable_watchdog = False, heartbeat_msg_rate_ms = 100 (ODrive docs, factory config).
    A raw python-can host arms the axis and then goes silent for 1 s of simulated time: the axis
    stays in CLOSED_LOOP_CONTROL without error, and exactly one heartbeat per 100 ticks of 1 ms
    arrives (ticks 100, 200, ..., 1000 -> 10 heartbeats)."""
    ch = channel()
    j = FreeJoints()
    with SimODrive(j, ch, node_id=3, dt=0.001) as node, can.Bus(interface="virtual", channel=ch) as host:
        assert node.heartbeat_every == 100 and not node.watchdog_enabled
        _raw(host, 3, od.CMD_SET_CONTROLLER_MODE, od.encode_controller_mode(1, 1))
        _raw(host, 3, od.CMD_SET_AXIS_STATE, od.encode_u32(8))
        beats = []
        for _ in range(1000):
            node.tick()
            beats += [m for m in _frames(host) if m.arbitration_id == (3 << 5) | od.CMD_HEARTBEAT]
        assert len(beats) == 10
        assert all(od.decode_heartbeat(m.data) == (0, 8) for m in beats)
        assert node.watchdog_expired == 0


def test_watchdog_fed_by_every_message_and_expiry_sets_watchdog_timer_expired():
    """Spec: can_simple.cpp feeds the watchdog on each message of the node (an RTR estimate
    request is enough); axis.cpp latches 0x01000000 on expiry and disarms; Clear_Errors clears it."""
    ch = channel()
    j = FreeJoints()
    with SimODrive(j, ch, node_id=1, dt=0.001, heartbeat_every=1) as node, \
            can.Bus(interface="virtual", channel=ch) as host:
        ep = SIM_WATCHDOG_ENDPOINTS
        _raw(host, 1, od.CMD_RX_SDO, od.encode_sdo_write(ep["watchdog_timeout"], od.encode_f32(0.005)))
        _raw(host, 1, od.CMD_RX_SDO, od.encode_sdo_write(ep["enable_watchdog"], b"\x01"))
        _raw(host, 1, od.CMD_SET_CONTROLLER_MODE, od.encode_controller_mode(1, 1))
        _raw(host, 1, od.CMD_SET_AXIS_STATE, od.encode_u32(8))
        _raw(host, 1, od.CMD_SET_INPUT_TORQUE, od.encode_f32(0.3))
        node.tick()
        for _ in range(50):  # only estimate requests, no torque command: still fed
            _raw(host, 1, od.CMD_GET_ENCODER_ESTIMATES, remote=True)
            node.tick()
        assert node.axis_state == od.AxisState.CLOSED_LOOP_CONTROL and node.axis_error == 0
        assert node.applied_motor_torque() == pytest.approx(0.3)
        _frames(host)
        for _ in range(7):  # silent host: expires after more than 5 ticks
            node.tick()
        assert node.axis_state == od.AxisState.IDLE and node.applied_motor_torque() == 0.0
        assert node.axis_error & od.AXIS_ERROR_WATCHDOG_TIMER_EXPIRED
        hb = [m for m in _frames(host) if m.arbitration_id == (1 << 5) | od.CMD_HEARTBEAT][-1]
        err, state = od.decode_heartbeat(hb.data)
        assert err == 0x01000000 and state == od.AxisState.IDLE
        assert "WATCHDOG_TIMER_EXPIRED" in od.describe_axis_error(err)
        _raw(host, 1, od.CMD_CLEAR_ERRORS, b"\x00")
        node.tick()
        assert node.axis_error == 0


def test_adapter_refuses_an_axis_that_does_not_enter_closed_loop():
    """Spec: the drive refuses CLOSED_LOOP_CONTROL while in error and reports it in the heartbeat;
    the adapter must not silently send efforts that are not applied (DeviceFault with the code)."""
    ch = channel()
    j = FreeJoints()
    plan = FaultPlan(error_code=0x2000, error_at_tick=0)  # MOTOR_OVER_TEMP from the start
    with SimODrive(j, ch, node_id=2, sync=True, faults=plan) as node:
        with pytest.raises(DeviceFault, match="did not enter CLOSED_LOOP_CONTROL") as ei:
            ODriveCAN(2, ch, "virtual")
        assert ei.value.code == 0x2000
        assert node.axis_state == od.AxisState.IDLE


def test_adapter_faults_when_the_axis_falls_idle_after_the_watchdog():
    """Spec: after watchdog expiry the heartbeat shows IDLE + 0x01000000; every read raises."""
    ch = channel()
    j = FreeJoints()
    with SimODrive(j, ch, node_id=4, sync=True, heartbeat_every=1, dt=0.001) as node, \
            ODriveCAN(4, ch, "virtual", watchdog_s=0.003, watchdog_endpoints=dict(SIM_WATCHDOG_ENDPOINTS)) as dev:
        node.tick()
        dev.command_effort(np.array([0.2]))
        dev.read()
        for _ in range(5):  # the host stalls
            node.tick()
        with pytest.raises(DeviceFault) as ei:
            dev.read()
        assert ei.value.code == od.AXIS_ERROR_WATCHDOG_TIMER_EXPIRED


def test_firmware_05_has_no_get_torques():
    """Spec: on 0.5.x cmd 0x1C is Get_ADC_Voltage (can_simple.cpp 0.5: a data frame whose byte 0 is
    the GPIO number, answered with one float32 volts in an 8-byte frame, as odrive-cansimple-0.5.6.dbc
    gives it): the adapter refuses read_torque; the 0.6 simulator answers an RTR 0x1C with two
    float32 torques."""
    with pytest.raises(ValueError, match="Get_ADC_Voltage"):
        ODriveCAN(0, channel(), "virtual", read_torque=True, firmware="0.5")
    for fw, request in (("0.5", {"data": b"\x03"}), ("0.6", {"remote": True})):
        ch = channel()
        with SimODrive(FreeJoints(), ch, node_id=0, firmware=fw, adc_voltage=1.25) as node, \
                can.Bus(interface="virtual", channel=ch) as host:
            _raw(host, 0, 0x1C, **request)
            node.tick()
            reply = [m for m in _frames(host) if m.arbitration_id == 0x1C and not m.is_remote_frame]
            assert len(reply) == 1 and len(reply[0].data) == 8
            if fw == "0.5":
                assert struct.unpack_from("<f", reply[0].data)[0] == 1.25
    ch = channel()
    with SimODrive(FreeJoints(), ch, node_id=0, sync=True, firmware="0.5") as node, \
            ODriveCAN(0, ch, "virtual", firmware="0.5") as dev:
        dev.clear_errors()  # 0.5.x Clear_Errors has no payload
        assert dev.info.firmware == "0.5"
        assert node.frames_in >= 4
