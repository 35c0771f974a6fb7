"""ODrive CANSimple adapter against the simulated node over a python-can virtual bus."""

from __future__ import annotations

import itertools
import math
import struct

import can
import numpy as np
import pytest

from hil.errors import DeviceDisconnected, DeviceFault, DeviceTimeout
from hil.mocks.can_devices import SimODrive
from hil.mocks.faults import FaultPlan
from hil.mocks.interfaces import FreeJoints
from hil.protocols import can_odrive as od
from hil.protocols.can_odrive import ODriveCAN

pytestmark = pytest.mark.timeout(20)
_chan = itertools.count()


def channel() -> str:
    return f"test-odrive-{next(_chan)}"


# (description, node, cmd, payload, expected id, expected data) -- from the ODrive CAN docs
# (id formula example, Set_Input_Torque float32 LE) and the odrive_can DBC example (heartbeat).
WIRE_VECTORS = [
    ("Set_Input_Torque node 3, 1.5 N.m", 3, 0x0E, od.encode_f32(1.5), 0x6E, "0000c03f"),
    ("docs example axis 1 cmd 0x0C", 1, 0x0C, b"", 0x2C, ""),
    ("Set_Axis_State CLOSED_LOOP node 0", 0, 0x07, od.encode_u32(8), 0x007, "08000000"),
    ("Set_Controller_Mode torque/passthrough", 2, 0x0B, od.encode_controller_mode(1, 1), 0x04B, "0100000001000000"),
    ("Heartbeat error=1 state=HOMING(11)", 0, 0x01, od.encode_heartbeat(1, 11), 0x001, "010000000b000000"),
    ("Estop node 63", 63, 0x02, b"", 0x7E2, ""),
]


@pytest.mark.parametrize(("desc", "node", "cmd", "payload", "arb", "hexdata"), WIRE_VECTORS)
def test_wire_vectors(desc, node, cmd, payload, arb, hexdata):
    assert od.arbitration_id(node, cmd) == arb, desc
    assert od.split_id(arb) == (node, cmd)
    assert payload.hex() == hexdata


def test_set_input_torque_frame_on_the_bus():
    """Nobody answers the RTR Get_Version (0x60 for node 3): the adapter takes the drive for 0.5.x;
    Set_Input_Torque is the float32 in an 8-byte frame (both ODrive DBCs: length 8)."""
    ch = channel()
    spy = can.Bus(interface="virtual", channel=ch)
    with ODriveCAN(3, ch, "virtual", enable=False, timeout=0.02) as dev:
        assert dev.firmware == "0.5" and dev.firmware_version is None
        dev.command_effort(np.array([1.5]))
    frames = list(iter(lambda: spy.recv(0.05), None))
    spy.shutdown()
    asks, (msg,) = frames[:-1], frames[-1:]
    assert len(asks) == 1 + dev.retries and all(a.arbitration_id == 0x60 and a.is_remote_frame for a in asks)
    assert msg.arbitration_id == 0x6E and bytes(msg.data) == bytes.fromhex("0000c03f00000000")


@pytest.fixture
def rig():
    """FreeJoints + simulated ODrive (sync replies) + adapter, gear ratio 2."""
    ch = channel()
    j = FreeJoints(mass=2.0)
    node = SimODrive(j, ch, node_id=5, gear_ratio=2.0, sync=True)
    dev = ODriveCAN(5, ch, "virtual", gear_ratio=2.0, read_torque=True)
    yield j, node, dev
    dev.close()
    node.close()


def test_enable_and_torque_scaling(rig):
    j, node, dev = rig
    assert node.axis_state == od.AxisState.CLOSED_LOOP_CONTROL
    assert node.control_mode == od.ControlMode.TORQUE_CONTROL
    dev.command_effort(np.array([3.0]))  # joint N.m
    assert node.input_torque == pytest.approx(1.5)  # motor N.m = joint / gear ratio
    np.testing.assert_allclose(j.measured_force(), [3.0])


def test_feedback_decodes_to_rad(rig):
    j, node, dev = rig
    dev.command_effort(np.array([2.0]))
    for _ in range(100):
        j.step(0.001)
    node.tick()
    s = dev.read(timeout=0.2)
    np.testing.assert_allclose(s.position, j.position(), rtol=1e-6)
    np.testing.assert_allclose(s.velocity, j.velocity(), rtol=1e-6)
    np.testing.assert_allclose(s.effort, [2.0], rtol=1e-6)
    assert s.seq == 1 and s.fault == 0
    assert dev.read().seq == 2


