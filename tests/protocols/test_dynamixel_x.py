"""DynamixelX adapter against the simulated servo chain over a real pty.

The chain is served in the test's thread and the adapter waits on simulated time (``tests/simtime``):
nothing here depends on how fast the machine runs, and "no hang" is the simulated time a wait took."""

from __future__ import annotations

import math

import numpy as np
import pytest
from simtime import served

from hil.errors import ChecksumError, DeviceDisconnected, DeviceFault, DeviceTimeout
from hil.mocks.dynamixel_devices import (
    ADDR_GOAL_CURRENT,
    ADDR_OPERATING_MODE,
    ADDR_TORQUE_ENABLE,
    DynamixelChain,
)
from hil.mocks.faults import FaultPlan
from hil.mocks.interfaces import FreeJoints
from hil.protocols.base import Actuator
from hil.protocols.dynamixel_x import (
    CURRENT_UNIT_A,
    MODELS,
    DynamixelX,
    decode_present_block,
    effort_to_current_raw,
    to_signed,
    to_unsigned,
)

pytestmark = pytest.mark.timeout(120)

KT = MODELS["XM430-W350"].torque_constant

SIGNED = [
    # (unsigned, bytes, signed)
    (0x0000, 2, 0),
    (0x7FFF, 2, 32767),
    (0x8000, 2, -32768),
    (0xFF38, 2, -200),
    (0xFFFFFFFF, 4, -1),
    (0x80000000, 4, -(2**31)),
    (4095, 4, 4095),
]


@pytest.mark.parametrize(("unsigned", "nbytes", "signed"), SIGNED)
def test_twos_complement(unsigned: int, nbytes: int, signed: int) -> None:
    assert to_signed(unsigned, nbytes) == signed
    assert to_unsigned(signed, nbytes) == unsigned


def test_to_unsigned_overflow() -> None:
    with pytest.raises(OverflowError):
        to_unsigned(70000, 2)


CURRENTS = [
    # effort N.m, direction, expected raw (kt = 4.1/2.3, unit 2.69 mA, limit 1193)
    (0.0, 1, 0),
    (KT * 200 * CURRENT_UNIT_A, 1, 200),
    (-KT * 200 * CURRENT_UNIT_A, 1, -200),
    (KT * 200 * CURRENT_UNIT_A, -1, -200),
    (1.0, 1, round(1.0 / KT / CURRENT_UNIT_A)),  # 1 N.m ~ 209 counts
    (100.0, 1, 1193),  # clamped to Current Limit
    (-100.0, 1, -1193),
]


@pytest.mark.parametrize(("effort", "direction", "raw"), CURRENTS)
def test_effort_to_current(effort: float, direction: int, raw: int) -> None:
    out = effort_to_current_raw(np.array([effort]), np.array([KT]), np.array([1193]), np.array([direction]))
    assert out.tolist() == [raw]


def test_decode_present_block() -> None:
    # current -200, velocity -3, position 2079 (e-manual sync read example value)
    block = (0xFF38).to_bytes(2, "little") + (2**32 - 3).to_bytes(4, "little") + (2079).to_bytes(4, "little")
    assert decode_present_block(block) == (-200, -3, 2079)


# ---- adapter against the simulated chain ------------------------------------------------------
def Chain(*args, **kw) -> DynamixelChain:
    """A chain served in the test's thread (the adapter's waits run it: :func:`simtime.served`)."""
    return DynamixelChain(*args, threaded=False, **kw)


def _tick(dx: DynamixelX, chain: DynamixelChain, plant: FreeJoints, effort, dt: float = 0.01):
    """One lockstep tick: command, wait until the chain processed it, step physics, read."""
    dx.command_effort(np.asarray(effort, dtype=float))
    chain.sync(dx.tx_bytes)
    plant.step(dt)
    return dx.read()


