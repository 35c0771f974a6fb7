"""Identification benchmark: parameter error and interval width against run time (not a test).

Run: ``python benchmarks/bench_identify.py [--quick]``. For each configuration (chirp length, number
of frequency bins, walkers, step budget) a seeded synthetic dataset is generated, identified with
the full pipeline (checks -> H1 -> Fisher -> LS -> emcee until converged or budget) and we print:
max relative error of the posterior medians, max |median - truth| / posterior std, mean relative
90 % interval width, converged flag, steps, total fit time and its ratio to the baseline measured in
the same run. Targets: 4-parameter SDEA converged in < 10 s; 2-DOF cross-coupled device in < 2 min.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "identify"))

from conftest import MBK_SETUP, MBK_TRUTH, SDEA_SETUP, SDEA_TRUTH, make_mbk_records, make_sdea_record

from hil.identify.api import identify_experiments
from hil.identify.models import MbkModel, SdeaLockedOutput


def _row(label: str, res, truth: np.ndarray, t_fit: float, t_base: float | None) -> dict:
    q05, med, q95 = res.posterior.quantiles([0.05, 0.5, 0.95])[:, : truth.size]
    std = res.posterior.samples[:, : truth.size].std(axis=0)
    scale = np.where(np.abs(truth) > 0, np.abs(truth), 1.0)
    return {
        "config": label,
        "bins": res.frf.n_bins,
        "max_rel_err": float(np.max(np.abs(med - truth) / scale)),
        "max_err_over_std": float(np.max(np.abs(med - truth) / std)),
        "mean_rel_width90": float(np.mean((q95 - q05) / scale)),
        "converged": res.converged,
        "steps": res.posterior.diagnostics.n_steps,
        "walkers": res.posterior.diagnostics.n_walkers,
        "time_s": t_fit,
        "ratio": t_fit / t_base if t_base else 1.0,
    }


def run_sdea(
    label: str,
    seed: int,
    t_base: float | None,
    *,
    period: float = SDEA_SETUP["period"],
    n_periods: int = SDEA_SETUP["n_periods"],
    **fit_kw,
) -> dict:
    rec = make_sdea_record(seed, period=period, n_periods=n_periods)
    m = SdeaLockedOutput()
    t0 = time.perf_counter()
    res = identify_experiments(
        [{"t": rec.t, "inputs": rec.u, "outputs": rec.y}],
        model=m,
        band=SDEA_SETUP["band"],
        period=period,
        seed=seed,
        **fit_kw,
    )
    return _row(label, res, m.vector(SDEA_TRUTH), time.perf_counter() - t0, t_base)


def run_mbk(label: str, seed: int, t_base: float | None, **fit_kw) -> dict:
    recs = make_mbk_records(seed)
    m = MbkModel(2, M=np.diag([0.8, 0.8]), B=np.diag([5.0, 5.0]), K=np.diag([7000.0, 7000.0]))
    t0 = time.perf_counter()
    res = identify_experiments(
        [{"t": r.t, "inputs": r.u, "outputs": r.y} for r in recs],
        model=m,
        band=MBK_SETUP["band"],
        period=MBK_SETUP["period"],
        seed=seed,
        **fit_kw,
    )
    return _row(label, res, m.theta_from_matrices(**MBK_TRUTH), time.perf_counter() - t0, t_base)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="baselines only")
    ap.add_argument("--seed", type=int, default=100)
    a = ap.parse_args(argv)
    s = a.seed
    rows = []
    base = run_sdea("SDEA baseline: 16 periods x 0.5 s, 198 bins, 32 walkers", s, None)
    rows.append(base)
    tb = base["time_s"]
    if not a.quick:
        rows += [
            run_sdea("SDEA chirp 4 periods (2 s)", s, tb, n_periods=4),
            run_sdea("SDEA chirp 8 periods (4 s)", s, tb, n_periods=8),
            run_sdea("SDEA chirp 32 periods (16 s)", s, tb, n_periods=32),
            run_sdea("SDEA 99 bins (period 0.25 s x 32)", s, tb, period=0.25, n_periods=32),
            run_sdea("SDEA 396 bins (period 1 s x 8)", s, tb, period=1.0, n_periods=8),
            run_sdea("SDEA 16 walkers", s, tb, n_walkers=16),
            run_sdea("SDEA 64 walkers", s, tb, n_walkers=64),
            run_sdea("SDEA step budget 300", s, tb, max_steps=300),
            run_sdea("SDEA step budget 600", s, tb, max_steps=600),
            run_sdea("SDEA gaussian noise model", s, tb, noise="gaussian"),
        ]
    rows.append(run_mbk("2-DOF MBK cross-coupled, 9 params, 2 x 30 s", s, tb))
    hdr = (
        f"{'configuration':<56}{'bins':>5}{'relerr':>9}{'err/sd':>8}{'width90':>9}{'conv':>6}{'steps':>7}"
        f"{'walk':>5}{'time s':>8}{'ratio':>7}"
    )
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        print(
            f"{r['config']:<56}{r['bins']:>5}{r['max_rel_err']:>9.2e}{r['max_err_over_std']:>8.2f}"
            f"{r['mean_rel_width90']:>9.2e}{r['converged']!s:>6}{r['steps']:>7}{r['walkers']:>5}"
            f"{r['time_s']:>8.2f}{r['ratio']:>7.2f}"
        )
    ok_sdea = base["converged"] and base["time_s"] < 10
    ok_mbk = rows[-1]["converged"] and rows[-1]["time_s"] < 120
    print(f"targets: SDEA converged < 10 s: {ok_sdea}; 2-DOF converged < 120 s: {ok_mbk}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
