"""Benchmark: can the realtime loop hold its deadlines? (issue 17; goal: 1 kHz with 0 overruns over
60 s and p99 lateness <= 100 µs; 2 kHz with <= 0.1 % overruns).

For each rate (500 Hz, 1 kHz, 2 kHz), ``sdea_bench``'s locked chirp (f1 capped at rate / 10) runs in realtime mode for
``--seconds`` under five configurations:

* ``before``: the simulated devices in the loop's own process (the in-process bench, plant stepped
  by the loop), sleep-only wait, no realtime scheduling, garbage collector on (what ``hil run
  --realtime`` did before issue 17);
* ``without``: the devices served from another process (:class:`hil.bench.runtime.ProcessSimBench`, as at
  a real bench), sleep-only wait, no realtime scheduling, garbage collector on, and every read
  waits for a fresh frame or reply (up to ``watchdog_ms``), which locks each tick to the devices;
* ``blocking``: as ``without`` but with the measures: the hybrid wait (sleep, then spin the last
  200 µs), SCHED_FIFO 80 + mlockall + the loop pinned to its own CPU (where permitted), gc
  frozen/disabled; reads still wait;
* ``with``: all the measures and non-blocking reads, the realtime default
  (:data:`hil.run.runner.REALTIME_READ_TIMEOUT_S` = 0): every read takes the newest sample that has
  arrived (the polled ODrive's request for the next tick is sent ahead), a read without a new sample
  is stale (counted in ``stale``); a device that stops sending is caught by the watchdog on the
  samples' age (recorded per tick as ``<device>.age``); the record is written by its writer thread
  (:class:`hil.record.hdf5.RecordWriter` ``background="process"``: a writer thread hands the blocks,
  preallocated in shared memory, to a writer process that makes every h5py call), so no HDF5 write
  runs in a tick and the loop never waits for the GIL held by h5py; the devices' process is pinned
  off the loop's CPU and SCHED_FIFO 70, the writer FIFO 79 off the loop's CPU, the GIL switch
  interval 0.2 ms, the spin 100 µs, and the simulated CAN frames stay on the host (multicast TTL 0);
* ``thread``: as ``with`` but the h5py calls in the writer thread (``Runner.record_process =
  False``; what ``with`` did before the writer process): ~4 ms of HDF5 CPU per 0.1 s block with
  the GIL held;
* ``ttl1``: as ``with`` but the CAN frames also sent out of the network interface (python-can's
  default hop limit 1; what ``with`` did before);
* ``syncrec``: as ``with`` but the record blocks are written and flushed inside the tick that
  fills them (``Runner.record_thread = False``; what ``with`` did before the writer thread);
* ``devother``: as ``with`` but the simulated devices' process left at ordinary scheduling
  (``ProcessSimBench(rt_priority=None)``) instead of SCHED_FIFO 70;
* ``live``: as ``with`` plus ``hil run --live`` (:mod:`hil.run.live`: the Foxglove server in a separate
  process, 50 samples/s offered from the loop through a bounded dropping queue); issue 30's goal: overruns
  no higher than ``with``.

``--phases`` adds, per row, the loop thread's mean CPU time per tick [µs] in each phase of the tick
(``time.thread_time_ns`` around the bench's read and command, the record append, the safety checks,
the wait for the deadline: its spin) and the wall time the loop spent blocked in them (wall - CPU:
waiting for the GIL, or in a syscall).

The late-loop safe stop is relaxed for the benchmark (``max_lateness_ms`` 10 s, overrun fraction
1) so the whole distribution is measured; the device watchdog (50 ms) still applies: a row whose
devices stop answering ends early with its status. Lateness = tick start - deadline (s); overrun =
a tick later than one period. Next to them, in the same run: the machine's wake-up latency
(:func:`hil.run.realtime.measure_wakeup`, cyclictest's method, and the loop's hybrid wait) with the
same scheduling, and rt-tests' ``cyclictest`` when installed.

Run: ``python benchmarks/bench_realtime.py [--seconds 60] [--rates 500 1000 2000]``. Not a test:
prints tables.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import logging
import math
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml  # type: ignore[import-untyped]  # no PyYAML stubs in the env

from hil.bench.runtime import Bench, ProcessSimBench
from hil.record.hdf5 import RunRecord
from hil.run.realtime import holdable_rates, measure_wakeup, realtime_scheduling, run_cyclictest, spin_for, steal_time_s
from hil.run.runner import Runner
from hil.scene.spec import load_scene, scene_from_dict

WATCHDOG_S = 0.050  # sdea_bench's watchdog_ms: the bench's own read timeout on external devices
CONFIGS: dict[str, dict[str, Any]] = {
    "before": {"bench": Bench, "rt_scheduling": False, "gc_pause": False, "spin_ns": 0},
    "without": {"bench": ProcessSimBench, "rt_scheduling": False, "gc_pause": False, "spin_ns": 0,
                "read_timeout": WATCHDOG_S},
    "blocking": {"bench": ProcessSimBench, "rt_scheduling": True, "gc_pause": True, "spin_ns": None,
                 "read_timeout": WATCHDOG_S},
    "with": {"bench": ProcessSimBench, "rt_scheduling": True, "gc_pause": True, "spin_ns": None},
    "thread": {"bench": ProcessSimBench, "rt_scheduling": True, "gc_pause": True, "spin_ns": None,
               "record_process": False},
    "ttl1": {"bench": ProcessSimBench, "rt_scheduling": True, "gc_pause": True, "spin_ns": None, "hop_limit": 1},
    "syncrec": {"bench": ProcessSimBench, "rt_scheduling": True, "gc_pause": True, "spin_ns": None,
                "record_thread": False},
    "devother": {"bench": functools.partial(ProcessSimBench, rt_priority=None), "rt_scheduling": True,
                 "gc_pause": True, "spin_ns": None},
    # "with" plus hil run --live (hil.run.live: its server in a separate process, 50 samples/s offered)
    "live": {"bench": ProcessSimBench, "rt_scheduling": True, "gc_pause": True, "spin_ns": None, "live": True},
}
#: the tick's phases --phases times: (label, object path, attribute)
PHASES = ("wait", "read", "check", "append", "command")


class _PhaseTimes:
    """Per-phase CPU and wall time of the loop thread, accumulated by wrapping the phases' functions."""

    def __init__(self) -> None:
        self.cpu = dict.fromkeys(PHASES, 0)
        self.wall = dict.fromkeys(PHASES, 0)
        self.ticks = 0
        self._undo: list[tuple[Any, str, Any]] = []

    def wrap(self, owner: Any, attr: str, phase: str) -> None:
        fn = getattr(owner, attr)
        cpu, wall, tt, pc = self.cpu, self.wall, time.thread_time_ns, time.perf_counter_ns

        def timed(*a: Any, **kw: Any) -> Any:
            w0, c0 = pc(), tt()
            try:
                return fn(*a, **kw)
            finally:
                cpu[phase] += tt() - c0
                wall[phase] += pc() - w0

        self._undo.append((owner, attr, owner.__dict__.get(attr) if isinstance(owner, type) else None))
        setattr(owner, attr, timed)

    def restore(self) -> None:
        for owner, attr, old in reversed(self._undo):
            if old is None:
                with contextlib.suppress(AttributeError):
                    delattr(owner, attr)
            else:
                setattr(owner, attr, old)
        self._undo.clear()
