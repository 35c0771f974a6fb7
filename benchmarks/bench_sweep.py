"""Stability maps at scale: points per second against workers and executors, the overhead per
task, and the boundary refinement's verdict count against a uniform grid of the same accuracy.

    python benchmarks/bench_sweep.py [--n 41] [--quick]

Table 1 (same SDEA passivity grid on every row, cache off): wall time, points/s, ratio to the
serial executor measured in the same run, and whether the table is bit-identical to serial.
Table 2: overhead per task (a task of one point minus the verdict's own time), per executor.
Table 3: for the boundary k22_max(b22) at ``n_b`` values of b22, the exact verdicts spent by a
coarse grid + bisection (to ``tol`` × step) against a uniform k22 grid whose spacing equals the
refined accuracy, and the largest error against ``hil design``'s k22_max.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from hil.certify.sweep import DaskExecutor, ProcessExecutor, SerialExecutor, SweepSpec, parse_grid, run_sweep
from hil.models.design import k22_max


def _spec(n: int, chunk: int = 32, refine: bool = False) -> SweepSpec:
    return SweepSpec("sdea", [parse_grid(f"b22=0.03:0.19:{n}"), parse_grid(f"k22=100:500:{n}")],
                     criterion="passivity", chunk=chunk, refine=refine)


def _same(a, b) -> bool:
    return bool(np.array_equal(a.verdict, b.verdict) and np.array_equal(a.margin, b.margin, equal_nan=True))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=41, help="grid points per axis (table 1)")
    ap.add_argument("--quick", action="store_true", help="small sizes (a smoke run)")
    a = ap.parse_args()
    n = 15 if a.quick else a.n
    print(f"machine: {os.cpu_count()} cores; grid {n}×{n} = {n * n} SDEA passivity verdicts\n")

    rows = []
    t0 = time.perf_counter()
    ref = run_sweep(_spec(n), SerialExecutor())
    t_serial = time.perf_counter() - t0
    rows.append(("serial", 1, t_serial, True))
    for w in (1, 2):
        ex = ProcessExecutor(w)
        try:
            t0 = time.perf_counter()
            r = run_sweep(_spec(n), ex)
            rows.append(("process pool", w, time.perf_counter() - t0, _same(ref, r)))
        finally:
            ex.close()
    import distributed

    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cl, \
            distributed.Client(cl) as client:
        t0 = time.perf_counter()
        r = run_sweep(_spec(n), DaskExecutor(client))
        rows.append(("dask LocalCluster", 2, time.perf_counter() - t0, _same(ref, r)))
    print(f"{'executor':>18} {'workers':>7} {'time [s]':>9} {'points/s':>9} {'× serial':>9} {'identical':>9}")
    for name, w, t, same in rows:
        print(f"{name:>18} {w:7d} {t:9.2f} {n * n / t:9.0f} {t_serial / t:9.2f} {same!s:>9}")
    print("(process-pool and dask times include starting the workers)\n")

    # overhead per task: tasks of one point against the in-process time of the same verdicts
    m = 40 if not a.quick else 12
    one = SweepSpec("sdea", [parse_grid(f"k22=100:500:{m}")], params={"b22": 0.1}, criterion="passivity",
                    chunk=1, refine=False)
    t0 = time.perf_counter()
    run_sweep(one, SerialExecutor())
    t_work = (time.perf_counter() - t0) / m
    print(f"{'executor':>18} {'per task [ms]':>13} {'verdict [ms]':>12} {'overhead [ms]':>13}")
    print(f"{'serial':>18} {t_work * 1e3:13.3f} {t_work * 1e3:12.3f} {0.0:13.3f}")
    ex = ProcessExecutor(2)
    try:
        run_sweep(SweepSpec("sdea", [parse_grid("k22=1:2:2")], criterion="passivity"), ex)  # warm the pool
        t0 = time.perf_counter()
        run_sweep(one, ex)
        t = (time.perf_counter() - t0) / m * 2  # two workers: per-task time on one of them
        print(f"{'process pool (2)':>18} {t * 1e3:13.3f} {t_work * 1e3:12.3f} {(t - t_work) * 1e3:13.3f}")
    finally:
        ex.close()
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cl, \
            distributed.Client(cl) as client:
        dx = DaskExecutor(client)
        run_sweep(SweepSpec("sdea", [parse_grid("k22=1:2:2")], criterion="passivity"), dx)
        t0 = time.perf_counter()
        run_sweep(one, dx)
        t = (time.perf_counter() - t0) / m * 2
        print(f"{'dask (2)':>18} {t * 1e3:13.3f} {t_work * 1e3:12.3f} {(t - t_work) * 1e3:13.3f}\n")

    # refinement against a uniform grid of the same accuracy
    nb, nk, tol = (5, 9, 1e-4) if a.quick else (9, 11, 1e-4)
    spec = SweepSpec("sdea", [parse_grid(f"b22=0.03:0.17:{nb}"), parse_grid(f"k22=100:500:{nk}")],
                     criterion="passivity", boundary_tol=tol)
    res = run_sweep(spec, SerialExecutor())
    b, k = res.boundary_curve("k22")
    err = max(abs(ki - k22_max(float(bi)).k22_max) for bi, ki in zip(b, k, strict=True))
    step = 400 / (nk - 1)
    accuracy = tol * step
    uniform = nb * (int(np.ceil(400 / accuracy)) + 1)
    print(f"boundary k22_max(b22) on {nb} b22 lines, accuracy {accuracy:.3g} N.m/rad:")
    print(f"{'method':>26} {'exact verdicts':>15} {'max |err| [N.m/rad]':>20}")
    print(f"{'grid ' + str(nb) + '×' + str(nk) + ' + bisection':>26} {res.evaluations:15d} {err:20.3g}")
    print(f"{'uniform grid, same acc.':>26} {uniform:15d} {'≤ ' + format(accuracy, '.3g'):>20}")
    print(f"ratio: {uniform / res.evaluations:.0f}× fewer verdicts with refinement")


if __name__ == "__main__":
    main()
