"""Error vs run time of the physics step on a stiff case: exact ZOH vs explicit integrators.

Plant: m x'' + b x' + k x = F (step force from rest), m = 1e-3 kg, k = 1e6 N/m
(w0 = 3.16e4 rad/s, above the 1 kHz Nyquist frequency), zeta = 0 by default. The exact solution
at the sample instants is the closed form; the error is max |x - x_exact| / (F/k) over 1 s.

Methods (all stepping the same numpy state vector in a Python loop, so the per-step overhead is
comparable): exact ZOH (``x <- Ad x + Bd u`` from :mod:`hil.lti`), forward Euler,
semi-implicit (symplectic) Euler, classical RK4; plus the lockstep
:class:`hil.mocks.simulator.Simulator` (``exact_sum=True``: fsum-based, bit-reproducible step).
Run time is wall time for 1 s of simulated time; ``ratio`` is relative to the exact-ZOH run at
the same dt measured in this run. Not a test: nothing is asserted.

Usage: ``python benchmarks/bench_physics.py [--zeta 0.0] [--min-dt 1e-6]``
"""

from __future__ import annotations

import argparse
import logging
import math
import time
from collections.abc import Callable

import numpy as np

from hil.lti import StateSpace
from hil.mocks.physics import mbk_plant
from hil.mocks.simulator import Simulator

logger = logging.getLogger(__name__)

M, K, F, T_END = 1e-3, 1e6, 1.0, 1.0


def exact_position(t: np.ndarray, b: float) -> np.ndarray:
    """Closed-form step response (underdamped or undamped) at times ``t``."""
    w = math.sqrt(K / M)
    z = b / (2 * math.sqrt(K * M))
    wd = w * math.sqrt(1 - z * z)
    return F / K * (1 - np.exp(-z * w * t) * (np.cos(wd * t) + z / math.sqrt(1 - z * z) * np.sin(wd * t)))


def run_loop(step: Callable[[np.ndarray], np.ndarray], n: int) -> tuple[np.ndarray, float]:
    xs = np.empty(n + 1)
    x = np.zeros(2)
    xs[0] = 0.0
    t0 = time.perf_counter()
    with np.errstate(all="ignore"):
        for i in range(n):
            x = step(x)
            xs[i + 1] = x[0]
    return xs, time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--zeta", type=float, default=0.0, help="damping ratio (default 0: undamped)")
    parser.add_argument("--min-dt", type=float, default=1e-6, help="smallest step (s)")
    args = parser.parse_args()
    b = 2 * args.zeta * math.sqrt(K * M)
    A = np.array([[0.0, 1.0], [-K / M, -b / M]])
    Bf = np.array([0.0, F / M])  # input column times the (constant) force

    def f(x: np.ndarray) -> np.ndarray:
        return A @ x + Bf

    dts = [d for d in (1e-3, 1e-4, 1e-5, 1e-6) if d >= args.min_dt * (1 - 1e-9)]
    print(f"stiff MSD: m={M:g} kg, k={K:g} N/m, w0={math.sqrt(K / M):.4g} rad/s, zeta={args.zeta:g}, "
          f"step F={F:g} N, horizon {T_END:g} s; error = max|x - x_exact| / (F/k)")
    print(f"{'method':<28}{'dt [s]':>9}{'max error':>13}{'run time [s]':>14}{'ratio':>9}")
    for dt in dts:
        n = round(T_END / dt)
        t = np.arange(n + 1) * dt
        ref = exact_position(t, b)
        t_disc = time.perf_counter()
        disc = StateSpace(A, [[0.0], [1.0 / M]], np.eye(2), np.zeros((2, 1))).discretize(dt)
        t_disc = time.perf_counter() - t_disc
        Ad, bd = disc.Ad, disc.Bd[:, 0] * F

        def euler(x: np.ndarray, dt: float = dt) -> np.ndarray:
            return x + dt * f(x)

        def semi_implicit(x: np.ndarray, dt: float = dt) -> np.ndarray:
            v = x[1] + dt * (-K / M * x[0] - b / M * x[1] + F / M)
            return np.array([x[0] + dt * v, v])

        def rk4(x: np.ndarray, dt: float = dt) -> np.ndarray:
            k1 = f(x)
            k2 = f(x + 0.5 * dt * k1)
            k3 = f(x + 0.5 * dt * k2)
            k4 = f(x + dt * k3)
            return x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)

        rows: list[tuple[str, float, float]] = []
        xs, t_exact = run_loop(lambda x, Ad=Ad, bd=bd: Ad @ x + bd, n)
        rows.append((f"exact ZOH (expm {t_disc * 1e3:.1f} ms)", float(np.max(np.abs(xs - ref))), t_exact))
        for name, step in (("forward Euler", euler), ("semi-implicit Euler", semi_implicit), ("RK4", rk4)):
            xs, el = run_loop(step, n)
            err = float(np.max(np.abs(xs - ref)))
            rows.append((name, err if np.all(np.isfinite(xs)) else math.inf, el))
        if dt >= 1e-4:
            sim = Simulator(mbk_plant(M, b, K), dt)
            h = sim.joints("body")
            h.apply_effort([F])
            xs = np.empty(n + 1)
            xs[0] = 0.0
            t0 = time.perf_counter()
            for i in range(n):
                sim.tick()
                xs[i + 1] = h.position()[0]
            rows.append(("Simulator (fsum)", float(np.max(np.abs(xs - ref))), time.perf_counter() - t0))
        for name, err, el in rows:
            err_s = "diverged" if not math.isfinite(err) or err * K / F > 1e6 else f"{err * K / F:.2e}"
            print(f"{name:<28}{dt:>9.0e}{err_s:>13}{el:>14.3f}{el / t_exact:>9.2f}")


if __name__ == "__main__":
    main()