#: ticks after a record flush (every 0.1 s of run time) whose overruns are attributed to it
FLUSH_SHADOW_TICKS = 8


def _scene(rate: float, seconds: float = 16.0) -> Any:
    """sdea_bench's locked chirp at ``rate``, lasting ``seconds`` (at least the scene's 16 s; periods
    of 2 s as in the scene), without certification, the late-loop stop relaxed."""
    d = yaml.safe_load(load_scene("sdea_bench").source_text)
    d["rate_hz"] = rate
    d["experiments"] = d["experiments"][:1]
    d["experiments"][0]["f1"] = min(200.0, rate / 10.0)  # the scene's check: f1 <= Nyquist / 5
    dur = max(float(d["experiments"][0]["duration"]), 2.0 * math.ceil(seconds / 2.0))
    d["experiments"][0].update(duration=dur, periods=round(dur / 2.0))
    d.pop("certification", None)
    d["safety"].update(max_lateness_ms=10_000.0, max_overrun_fraction=1.0)
    return scene_from_dict(d, label=f"sdea_bench@{rate:g}")


def _process_cpu_s(pid: int) -> float:
    """User + system CPU time [s] of process ``pid`` so far, all its threads (``/proc/PID/stat``); NaN
    where unreadable."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return math.nan


def loop_row(rate: float, seconds: float, config: str, tmp: Path, phases: bool = False) -> dict[str, Any]:
    import hil.bench.runtime as hb
    import hil.run.realtime as hrt
    import hil.run.runner as hrun

    c = CONFIGS[config]
    sc = _scene(rate, seconds)
    n = round(seconds * rate)
    pt = _PhaseTimes() if phases else None

    dev_cpu: list[float] = []

    def make(v: str | None) -> Any:
        b = c["bench"](sc, seed=sc.seed, variant=v)
        proc = getattr(b, "_proc", None)
        if proc is not None:  # the devices' process: its CPU time from the bench's start to just before it stops
            dev_cpu.append(-_process_cpu_s(proc.pid))  # started, warmed up: its imports are not counted
            close = b.close

            def close_measured() -> None:
                dev_cpu[-1] += _process_cpu_s(proc.pid)
                close()

            b.close = close_measured
        if pt is not None:
            pt.wrap(b, "read", "read")
            pt.wrap(b, "command", "command")
        return b

    live = None
    if c.get("live"):
        from hil.run.live import REALTIME_RATE_HZ, LiveView

        live = LiveView(0, process=True, max_rate_hz=REALTIME_RATE_HZ).start()
    t0 = time.perf_counter()
    r = Runner(sc, tmp / f"{config}-{rate:g}", realtime=True, max_ticks=n, bench_factory=make,
               rt_scheduling=c["rt_scheduling"], gc_pause=c["gc_pause"], spin_ns=c["spin_ns"],
               read_timeout=c.get("read_timeout"), live=live)
    r.record_thread = c.get("record_thread", True)
    r.record_process = c.get("record_process", True)
    old_hop = hb.MULTICAST_HOP_LIMIT
    hb.MULTICAST_HOP_LIMIT = c.get("hop_limit", old_hop)
    if pt is not None:
        pt.wrap(hrt.Pacer, "wait", "wait")
        pt.wrap(r, "_append", "append")
        for m in ("check_finite", "check_feedback", "check_command", "check_energy"):
            pt.wrap(hrun.SafetyMonitor, m, "check")
    try:
        o = r.run(select=[0])[0]
    finally:
        hb.MULTICAST_HOP_LIMIT = old_hop
        if pt is not None:
            pt.restore()
        if live is not None:
            live.close()
    wall = time.perf_counter() - t0
    ticks = int(o.stats.get("ticks", 0))
    loop_wall = max(ticks, 1) / rate
    row = {"config": config, "rate": rate, "ticks": ticks, "status": o.status,
           "reason": o.stop_reason, "sched": o.stats.get("scheduling", ""), "wall": wall,
           "dev_cpu": dev_cpu[0] / loop_wall if dev_cpu and math.isfinite(dev_cpu[0]) else math.nan}
    if pt is not None and ticks:
        row["phases"] = {k: (pt.cpu[k] / ticks / 1e3, (pt.wall[k] - pt.cpu[k]) / ticks / 1e3) for k in PHASES}
        row["loop_cpu"] = sum(pt.cpu.values()) / 1e9 / loop_wall
    counters = o.results.get("device_counters", {}) if isinstance(o.results, dict) else {}
    row["stale"] = sum(int(c.get("stale", 0)) for c in counters.values())
    if o.record is not None:
        late = RunRecord.open(o.record).channels["loop.late"][:, 0]
        over = np.flatnonzero(np.isfinite(late) & (late > 1.0 / rate))
        late = late[np.isfinite(late)]
        if late.size:
            flush_every = max(1, round(0.1 * rate))  # the record writer's flush period, in ticks
            row.update(p50=np.percentile(late, 50), p99=np.percentile(late, 99), max=late.max(),
                       overruns=over.size, frac=over.size / late.size,
                       after_flush=int(np.count_nonzero(over % flush_every < FLUSH_SHADOW_TICKS)))
    return row


def summary(rows: list[dict[str, Any]], configs: list[str], rates: list[float]) -> None:
    """Per rate and configuration over the interleaved rounds: rows completed, the overrun fraction of
    every tick run (completed or not), its median over the rounds, and the ratio of each
    configuration's pooled fraction to the first configuration's (the baseline of the same run), and
    the rounds in which its fraction was no higher than the baseline's of the same round (a row
    stopped early counts with the fraction of the ticks it ran)."""
    print()
    print(f"Summary over the rounds (pooled: overruns / ticks of every row of the config; ratio: to {configs[0]!r})")
    print(f"{'config':8s} {'rate':>5s} {'rows':>4s} {'completed':>9s} {'ticks':>8s} {'pooled %':>9s} "
          f"{'median %':>9s} {'ratio':>6s} {'<=base':>7s} {'steal':>7s}")
    for rate in rates:
        base = math.nan
        for config in configs:
            rs = [r for r in rows if r["config"] == config and r["rate"] == rate]
            ticks = sum(int(r["ticks"]) for r in rs)
            over = sum(int(r.get("overruns", 0)) for r in rs)
            pooled = over / ticks if ticks else math.nan
            med = float(np.median([r["frac"] for r in rs if "frac" in r])) if any("frac" in r for r in rs) else math.nan
            if config == configs[0]:
                base = pooled
            done = sum(r["status"] == "completed" for r in rs)
            # paired: rounds in which this config's overrun fraction was no higher than the baseline's
            fr = {r["round"]: r.get("frac", 1.0) for r in rs}
            b0 = {r["round"]: r.get("frac", 1.0) for r in rows if r["config"] == configs[0] and r["rate"] == rate}
            paired = sum(fr[k] <= b0[k] for k in fr if k in b0)
            print(f"{config:8s} {rate:5g} {len(rs):4d} {done:9d} {ticks:8d} {100 * pooled:9.3f} {100 * med:9.3f} "
                  f"{pooled / base if base > 0 else math.nan:6.2f} {paired:3d}/{len(fr):<3d} "
                  f"{sum(r['steal'] for r in rs):5.0f}ms")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="seconds per row")
    ap.add_argument("--rates", type=float, nargs="+", default=[500.0, 1000.0, 2000.0])
    ap.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS))
    ap.add_argument("--phases", action="store_true", help="per-phase CPU time of the loop thread per tick")
    ap.add_argument("--repeat", type=int, default=1,
                    help="rounds of the configurations, interleaved (config A, B, A, B, ...), and a summary per config")
    ap.add_argument("--no-wakeup", action="store_true", help="skip the machine wake-up latency table")
    ap.add_argument("--fifo-only", action="store_true", help="wake-up table: only under SCHED_FIFO (the loop's)")
    args = ap.parse_args(argv)
    logging.disable(logging.WARNING)
    us = 1e6
    print(f"Loop lateness, sdea_bench locked chirp in realtime mode, {args.seconds:g} s per row")
    print(f"load average at start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"{'config':8s} {'rate':>5s} {'ticks':>7s} {'p50 µs':>9s} {'p99 µs':>9s} {'max µs':>9s} {'overruns':>8s} "
          f"{'overrun %':>9s} {'<flush':>6s} {'stale':>6s} {'dev CPU':>7s} {'steal':>7s} {'status':12s} scheduling")
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as d:
        for rate in args.rates:
            for k, config in ((k, c) for k in range(args.repeat) for c in args.configs):
                st0 = 1e3 * steal_time_s()
                (Path(d) / f"{k}").mkdir(exist_ok=True)
                r = loop_row(rate, args.seconds, config, Path(d) / f"{k}", phases=args.phases)
                r["steal"] = 1e3 * steal_time_s() - st0
                r["round"] = k
                rows.append(r)
                if "p50" in r:
                    print(f"{config:8s} {rate:5g} {r['ticks']:7d} {us * r['p50']:9.1f} {us * r['p99']:9.1f} "
                          f"{us * r['max']:9.1f} {r['overruns']:8d} {100 * r['frac']:9.3f} {r['after_flush']:6d} "
                          f"{r['stale']:6d} {100 * r['dev_cpu']:6.0f}% {r['steal']:5.0f}ms {r['status']:12s} "
                          f"{r['sched'] or 'SCHED_OTHER, no measures'}", flush=True)
                else:
                    print(f"{config:8s} {rate:5g} {r['ticks']:7d}  no ticks: {r['status']} {r['reason']}", flush=True)
                if r["status"] != "completed":
                    print(f"{'':8s} stopped: {r['reason']}", flush=True)
                if "phases" in r:
                    ph = r["phases"]
                    print(f"{'':8s} CPU µs/tick: " + ", ".join(f"{k} {ph[k][0]:.0f}" for k in PHASES)
                          + f" (sum {sum(v[0] for v in ph.values()):.0f}, {100 * r['loop_cpu']:.0f} % of its CPU)"
                          + "; blocked µs/tick: "
                          + ", ".join(f"{k} {ph[k][1]:.0f}" for k in PHASES if k != "wait"), flush=True)
    print(f"(<flush: overruns within {FLUSH_SHADOW_TICKS} ticks after a record flush; stale: reads without a "
          "new sample; dev CPU: CPU time of the simulated devices' process, all threads, over the row's run time, "
          "in % of one CPU: the process has every CPU but the loop's; steal: the machine's steal time during the row, "
          "all CPUs)")
    print(f"load average after the loop rows: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    if args.repeat > 1:
        summary(rows, args.configs, args.rates)
    if args.no_wakeup:
        return 0
    print()
    print(f"Machine wake-up latency, {args.seconds:g} s per row (same run; hil check-realtime's measurement)")
    print(f"{'method':12s} {'sched':6s} {'rate':>5s} {'p50 µs':>9s} {'p99 µs':>9s} {'max µs':>9s} {'overruns':>8s} "
          f"{'steal':>7s} holds (p99 <= 10 % period, max < period)")
    for rt in ((True,) if args.fifo_only else (False, True)):
        with realtime_scheduling(enabled=rt) as sched:
            for rate in args.rates:
                for method in ("sleep", "hybrid"):
                    st0 = 1e3 * steal_time_s()
                    st = measure_wakeup(rate, args.seconds, method=method, spin_ns=spin_for(sched))
                    stolen = 1e3 * steal_time_s() - st0
                    held = [f"{k:g}" for k, v in holdable_rates(st).items() if v]
                    print(f"{method:12s} {'FIFO' if 'FIFO' in sched.policy else 'other':6s} {rate:5g} "
                          f"{us * st.p50:9.1f} {us * st.p99:9.1f} {us * st.max:9.1f} {st.overruns:8d} "
                          f"{stolen:5.0f}ms {','.join(held) or '-'}", flush=True)
    for rate in args.rates:
        st0 = 1e3 * steal_time_s()
        cyc = run_cyclictest(rate, args.seconds)
        stolen = 1e3 * steal_time_s() - st0
        if isinstance(cyc, str):
            print(cyc)
            break
        p99 = f"{us * cyc.p99:9.1f}" if np.isfinite(cyc.p99) else f"{'>period':>9s}"
        print(f"{'cyclictest':12s} {'FIFO':6s} {rate:5g} {us * cyc.p50:9.1f} {p99} {us * cyc.max:9.1f} "
              f"{cyc.overruns:8d} {stolen:5.0f}ms", flush=True)
    print(f"load average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
