"""Closed-loop lockstep ticks per second over the Modbus and DYNAMIXEL transports (not a test).

Each tick of a transport row does what a lockstep runner does with a real adapter and a simulated
device on the other side of a real transport:

* ``dynamixel pty``: sync write Goal Current -> wait until the chain processed it -> step the
  plant -> sync read Present Current/Velocity/Position (2 servos on one pty);
* ``ft300 modbus-tcp`` / ``ft300 rtu-over-tcp``: step the plant -> one FC03 read of 180-185 over
  loopback TCP.

The baseline does the same plant step and unit conversions without any transport. The ratio
column is (mean tick time) / (baseline mean tick time), measured in the same run.

Usage: ``python benchmarks/bench_transports_modbus_dynamixel.py [--ticks N]``
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np

from hil.mocks.dynamixel_devices import DynamixelChain
from hil.mocks.interfaces import FreeJoints
from hil.mocks.modbus_devices import SimulatedFT300, wrench_to_registers
from hil.protocols.dynamixel_x import DynamixelX, decode_present_block, effort_to_current_raw
from hil.protocols.modbus_robotiq import RobotiqFT300, registers_to_wrench

DT = 0.001


def _measure(tick: Callable[[int], None], n: int, warmup: int = 20) -> np.ndarray:
    for k in range(warmup):
        tick(k)
    out = np.empty(n)
    for k in range(n):
        t0 = time.perf_counter()
        tick(k)
        out[k] = time.perf_counter() - t0
    return out


def _baseline(n: int) -> np.ndarray:
    plant = FreeJoints(dof=2)
    kt, lim, d = np.full(2, 1.78), np.full(2, 1193), np.ones(2)
    block = bytes(10)

    def tick(k: int) -> None:
        raw = effort_to_current_raw(np.array([0.1, -0.1]) * np.sin(k * DT), kt, lim, d)
        plant.apply_effort(raw * 2.69e-3 * kt)
        plant.step(DT)
        decode_present_block(block)
        registers_to_wrench(wrench_to_registers(plant.measured_force()))

    return _measure(tick, n)


def _dynamixel(n: int) -> np.ndarray:
    plant = FreeJoints(dof=2, mass=0.05)
    with DynamixelChain(plant, ids=[1, 2]) as chain, DynamixelX(chain.port, ids=[1, 2]) as dx:

        def tick(k: int) -> None:
            dx.command_effort(np.array([0.1, -0.1]) * np.sin(k * DT))
            chain.sync(dx.tx_bytes)
            plant.step(DT)
            dx.read()

        return _measure(tick, n)


def _ft300(n: int, framing: str) -> np.ndarray:
    plant = FreeJoints(dof=6)
    with SimulatedFT300(plant, framing=framing) as sim, RobotiqFT300(sim.url, read_info=False) as ft:

        def tick(k: int) -> None:
            plant.apply_effort(np.full(6, np.sin(k * DT)))
            plant.step(DT)
            ft.read()

        return _measure(tick, n)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ticks", type=int, default=1000)
    args = ap.parse_args()
    rows = [("baseline (no transport)", _baseline(args.ticks))]
    rows.append(("dynamixel pty, 2 servos", _dynamixel(args.ticks)))
    rows.append(("ft300 modbus-tcp", _ft300(args.ticks, "tcp")))
    rows.append(("ft300 rtu-over-tcp", _ft300(args.ticks, "rtu")))
    base = rows[0][1].mean()
    print(f"{'transport':<26} {'ticks/s':>10} {'mean us':>10} {'p99 us':>10} {'x baseline':>11}")
    for name, t in rows:
        print(
            f"{name:<26} {1.0 / t.mean():>10.0f} {t.mean() * 1e6:>10.1f} "
            f"{np.percentile(t, 99) * 1e6:>10.1f} {t.mean() / base:>11.1f}"
        )


if __name__ == "__main__":
    main()
