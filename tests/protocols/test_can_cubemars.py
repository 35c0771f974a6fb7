"""CubeMars AK MIT-mode adapter: pack/unpack conformance and the adapter against the simulated motor."""

from __future__ import annotations

import itertools
import math

import can
import numpy as np
import pytest

from hil.errors import DeviceFault, DeviceTimeout
from hil.mocks.can_devices import SimCubeMars
from hil.mocks.faults import FaultPlan
from hil.mocks.interfaces import FreeJoints
from hil.protocols import can_cubemars as cm
from hil.protocols.can_cubemars import CubeMarsMIT, MitCommand, MitReply

pytestmark = pytest.mark.timeout(20)
_chan = itertools.count()
AK80_9 = cm.MODEL_LIMITS["AK80-9"]


def channel() -> str:
    return f"test-cubemars-{next(_chan)}"


# Known frames (AK manual / MIT mini-cheetah pack_cmd, truncating float->uint):
KNOWN_COMMANDS = [
    # zero command: p=0x7FFF, v=0x7FF, kp=0, kd=0, t=0x7FF
    (MitCommand(0, 0, 0, 0, 0), "7fff7ff0000007ff"),
    # every field at its minimum
    (MitCommand(-12.5, -50, 0, 0, -18), "0000000000000000"),
    # every field at its maximum
    (MitCommand(12.5, 50, 500, 5, 18), "ffffffffffffffff"),
    # beyond range saturates
    (MitCommand(99, -99, 1e4, -1, 99), "ffff000fff000fff"),
]


@pytest.mark.parametrize(("cmd", "hexdata"), KNOWN_COMMANDS)
def test_known_command_frames(cmd, hexdata):
    assert cm.pack_command(cmd, AK80_9).hex() == hexdata


@pytest.mark.parametrize("model", sorted(cm.MODEL_LIMITS))
def test_roundtrip_at_range_ends(model):
    lim = cm.MODEL_LIMITS[model]
    for c in (
        MitCommand(lim.p_min, lim.v_min, lim.kp_min, lim.kd_min, lim.t_min),
        MitCommand(lim.p_max, lim.v_max, lim.kp_max, lim.kd_max, lim.t_max),
    ):
        back = cm.unpack_command(cm.pack_command(c, lim), lim)
        for a, b in zip(back.__dict__.values(), c.__dict__.values(), strict=True):
            assert a == pytest.approx(b, abs=1e-9)
    for r in (MitReply(3, lim.p_min, lim.v_min, lim.t_min, 40, 0), MitReply(3, lim.p_max, lim.v_max, lim.t_max, 41, 2)):
        back = cm.unpack_reply(cm.pack_reply(r, lim), lim)
        assert back.__dict__ == pytest.approx(r.__dict__)


def test_roundtrip_resolution_mid_range():
    rng = np.random.default_rng(0)
    for _ in range(200):
        c = MitCommand(*rng.uniform([-12.5, -50, 0, 0, -18], [12.5, 50, 500, 5, 18]))
        back = cm.unpack_command(cm.pack_command(c, AK80_9), AK80_9)
        assert abs(back.p_des - c.p_des) <= 25 / 65535
        assert abs(back.v_des - c.v_des) <= 100 / 4095
        assert abs(back.t_ff - c.t_ff) <= 36 / 4095


def test_known_reply_frame():
    # id 1, position 0x8000, velocity 0x800, torque 0x800, 30 degC, no error
    r = cm.unpack_reply(bytes.fromhex("0180008008001e00"), AK80_9)
    assert r.motor_id == 1 and r.temperature == 30 and r.error == 0
    assert r.position == pytest.approx(25 * 0x8000 / 65535 - 12.5)
    short = cm.unpack_reply(bytes.fromhex("018000800800"), AK80_9)
    assert short.temperature is None and short.error is None


def test_special_frames_on_the_bus():
    ch = channel()
    j = FreeJoints()
    spy = can.Bus(interface="virtual", channel=ch)
    with SimCubeMars(j, ch, motor_id=2, sync=True) as node:
        dev = CubeMarsMIT(2, ch, "virtual", zero_on_open=True)
        assert node.enabled
        dev.close()
        assert not node.enabled
    frames = []
    while (m := spy.recv(0.0)) is not None:
        if m.arbitration_id == 2:
            frames.append(bytes(m.data).hex())
    spy.shutdown()
    assert frames[0] == "fffffffffffffffc" and frames[1] == "fffffffffffffffe"
    assert frames[-1] == "fffffffffffffffd"


@pytest.fixture
def rig():
    ch = channel()
    j = FreeJoints()
    node = SimCubeMars(j, ch, motor_id=1, sync=True)
    dev = CubeMarsMIT(1, ch, "virtual", reply_id=0)
    yield j, node, dev
    dev.close()
    node.close()


def test_torque_command_scaling_and_feedback(rig):
    j, node, dev = rig
    dev.command_effort(np.array([5.0]))
    _, c = node.commands[-1]
    assert c.kp == 0 and c.kd == 0 and c.t_ff == pytest.approx(5.0, abs=36 / 4095)
    assert j.measured_force()[0] == pytest.approx(5.0, abs=36 / 4095)
    s = dev.read()  # the reply to the command
    assert s.effort[0] == pytest.approx(5.0, abs=2 * 36 / 4095)
    for _ in range(100):
        j.step(0.001)
    s = dev.read()  # re-sends the last command to get a fresh state
    assert s.position[0] == pytest.approx(j.position()[0], abs=25 / 65535)
    assert s.velocity[0] == pytest.approx(j.velocity()[0], abs=100 / 4095)
    assert dev.temperature == 30


