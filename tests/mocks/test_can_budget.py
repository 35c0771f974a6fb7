"""The simulated CAN bus carries at most its bit rate per simulated second
(hil.mocks.can_devices.CanBusBudget): a node whose cyclic traffic exceeds it sees its frames
delayed in arbitration order (the higher-priority heartbeat keeps going, the encoder estimates
starve) and, once its transmit queue is full, lost; a compliant node is unchanged frame for frame.

Bits per frame: worst case with stuffing (hil.protocols.link_budget.can_frame_bits): 135 for an
8-byte frame."""

from __future__ import annotations

import itertools

import can
import pytest

from hil.mocks.can_devices import CAN_TX_QUEUE_LEN, CanBusBudget, SimODrive, frame_bits
from hil.mocks.interfaces import FreeJoints
from hil.protocols import can_odrive as od
from hil.protocols.link_budget import can_frame_bits

_ch = itertools.count()
DT = 0.001
N = 200


def _run(bitrate: float | None, ticks: int = N) -> tuple[list[tuple[int, bytes]], SimODrive]:
    """An ODrive sending a heartbeat and an encoder estimate every tick (2 x 135 bits per 1 ms =
    270 kbit/s; no cyclic Get_Version), seen by a raw python-can listener on the same virtual channel."""
    ch = f"test-can-budget-{next(_ch)}"
    host = can.Bus(interface="virtual", channel=ch)
    node = SimODrive(FreeJoints(1), ch, 3, "virtual", sync=True, dt=DT, heartbeat_every=1, encoder_every=1,
                     cyclic_ms={"Get_Version": 0}, bitrate=bitrate)
    got: list[tuple[int, bytes]] = []
    try:
        for _ in range(ticks):
            node.tick()
            while (m := host.recv(timeout=0.0)) is not None:
                got.append((m.arbitration_id, bytes(m.data)))
    finally:
        node.close()
        host.shutdown()
    return got, node


def test_frame_bits():
    assert frame_bits(can.Message(arbitration_id=1, data=bytes(8))) == can_frame_bits(8) == 135
    assert frame_bits(can.Message(arbitration_id=1, is_remote_frame=True, dlc=8)) == can_frame_bits(0) == 55


def test_compliant_bus_is_unchanged():
    """At 1 Mbit/s (27 % load) every frame goes at once: the same frames, in the same order, as
    without a budget."""
    free, _ = _run(None)
    budgeted, node = _run(1_000_000)
    assert budgeted == free and len(free) == 2 * N
    assert node.budget is not None and node.budget.stats["delayed"] == 0 and node.budget.stats["dropped"] == 0


def test_saturated_bus_delays_by_priority_and_drops():
    """At 135 kbit/s the bus carries one 8-byte frame per 1 ms tick, the node produces two."""
    bitrate = 135_000
    got, node = _run(bitrate)
    b = node.budget
    assert b is not None
    hb_id = (3 << 5) | od.CMD_HEARTBEAT
    enc_id = (3 << 5) | od.CMD_GET_ENCODER_ESTIMATES
    # independent bound: the start-up burst allowance (20 ms of bits + one frame = 2 835 bits) plus
    # 135 bits per simulated ms after the first tick, 135 bits per frame
    cap_bits = bitrate * 0.02 + 135
    carried_bound = int((cap_bits + (N - 1) * DT * bitrate) // 135)
    assert len(got) == carried_bound == 21 + (N - 1)  # exactly what the bus can carry
    assert b.stats["bits"] == 135 * len(got) <= cap_bits + (N - 1) * DT * bitrate
    # arbitration: the heartbeat (lower id) wins every tick; the estimates starve once saturated
    tail = got[-50:]
    assert all(i == hb_id for i, _ in tail)
    # ... one tick late once saturated: the last tick's heartbeat waits for the next tick's bits
    assert sum(1 for i, _ in got if i == hb_id) == N - 1
    assert 0 < sum(1 for i, _ in got if i == enc_id) < N
    # the node keeps its 10 highest-priority frames waiting (CAN_TX_QUEUE_LEN); the rest are lost
    assert len(b.pending) == CAN_TX_QUEUE_LEN
    assert b.stats["dropped"] == 2 * N - len(got) - CAN_TX_QUEUE_LEN
    assert b.stats["delayed"] > 0


def test_host_frames_wait_for_the_bus_too():
    """A host command sent while the bus is saturated reaches the drive only when the bus carries it."""
    ch = f"test-can-budget-{next(_ch)}"
    host = can.Bus(interface="virtual", channel=ch)
    node = SimODrive(FreeJoints(1), ch, 3, "virtual", sync=True, dt=DT, heartbeat_every=0, bitrate=135_000)
    try:
        assert isinstance(node.budget, CanBusBudget)
        node.tick()
        node.budget.credit = 0.0  # bus busy: nothing carried until the next tick's bits
        before = node.frames_in
        host.send(can.Message(arbitration_id=(3 << 5) | od.CMD_SET_INPUT_TORQUE, data=od.encode_f32(0.25),
                              is_extended_id=False))
        assert node.frames_in == before  # waiting for the bus
        node.tick()  # 135 bits more: the 4-byte frame (95 bits) goes
        assert node.frames_in == before + 1
    finally:
        node.close()
        host.shutdown()


def test_budget_needs_lockstep():
    with pytest.raises(ValueError, match="sync=True"):
        SimODrive(FreeJoints(1), f"test-can-budget-{next(_ch)}", 3, "virtual", sync=False, bitrate=1_000_000)
