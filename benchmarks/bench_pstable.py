"""Benchmark: error of P(stable) against the number of verdicts and run time, plain Monte Carlo
against importance sampling around the FORM design point (hil.stability.reliability).

Known truth: a linear limit state in standard-normal coordinates, g(u) = β − aᵀu (d = 4,
‖a‖ = 1), so P_f = P(not stable) = Φ(−β) exactly; β is chosen for P_f = 1e-3 and 1e-6 (the
"P(stable) ≥ 1 − 1e-6" requirement). For each method and sample size: the mean relative error of
P̂_f over repetitions, the mean upper 95 % bound of P_f (Clopper-Pearson for plain MC; the
normal-approximation interval for IS, which also spends FORM's verdicts, counted in "verdicts"),
the fraction of repetitions whose interval covers the truth, and the run time (ratio to the
smallest plain MC run in the same process).

Run: ``python benchmarks/bench_pstable.py``. Not a test; prints a table.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.stats import beta as beta_dist
from scipy.stats import norm

from hil.stability.reliability import form, importance_sampling

D = 4
A = np.array([1.0, -2.0, 0.5, 0.3]) / np.linalg.norm([1.0, -2.0, 0.5, 0.3])


def plain_mc(fn, n: int, rng: np.random.Generator, chunk: int = 1_000_000) -> tuple[float, float, float]:
    k, left = 0, n
    while left:
        m = min(chunk, left)
        k += int((~fn(rng.standard_normal((m, D)))).sum())
        left -= m
    lo = 0.0 if k == 0 else float(beta_dist.ppf(0.025, k, n - k + 1))
    hi = float(beta_dist.ppf(0.975, k + 1, n - k))
    return k / n, lo, hi


def main() -> None:
    reps = 5
    base = None
    print(f"{'P_f':>8s} {'method':>6s} {'verdicts':>10s} {'mean rel err':>13s} {'upper 95%':>11s} {'covers':>7s} "
          f"{'time':>10s} {'ratio':>8s}")
    for pf in (1e-3, 1e-6):
        b = float(-norm.ppf(pf))

        def fn(U: np.ndarray, b: float = b) -> np.ndarray:
            return np.atleast_2d(U) @ A < b

        for n in (10_000, 100_000, 1_000_000, 10_000_000):
            errs, ups, cov = [], [], 0
            t0 = time.perf_counter()
            for r in range(reps if n < 10_000_000 else 2):
                p, lo, hi = plain_mc(fn, n, np.random.default_rng(r))
                errs.append(abs(p - pf) / pf)
                ups.append(hi)
                cov += lo <= pf <= hi
            k = reps if n < 10_000_000 else 2
            dt = (time.perf_counter() - t0) / k
            base = base or dt
            print(f"{pf:8.0e} {'MC':>6s} {n:10d} {np.mean(errs):13.3g} {np.mean(ups):11.3g} {cov / k:7.2f} "
                  f"{dt * 1e3:8.1f}ms {dt / base:8.1f}")
        for n in (100, 1000, 10_000):
            errs, ups, cov, nv = [], [], 0, 0
            t0 = time.perf_counter()
            for r in range(reps):
                fr = form(fn, D, seed=r)
                res = importance_sampling(fn, fr.design_point_u, n=n, seed=100 + r)
                nv = fr.evaluations + n
                errs.append(abs(res.p_failure - pf) / pf)
                ups.append(res.upper)
                cov += res.lower <= pf <= res.upper
            dt = (time.perf_counter() - t0) / reps
            print(f"{pf:8.0e} {'IS':>6s} {nv:10d} {np.mean(errs):13.3g} {np.mean(ups):11.3g} {cov / reps:7.2f} "
                  f"{dt * 1e3:8.1f}ms {dt / base:8.1f}")


if __name__ == "__main__":
    main()
