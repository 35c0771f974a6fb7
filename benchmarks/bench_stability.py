"""Benchmark: exact stability decisions vs frequency grids, and batch throughput.

Prints two tables (not a test; no assertions):

1. Hard cases: for each, the exact verdict and its time, then for grids of 1e2..1e5 log-spaced
   points: the grid's verdict, whether it missed the violation, the error of its margin against
   the exact margin (docs/VERDICTS.md), and its time (ratio to the exact time measured in the same run).
2. Throughput over 1e4 posterior-like draws of the SDEA model: the vectorized batch path vs the
   general exact criterion (timed on a subset and extrapolated), with their agreement.

3. Verdict time per network size (one-port of degree 2..8, two-port, three-port, 4×4): the exact
   verdict with and without margins against a 1e4-point numpy grid of the same frequency
   conditions, measured in the same run (issue 11; speed goal of issue 15: one-port ≤ 50 µs,
   two-port ≤ 200 µs).

Run: ``python benchmarks/bench_stability.py`` (about a minute on one core);
``python benchmarks/bench_stability.py sizes`` runs table 3 only.
"""

from __future__ import annotations

import math
import time

import numpy as np

from hil.models.batch import sdea_passivity_batch
from hil.models.design import k22_max
from hil.models.sdea import SDEA_TABLE1, sdea_vsic
from hil.models.teleop import dual_master_3dof, mcet_trilateral, termination_T1
from hil.stability.criteria import (
    _freq_range,
    _hermitian_ratio,
    absolute_stability,
    margin_curve,
    positive_real,
    two_port_passivity,
)
from hil.stability.rational import Rational, TransferMatrix


def narrow_band(w0: float, rel: float) -> Rational:
    x0 = w0 * w0
    eps = rel * x0
    d1 = 0.6 * w0
    return Rational.from_desc([1.0, -eps * eps / (x0 * d1), (x0 * x0 - eps * eps) / x0], [1.0, d1, x0])


def cases() -> list[tuple[str, TransferMatrix, str]]:
    kmax = k22_max(0.17, 1.0, "passivity").k22_max
    return [
        ("one-port, band 5e-5 wide @100 rad/s", TransferMatrix([[narrow_band(100.0, 5e-5)]]), "pr"),
        ("one-port, band 1e-6 wide @3e4 rad/s", TransferMatrix([[narrow_band(3e4, 1e-6)]]), "pr"),
        ("SDEA k22 = 1.0001 k22_max (passivity)", sdea_vsic(k22=kmax * 1.0001), "pr"),
        ("SDEA nominal (Table I)", sdea_vsic(), "pr"),
        ("000 T1 termination", termination_T1(), "pr"),
        ("000 MCET k_vm1 = 64.01", mcet_trilateral(k_vm1=64.01), "eta"),
        ("001 Table I k_pmyz = 300", dual_master_3dof(k_pmyz=300, k_psxz=0, k_vsxz=0), "nport"),
    ]


def exact(tm: TransferMatrix, kind: str):
    if kind == "pr":
        return two_port_passivity(tm) if tm.n_ports == 2 else positive_real(tm)
    return absolute_stability(tm)


def grid_verdict(tm: TransferMatrix, kind: str, n: int) -> tuple[str, float, float]:
    """Sampled check of the frequency conditions only (what a sweep-based tool does): the minimum
    over n log-spaced points of the same quantity whose exact minimum is the reported margin
    (p/m_r, docs/VERDICTS.md; built once, outside the timing), or for Theorem 1 n-ports the
    normalized Hermitian minors of Z."""
    import itertools

    lo, hi = _freq_range(tm.entries)
    w = np.geomspace(lo * 1e-1, hi * 1e1, n)
    idx = list(range(tm.n))
    if kind == "eta":
        sub = TransferMatrix([[tm[0, 0], tm[0, 1]], [tm[1, 0], tm[1, 1]]], "impedance", (1, 1))
        fns = [margin_curve(sub, "L1"), margin_curve(sub, "L2")]
    elif kind == "pr":
        fns = [margin_curve(tm, "E{" + ",".join(str(i + 1) for i in sel) + "}")
               for k in range(1, tm.n + 1) for sel in itertools.combinations(idx, k)]
    else:
        fns = [_hermitian_ratio([[tm[i, j] for j in sel] for i in sel])
               for k in range(1, tm.n + 1) for sel in itertools.combinations(idx, k)]
    t0 = time.perf_counter()
    vals = np.full(w.size, np.inf)
    for f in fns:
        vals = np.minimum(vals, f(w))
    dt = time.perf_counter() - t0
    m = float(np.min(vals))
    return ("potentially_unstable" if m < 0 else "stable"), m, dt


