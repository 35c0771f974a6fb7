"""CubeMars AK (MIT mode) simulator and adapter against the real motor (issue 14, item 1).

Specs followed: CubeMars "AK Series Module Driver User Manual", 5.3 MIT mode (enter motor mode
before control, set zero, the range table: AK60-6 V +-45 rad/s), the 16-bit position field over
[-12.5, 12.5] rad that the motor wraps, and the ~1 s silence after set zero.
"""

from __future__ import annotations

import itertools

import can
import numpy as np
import pytest

from hil.errors import DeviceTimeout
from hil.mocks.can_devices import SimCubeMars
from hil.mocks.interfaces import FreeJoints
from hil.protocols import can_cubemars as cm
from hil.protocols.can_cubemars import CubeMarsMIT, MitCommand

pytestmark = pytest.mark.timeout(20)
_chan = itertools.count()
LIM = cm.model_limits("AK80-9")
LSB_P = (LIM.p_max - LIM.p_min) / 65535  # one position code (rad); float_to_uint truncates


def channel() -> str:
    return f"test-cubemars-fid-{next(_chan)}"


def _send(bus: can.BusABC, motor: int, data: bytes) -> None:
    bus.send(can.Message(arbitration_id=motor, data=data, is_extended_id=False))


def _replies(bus: can.BusABC) -> list[bytes]:
    out = []
    while (m := bus.recv(timeout=0.0)) is not None:
        out.append(bytes(m.data))
    return out


def test_model_table_has_a_source_per_row_and_ak60_6_velocity_is_45():
    """Spec: manual range table, AK60-6 V = +-45 rad/s; every row names its source."""
    assert set(cm.MODEL_SOURCES) == set(cm.MODEL_LIMITS)
    ak60 = cm.model_limits("AK60-6")
    assert (ak60.v_min, ak60.v_max) == (-45.0, 45.0)
    # the 12-bit velocity field spans exactly that range: +45 -> 0xFFF, -45 -> 0x000
    data = cm.pack_command(MitCommand(0, 45.0, 0, 0, 0), ak60)
    assert ((data[2] << 4) | (data[3] >> 4)) == 0xFFF
    data = cm.pack_command(MitCommand(0, -45.0, 0, 0, 0), ak60)
    assert ((data[2] << 4) | (data[3] >> 4)) == 0


def test_commands_before_enter_motor_mode_are_ignored():
    """Spec: in rest mode the motor ignores control commands; enabling afterwards applies no
    torque until a new command arrives (no torque step at enable). Raw python-can host."""
    ch = channel()
    j = FreeJoints()
    with SimCubeMars(j, ch, motor_id=2) as node, can.Bus(interface="virtual", channel=ch) as host:
        _send(host, 2, cm.pack_command(MitCommand(0, 0, 0, 0, 5.0), LIM))
        node.tick()
        assert node.ignored_in_rest == 1 and j.measured_force()[0] == 0.0
        _send(host, 2, cm.SPECIAL_FRAMES["enter"])
        node.tick()
        assert node.enabled and j.measured_force()[0] == 0.0  # the earlier 5 N.m is not applied
        _send(host, 2, cm.pack_command(MitCommand(0, 0, 0, 0, 5.0), LIM))
        node.tick()
        # the applied torque is the decoded 12-bit value: within one code (36/4095 N.m) of 5
        assert j.measured_force()[0] == pytest.approx(5.0, abs=36 / 4095)
        assert len(_replies(host)) == 3  # every frame is answered with the state


def test_position_wraps_in_the_simulator_and_is_unwrapped_by_the_adapter():
    """Spec: the position field covers +-12.5 rad and wraps. At q = 13 rad a raw client reads
    13 - 25 = -12 rad; the adapter, fed a slow ramp from 0 to 40 rad, reports the ramp itself."""
    ch = channel()
    j = FreeJoints()
    with SimCubeMars(j, ch, motor_id=1, sync=True) as node, can.Bus(interface="virtual", channel=ch) as host:
        _send(host, 1, cm.SPECIAL_FRAMES["enter"])
        j._x[:] = 13.0
        _send(host, 1, cm.pack_command(MitCommand(0, 0, 0, 0, 0), LIM))
        raw = cm.unpack_reply(_replies(host)[-1], LIM)
        assert raw.position == pytest.approx(13.0 - 25.0, abs=2 * LSB_P)
        assert node.wrapped_position() == pytest.approx(-12.0)
    ch = channel()
    j = FreeJoints()
    with SimCubeMars(j, ch, motor_id=1, sync=True), CubeMarsMIT(1, ch, "virtual") as dev:
        got = []
        for q in np.arange(0.0, 40.0, 0.5):
            j._x[:] = q
            dev.command_effort(np.zeros(1))
            got.append(dev.read().position[0])
        # each value within 2 codes of the truth (truncation + the float32 of the wrap)
        np.testing.assert_allclose(got, np.arange(0.0, 40.0, 0.5), atol=2 * LSB_P)
        j._x[:] = -30.0  # and back down through two wraps, in steps below half the span
        for q in np.arange(39.5, -30.0, -0.5):
            j._x[:] = q
            dev.command_effort(np.zeros(1))
            last = dev.read().position[0]
        assert last == pytest.approx(-29.5, abs=2 * LSB_P)