def test_open_configures_current_mode_and_torque() -> None:
    plant = FreeJoints(dof=3)
    with Chain(plant, ids=[3, 5, 7]) as chain, DynamixelX(chain.port, waits=served(chain), ids=[3, 5, 7]) as dx:
        assert isinstance(dx, Actuator) and dx.dof == 3 and dx.units == "rotary"
        assert dx.info.model == "XM430-W350" and dx.info.firmware == "45"
        assert dx.current_limit.tolist() == [1193] * 3
        for servo in chain.servos.values():
            assert servo.table[ADDR_OPERATING_MODE] == 0 and servo.table[ADDR_TORQUE_ENABLE] == 1
    for servo in chain.servos.values():  # close(): zero current, torque off
        assert servo.table[ADDR_TORQUE_ENABLE] == 0
        assert servo.get(ADDR_GOAL_CURRENT, 2, signed=True) == 0


def test_commands_arrive_with_the_right_scaling() -> None:
    plant = FreeJoints(dof=3)
    with (
        Chain(plant, ids=[1, 2, 3]) as chain,
        DynamixelX(chain.port, waits=served(chain), ids=[1, 2, 3], directions=[1, -1, 1], current_limit=1000) as dx,
    ):
        effort = np.array([0.5, 0.5, -50.0])
        dx.command_effort(effort)
        chain.sync(dx.tx_bytes)
        raw = [chain.servos[i].get(ADDR_GOAL_CURRENT, 2, signed=True) for i in (1, 2, 3)]
        expected = round(0.5 / KT / CURRENT_UNIT_A)
        assert raw == [expected, -expected, -1000]  # direction flip; clamp to the user limit
        np.testing.assert_allclose(plant.measured_force(), np.array(raw) * CURRENT_UNIT_A * KT)


def test_feedback_decodes_signed_si_values() -> None:
    plant = FreeJoints(dof=2, mass=0.01)
    with Chain(plant, ids=[1, 2]) as chain, DynamixelX(chain.port, waits=served(chain), ids=[1, 2]) as dx:
        s = _tick(dx, chain, plant, [0.2, -0.3], dt=0.05)
        q_true, v_true = plant.position(), plant.velocity()
        assert q_true[1] < 0 and v_true[1] < 0
        np.testing.assert_allclose(s.position, q_true, atol=2 * math.pi / 4096)
        np.testing.assert_allclose(s.velocity, v_true, atol=0.229 * 2 * math.pi / 60)
        raw = dx.current_command(np.array([0.2, -0.3]))
        np.testing.assert_allclose(s.effort, raw * CURRENT_UNIT_A * KT)
        assert s.seq == 1 and s.fault == 0


def test_directions_and_zero_offset() -> None:
    plant = FreeJoints(dof=1, mass=0.01)
    with (
        Chain(plant, ids=[4]) as chain,
        DynamixelX(chain.port, waits=served(chain), ids=[4], directions=[-1], zero_ticks=[100]) as dx,
    ):
        s = _tick(dx, chain, plant, [0.1], dt=0.05)
        # a positive command drives the servo negative; position reported relative to tick 100
        assert plant.position()[0] < 0 and s.position[0] > 0 and s.velocity[0] > 0
        ticks = round(plant.position()[0] * 4096 / (2 * math.pi))
        assert s.position[0] == pytest.approx(-(ticks - 100) * 2 * math.pi / 4096)


def _trajectory(seed: int) -> np.ndarray:
    plant = FreeJoints(dof=2, mass=0.05)
    rng = np.random.default_rng(seed)
    out = []
    with Chain(plant, ids=[1, 2]) as chain, DynamixelX(chain.port, waits=served(chain), ids=[1, 2]) as dx:
        for _ in range(20):
            s = _tick(dx, chain, plant, rng.normal(0, 0.3, 2), dt=0.002)
            out.append(np.concatenate([s.position, s.velocity, s.effort]))
    return np.array(out)


def test_lockstep_run_is_deterministic() -> None:
    a, b = _trajectory(5), _trajectory(5)
    assert np.array_equal(a, b)


@pytest.mark.parametrize(
    ("plan", "exc"),
    [
        (FaultPlan(drop_ticks=[0]), DeviceTimeout),
        (FaultPlan(disconnect_at_tick=0), DeviceTimeout),
        (FaultPlan(corrupt_ticks=[0]), ChecksumError),
    ],
)
def test_faults_during_open_surface_as_exceptions(plan: FaultPlan, exc: type[Exception]) -> None:
    with Chain(FreeJoints(1), ids=[1], faults=plan) as chain:
        waits = served(chain)
        with pytest.raises(exc):
            DynamixelX(chain.port, waits=waits, ids=[1], timeout=0.05, scan_baudrates=False)  # no second ping
        # at most the adapter's timeout of simulated time (its first ping's too: it was a fixed
        # 100 ms), no second ping: no hang
        assert waits.waited <= 0.05 + 1e-6