def test_impedance_command(rig):
    j, node, dev = rig
    j._x[:] = 1.0
    dev.command_mit(p_des=0.0, v_des=0.0, kp=10.0, kd=0.0, t_ff=0.0)
    assert node.torque == pytest.approx(-10.0, abs=500 / 4095)  # kp LSB = 0.122


def test_error_code_raises_fault():
    ch = channel()
    j = FreeJoints()
    plan = FaultPlan(error_code=1, error_at_tick=1)
    with SimCubeMars(j, ch, motor_id=1, sync=True, faults=plan) as node, CubeMarsMIT(1, ch, "virtual") as dev:
        dev.command_effort(np.array([1.0]))
        dev.read()
        node.tick()
        dev.command_effort(np.array([1.0]))
        with pytest.raises(DeviceFault) as ei:
            dev.read()
        assert ei.value.code == 1 and "over temperature" in str(ei.value)
        assert j.measured_force()[0] == 0.0


def test_drop_and_corrupt_time_out():
    ch = channel()
    j = FreeJoints()
    plan = FaultPlan(drop_ticks=frozenset({1}), corrupt_ticks=frozenset({2}))
    with SimCubeMars(j, ch, motor_id=1, sync=True, faults=plan) as node, CubeMarsMIT(1, ch, "virtual") as dev:
        for expect in ("timeout", "timeout", "ok"):
            node.tick()
            try:
                dev.read(timeout=0.02)
                got = "ok"
            except DeviceTimeout:
                got = "timeout"
            assert got == expect
        assert dev.error_frames == 1


def test_old_firmware_short_reply():
    ch = channel()
    j = FreeJoints()
    with SimCubeMars(j, ch, motor_id=9, sync=True, short_reply=True), CubeMarsMIT(9, ch, "virtual") as dev:
        s = dev.read()
        assert s.fault == 0 and dev.temperature is None


def test_lockstep_without_sync_uses_tick():
    ch = channel()
    j = FreeJoints()
    node = SimCubeMars(j, ch, motor_id=1)
    try:
        dev = CubeMarsMIT(1, ch, "virtual", enable=False)
        dev.command_effort(np.array([1.0]))
        node.tick()  # answers the command
        s = dev.read(timeout=0.05)
        assert s.seq == 1
        dev.close()
    finally:
        node.close()


def test_reply_arrival_dates_the_sample_and_counters():
    ch = channel()
    j = FreeJoints()
    clock = {"t": 0.0}
    with SimCubeMars(j, ch, motor_id=1, sync=True) as node, \
            CubeMarsMIT(1, ch, "virtual", clock=lambda: clock["t"]) as dev:
        clock["t"] = 1.0
        dev.command_effort(np.array([0.5]))  # the reply is queued on the bus
        clock["t"] = 2.0
        s = dev.read()  # taken off the bus now: dated by its reception (at most one read late)
        assert s.produced_at == 2.0 and s.t == 2.0 and s.age == 0.0 and s.seq == 1
        clock["t"] = 3.0
        s2 = dev.read()  # nothing new: re-sends the last command, a new reply at t = 3
        assert s2.produced_at == 3.0 and s2.seq == 2
        # nothing was dropped (the read took the command's reply), late, or frozen (the re-sent
        # command is the same: its equal reply is a motor at rest) (issue 27)
        assert dev.counters() == {"error_frames": 0, "decode_errors": 0, "skipped": 0, "timeouts": 0}
        assert node.commands_total >= 2


def test_effort_on_wire_is_what_the_motor_applies(rig):
    """effort_on_wire (hil.run.runner's effort_cmd) = the 12-bit t_ff field the motor decodes (manual
    5.3: linear over [T_min, T_max], 4095 steps; truncated like the reference float_to_uint)."""
    j, node, dev = rig
    lim = dev.limits
    step = (lim.t_max - lim.t_min) / 4095
    for u in (5.0, -3.21, 0.0, 1e6):
        wire = dev.effort_on_wire(np.array([u]))[0]
        dev.command_effort(np.array([u]))
        _, c = node.commands[-1]
        assert wire == pytest.approx(c.t_ff, abs=1e-12) == pytest.approx(j.measured_force()[0], abs=1e-12)
        # independent derivation: code = floor((clamp(u) - T_min) * 4095 / span), decoded linearly
        code = math.floor((min(max(u, lim.t_min), lim.t_max) - lim.t_min) / step)
        assert wire == pytest.approx(lim.t_min + code * step, abs=1e-9)


def test_effort_on_wire_applies_the_effort_limit_like_command_effort(rig):
    """The recorded effort of a command beyond the adapter's effort_limit is the clamped one the
    motor receives (command_effort clamps before encoding; effort_on_wire must do the same)."""
    _, node, dev = rig
    dev.effort_limit = 2.0
    wire = dev.effort_on_wire(np.array([7.5]))[0]
    dev.command_effort(np.array([7.5]))
    _, c = node.commands[-1]
    assert wire == pytest.approx(c.t_ff, abs=1e-12)
    assert abs(wire - 2.0) <= (dev.limits.t_max - dev.limits.t_min) / 4095  # one code of the clamp