def table_hard_cases() -> None:
    print("\nExact decision vs frequency grids (hard cases)")
    hdr = f"{'case':40s} {'exact':22s} {'t_exact':>9s} | " + " | ".join(
        f"{'grid ' + f'{n:.0e}':>10s} {'miss':>4s} {'|Δm|':>8s} {'t/t_ex':>7s}" for n in (1e2, 1e3, 1e4, 1e5))
    print(hdr)
    print("-" * len(hdr))
    for name, tm, kind in cases():
        t0 = time.perf_counter()
        r = exact(tm, kind)
        te = time.perf_counter() - t0
        row = f"{name:40s} {r.verdict!s:22s} {te * 1e3:7.1f}ms | "
        cells = []
        for n in (100, 1000, 10_000, 100_000):
            v, m, tg = grid_verdict(tm, kind, n)
            miss = "YES" if (r.verdict == "potentially_unstable" and v == "stable") else "no"
            dm = abs(m - r.margin) if math.isfinite(r.margin) else float("nan")
            cells.append(f"{v[:10]:>10s} {miss:>4s} {dm:8.1e} {tg / te:7.2f}")
        print(row + " | ".join(cells))
    print("(grid columns check only the frequency conditions; 'miss' = a real violation the grid did not see;"
          " |Δm| = error of the grid's minimum of p/m_r against the exact margin)")


def table_throughput(n: int = 10_000, n_exact: int = 200) -> None:
    rng = np.random.default_rng(0)
    draws = {k: SDEA_TABLE1[k] * np.exp(0.05 * rng.normal(size=n)) for k in ("K_f", "B_f", "M", "B")}
    draws["k22"] = rng.uniform(300.0, 450.0, n)
    t0 = time.perf_counter()
    res = sdea_passivity_batch(draws)
    tb = time.perf_counter() - t0
    idx = rng.choice(n, n_exact, replace=False)
    t0 = time.perf_counter()
    agree = 0
    for i in idx:
        v = two_port_passivity(sdea_vsic({k: float(draws[k][i]) for k in draws})).verdict
        agree += (v == "stable") == bool(res["passive"][i])
    te = (time.perf_counter() - t0) / n_exact
    print(f"\nThroughput: {n} SDEA draws (K_f, B_f, M, B ±5 % log-normal; k22 ∈ [300, 450])")
    print(f"{'method':34s} {'time':>10s} {'per draw':>10s} {'ratio':>8s}")
    print(f"{'batch (closed form, vectorized)':34s} {tb:9.3f}s {tb / n * 1e6:8.1f}µs {1.0:8.2f}")
    print(f"{'general exact (extrapolated)':34s} {te * n:9.1f}s {te * 1e6:8.0f}µs {te * n / tb:8.1f}")
    print(f"passive fraction {res['passive'].mean():.3f}; exact re-checks in batch {int(res['exact_rechecked'].sum())};"
          f" agreement with the general criterion on {n_exact} draws: {agree}/{n_exact}")


def table_single_verdict(n: int = 200) -> None:
    """Time per single two-port verdict (SDEA, Table I) by path."""
    tm = sdea_vsic()

    def per_call(f) -> float:
        f()
        t0 = time.perf_counter()
        for _ in range(n):
            f()
        return (time.perf_counter() - t0) / n

    base = per_call(lambda: two_port_passivity(tm))
    rows = [
        ("general exact, with margins", base),
        ("general exact, verdict only (margins=False)", per_call(lambda: two_port_passivity(tm, margins=False))),
        ("general exact, verdict only, fresh model", per_call(lambda: two_port_passivity(sdea_vsic(k22=350),
                                                                                        margins=False))),
        ("SDEA closed form (batch path, 1 draw)", per_call(lambda: sdea_passivity_batch({"k22": np.array([350.0])}))),
    ]
    print("\nSingle two-port passivity verdict (SDEA, Table I)")
    print(f"{'path':46s} {'time':>10s} {'ratio':>8s}")
    for name, t in rows:
        print(f"{name:46s} {t * 1e3:8.3f}ms {t / base:8.2f}")


