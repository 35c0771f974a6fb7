"""Benchmark: time of one exact verdict (issue 15's rows) against a 1e4-point numpy grid.

Rows (each the criterion the CLI would run): a passive one-port of degree 4, the SDEA two-port
(paper 002 Table I, hybrid form) by two-port passivity and by Llewellyn, the MCET 3-port of paper
000 (k_vm1 = 64) by Theorem 1, and the 2-DOF bilateral teleoperator of paper 000 (4×4, gains A1)
by Theorem 1. For each: the exact verdict with margins, without margins (verdict only), a
10⁴-point numpy grid of the same frequency conditions (which decides nothing exactly), the ratios
exact/grid (python-control's ``ispassive``, issue 15's third baseline, is not a dependency of this
project and is not run). Warm medians of process CPU time over repeated calls; the network
object is fresh for each call (no per-object cache).

Not a test: prints a table, asserts nothing. Run: ``python benchmarks/bench_verdicts.py``
(about 30 s on one core). Before/after in the same run: ``python benchmarks/bench_verdicts.py
--before <root of another checkout>`` times the verdict-only path with that checkout's ``hil``
in child processes interleaved with this one's (``--rounds`` each, per-row medians), and stops
if any verdict differs.
Results: docs/BENCHMARKS.md, "Exact verdict time (issue 15)".
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from functools import partial
from typing import cast

import numpy as np

from hil.models.sdea import sdea_vsic
from hil.models.teleop import bilateral_2dof, mcet_trilateral
from hil.stability.criteria import _freq_range, absolute_stability, llewellyn, positive_real, two_port_passivity
from hil.stability.rational import Rational, S, TransferMatrix


def one_port_degree4() -> TransferMatrix:
    """A resistor plus two damped resonances (degree 4), passive."""
    z = 1.0 + 0.3 * 2.0 * S / (S**2 + 0.02 * S + 4.0) + 0.5 * 30.0 * S / (S**2 + 3.0 * S + 900.0)
    assert isinstance(z, Rational)
    return TransferMatrix([[z]])


def rows() -> list[tuple[str, Callable[[], TransferMatrix], Callable[..., object], str]]:
    return [
        ("one-port, degree 4", one_port_degree4, positive_real, "E"),
        ("SDEA two-port passivity", sdea_vsic, two_port_passivity, "E"),
        ("SDEA Llewellyn", sdea_vsic, llewellyn, "L"),
        ("MCET 3-port, Theorem 1", lambda: mcet_trilateral(k_vm1=64), absolute_stability, "T"),
        ("2-DOF bilateral (4x4), Theorem 1", lambda: bilateral_2dof("A1"), absolute_stability, "T"),
    ]


def grid(tm: TransferMatrix, kind: str, n: int = 10_000) -> float:
    """The smallest value of the frequency conditions on n log-spaced points (numpy): principal
    minors of G + Gᴴ (E), Llewellyn's η (L), principal minors of Re Z with the symmetrized
    off-diagonal products (T, as sign(z_ij)·√(z_ij z_ji) pointwise)."""
    lo, hi = _freq_range(tm.entries)
    w = np.geomspace(lo, hi, n)
    G = tm.freq(w)
    if kind == "L":
        c = G[:, 0, 1] * G[:, 1, 0]
        eta = 2 * G[:, 0, 0].real * G[:, 1, 1].real - c.real - np.abs(c)
        return float(min(np.min(G[:, 0, 0].real), np.min(G[:, 1, 1].real), np.min(eta)))
    if kind == "T":
        R = G.real.copy()
        for i, j in itertools.combinations(range(tm.n), 2):
            r = np.sqrt(G[:, i, j] * G[:, j, i]).real
            R[:, i, j] = R[:, j, i] = r
        H = 2 * R
    else:
        H = (G + np.conj(np.swapaxes(G, 1, 2))).real
    worst = np.inf
    for k in range(1, tm.n + 1):
        for sel in itertools.combinations(range(tm.n), k):
            sub = H[:, sel][:, :, sel]
            worst = min(worst, float(np.min(np.linalg.det(sub))))
    return worst


def median_time(f: Callable[[], object], reps: int) -> float:
    """Median process CPU time of f() (warm): on a shared machine wall time also counts the time
    other processes hold the core."""
    f()
    ts = []
    for _ in range(reps):
        t0 = time.process_time()
        f()
        ts.append(time.process_time() - t0)
    return statistics.median(ts)


def median_time_fresh(make: Callable[[], TransferMatrix], crit: Callable[..., object], reps: int,
                      **kw: bool) -> float:
    """Median process CPU time of ``crit(tm, **kw)`` over ``reps`` calls, each on a network built
    beforehand by ``make()`` (fresh: nothing cached on it), after one warm-up call. Building the
    network is outside the timed region (no subtraction of separately measured medians)."""
    nets = [make() for _ in range(reps + 1)]
    crit(nets[0], **kw)
    ts = []
    for tm in nets[1:]:
        t0 = time.process_time()
        crit(tm, **kw)
        ts.append(time.process_time() - t0)
    return statistics.median(ts)


def measure(reps: int, grid_too: bool = True) -> list[dict[str, object]]:
    """One pass over the rows: verdict, exact time with margins, verdict-only time, grid time (s)."""
    out: list[dict[str, object]] = []
    for name, make, crit, kind in rows():
        tm = make()
        verdict = str(crit(tm).verdict)  # type: ignore[attr-defined]
        verdict_nm = str(crit(make(), margins=False).verdict)  # type: ignore[attr-defined]
        te = median_time_fresh(make, crit, reps)
        tn = median_time_fresh(make, crit, reps, margins=False)
        tg = median_time(partial(grid, tm, kind), max(5, reps // 4)) if grid_too else math.nan
        out.append({"name": name, "verdict": verdict, "verdict_nm": verdict_nm, "exact": te, "nm": tn, "grid": tg})
    return out


def _child(before: str | None, reps: int, grid_too: bool) -> list[dict[str, object]]:
    """The measurement in a fresh interpreter, with ``hil`` imported from ``before`` (a checkout's
    root) when given, else from this checkout."""
    env = dict(os.environ)
    if before:
        env["PYTHONPATH"] = before + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    cmd = [sys.executable, os.path.abspath(__file__), "--child", "--reps", str(reps)]
    if not grid_too:
        cmd.append("--no-grid")
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
    return cast("list[dict[str, object]]", json.loads(res.stdout.strip().splitlines()[-1]))


def main(reps: int = 41, before: str | None = None, rounds: int = 3) -> None:
    if before is None:
        res = measure(reps)
        tb: list[float] = [math.nan] * len(res)
    else:
        # before/after interleaved in the same run: `rounds` child processes each, alternating,
        # per-row median over the rounds (the load of a shared machine drifts over a run)
        runs_a: list[list[dict[str, object]]] = []
        runs_b: list[list[dict[str, object]]] = []
        for r in range(rounds):
            runs_b.append(_child(before, reps, grid_too=False))
            runs_a.append(_child(None, reps, grid_too=r == 0))
        res = runs_a[0]
        for k, row in enumerate(res):
            for key in ("exact", "nm"):
                row[key] = statistics.median(float(cast(float, ra[k][key])) for ra in runs_a)
            vb = {str(rb[k]["verdict_nm"]) for rb in runs_b} | {str(rb[k]["verdict"]) for rb in runs_b}
            va = {str(ra[k]["verdict_nm"]) for ra in runs_a} | {str(ra[k]["verdict"]) for ra in runs_a}
            if vb != va:
                raise SystemExit(f"verdicts differ on {row['name']}: before {vb}, after {va}")
        tb = [statistics.median(float(cast(float, rb[k]["nm"])) for rb in runs_b) for k in range(len(res))]
    hdr = (f"{'work':34s} {'verdict':22s} {'exact':>9s} {'no margins':>11s} {'before':>9s} {'speed-up':>8s} "
           f"{'grid 1e4':>9s} {'grid/nm':>8s}")
    print("Exact verdict time, warm median per call (fresh network each call), against a 1e4-point numpy grid")
    print(hdr)
    print("-" * len(hdr))
    for row, b in zip(res, tb, strict=True):
        te, tn, tg = (float(cast(float, row[k])) for k in ("exact", "nm", "grid"))
        print(f"{row['name']!s:34s} {row['verdict']!s:22s} {te * 1e6:7.0f}µs {tn * 1e6:9.0f}µs "
              f"{b * 1e6:7.0f}µs {b / tn:7.2f}x {tg * 1e6:7.0f}µs {tg / tn:7.1f}x")
    print("(exact: the criterion with margins; no margins: verdict only (margins=False); before: verdict only "
          "with the hil given by --before, same run, interleaved; grid/nm: how many times faster the verdict-only "
          "exact path is than the grid; times are process CPU time, excluding building the network; grid: numpy, "
          "decides nothing exactly)")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=41)
    ap.add_argument("--before", help="root of another checkout whose hil is timed in the same run (before/after)")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved child runs per side with --before")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--no-grid", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        print(json.dumps(measure(a.reps, grid_too=not a.no_grid)))
    else:
        main(a.reps, a.before, a.rounds)
