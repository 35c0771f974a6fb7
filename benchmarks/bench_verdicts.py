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
(about 30 s on one core). A before/after comparison runs the same script against another
checkout of ``hil`` (``PYTHONPATH=<that checkout> python benchmarks/bench_verdicts.py``).
Results: docs/BENCHMARKS.md, "Exact verdict time (issue 15)".
"""

from __future__ import annotations

import itertools
import statistics
import time
from collections.abc import Callable
from functools import partial

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


def _call(make: Callable[[], TransferMatrix], crit: Callable[..., object], **kw: bool) -> object:
    return crit(make(), **kw)


def main(reps: int = 41) -> None:
    hdr = (f"{'work':34s} {'verdict':22s} {'exact':>10s} {'no margins':>11s} {'grid 1e4':>10s} "
           f"{'exact/grid':>10s} {'nm/grid':>8s}")
    print("Exact verdict time, warm median per call (fresh network each call), against a 1e4-point numpy grid")
    print(hdr)
    print("-" * len(hdr))
    for name, make, crit, kind in rows():
        tm = make()
        verdict = crit(tm).verdict  # type: ignore[attr-defined]
        te = median_time(partial(_call, make, crit), reps)
        tb = median_time(make, reps)  # building the network, subtracted
        try:
            crit(make(), margins=False)
            tn = median_time(partial(_call, make, crit, margins=False), reps) - tb
        except TypeError:  # an older hil.stability without the switch (for before/after runs)
            tn = float("nan")
        te -= tb
        tg = median_time(partial(grid, tm, kind), max(5, reps // 4))
        print(f"{name:34s} {verdict!s:22s} {te * 1e6:8.0f}µs {tn * 1e6:9.0f}µs {tg * 1e6:8.0f}µs "
              f"{te / tg:10.2f} {tn / tg:8.2f}")
    print("(exact: the criterion with margins; no margins: verdict only (margins=False); times are process CPU "
          "time, excluding building the network; grid: numpy, decides nothing exactly)")


if __name__ == "__main__":
    main()