def _opened(plan: FaultPlan, ids=(1, 2)):
    plant = FreeJoints(dof=len(ids))
    chain = Chain(plant, ids=list(ids), faults=plan)
    dx = DynamixelX(chain.port, waits=served(chain), ids=list(ids), timeout=0.05)
    return plant, chain, dx


# open(): ping, read limit, read firmware, torque off, read Return Delay Time, write it (factory
# 250 -> 0), mode, Bus Watchdog off, zero goal, torque on = 10 packets per servo
OPEN_TICKS = 20


def test_read_faults_surface_as_exceptions_and_recover() -> None:
    t = OPEN_TICKS
    plan = FaultPlan(
        drop_ticks=[t], corrupt_ticks=[t + 1], error_code=0x20, error_at_tick=t + 2, error_until_tick=t + 4
    )
    _, chain, dx = _opened(plan)
    try:
        assert chain.tick == t - 1
        with pytest.raises(DeviceTimeout):
            dx.read()
        with pytest.raises(ChecksumError):
            dx.read()
        with pytest.raises(DeviceFault) as info:
            dx.read()  # alert bit -> the adapter reads Hardware Error Status(70)
        assert info.value.code == 0x20  # overload error bit
        sample = dx.read()  # recovered
        assert sample.seq == 1
    finally:
        dx.close()
        chain.close()


def test_disconnected_chain_times_out_without_hanging() -> None:
    plan = FaultPlan(disconnect_at_tick=OPEN_TICKS)
    _, chain, dx = _opened(plan)
    try:
        dx.command_effort(np.array([0.1, 0.1]))  # a sync write never waits: no error
        waited = dx._waits.waited
        with pytest.raises(DeviceTimeout):
            dx.read(timeout=0.03)
        assert dx._waits.waited - waited == pytest.approx(0.03)  # the read's timeout, then no more
    finally:
        dx.close()
        chain.close()


def test_stale_feedback_repeats_previous_values() -> None:
    plant, chain, dx = _opened(FaultPlan(stale_prob=1.0), ids=(1,))
    try:
        first = _tick(dx, chain, plant, [0.5])
        second = _tick(dx, chain, plant, [0.5])
        assert np.array_equal(first.position, second.position) and chain.stale_replies >= 1
        assert second.seq == first.seq + 1
    finally:
        dx.close()
        chain.close()


def test_close_is_idempotent_and_blocks_further_use() -> None:
    with Chain(FreeJoints(1), ids=[1]) as chain:
        dx = DynamixelX(chain.port, waits=served(chain), ids=[1])
        dx.close()
        dx.close()
        with pytest.raises(DeviceDisconnected):
            dx.read()


def test_bad_port_raises() -> None:
    with pytest.raises(DeviceDisconnected):
        DynamixelX("/dev/does-not-exist-hil", ids=[1])


def test_invalid_ids() -> None:
    with pytest.raises(ValueError):
        DynamixelX("/dev/null", ids=[1, 1])


# -- Bus Watchdog(98) and freshness -------------------------------------------------------------
def test_bus_watchdog_units_round_up() -> None:
    from hil.protocols.dynamixel_x import bus_watchdog_units

    assert [bus_watchdog_units(s) for s in (0.001, 0.02, 0.021, 0.05, 0.1, 10.0)] == [1, 1, 2, 3, 5, 127]
    with pytest.raises(ValueError):
        bus_watchdog_units(0.0)


