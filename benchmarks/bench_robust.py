"""Benchmark: robust certification over posterior-like draws for networks without a closed-form
batch (issue 15): the screened general path (hil.models.batch_general, what
hil.certify.pipeline._robust_eval runs) against the per-draw exact path (build + exact criterion for
every draw), both measured in the same run on the same draws.

Columns: model and posterior ("straddling": spread across the stability boundary, "stable": a
narrow posterior inside the stable region), draws, P(stable) (exact), the fraction of draws the
screen rejects without the exact path, the screen's own time (coefficient map + grid), the
screened path's total time, the per-draw exact time, their ratio, and whether the two agree on
every draw (must be "yes").

Run: ``python benchmarks/bench_robust.py [--draws N]`` (default 400). Not a test; prints a table.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from hil.certify.pipeline import _robust_eval, exactly_stable
from hil.models import get_model
from hil.models.batch_general import coefficient_map, screen

Posterior = Callable[[np.random.Generator, int], dict[str, np.ndarray]]


def _rel(rng: np.random.Generator, n: int, spec: Mapping[str, tuple[float, float]]) -> dict[str, np.ndarray]:
    return {k: c * (1 + s * rng.standard_normal(n)) for k, (c, s) in spec.items()}


CASES: list[tuple[str, str, Posterior]] = [
    ("mbk_impedance", "straddling",
     lambda r, n: {**_rel(r, n, {"B_00": (8.0, 0.05), "B_11": (6.0, 0.05)}),
                   "B_01": -2.0 + 3.5 * r.standard_normal(n), "M_01": 0.2 + 0.3 * r.standard_normal(n)}),
    ("mbk_impedance", "stable",
     lambda r, n: _rel(r, n, {"B_00": (8.0, 0.05), "B_11": (6.0, 0.05), "B_01": (-2.0, 0.1)})),
    ("bilateral_1dof", "straddling",
     lambda r, n: {"b_m": 0.01 + 0.01 * r.standard_normal(n), "b_s": 0.01 + 0.01 * r.standard_normal(n)}),
    ("bilateral_2dof", "straddling", lambda r, n: _rel(r, n, {"k_vyz": (250.0, 0.2), "m_yy": (2.0, 0.1)})),
    ("bilateral_2dof", "stable", lambda r, n: _rel(r, n, {"k_vyz": (250.0, 0.02), "m_yy": (2.0, 0.1)})),
    ("mcet_trilateral", "stable", lambda r, n: _rel(r, n, {"m_m1": (0.7, 0.1), "m_s": (1.5, 0.1)})),
    ("mcet_trilateral", "k_vm1 drawn", lambda r, n: _rel(r, n, {"k_vm1": (64.0, 0.05), "m_s": (1.5, 0.1)})),
]


def _exact(model: str, criterion: str, params: Mapping[str, Any], draws: Mapping[str, np.ndarray]) -> np.ndarray:
    n = len(next(iter(draws.values())))
    return np.array([exactly_stable(model, criterion, {**params, **{k: float(v[i]) for k, v in draws.items()}})
                     for i in range(n)], dtype=bool)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=400)
    n = ap.parse_args().draws
    print(f"{'model':>16s} {'posterior':>12s} {'draws':>6s} {'P(stable)':>9s} {'rejected':>8s} {'screen':>9s} "
          f"{'screened':>9s} {'exact':>9s} {'ratio':>6s} {'agree':>5s}")
    for model, label, post in CASES:
        m = get_model(model)
        draws = post(np.random.default_rng(0), n)
        params = {k: v for k, v in m.defaults.items() if v is not None and k not in draws}
        names = sorted(draws)
        X = np.column_stack([draws[k] for k in names])
        t0 = time.perf_counter()
        def build(th: Mapping[str, float], m: Any = m, params: dict[str, Any] = params) -> Any:
            return m.network({**params, **th})

        cmap = coefficient_map(build, names, X)
        rej = screen(cmap, X, m.criterion)[0] if cmap is not None else np.zeros(n, bool)
        t_screen = time.perf_counter() - t0
        t0 = time.perf_counter()
        stable = _robust_eval(model, m.criterion, params, draws)[0]
        t_scr = time.perf_counter() - t0
        t0 = time.perf_counter()
        ref = _exact(model, m.criterion, params, draws)
        t_ex = time.perf_counter() - t0
        agree = "yes" if np.array_equal(stable, ref) else "NO"
        print(f"{model:>16s} {label:>12s} {n:6d} {ref.mean():9.3f} {rej.mean():8.3f} {t_screen:8.3f}s "
              f"{t_scr:8.2f}s {t_ex:8.2f}s {t_ex / t_scr:6.1f} {agree:>5s}")


if __name__ == "__main__":
    main()
