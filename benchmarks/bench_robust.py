"""Benchmark: robust certification over posterior-like draws for networks without a closed-form
batch (issue 15): the screened general path (hil.models.batch_general, what
hil.certify.evaluation._robust_eval runs) against the per-draw exact path (build + exact criterion for
every draw), both measured in the same run on the same draws.

Columns: model and posterior ("straddling": spread across the stability boundary, "stable": a
narrow posterior inside the stable region), draws, P(stable), the fractions of draws the
vectorized screen accepts (a sufficient condition certified, hil.models.batch_accept) and rejects
(a necessary condition violated) and the fraction left to the exact path, the screened path's CPU
time for all draws (one process, one core: process_time), the per-draw exact path's CPU time per
draw (measured on the first ``--check`` draws) and extrapolated to all draws, their ratio, and
the agreement of the two on the checked draws (must be all; tests/models/test_batch_general.py checks
every draw).

Run: ``python benchmarks/bench_robust.py [--draws N] [--check M]`` (default 10000, 200). Not a
test; prints a table.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from hil.certify.evaluation import exactly_stable
from hil.models import get_model
from hil.models.batch_general import screened_stability

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
    ("mbk_impedance", "one-port",
     lambda r, n: {"B_00": 0.3 + 0.5 * r.standard_normal(n), "M_00": 1.0 + 0.1 * r.standard_normal(n)}),
    ("sdea", "general path", lambda r, n: _rel(r, n, {"k22": (360.0, 0.15), "M": (6.399e-4, 0.05)})),
]

#: fixed parameters of a case (besides the model's defaults not drawn)
FIXED: dict[tuple[str, str], dict[str, Any]] = {("mbk_impedance", "one-port"): {"dof": 1}}


def _exact(model: str, criterion: str, params: Mapping[str, Any], draws: Mapping[str, np.ndarray]) -> np.ndarray:
    n = len(next(iter(draws.values())))
    return np.array([exactly_stable(model, criterion, {**params, **{k: float(v[i]) for k, v in draws.items()}})
                     for i in range(n)], dtype=bool)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=10000)
    ap.add_argument("--check", type=int, default=200,
                    help="draws also run through the per-draw exact path (agreement, exact time per draw)")
    ap.add_argument("--only", nargs="*", default=None, help="model names to run (default: all)")
    args = ap.parse_args()
    n, n_chk = args.draws, args.check
    print(f"{'model':>16s} {'posterior':>12s} {'draws':>6s} {'P(stable)':>9s} {'accepted':>8s} {'rejected':>8s} "
          f"{'exact':>6s} {'screened':>9s} {'exact/draw':>10s} {'all exact':>9s} {'ratio':>6s} {'agree':>9s}")
    for model, label, post in CASES:
        m = get_model(model)
        draws = post(np.random.default_rng(0), n)
        params = {k: v for k, v in m.defaults.items() if v is not None and k not in draws}
        fixed = FIXED.get((model, label))
        if fixed is not None:  # a 1-DOF body: only the _00 entries of the 2-DOF defaults
            params = {k: v for k, v in params.items() if not k.endswith(("_01", "_10", "_11"))} | fixed
        if args.only and model not in args.only:
            continue
        t0 = time.process_time()
        def exact_one(q: Mapping[str, Any], model: str = model, crit: str = m.criterion) -> bool:
            return exactly_stable(model, crit, q)

        res = screened_stability(model, m.criterion, params, draws, exact_one)
        t_scr = time.process_time() - t0
        sub = {k: v[:n_chk] for k, v in draws.items()}
        t0 = time.process_time()
        ref = _exact(model, m.criterion, params, sub)
        t_ex = (time.process_time() - t0) / n_chk
        agree = int(np.sum(res["stable"][:n_chk] == ref))
        undecided = ~res["accepted"] & ~res["rejected"]
        print(f"{model:>16s} {label:>12s} {n:6d} {res['stable'].mean():9.3f} {res['accepted'].mean():8.3f} "
              f"{res['rejected'].mean():8.3f} {undecided.mean():6.3f} {t_scr:8.2f}s {t_ex * 1e3:8.2f}ms "
              f"{t_ex * n:8.1f}s {t_ex * n / t_scr:6.1f} {agree:4d}/{n_chk:<4d}")


if __name__ == "__main__":
    main()
