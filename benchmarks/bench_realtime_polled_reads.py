"""What a read costs inside the tick for the polled adapters (issue 17): blocking (the request and
its answer inside the tick, what these adapters did before) against non-blocking (``timeout=0``:
collect the answer to the request sent ahead, send the next one).

Per device, ``--ticks`` ticks of a ``--rate`` Hz loop: the loop sleeps to its next tick (the
simulated device, in a process of its own as the realtime runner serves them, answers meanwhile,
as a real device answers while the host waits), then the timed part: ``read`` (and, for
actuators, ``command_effort``: the DYNAMIXEL adapter sends its sync read after the sync write).
Printed: median and p99 wall time of the timed part (us), its median CPU time of this thread
(us), the fraction of fresh samples, and the ratio blocking / non-blocking measured in the same
run. CAN runs on python-can's
``udp_multicast`` interface (a process-local virtual bus cannot cross processes).

    python benchmarks/bench_realtime_polled_reads.py [--rate 1000] [--ticks 2000]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np


def _serve(kind: str, conn: Any) -> None:
    """Child process: the simulated device, answering on its own until told to stop."""
    import numpy as np

    from hil.mocks.interfaces import FreeJoints

    if kind == "dynamixel":
        from hil.mocks.dynamixel_devices import DynamixelChain

        dev: Any = DynamixelChain(FreeJoints(2), [1, 2], baudrate=1_000_000, return_delay=0)
        conn.send(dev.port)
    elif kind.startswith("ft300"):
        from hil.mocks.modbus_devices import SimulatedFT300

        dev = SimulatedFT300(lambda: np.ones(6), framing=kind.split("-")[1])
        conn.send(dev.url)
    else:
        from hil.mocks.cia402_drive import SimCiA402

        dev = SimCiA402(FreeJoints(1, 0.01), CAN_GROUP, 7, "udp_multicast", dt=0.001, heartbeat_ms=0, port=CAN_PORT)
        dev.start(1000.0)
        conn.send(CAN_GROUP)
    conn.recv()
    dev.close()


#: a site-local multicast group and port of this benchmark's own (python-can udp_multicast)
CAN_GROUP, CAN_PORT = "239.255.74.17", 43917


@contextmanager
def served(kind: str) -> Iterator[Any]:
    """The adapter, talking to its simulated device in another process (as in realtime runs)."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    parent, child = ctx.Pipe()
    proc = ctx.Process(target=_serve, args=(kind, child), daemon=True)
    proc.start()
    try:
        address = parent.recv()
        if kind == "dynamixel":
            from hil.protocols.dynamixel_x import DynamixelX

            dev: Any = DynamixelX(address, [1, 2], baudrate=1_000_000, timeout=0.1)
        elif kind.startswith("ft300"):
            from hil.protocols.modbus_robotiq import RobotiqFT300

            dev = RobotiqFT300(address, timeout=0.1)
        else:
            from hil.protocols.cia402 import CiA402Drive

            dev = CiA402Drive(7, address, "udp_multicast", timeout=0.1, heartbeat_ms=0, port=CAN_PORT)
        try:
            yield dev
        finally:
            dev.close()
    finally:
        parent.send("stop")
        proc.join(5.0)
        if proc.is_alive():
            proc.kill()


DEVICES: dict[str, str] = {
    "dynamixel_x (2 servos, 1 Mbps)": "dynamixel",
    "robotiq_ft300 (Modbus/TCP)": "ft300-tcp",
    "robotiq_ft300 (RTU over TCP)": "ft300-rtu",
    "cia402 (SYNC + 2 TPDOs)": "cia402",
}


def measure(dev: Any, timeout: float, rate: float, ticks: int) -> tuple[float, float, float, float]:
    """(median us, p99 us, median CPU us, fresh fraction) of read (+ command) per tick."""
    period = 1.0 / rate
    actuator = hasattr(dev, "command_effort")
    zero = np.zeros(getattr(dev, "dof", 1))
    wall = np.empty(ticks)
    cpu = np.empty(ticks)
    fresh = 0
    last = dev.read(timeout=0.1 if timeout else 0.0).seq
    next_t = time.perf_counter() + period
    for k in range(ticks):
        delay = next_t - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        next_t += period
        t0, c0 = time.perf_counter(), time.thread_time()
        s = dev.read(timeout=timeout)
        if actuator:
            dev.command_effort(zero, timeout=0.01)
        wall[k], cpu[k] = time.perf_counter() - t0, time.thread_time() - c0
        fresh += s.seq != last
        last = s.seq
    return (float(np.median(wall)) * 1e6, float(np.percentile(wall, 99)) * 1e6, float(np.median(cpu)) * 1e6,
            fresh / ticks)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--ticks", type=int, default=2000)
    a = ap.parse_args()
    print(f"read (+ command) per tick at {a.rate:.0f} Hz, {a.ticks} ticks; us (wall median / p99, CPU median)")
    print(f"{'device':32s} {'mode':13s} {'median':>8s} {'p99':>8s} {'cpu':>7s} {'fresh':>6s}  ratio")
    for name, kind in DEVICES.items():
        rows = {}
        for mode, timeout in (("blocking", 0.1), ("non-blocking", 0.0)):
            with served(kind) as dev:
                rows[mode] = measure(dev, timeout, a.rate, a.ticks)
        for mode, (med, p99, cpu, fr) in rows.items():
            ratio = rows["blocking"][0] / med if mode == "non-blocking" else 1.0
            print(f"{name:32s} {mode:13s} {med:8.0f} {p99:8.0f} {cpu:7.0f} {fr:6.2f}  {ratio:5.1f}")


if __name__ == "__main__":
    main()