def test_linear_scale():
    ch = channel()
    j = FreeJoints()
    lead = 0.005  # m per motor turn
    with SimODrive(j, ch, node_id=1, linear_scale=lead, sync=True) as node, ODriveCAN(
        1, ch, "virtual", linear_scale=lead
    ) as dev:
        assert dev.units == "linear"
        dev.command_effort(np.array([100.0]))  # N
        assert node.input_torque == pytest.approx(100.0 * lead / (2 * math.pi), rel=1e-6)
        j._x[:] = 0.0123
        s = dev.read()
        assert s.position[0] == pytest.approx(0.0123, rel=1e-6)


def test_cyclic_feedback_lockstep_without_sync():
    ch = channel()
    j = FreeJoints()
    with SimODrive(j, ch, node_id=2, encoder_every=1) as node, \
            ODriveCAN(2, ch, "virtual", feedback="cyclic", state_timeout=None) as dev:
        node.tick()  # handles mode/state commands, publishes heartbeat + estimate
        dev.read()
        dev.command_effort(np.array([1.0]))
        node.tick()  # torque applied before the step
        j.step(0.01)
        node.tick()
        s = dev.read()
        assert s.position[0] == pytest.approx(j.position()[0] * 1.0, rel=1e-6)
        again = dev.read(timeout=0.01)  # no new cyclic frame since: the same data, not fresh
        assert again.seq == s.seq and again.produced_at == s.produced_at
        assert dev.counters()["stale"] == 1


def test_cyclic_first_read_without_estimate_times_out():
    ch = channel()
    j = FreeJoints()
    with SimODrive(j, ch, node_id=2, encoder_every=0) as node, \
            ODriveCAN(2, ch, "virtual", feedback="cyclic", state_timeout=None) as dev:
        node.tick()
        with pytest.raises(DeviceTimeout):
            dev.read(timeout=0.01)
        assert dev.counters()["timeouts"] == 1


def test_cyclic_produced_at_is_frame_arrival_and_stale_estimates_are_not_fresh():
    """Lockstep clock k: produced_at is the clock when the estimate frame was taken off the bus;
    while the drive is stale (no estimate frames, heartbeats go on) reads repeat the last sample."""
    ch = channel()
    j = FreeJoints()
    clock = {"t": 0.0}
    plan = FaultPlan(stale_at_tick=3, stale_until_tick=6)
    with SimODrive(j, ch, node_id=2, encoder_every=1, heartbeat_every=1, sync=True, faults=plan) as node, \
            ODriveCAN(2, ch, "virtual", feedback="cyclic", clock=lambda: clock["t"]) as dev:
        seen = []
        for k in range(1, 9):
            node.tick()  # publishes the estimate of tick k (none at ticks 3, 4, 5)
            clock["t"] = float(k)
            s = dev.read(timeout=0.0)
            seen.append((s.seq, s.produced_at))
        assert seen == [(1, 1.0), (2, 2.0), (2, 2.0), (2, 2.0), (2, 2.0), (3, 6.0), (4, 7.0), (5, 8.0)]
        assert node.frames_suppressed == 3 and dev.counters()["stale"] == 3
        assert dev.axis_state == od.AxisState.CLOSED_LOOP_CONTROL  # heartbeats kept coming


def test_free_running_thread():
    ch = channel()
    j = FreeJoints()
    node = SimODrive(j, ch, node_id=4)
    node.start(rate_hz=500)
    try:
        with ODriveCAN(4, ch, "virtual") as dev:
            dev.command_effort(np.array([0.5]))
            for _ in range(5):
                dev.read(timeout=1.0)
    finally:
        node.close()
    assert node.commands and node.commands[0][1] == pytest.approx(0.5)


def test_drop_times_out_then_recovers():
    ch = channel()
    j = FreeJoints()
    plan = FaultPlan(drop_ticks=frozenset({1}))
    with SimODrive(j, ch, node_id=1, sync=True, faults=plan, heartbeat_every=0) as node, ODriveCAN(
        1, ch, "virtual"
    ) as dev:
        node.tick()
        with pytest.raises(DeviceTimeout):
            dev.read(timeout=0.02)
        node.tick()
        dev.read(timeout=0.02)


def test_error_code_raises_device_fault_and_disarms():
    ch = channel()
    j = FreeJoints()
    plan = FaultPlan(error_code=0x2000, error_at_tick=3)  # MOTOR_OVER_TEMP
    # heartbeat every tick (the factory rate is 100 ms): the error shows up on the next tick
    with SimODrive(j, ch, node_id=1, sync=True, faults=plan, heartbeat_every=1) as node, \
            ODriveCAN(1, ch, "virtual") as dev:
        for _ in range(2):
            node.tick()
            dev.command_effort(np.array([1.0]))
            dev.read()
        node.tick()
        with pytest.raises(DeviceFault) as ei:
            dev.read()
        assert ei.value.code == 0x2000 and "MOTOR_OVER_TEMP" in str(ei.value)
        assert node.axis_state == od.AxisState.IDLE
        assert j.measured_force()[0] == 0.0