def test_set_zero_waits_for_the_motor_silence():
    """Spec: after set zero the motor is silent ~1 s (here 0.3 s to keep the test short): a frame
    sent during the silence gets no answer; the adapter's set_zero waits it out (zero_on_open
    works), and gives DeviceTimeout when its zero_timeout is shorter than the silence."""
    ch = channel()
    j = FreeJoints()
    j._x[:] = 2.0
    with SimCubeMars(j, ch, motor_id=3, sync=True, zero_silence_s=0.3) as node:
        with CubeMarsMIT(3, ch, "virtual", zero_on_open=True) as dev:
            assert node.zero_offset == 2.0
            dev.command_effort(np.zeros(1))
            assert dev.read().position[0] == pytest.approx(0.0, abs=2 * LSB_P)
        with can.Bus(interface="virtual", channel=ch) as host:
            _send(host, 3, cm.SPECIAL_FRAMES["zero"])
            _send(host, 3, cm.SPECIAL_FRAMES["enter"])
            assert _replies(host) == []  # silent
            with pytest.raises(DeviceTimeout):  # even "enter motor mode" gets no answer now
                CubeMarsMIT(3, ch, "virtual")
    ch = channel()
    with SimCubeMars(j, ch, motor_id=3, sync=True, zero_silence_s=0.3), \
            pytest.raises(DeviceTimeout, match="silent"):
        CubeMarsMIT(3, ch, "virtual", zero_on_open=True, zero_timeout=0.05)


def test_mit_law_is_recomputed_between_commands():
    """Spec: the AK driver evaluates tau = kp (p_des - q) + kd (v_des - qd) + t_ff in its loop (manual
    5.3, MIT power mode block diagram), not once per command. K = 200 N.m/rad, B = 2 N.m.s/rad,
    J = 0.02 kg.m^2, a step to 0.05 rad commanded at 40 Hz (every 25 ticks of 1 ms), 2 s.

    Second method: the exact sampled-data model of the same loop (FreeJoints integrates a constant
    torque exactly: q += v dt + a dt^2 / 2, v += a dt) with the law evaluated every tick from the
    decoded command (the wire's 12/16-bit quantization) matches the twin to rounding; the same
    model with the law held for 25 ms (what the twin did before issue 29) does not settle; the
    continuous-time closed loop (zeta = 0.5, omega = 100 rad/s) is within the tick's hold of it."""
    J, K, B, P = 0.02, 200.0, 2.0, 0.05  # K P = 10 N.m: within the AK80-9's 18 N.m (linear loop)
    ch = channel()
    j = FreeJoints(1, J)
    sent = cm.pack_command(MitCommand(P, 0.0, K, B, 0.0), LIM)
    c = cm.unpack_command(sent, LIM)  # what the motor decodes
    twin = []
    with SimCubeMars(j, ch, motor_id=1, sync=True) as node, can.Bus(interface="virtual", channel=ch) as host:
        _send(host, 1, cm.SPECIAL_FRAMES["enter"])
        for k in range(2000):
            if k % 25 == 0:
                _send(host, 1, sent)
            j.step(0.001)
            node.tick()
            twin.append(j.position()[0])
        _replies(host)

    def sampled(hold: int) -> np.ndarray:
        q = v = tau = 0.0
        out = []
        for k in range(2000):
            if k % hold == 0:
                tau = min(max(c.kp * (c.p_des - q) + c.kd * (c.v_des - v) + c.t_ff, LIM.t_min), LIM.t_max)
            a = tau / J
            q, v = q + v * 0.001 + 0.5 * a * 1e-6, v + a * 0.001
            out.append(q)
        return np.array(out)

    twin = np.array(twin)
    np.testing.assert_allclose(twin, sampled(1), rtol=0, atol=1e-9)
    # settled at the equilibrium of the decoded law (v = 0): kp (p_des - q) + kd v_des + t_ff = 0
    assert abs(twin[-1] - (c.p_des + (c.kd * c.v_des + c.t_ff) / c.kp)) < 1e-6
    held = sampled(25)
    assert np.ptp(held[-500:]) > 0.5  # the once-per-command law keeps oscillating (diverging)
    zeta, w = B / (2 * np.sqrt(K * J)), np.sqrt(K / J)
    wd, t = w * np.sqrt(1 - zeta ** 2), np.arange(1, 2001) * 1e-3
    q_eq = c.p_des + (c.kd * c.v_des + c.t_ff) / c.kp
    cont = q_eq * (1 - np.exp(-zeta * w * t) * (np.cos(wd * t) + zeta * w / wd * np.sin(wd * t)))
    # the tick's hold delays the law by dt/2 (w dt/2 = 0.05 rad of phase): a few % of the step
    assert np.max(np.abs(twin - cont)) < 0.1 * P