def test_bus_watchdog_armed_on_open_stops_the_servo_when_the_host_goes_silent() -> None:
    """Simulated clock: the host talks every 1 ms for 10 ms, then is silent; the 40 ms Bus Watchdog
    (2 units) stops the servo at the first check more than 40 ms after the last packet, and the
    adapter reports it as a DeviceFault on its next check."""
    from hil.mocks.dynamixel_devices import ADDR_BUS_WATCHDOG

    clock = {"t": 0.0}
    plant = FreeJoints(dof=1)
    with Chain(plant, ids=[1], clock=lambda: clock["t"]) as chain, \
            DynamixelX(chain.port, waits=served(chain), ids=[1], bus_watchdog_s=0.04, watchdog_check_every=1,
                       clock=lambda: clock["t"]) as dx:
        assert chain.servos[1].table[ADDR_BUS_WATCHDOG] == 2
        for k in range(10):
            clock["t"] = k * 0.001
            dx.command_effort(np.array([0.2]))
            s = dx.read()
            assert s.produced_at == s.t == k * 0.001 and s.seq == k + 1
        assert chain.effort()[0] != 0.0
        last = clock["t"]
        expired_at = None
        for k in range(1, 100):  # the host is silent; the bench would call check_watchdog per tick
            clock["t"] = last + k * 0.001
            if chain.check_watchdog():
                expired_at = clock["t"]
                break
        assert expired_at == pytest.approx(last + 0.041)  # first tick with silence > 40 ms
        assert chain.effort()[0] == 0.0 and plant.measured_force()[0] == 0.0
        assert chain.servos[1].table[ADDR_BUS_WATCHDOG] == 0xFF
        with pytest.raises(DeviceFault) as ei:
            dx.read()
        assert ei.value.code == 0x200 and dx.counters()["bus_watchdog_errors"] == 1
        # goal values are refused until 98 is cleared (a new open clears it)
        dx.command_effort(np.array([0.3]))
        chain.sync(dx.tx_bytes)
        assert chain.servos[1].get(ADDR_GOAL_CURRENT, 2, signed=True) == 0


def test_bus_watchdog_kept_fed_by_a_running_host() -> None:
    clock = {"t": 0.0}
    plant = FreeJoints(dof=1)
    with Chain(plant, ids=[1], clock=lambda: clock["t"]) as chain, \
            DynamixelX(chain.port, waits=served(chain), ids=[1], bus_watchdog_s=0.02, watchdog_check_every=10,
                       clock=lambda: clock["t"]) as dx:
        for k in range(200):
            clock["t"] = k * 0.005
            dx.command_effort(np.array([0.1]))
            dx.read()
            assert chain.check_watchdog() == []
        assert chain.watchdog_expired == 0 and dx.counters() == {"crc_errors": 0, "timeouts": 0,
                                                                 "bus_watchdog_errors": 0}


def test_effort_on_wire_is_what_the_servo_applies() -> None:
    """effort_on_wire (hil.run.runner's effort_cmd) = the Goal Current the servo receives (2.69 mA
    units, clamped to the Current Limit), decoded back to N.m in the joint frame (direction)."""
    plant = FreeJoints(dof=3)
    with (
        Chain(plant, ids=[1, 2, 3]) as chain,
        DynamixelX(chain.port, waits=served(chain), ids=[1, 2, 3], directions=[1, -1, 1], current_limit=1000) as dx,
    ):
        effort = np.array([0.5003, 0.5003, -50.0])
        wire = dx.effort_on_wire(effort)
        dx.command_effort(effort)
        chain.sync(dx.tx_bytes)
        # the plant gets the servo-frame torque; the joint frame flips joint 2 back
        np.testing.assert_allclose(wire, np.array([1, -1, 1]) * plant.measured_force(), rtol=1e-12)
        step = CURRENT_UNIT_A * KT
        assert abs(wire[0] - 0.5003) <= step / 2 and wire[0] != 0.5003  # rounded to one current unit
        assert wire[2] == pytest.approx(-1000 * step)  # the clamp


def test_effort_on_wire_applies_the_effort_limit_like_command_effort() -> None:
    """A command beyond effort_limit is recorded as the clamped effort the servo receives."""
    plant = FreeJoints(dof=1)
    with Chain(plant, ids=[1]) as chain, DynamixelX(chain.port, waits=served(chain), ids=[1], current_limit=1000) as dx:
        dx.effort_limit = 0.2
        wire = dx.effort_on_wire(np.array([0.9]))
        dx.command_effort(np.array([0.9]))
        chain.sync(dx.tx_bytes)
        np.testing.assert_allclose(wire, plant.measured_force(), rtol=1e-12)
        assert abs(wire[0] - 0.2) <= CURRENT_UNIT_A * KT / 2  # the clamp, rounded to one current unit
