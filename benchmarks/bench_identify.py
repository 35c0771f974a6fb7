"""Identification benchmark: parameter error and interval width against run time (not a test).

Run: ``python benchmarks/bench_identify.py [--quick]``. For each configuration (chirp length, number
of frequency bins, walkers, step budget) a seeded synthetic dataset is generated, identified with
the full pipeline (checks -> H1 -> Fisher -> LS -> emcee until converged or budget) and we print:
max relative error of the posterior medians, max |median - truth| / posterior std, mean relative
90 % interval width, converged flag, steps, total fit time and its ratio to the baseline measured in
the same run. Targets: 4-parameter SDEA converged in < 10 s; 2-DOF cross-coupled device in < 2 min.

``--nonperiodic [--seeds N]`` (issue 12): on one-shot (non-periodic) log-chirp records, the bias /
90 % coverage / sd over the Cramér-Rao bound / scatter over the bound per noise level for the
output-error ML path against the old H1 path; error and posterior sd against record length
(periodic H1 and non-periodic ML paths) and against sampler steps (wall-clock); the 2-DOF
cross-coupled M, B, K table. Numbers in docs/BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "identify"))

from conftest import (
    MBK_SETUP,
    MBK_TRUTH,
    SDEA_SETUP,
    SDEA_TRUTH,
    make_mbk_records,
    make_nonperiodic_record,
    make_sdea_record,
    mbk_ss,
    sdea_locked_ss,
)

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


# ------------------------------------------------------------------ non-periodic records (issue 12)
SDEA_NAMES = ("K_f", "B_f", "M", "B")


def _sdea_ident(rec, **kw):
    return identify_experiments(
        [{"t": rec.t, "inputs": {"torque": rec.u[:, 0]}, "outputs": {"velocity": rec.y[:, 0], "force": rec.y[:, 1]}}],
        model="sdea_locked", sampling="zoh", **kw)


def periodic_log_chirp_record(seed: int, noise: float, duration: float, period: float = 0.5, fs: float = 5000.0):
    """Exactly periodic log chirp 2-400 Hz (one sweep per ``period``), steady state (one period dropped),
    simulated like the non-periodic records (hil.lti exact ZOH), noise as a fraction of output RMS."""
    from conftest import SimRecord
    from scipy import signal as sg

    from hil.lti import StateSpace

    n_per = round(period * fs)
    t1 = np.arange(n_per) / fs
    one = 0.5 * sg.chirp(t1, 2.0, period, 400.0, method="logarithmic", phi=-90)
    n_periods = max(round(duration / period), 2)
    u = np.tile(one, n_periods + 1)[:, None]
    A, Bm, C, D = sdea_locked_ss(**SDEA_TRUTH)
    _, y = StateSpace(A, Bm, C, D).discretize(1 / fs, "zoh").simulate(u)
    u, y = u[n_per:], y[n_per:]
    rng = np.random.default_rng(seed)
    sd = noise * np.sqrt(np.mean(y**2, axis=0))
    return SimRecord(np.arange(u.shape[0]) / fs, u, y + rng.standard_normal(y.shape) * sd, fs, sd)


def _stats(truth: np.ndarray, meds, sds, q05s, q95s, crbs) -> dict[str, np.ndarray]:
    meds, sds, crbs = np.array(meds), np.array(sds), np.array(crbs)
    hits = (np.array(q05s) <= truth) & (np.array(q95s) >= truth)
    return {"bias_sd": np.mean((meds - truth) / sds, axis=0), "cover": hits.mean(axis=0),
            "sd_crb": np.mean(sds / crbs, axis=0),
            "scatter_crb": (meds.std(axis=0, ddof=1) / crbs.mean(axis=0)) if len(meds) > 2
            else np.full(truth.size, np.nan)}


def table_calibration(n_seeds: int, n_h1: int) -> None:
    """Bias / coverage / sd against the true CRB per noise level: ML (Laplace) vs the H1 path."""
    truth = SdeaLockedOutput().vector(SDEA_TRUTH)
    print(f"\nnon-periodic log chirp 1-400 Hz, 5 kHz, 4 s: per parameter {SDEA_NAMES}")
    print(f"{'path':<26}{'noise':>6}{'n':>4}  {'bias/sd':<26}{'coverage90':<26}{'sd/CRB':<28}{'scatter/CRB':<26}")
    for li, noise in enumerate((0.001, 0.01, 0.05)):
        for path, n in (("ML + Laplace (new)", n_seeds), ("H1 FRF + emcee (old)", n_h1)):
            acc: list[list] = [[], [], [], [], []]
            for k in range(n):
                rec = make_nonperiodic_record(sdea_locked_ss(**SDEA_TRUTH), 90_000 + 1000 * li + k, noise)
                ml = _sdea_ident(rec, seed=k, posterior="laplace")  # its crb_std: the bound for this record
                if path.startswith("ML + L"):
                    res = ml
                else:  # the old path on this record: rectangular Welch segments of 1/16 of it, chirp band
                    res = _sdea_ident(rec, seed=k, method="frf", band=(2.0, 400.0), max_seconds=30)
                q05, med, q95 = res.posterior.quantiles([0.05, 0.5, 0.95])
                for lst, v in zip(acc, (med, res.posterior.samples.std(axis=0, ddof=1), q05, q95, ml.crb_std),
                                  strict=True):
                    lst.append(v)
            st = _stats(truth, *acc)
            f = lambda a: " ".join(f"{x:6.2f}" for x in a)  # noqa: E731
            print(f"{path:<26}{noise:>6.1%}{n:>4}  {f(st['bias_sd']):<26}{f(st['cover']):<26}{f(st['sd_crb']):<28}"
                  f"{f(st['scatter_crb']):<26}")


def table_length(n_seeds: int) -> None:
    """Parameter error and posterior sd against record length, periodic (H1) and non-periodic (ML) paths."""
    truth = SdeaLockedOutput().vector(SDEA_TRUTH)
    print("\nerror and posterior sd against record length (1 % noise); rel = relative to truth, max over parameters")
    print(f"{'record':>7} {'path':<28}{'n':>3}{'rms rel err':>12}{'rel sd':>10}{'sd/CRB':>8}{'steps':>7}{'time s':>8}")
    for dur in (0.5, 1.0, 2.0, 4.0, 8.0):
        for path in ("non-periodic ML + Laplace", "non-periodic ML + emcee", "periodic H1 FRF + emcee"):
            n = n_seeds if "Laplace" in path else 1
            errs, sds, ratios, steps, times = [], [], [], [], []
            for k in range(n):
                if path.startswith("periodic"):
                    rec = periodic_log_chirp_record(500 + k, 0.01, dur)
                    t0 = time.perf_counter()
                    res = _sdea_ident(rec, seed=k, period=0.5, band=(2.0, 450.0), max_seconds=120)
                else:
                    rec = make_nonperiodic_record(sdea_locked_ss(**SDEA_TRUTH), 700 + k, 0.01, duration=dur)
                    t0 = time.perf_counter()
                    res = _sdea_ident(rec, seed=k, posterior="laplace" if "Laplace" in path else "emcee",
                                      max_seconds=120)
                times.append(time.perf_counter() - t0)
                med = res.posterior.quantiles([0.5])[0]
                sd = res.posterior.samples.std(axis=0, ddof=1)
                errs.append((med - truth) / truth)
                sds.append(sd / truth)
                ratios.append(sd / res.crb_std)
                steps.append(res.posterior.diagnostics.n_steps if "Laplace" not in path else 0)
            rms = np.sqrt(np.mean(np.square(errs), axis=0))
            print(f"{dur:>6.1f}s {path:<28}{n:>3}{np.max(rms):>12.2e}{np.max(np.mean(sds, axis=0)):>10.2e}"
                  f"{np.max(np.mean(ratios, axis=0)):>8.2f}{int(np.mean(steps)):>7}{np.mean(times):>8.2f}")


def table_steps() -> None:
    """Posterior sd and error against sampler steps (wall-clock), one 2 s non-periodic record."""
    truth = SdeaLockedOutput().vector(SDEA_TRUTH)
    rec = make_nonperiodic_record(sdea_locked_ss(**SDEA_TRUTH), 4242, 0.01, duration=2.0)
    print("\nerror and sd against sampler steps (non-periodic, 2 s, 1 % noise, 32 walkers)")
    print(f"{'posterior':<22}{'steps':>7}{'conv':>6}{'max |err|/sd':>13}{'sd/CRB min..max':>18}{'time s':>8}")
    for label, kw in [("Laplace", {"posterior": "laplace"})] + [
        (f"emcee <= {n} steps", {"max_steps": n}) for n in (300, 600, 1200, 2400)
    ]:
        t0 = time.perf_counter()
        res = _sdea_ident(rec, seed=1, **kw)
        el = time.perf_counter() - t0
        med = res.posterior.quantiles([0.5])[0]
        sd = res.posterior.samples.std(axis=0, ddof=1)
        r = sd / res.crb_std
        print(f"{label:<22}{res.posterior.diagnostics.n_steps:>7}{res.converged!s:>6}"
              f"{np.max(np.abs(med - truth) / sd):>13.2f}{f'{r.min():.2f}..{r.max():.2f}':>18}{el:>8.2f}")


def table_mbk(n_seeds: int) -> None:
    """2-DOF cross-coupled M, B, K from simultaneous non-periodic chirps on both inputs (ML + Laplace)."""
    m0 = MbkModel(2, zoh_fs=500.0)
    truth = m0.theta_from_matrices(MBK_TRUTH["M"], MBK_TRUTH["B"], MBK_TRUTH["K"])
    acc: list[list] = [[], [], [], [], []]
    t0 = time.perf_counter()
    n_mis = 0
    for k in range(n_seeds):
        rec = make_nonperiodic_record(mbk_ss(MBK_TRUTH["M"], MBK_TRUTH["B"], MBK_TRUTH["K"]), 7000 + k, 0.01, n_in=2,
                                      fs=500.0, duration=20.0, pre_roll=1.0, f0=0.5, f1=60.0, amplitude=20.0)
        res = identify_experiments(
            [{"t": rec.t, "inputs": {"force_0": rec.u[:, 0], "force_1": rec.u[:, 1]},
              "outputs": {"velocity_0": rec.y[:, 0], "velocity_1": rec.y[:, 1]}}],
            model="mbk", model_options={"n_dof": 2}, sampling="zoh", seed=k, posterior="laplace")
        n_mis += res.misfit
        q05, med, q95 = res.posterior.quantiles([0.05, 0.5, 0.95])
        for lst, v in zip(acc, (med, res.posterior.samples.std(axis=0, ddof=1), q05, q95, res.crb_std), strict=True):
            lst.append(v)
    st = _stats(truth, *acc)
    print(f"\n2-DOF MBK, cross-coupled, simultaneous non-periodic log chirps 0.5-60 Hz on both inputs, 500 Hz, 20 s, "
          f"1 % noise; {n_seeds} seeds, {n_mis} flagged misfit, {time.perf_counter() - t0:.0f} s")
    print(f"{'param':<8}{'bias/sd':>9}{'cover90':>9}{'scatter/CRB':>13}")
    for i, name in enumerate(m0.names):
        print(f"{name:<8}{st['bias_sd'][i]:>9.2f}{st['cover'][i]:>9.2f}{st['scatter_crb'][i]:>13.2f}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="baselines only")
    ap.add_argument("--seed", type=int, default=100)
    ap.add_argument("--nonperiodic", action="store_true",
                    help="issue 12 tables only: non-periodic calibration, error vs length and vs sampler steps, MBK")
    ap.add_argument("--seeds", type=int, default=20, help="datasets per cell of the non-periodic tables")
    a = ap.parse_args(argv)
    if a.nonperiodic:
        table_calibration(a.seeds, 4)
        table_length(max(a.seeds // 2, 3))
        table_steps()
        table_mbk(a.seeds)
        return 0
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