def _random_one_port(rng: np.random.Generator, deg: int) -> Rational:
    """A passive one-port of degree ``deg``: a resistor plus deg//2 damped resonances (R-L-C)."""
    from hil.stability.rational import S

    z = Rational.const(float(rng.uniform(0.5, 2.0)))
    for _ in range(deg // 2):
        w = float(10 ** rng.uniform(-1, 2))
        zeta = float(10 ** rng.uniform(-3, -0.5))
        z = z + float(rng.uniform(0.1, 1.0)) * w * S / (S**2 + 2 * zeta * w * S + w * w)
    if deg % 2:
        z = z + float(rng.uniform(0.1, 1.0)) / (S + float(rng.uniform(0.1, 10.0)))
    return z


def _grid_baseline(tm: TransferMatrix, n: int = 10_000) -> float:
    """Time of a numpy grid of every principal minor of G(jω) + G(jω)ᴴ at n log-spaced points."""
    import itertools

    lo, hi = _freq_range(tm.entries)
    w = np.geomspace(lo, hi, n)
    t0 = time.perf_counter()
    G = tm.freq(w)
    H = G + np.conj(np.swapaxes(G, 1, 2))
    worst = np.inf
    for k in range(1, tm.n + 1):
        for sel in itertools.combinations(range(tm.n), k):
            sub = H[:, sel][:, :, sel]
            worst = min(worst, float(np.min(np.linalg.det(sub).real)))
    return time.perf_counter() - t0


def table_sizes(reps: int = 30) -> None:
    from hil.models.teleop import bilateral_2dof
    from hil.stability.criteria import check

    rng = np.random.default_rng(11)
    nets: list[tuple[str, TransferMatrix]] = []
    for deg in range(2, 9):
        nets.append((f"one-port, degree {deg}", TransferMatrix([[_random_one_port(rng, deg)]])))
    nets.append(("two-port (SDEA hybrid, Table I)", sdea_vsic()))
    nets.append(("three-port (000 MCET, k_vm1 = 64)", mcet_trilateral(k_vm1=64)))
    nets.append(("4x4 (000 bilateral 2-DOF, gains A1)", bilateral_2dof("A1")))

    def per_call(f, n: int) -> float:
        f()
        t0 = time.perf_counter()
        for _ in range(n):
            f()
        return (time.perf_counter() - t0) / n

    print("\nVerdict time per network size (exact, this run) against a 1e4-point numpy grid")
    hdr = (f"{'network':38s} {'verdict':22s} {'exact':>10s} {'no margins':>11s} {'grid 1e4':>10s} "
           f"{'exact/grid':>10s} {'nm/grid':>8s}")
    print(hdr)
    print("-" * len(hdr))
    for name, tm in nets:
        crit = "positive_real" if tm.n == 1 else ("passivity" if tm.n == 2 else "absolute_stability")
        n = reps if tm.n <= 2 else max(3, reps // 10)
        verdict = check(tm, crit).verdict
        te = per_call(lambda tm=tm, crit=crit: check(tm, crit), n)
        if crit == "positive_real":
            tn = per_call(lambda tm=tm: positive_real(tm, margins=False), n)
        elif crit == "passivity":
            tn = per_call(lambda tm=tm: two_port_passivity(tm, margins=False), n)
        else:
            tn = math.nan
        tg = min(_grid_baseline(tm) for _ in range(3))
        print(f"{name:38s} {verdict!s:22s} {te * 1e6:8.0f}µs {tn * 1e6:9.0f}µs {tg * 1e6:8.0f}µs "
              f"{te / tg:10.2f} {tn / tg:8.2f}")
    print("(exact = the criterion with margins; no margins = verdict only; grid 1e4 = numpy evaluation of "
          "every principal minor of G + Gᴴ at 1e4 points, which decides nothing exactly)")


if __name__ == "__main__":
    import sys

    if sys.argv[1:] == ["sizes"]:
        table_sizes()
    else:
        table_hard_cases()
        table_single_verdict()
        table_throughput()
        table_sizes()
