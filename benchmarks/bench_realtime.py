"""Benchmark: can the realtime loop hold its deadlines? (issue 17; goal: 1 kHz with 0 overruns over
60 s and p99 lateness <= 100 µs; 2 kHz with <= 0.1 % overruns).

For each rate (500 Hz, 1 kHz, 2 kHz), ``sdea_bench``'s locked chirp (f1 capped at rate / 10) runs in realtime mode for
``--seconds`` under three configurations:

* ``before``: the simulated devices in the loop's own process (the in-process bench, plant stepped
  by the loop), sleep-only wait, no realtime scheduling, garbage collector on (what ``hil run
  --realtime`` did before issue 17);
* ``without``: the devices served from another process (:class:`hil.bench.ProcessSimBench`, as at
  a real bench), sleep-only wait, no realtime scheduling, garbage collector on;
* ``with``: the same external devices, the hybrid wait (sleep, then spin the last 200 µs),
  SCHED_FIFO 80 + mlockall + the loop pinned to its own CPU (where permitted), gc frozen/disabled;
* ``stream``: as ``with``, and the ODrive streams its encoder estimates (``feedback: cyclic``) and
  every read takes the newest sample without waiting for a fresh one (``Runner(read_timeout=0)``;
  a device that stops sending is caught by the watchdog on the samples' ``produced_at``). The
  other rows' reads wait for a fresh frame or reply (up to ``watchdog_ms``), which locks each tick
  to the devices' streams.

The late-loop safe stop is relaxed for the benchmark (``max_lateness_ms`` 10 s, overrun fraction
1) so the whole distribution is measured; the device watchdog (50 ms) still applies: a row whose
devices stop answering ends early with its status. Lateness = tick start - deadline (s); overrun =
a tick later than one period. Next to them, in the same run: the machine's wake-up latency
(:func:`hil.realtime.measure_wakeup`, cyclictest's method, and the loop's hybrid wait) with the
same scheduling, and rt-tests' ``cyclictest`` when installed.

Run: ``python benchmarks/bench_realtime.py [--seconds 60] [--rates 500 1000 2000]``. Not a test:
prints tables.
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from hil.bench import Bench, ProcessSimBench
from hil.realtime import holdable_rates, measure_wakeup, realtime_scheduling, run_cyclictest
from hil.record import RunRecord
from hil.runner import Runner
from hil.scene import load_scene, scene_from_dict

CONFIGS = {
    "before": {"bench": Bench, "rt_scheduling": False, "gc_pause": False, "spin_ns": 0},
    "without": {"bench": ProcessSimBench, "rt_scheduling": False, "gc_pause": False, "spin_ns": 0},
    "with": {"bench": ProcessSimBench, "rt_scheduling": True, "gc_pause": True, "spin_ns": None},
    "stream": {"bench": ProcessSimBench, "rt_scheduling": True, "gc_pause": True, "spin_ns": None,
               "feedback": "cyclic", "read_timeout": 0.0},
}


def _scene(rate: float, feedback: str = "poll") -> Any:
    d = yaml.safe_load(load_scene("sdea_bench").source_text)
    if feedback == "cyclic":
        d["devices"][0]["params"]["feedback"] = "cyclic"
    d["rate_hz"] = rate
    d["experiments"] = d["experiments"][:1]
    d["experiments"][0]["f1"] = min(200.0, rate / 10.0)  # the scene's check: f1 <= Nyquist / 5
    d.pop("certification", None)
    d["safety"].update(max_lateness_ms=10_000.0, max_overrun_fraction=1.0)
    return scene_from_dict(d, label=f"sdea_bench@{rate:g}")


def loop_row(rate: float, seconds: float, config: str, tmp: Path) -> dict[str, Any]:
    c = CONFIGS[config]
    sc = _scene(rate, c.get("feedback", "poll"))
    n = round(seconds * rate)
    t0 = time.perf_counter()
    r = Runner(sc, tmp / f"{config}-{rate:g}", realtime=True, max_ticks=n,
               bench_factory=lambda v: c["bench"](sc, seed=sc.seed, variant=v),
               rt_scheduling=c["rt_scheduling"], gc_pause=c["gc_pause"], spin_ns=c["spin_ns"],
               read_timeout=c.get("read_timeout"))
    o = r.run(select=[0])[0]
    wall = time.perf_counter() - t0
    row = {"config": config, "rate": rate, "ticks": o.stats.get("ticks", 0), "status": o.status,
           "reason": o.stop_reason, "sched": o.stats.get("scheduling", ""), "wall": wall}
    if o.record is not None:
        late = RunRecord.open(o.record).channels["loop.late"][:, 0]
        late = late[np.isfinite(late)]
        if late.size:
            row.update(p50=np.percentile(late, 50), p99=np.percentile(late, 99), max=late.max(),
                       overruns=int(np.count_nonzero(late > 1.0 / rate)), frac=np.count_nonzero(late > 1.0 / rate)
                       / late.size)
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="seconds per row")
    ap.add_argument("--rates", type=float, nargs="+", default=[500.0, 1000.0, 2000.0])
    ap.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS))
    args = ap.parse_args(argv)
    logging.disable(logging.WARNING)
    us = 1e6
    print(f"Loop lateness, sdea_bench locked chirp in realtime mode, {args.seconds:g} s per row")
    print(f"{'config':8s} {'rate':>5s} {'ticks':>7s} {'p50 µs':>9s} {'p99 µs':>9s} {'max µs':>9s} {'overruns':>8s} "
          f"{'overrun %':>9s} {'status':12s} scheduling")
    with tempfile.TemporaryDirectory() as d:
        for rate in args.rates:
            for config in args.configs:
                r = loop_row(rate, args.seconds, config, Path(d))
                if "p50" in r:
                    print(f"{config:8s} {rate:5g} {r['ticks']:7d} {us * r['p50']:9.1f} {us * r['p99']:9.1f} "
                          f"{us * r['max']:9.1f} {r['overruns']:8d} {100 * r['frac']:9.3f} {r['status']:12s} "
                          f"{r['sched'] or 'SCHED_OTHER, no measures'}", flush=True)
                else:
                    print(f"{config:8s} {rate:5g} {r['ticks']:7d}  no ticks: {r['status']} {r['reason']}", flush=True)
                if r["status"] != "completed":
                    print(f"{'':8s} stopped: {r['reason']}", flush=True)
    print()
    print(f"Machine wake-up latency, {args.seconds:g} s per row (same run)")
    print(f"{'method':12s} {'sched':6s} {'rate':>5s} {'p50 µs':>9s} {'p99 µs':>9s} {'max µs':>9s} {'overruns':>8s} "
          "holds (p99 <= 10 % period, max < period)")
    for rt in (False, True):
        with realtime_scheduling(enabled=rt) as sched:
            for rate in args.rates:
                for method in ("sleep", "hybrid"):
                    st = measure_wakeup(rate, args.seconds, method=method)
                    held = [f"{k:g}" for k, v in holdable_rates(st).items() if v]
                    print(f"{method:12s} {'FIFO' if 'FIFO' in sched.policy else 'other':6s} {rate:5g} "
                          f"{us * st.p50:9.1f} {us * st.p99:9.1f} {us * st.max:9.1f} {st.overruns:8d} "
                          f"{','.join(held) or '-'}", flush=True)
    for rate in args.rates:
        cyc = run_cyclictest(rate, args.seconds)
        if isinstance(cyc, str):
            print(cyc)
            break
        print(f"{'cyclictest':12s} {'FIFO':6s} {rate:5g} {us * cyc.p50:9.1f} {'(avg)':>9s} {us * cyc.max:9.1f} "
              f"{cyc.overruns:8d}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
