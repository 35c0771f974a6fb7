"""Benchmark: the experiment loop.

1. Realtime mode at each scene's rate (1 kHz for most): how late each tick starts after its
   absolute deadline (percentiles), overruns (ticks later than one period), on this machine.
2. Lockstep throughput of every built-in scene: full runner ticks per second (read every device
   over its transport, controller, excitation, safety, record, advance the plant) against a
   baseline measured in the same run: the scene's physics alone (Simulator.tick).

Run: ``python benchmarks/bench_runner.py [--seconds 5]``. Not a test; prints tables.
"""

from __future__ import annotations

import argparse
import tempfile
import time

import numpy as np

from hil.bench.runtime import Bench
from hil.run.runner import Runner
from hil.scene.spec import builtin_scenes, load_scene


class _InstantBench:
    """Stand-in bench whose devices answer instantly: isolates the loop's own scheduling jitter
    (a real rig's devices run on their own hardware, not in this process)."""

    def __init__(self, scene) -> None:
        from hil.protocols.base import JointSample, WrenchSample

        self.scene = scene
        self._k = 0
        self._JS, self._WS = JointSample, WrenchSample

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        pass

    def read(self):
        out = {}
        for d in self.scene.devices:
            if d.role == "actuator":
                z = np.zeros(d.dof)
                out[d.name] = self._JS(self._k * 1e-3, self._k, z, z.copy())
            else:
                out[d.name] = self._WS(self._k * 1e-3, self._k, np.zeros(6))
        for g in self.scene.groups:
            n = self.scene.device(g.name).dof
            out[g.name] = self._JS(self._k * 1e-3, self._k, np.zeros(n), np.zeros(n))
        return out

    def force(self, meas, sensor):
        return np.asarray(meas[sensor].wrench)[self.scene.device(sensor).wrench_axes]

    def command(self, u) -> None:
        pass

    def set_human_force(self, port, f) -> None:
        pass

    def advance(self) -> None:
        self._k += 1

    def safe_stop(self) -> None:
        pass

    def device_identities(self):
        return {}


def loop_only(name: str, seconds: float) -> dict:
    sc = load_scene(name)
    n = int(seconds * sc.rate_hz)
    with tempfile.TemporaryDirectory() as d:
        o = Runner(sc, d, realtime=True, max_ticks=n, bench_factory=lambda v: _InstantBench(sc)).run(select=[0])[0]
    return {"scene": name + " (instant devices)", "rate": sc.rate_hz, "status": o.status, **o.stats}


def realtime(name: str, seconds: float) -> dict:
    sc = load_scene(name)
    n = int(seconds * sc.rate_hz)
    with tempfile.TemporaryDirectory() as d:
        o = Runner(sc, d, realtime=True, max_ticks=n).run(select=[0])[0]
    return {"scene": name, "rate": sc.rate_hz, "status": o.status, **o.stats}


def lockstep(name: str, ticks: int) -> dict:
    sc = load_scene(name)
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        o = Runner(sc, d, realtime=False, max_ticks=ticks).run(select=[0])[0]
        full = time.perf_counter() - t0
    with Bench(sc, seed=sc.seed) as bench:
        sim = bench.simulator
        t0 = time.perf_counter()
        for _ in range(ticks):
            sim.tick()
        base = time.perf_counter() - t0
    return {"scene": name, "status": o.status, "ticks": o.stats.get("ticks", ticks), "runner_tps": ticks / full,
            "plant_tps": ticks / base, "ratio": full / base}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=5.0, help="realtime run length per scene")
    ap.add_argument("--ticks", type=int, default=2000, help="lockstep ticks per scene")
    a = ap.parse_args()
    print("Realtime loop (absolute deadlines on the monotonic clock)")
    print(f"{'scene':40s} {'rate':>6s} {'ticks':>7s} {'late p50':>10s} {'late p99':>10s} {'late max':>10s} "
          f"{'overruns':>9s} status")
    rows = [loop_only("mcet_trilateral", a.seconds), loop_only("bilateral_2dof_A1", a.seconds)]
    rows += [realtime(n, a.seconds) for n in ("mcet_trilateral", "bilateral_2dof_A1", "dynamixel_leader_follower")]
    for r in rows:
        name = r["scene"]
        print(f"{name:40s} {r['rate']:6.0f} {r['ticks']:7d} {r.get('late_p50_us', np.nan):8.1f}µs "
              f"{r.get('late_p99_us', np.nan):8.1f}µs {r.get('late_max_us', np.nan):8.1f}µs {r['overruns']:9d} "
              f"{r['status']}")
    print("\nLockstep throughput (as fast as possible; the plant advances one period per tick)")
    print(f"{'scene':28s} {'ticks':>6s} {'runner ticks/s':>15s} {'plant-only ticks/s':>19s} {'ratio':>7s} status")
    for name, _ in builtin_scenes():
        r = lockstep(name, a.ticks)
        print(f"{name:28s} {r['ticks']:6d} {r['runner_tps']:15.0f} {r['plant_tps']:19.0f} {r['ratio']:7.1f} "
              f"{r['status']}")


if __name__ == "__main__":
    main()
