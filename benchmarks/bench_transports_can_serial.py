"""Closed-loop ticks per second in lockstep over real transports (not a test).

Each tick: command torque, step FreeJoints by dt, read joint feedback, read wrench.

* baseline: the same loop calling FreeJoints directly (no transport);
* odrive/virtual-can: ODriveCAN <-> SimODrive (sync replies) over a python-can virtual bus,
  polling feedback (RTR) - the sensor read is done directly on FreeJoints;
* bota/pty: the actuator is FreeJoints directly, the wrench comes from SimBota over a pty;
* odrive+bota: both transports in the loop.

Usage: python benchmarks/bench_transports_can_serial.py [--ticks N]
Target: >= 2000 ticks/s over virtual CAN on one core.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np

from hil.mocks.interfaces import FreeJoints
from hil.mocks.odrive_device import SimODrive
from hil.mocks.serial_devices import SimBota
from hil.protocols.can_odrive import ODriveCAN
from hil.protocols.serial_bota import BotaSerial

DT = 0.001


def _time_loop(tick: Callable[[int], None], n: int) -> np.ndarray:
    for k in range(min(200, n)):  # warm-up
        tick(k)
    out = np.empty(n)
    pc = time.perf_counter
    for k in range(n):
        t0 = pc()
        tick(k)
        out[k] = pc() - t0
    return out


def bench(n: int) -> list[tuple[str, np.ndarray]]:
    results = []
    u = np.zeros(1)

    # baseline
    j = FreeJoints()

    def base(k: int) -> None:
        u[0] = -1.0 * j.position()[0] + 0.1
        j.apply_effort(u)
        j.step(DT)
        j.position(), j.velocity()
        j.measured_force()

    results.append(("baseline (FreeJoints)", _time_loop(base, n)))

    # ODrive over virtual CAN
    j = FreeJoints()
    # polled, as before the factory cyclic messages (issue 29): no heartbeat, estimates or version frames
    node = SimODrive(j, "bench-can", node_id=1, sync=True, heartbeat_every=0, encoder_every=0,
                     cyclic_ms={"Get_Version": 0})
    dev = ODriveCAN(1, "bench-can", "virtual", clock=lambda: 0.0)

    def odrive(k: int) -> None:
        dev.command_effort(u)
        j.step(DT)
        node.tick()
        s = dev.read(timeout=0.05)
        u[0] = -1.0 * s.position[0] + 0.1
        j.measured_force()

    results.append(("odrive / virtual CAN", _time_loop(odrive, n)))

    # Bota over pty
    j2 = FreeJoints()
    sim = SimBota(j2)
    sensor = BotaSerial(sim.path, clock=lambda: 0.0)

    def bota(k: int) -> None:
        j2.apply_effort(u)
        j2.step(DT)
        j2.position(), j2.velocity()
        sim.emit()
        w = sensor.read(timeout=0.05)
        u[0] = 0.1 - 0.01 * w.wrench[2]

    results.append(("bota / pty", _time_loop(bota, n)))

    # both
    def both(k: int) -> None:
        dev.command_effort(u)
        j.step(DT)
        node.tick()
        s = dev.read(timeout=0.05)
        sim.emit()
        sensor.read(timeout=0.05)
        u[0] = -1.0 * s.position[0] + 0.1

    sim.joints = j
    results.append(("odrive CAN + bota pty", _time_loop(both, n)))
    dev.close()
    node.close()
    sensor.close()
    sim.close()
    return results


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--ticks", type=int, default=5000)
    args = ap.parse_args()
    results = bench(args.ticks)
    base_mean = results[0][1].mean()
    print(f"{'transport':26s} {'ticks/s':>10s} {'mean us':>9s} {'p99 us':>9s} {'x baseline':>11s}")
    for name, t in results:
        print(
            f"{name:26s} {1.0 / t.mean():10.0f} {t.mean() * 1e6:9.1f} {np.percentile(t, 99) * 1e6:9.1f}"
            f" {t.mean() / base_mean:11.1f}"
        )


if __name__ == "__main__":
    main()
