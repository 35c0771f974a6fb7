"""The simulated DYNAMIXEL line carries at most baud/10 bytes per simulated second, instructions
and replies together (hil.mocks.dynamixel_devices, ``link_budget=True`` as the bench builds it):
a loop that asks for more loses status packets (the adapter times out: DeviceTimeout), one within
the budget reads exactly what a chain without the budget gives."""

from __future__ import annotations

import numpy as np
import pytest
from simtime import served

from hil.errors import DeviceTimeout
from hil.mocks.dynamixel_devices import DynamixelChain
from hil.mocks.interfaces import FreeJoints
from hil.protocols.dynamixel_x import DynamixelX

pytestmark = pytest.mark.timeout(60)

IDS = [1, 2, 3]
BAUD = 57_600
BYTES_PER_TICK = 28 + 25 * len(IDS)  # sync write + sync read of 3 servos (hil.protocols.link_budget)


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def _loop(dt: float, ticks: int, *, budget: bool, timeout: float = 1.0) -> tuple[list[np.ndarray | None], int]:
    """Positions read per tick (None: timed out) and the replies the line dropped during the loop
    (the adapter's close afterwards, at the same simulated instant, is not counted). The chain is
    served in the test's thread and the adapter waits on simulated time: a reply that was sent is
    always there, one the line dropped times out without any wall-clock wait."""
    clock = Clock()
    plant = FreeJoints(dof=len(IDS), mass=0.01)
    out: list[np.ndarray | None] = []
    with (
        DynamixelChain(plant, IDS, clock=clock, baudrate=BAUD, link_budget=budget, threaded=False) as chain,
        DynamixelX(chain.port, ids=IDS, baudrate=BAUD, clock=clock, waits=served(chain, clock=clock)) as dx,
    ):
        for _ in range(ticks):
            clock.t += dt
            dx.command_effort(np.array([0.05, -0.05, 0.02]), timeout=timeout)
            chain.sync(dx.tx_bytes)
            plant.step(dt)
            try:
                out.append(dx.read(timeout=timeout).position.copy())
            except DeviceTimeout:
                out.append(None)
        dropped = chain.link_dropped
    return out, dropped


def test_compliant_loop_is_unchanged():
    """50 Hz: 103 bytes per tick = 5 150 of 5 760 B/s (89 %)."""
    free, _ = _loop(0.02, 40, budget=False)
    kept, dropped = _loop(0.02, 40, budget=True)
    assert dropped == 0
    assert all(a is not None for a in kept)
    assert all(np.array_equal(a, b) for a, b in zip(free, kept, strict=True))


def test_saturated_line_loses_replies():
    """100 Hz: 103 bytes per tick asked of a line carrying 57.6 per tick. The host's instructions
    (sync write 23 + sync read 17 bytes) always go out (its UART sent them); the servos' 63 bytes
    of status packets only when the line has room left. Independent count: every byte on the line
    comes out of the start-up allowance (0.02 s + 64 bytes; the first tick's bits cannot add to a
    full allowance) and 5 760 B/s after it, less what is left unused (under one reply)."""
    dt, n = 0.01, 60
    got, dropped = _loop(dt, n, budget=True, timeout=0.1)
    ok = sum(a is not None for a in got)
    assert dropped == n - ok > 0
    supply = (BAUD / 10 * 0.02 + 64) + (n - 1) * dt * BAUD / 10
    used = n * (23 + 17) + ok * 63
    assert supply - 63 < used <= supply
    assert 0 < ok < n