def test_estop_latches_fault():
    ch = channel()
    j = FreeJoints()
    with SimODrive(j, ch, node_id=7, sync=True, heartbeat_every=1) as node, ODriveCAN(7, ch, "virtual") as dev:
        dev.estop()
        node.tick()
        with pytest.raises(DeviceFault) as ei:
            dev.read()
        assert ei.value.code & od.AXIS_ERROR_ESTOP_REQUESTED
        dev.clear_errors()
        node.tick()
        with pytest.raises(DeviceFault, match="IDLE, not CLOSED_LOOP_CONTROL"):
            dev.read()  # the estop disarmed the axis: efforts would not be applied
        dev.set_axis_state(od.AxisState.CLOSED_LOOP_CONTROL)
        dev.confirm_closed_loop(0.5)
        dev.read()


def test_disconnect_and_reconnect():
    ch = channel()
    j = FreeJoints()
    plan = FaultPlan(disconnect_at_tick=2, reconnect_at_tick=4)
    with SimODrive(j, ch, node_id=1, sync=True, faults=plan) as node, ODriveCAN(1, ch, "virtual") as dev:
        outcomes = []
        for _ in range(5):
            node.tick()
            try:
                dev.read(timeout=0.02)
                outcomes.append("ok")
            except DeviceTimeout:
                outcomes.append("timeout")
        assert outcomes == ["ok", "timeout", "timeout", "ok", "ok"]


def test_corrupt_frame_is_error_frame_and_timeout():
    ch = channel()
    j = FreeJoints()
    plan = FaultPlan(corrupt_ticks=frozenset({1}))
    with SimODrive(j, ch, node_id=1, sync=True, faults=plan, heartbeat_every=0) as node, ODriveCAN(
        1, ch, "virtual"
    ) as dev:
        node.tick()
        with pytest.raises(DeviceTimeout):
            dev.read(timeout=0.02)
        # the request is sent twice (one retry), both answers destroyed at tick 1
        assert dev.error_frames == 2 and dev.counters()["retries"] == 1 and dev.counters()["timeouts"] == 1


def test_late_answer_is_discarded_not_mistaken():
    ch = channel()
    j = FreeJoints()
    plan = FaultPlan(late_prob=1.0, late_ticks=1)
    with SimODrive(j, ch, node_id=1, sync=True, faults=plan, heartbeat_every=0) as node, ODriveCAN(
        1, ch, "virtual", state_timeout=None  # every answer is late, the heartbeat too
    ) as dev:
        with pytest.raises(DeviceTimeout):
            dev.read(timeout=0.02)
        node.tick()  # the late answer arrives now
        with pytest.raises(DeviceTimeout):
            dev.read(timeout=0.02)  # it is discarded, the new request is late again
        assert dev.stale_discarded == 1


def _run(seed: int) -> list:
    ch = channel()
    j = FreeJoints()
    plan = FaultPlan(drop_prob=0.3, stale_prob=0.2)
    out = []
    with SimODrive(j, ch, node_id=1, sync=True, faults=plan, seed=seed, heartbeat_every=0) as node, ODriveCAN(
        1, ch, "virtual", clock=lambda: 0.0, firmware="0.6"  # as a scene gives it: no Get_Version exchange
    ) as dev:
        for k in range(40):
            dev.command_effort(np.array([math.sin(0.3 * k)]))
            j.step(0.01)
            node.tick()
            try:
                s = dev.read(timeout=0.005)
                out.append((s.position[0], s.velocity[0]))
            except DeviceTimeout:
                out.append("timeout")
    return out


def test_lockstep_determinism():
    a, b, c = _run(1), _run(1), _run(2)
    assert a == b
    assert a != c
    assert "timeout" in a


def test_close_is_idempotent_and_closed_raises():
    ch = channel()
    dev = ODriveCAN(1, ch, "virtual", enable=False)
    dev.close()
    dev.close()
    with pytest.raises(DeviceDisconnected):
        dev.command_effort(np.array([0.0]))
    with pytest.raises(DeviceDisconnected):
        dev.read()


def test_safe_stop_sends_zero_and_idle():
    ch = channel()
    j = FreeJoints()
    with SimODrive(j, ch, node_id=1, sync=True) as node:
        dev = ODriveCAN(1, ch, "virtual")
        dev.command_effort(np.array([1.0]))
        dev.close()
        assert node.input_torque == 0.0 and node.axis_state == od.AxisState.IDLE


def test_heartbeat_decode_short_payload_rejected():
    with pytest.raises(Exception, match="heartbeat"):
        od.decode_heartbeat(b"\x00\x00")
    assert od.decode_heartbeat(struct.pack("<IB", 5, 8)) == (5, 8)
