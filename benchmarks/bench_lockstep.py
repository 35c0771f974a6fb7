"""Benchmark: lockstep throughput of the mocked bench (issue 15).

For every built-in scene, the first experiment runs through the full :class:`hil.run.runner.Runner`
in lockstep (every device read over its real transport: python-can virtual bus, pty, loopback
Modbus; controller, safety, record, plant advance) for ``--ticks`` ticks; the table prints runner
ticks per second (bench opening and record included), the bench alone (read/command/advance with
zero effort, no runner; wall clock, and per second of this process's CPU time, which a loaded
machine disturbs less) and, as the baseline measured in the same run, the scene's physics alone
(``Simulator.tick``).

``--digest`` also prints the SHA-256 over every record channel and ``/t`` of each run (the
bit-identity check: the same seed must give the same digest before and after an optimisation).

Run: ``python benchmarks/bench_lockstep.py [--ticks 2000] [--scenes sdea_bench,...] [--digest]``.
Not a test; prints a table.
"""

from __future__ import annotations

import argparse
import hashlib
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

from hil.bench.runtime import Bench
from hil.run.runner import Runner
from hil.scene.spec import builtin_scenes, load_scene


def record_digest(out_dir: Path) -> str:
    """SHA-256 over ``/t`` and every ``/channels/*`` dataset (name, dtype, shape, bytes) of every
    record file under ``out_dir``, in sorted order."""
    h = hashlib.sha256()
    for p in sorted(out_dir.rglob("*.h5")):
        with h5py.File(p, "r") as f:
            names = ["t"] + [f"channels/{k}" for k in sorted(f["channels"])]
            for n in names:
                a = np.ascontiguousarray(f[n][()])
                h.update(n.encode() + str(a.dtype).encode() + str(a.shape).encode())
                h.update(a.tobytes())
    return h.hexdigest()


def runner_tps(name: str, ticks: int, digest: bool) -> tuple[float, str, str]:
    sc = load_scene(name)
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        o = Runner(sc, d, realtime=False, max_ticks=ticks).run(select=[0])[0]
        dt = time.perf_counter() - t0
        dig = record_digest(Path(d)) if digest else ""
    return ticks / dt, o.status, dig


def bench_tps(name: str, ticks: int) -> tuple[float, float, float]:
    """(bench ticks/s wall clock, bench ticks/s of this process's CPU time, plant-only ticks/s)."""
    sc = load_scene(name)
    with Bench(sc, seed=sc.seed) as bench:
        zero = {a: np.zeros(sc.device(a).dof) for a in bench.actuators}
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(ticks):
            bench.read()
            bench.command(zero)
            bench.advance()
        b, c = time.perf_counter() - t0, time.process_time() - c0
        bench.safe_stop()
    with Bench(sc, seed=sc.seed) as bench:
        sim = bench.simulator
        t0 = time.perf_counter()
        for _ in range(ticks):
            sim.tick()
        p = time.perf_counter() - t0
    return ticks / b, ticks / c, ticks / p


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--ticks", type=int, default=2000, help="lockstep ticks per scene")
    ap.add_argument("--scenes", default="", help="comma-separated scene names (default: every built-in scene)")
    ap.add_argument("--digest", action="store_true", help="print the SHA-256 of each run's record channels")
    a = ap.parse_args()
    names = [s for s in a.scenes.split(",") if s] or [n for n, _ in builtin_scenes()]
    print(f"Lockstep throughput, {a.ticks} ticks per scene (first experiment of each scene)")
    print(f"{'scene':28s} {'runner ticks/s':>15s} {'bench ticks/s':>14s} {'bench CPU t/s':>14s} {'plant ticks/s':>14s}"
          f" {'plant/bench':>12s} status" + ("   record sha256" if a.digest else ""))
    for name in names:
        r, status, dig = runner_tps(name, a.ticks, a.digest)
        b, c, p = bench_tps(name, a.ticks)
        print(f"{name:28s} {r:15.0f} {b:14.0f} {c:14.0f} {p:14.0f} {p / b:12.1f} {status}"
              + (f"   {dig[:16]}" if dig else ""))


if __name__ == "__main__":
    main()
