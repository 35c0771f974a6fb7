"""Memory of long-lived Dask workers across successive sweeps (issue 27 item 13).

    python benchmarks/bench_dask_memory.py [--sweeps 6] [--n 25]

One worker process (a LocalCluster with one single-threaded worker) serves ``--sweeps`` identical
sweeps (cache off) through one :class:`hil.certify.sweep.DaskExecutor`. After every sweep the table
shows the worker's resident memory [MB] (from /proc) in two configurations measured in the same run:

* ``as before``: the worker's statistical profiler on (distributed's default) and nothing released
  after a map (the executor's release step replaced by a no-op);
* ``now``: what ``hil sweep --executor dask`` without ``--scheduler`` does (profiler off for the
  cluster it starts) and the release after every map (:func:`hil.certify.executors._trim_memory`: the
  profiler's history and the task logs forgotten, garbage collected, freed heap returned).

A plain loop (the same tasks called in this process, no Dask) is the baseline column. The last
line gives each column's growth from sweep 1 to the last sweep [MB]."""

from __future__ import annotations

import argparse
import os
from typing import Any

import dask
import distributed

import hil.certify.executors as executors
from hil.certify.sweep import DaskExecutor, SerialExecutor, SweepSpec, parse_grid, run_sweep


def _rss_mb() -> float:
    with open("/proc/self/statm", encoding="ascii") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


def _spec(n: int) -> SweepSpec:
    return SweepSpec("sdea", [parse_grid(f"b22=0.03:0.19:{n}"), parse_grid(f"k22=100:500:{n}")],
                     criterion="passivity", chunk=8, refine=True)


def _series(n: int, sweeps: int, release: bool, profile: bool) -> list[float]:
    keep = executors._release_worker_memory
    if not release:
        executors._release_worker_memory = lambda client: None  # type: ignore[assignment]
    try:
        with dask.config.set({"distributed.worker.profile.enabled": profile}), \
                distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                         dashboard_address=None) as cl, distributed.Client(cl) as client:
            ex = DaskExecutor(client)
            out = []
            for _ in range(sweeps):
                run_sweep(_spec(n), ex)
                rss: Any = client.run(_rss_mb)
                out.append(float(next(iter(rss.values()))))
            return out
    finally:
        executors._release_worker_memory = keep


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sweeps", type=int, default=6)
    ap.add_argument("--n", type=int, default=25, help="grid points per axis")
    a = ap.parse_args()
    before = _series(a.n, a.sweeps, release=False, profile=True)
    now = _series(a.n, a.sweeps, release=True, profile=False)
    plain = []
    for _ in range(a.sweeps):
        run_sweep(_spec(a.n), SerialExecutor())
        plain.append(_rss_mb())
    print(f"{a.sweeps} sweeps of {a.n}x{a.n} points (refined), worker RSS after each [MB]")
    print(f"{'sweep':>5} {'as before':>10} {'now':>8} {'plain loop':>11}")
    for i in range(a.sweeps):
        print(f"{i + 1:>5} {before[i]:>10.1f} {now[i]:>8.1f} {plain[i]:>11.1f}")
    print(f"{'grew':>5} {before[-1] - before[0]:>10.1f} {now[-1] - now[0]:>8.1f} {plain[-1] - plain[0]:>11.1f}")


if __name__ == "__main__":
    main()
