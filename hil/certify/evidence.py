"""The certificate's evidence built from a run, for :mod:`hil.certify.pipeline`: the devices' fault
counters as measurements, the energy-injection evidence, and the plot builders (as data series,
:class:`hil.certify.certificate.Series`; rendered by :mod:`hil.report`)."""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from hil.certify.certificate import (
    Design,
    EnergyEvidence,
    Measurement,
    Series,
)
from hil.certify.stages import (
    Sheet,
    energy_spec,
    info_spec,
)
from hil.certify.statistics import (
    Policy,
)
from hil.errors import HilError
from hil.models import build_network

logger = logging.getLogger(__name__)

def _identification_plots(plots: dict[str, Series], name: str, res: Any, seed: int, units: str | None = None) -> None:
    """FRF evidence (measured H1 with its coherence-based confidence band, the posterior fit band,
    magnitude and phase, coherence and normalized residuals beneath) per output, and the corner
    plot of the posterior; see :func:`hil.certify.figures.identification_plots`."""
    from hil.certify.figures import identification_plots

    identification_plots(plots, name, res, seed, units)

def _fault_measurements(outcomes: Mapping[str, Any], measurements: list[Measurement]) -> None:
    """One INFO measurement per experiment whose devices report fault counters: the total count of
    faults the adapters tolerated during the run (CRC errors, resyncs, dropped, late and stale
    frames, retries, ...), each device's non-zero counters in the description. Evidence only: the
    decision does not use it (a fault the adapter could not tolerate is a safe stop, FAIL)."""
    for exp_name, o in outcomes.items():
        per = (getattr(o, "results", {}) or {}).get("device_counters", {})
        if not per:
            continue
        # "stale": a read with no new sample since the last tick -- expected, not a fault, for a
        # sensor slower than the loop (its samples are held; identification compensates the hold)
        faults = {dev: {k: int(v) for k, v in c.items() if k != "stale"} for dev, c in per.items()}
        total = sum(v for c in faults.values() for v in c.values())
        nonzero = [f"{dev}: " + ", ".join(f"{k}={v}" for k, v in sorted(c.items()) if v)
                   for dev, c in sorted(faults.items()) if any(c.values())]
        detail = "; ".join(nonzero) if nonzero else f"none on {len(per)} device(s)"
        held = {dev: int(c.get("stale", 0)) for dev, c in per.items() if int(c.get("stale", 0))}
        if held:
            detail += "; reads without a new sample (held, not counted): " + ", ".join(
                f"{dev}={n}" for dev, n in sorted(held.items()))
        measurements.append(info_spec(f"device faults tolerated ({exp_name})", "count").measure(
            float(total), description=f"adapter counters during the run: {detail}"))


def _energy_stage(opt: Sheet, name: str, o: Any, energy: list[EnergyEvidence], measurements: list[Measurement],
                  plots: dict[str, Series]) -> None:
    """The optional energy-evidence stage of one experiment, and its plot."""
    if opt.optional(f"energy evidence ({name})", _energy_evidence, name, o, energy, measurements, default=False):
        opt.optional(f"plots (energy {name})", _energy_plot, plots, name, o)


def _energy_evidence(name: str, o: Any, energy: list[EnergyEvidence], measurements: list[Measurement]) -> bool:
    """Energy-injection results of an experiment as evidence and a measurement; True if it had some."""
    r = o.results
    if r.get("type") != "energy_injection" or "went_negative" not in r:
        return False
    bound = float(r.get("bound_at_min", 0.0))
    ev = EnergyEvidence(experiment=name, port=str(r.get("port")), record=str(o.record),
                        went_negative=bool(r["went_negative"]), min_energy=float(r["min_energy"]),
                        bound=bound, first_time=r.get("first_time"))
    m = energy_spec(name).measure(float(r["min_energy"]), result=bool(r["went_negative"]), lower=-bound)
    energy.append(ev)  # both or neither
    measurements.append(m)
    return True


def _energy_plot(plots: dict[str, Series], name: str, outcome: Any) -> None:
    from hil.record.hdf5 import RunRecord

    try:
        rec = RunRecord.open(outcome.record)
    except HilError:
        return
    port = outcome.results.get("port")
    key = f"{port}.energy"
    if key not in rec.channels:
        return
    e = rec.channels[key].reshape(-1)
    step = max(1, e.size // 1500)
    plots[f"energy_{name}"] = Series(title=f"Port energy E_s(t) at {port} ({name})", x=rec.t[::step].tolist(),
                                     x_label="t [s]", y_label="E_s [J]", lines={"E_s": e[::step].tolist()}, hline=0.0)


def _decided_plot(plots: dict[str, Series], tm: Any, r: Any) -> None:
    """The decisive condition against frequency (the failing one of a NO-GO, the one with the
    smallest margin otherwise), negative band shaded, worst frequency marked, and the imaginary-axis
    and infinity conditions as their residue margins; see :func:`hil.certify.figures.decided_plot`."""
    from hil.certify.figures import decided_plot

    decided_plot(plots, tm, r)

def _critical_band_plot(plots: dict[str, Series], model: str, params: Mapping[str, Any],
                        draws: Mapping[str, np.ndarray], band: tuple[float, float],
                        centre: Mapping[str, Any] | None = None) -> None:
    """The model's normalized band condition (the SDEA's coupler condition) g(ω) = t(ω²)/|t|(ω²)
    at the nominal point ``centre`` (the nominal stage's parameters) and its 5-95 % band over the
    draws, with the 10 % threshold of the nominal curve and the certificate's critical band (over the
    draws) marked; nothing for a model without one."""
    centre = dict(centre or {k: float(np.median(v)) for k, v in draws.items()})
    from hil.models import get_model
    from hil.models.batch import BAND_GRID_RAD_S, CRITICAL_BAND_FRACTION

    m = get_model(model)
    if m.band_condition is None:
        return
    condition = m.band_condition
    table = m.defaults  # the model's parameter table (Table I for the SDEA)
    base = {**table, **{k: float(v) for k, v in params.items() if isinstance(v, int | float)}}
    n = len(next(iter(draws.values())))
    sub = slice(None, None, max(1, n // 400))
    w = BAND_GRID_RAD_S
    x = (w * w)[:, None]

    def g_of(q: Mapping[str, np.ndarray]) -> np.ndarray:
        t0, t1, t2, t3 = condition(q)
        tv = ((t3 * x + t2) * x + t1) * x + t0
        tm = ((np.abs(t3) * x + np.abs(t2)) * x + np.abs(t1)) * x + np.abs(t0)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(tm > 0, tv / tm, np.nan)

    qd = {k: np.asarray(draws[k], float)[sub] if k in draws else np.full(len(range(n)[sub]), base[k])
          for k in table}
    gd = g_of(qd)
    gm = g_of({k: np.array([float(centre[k]) if k in centre else base[k]]) for k in table})[:, 0]
    q05, q95 = np.nanquantile(gd, [0.05, 0.95], axis=1)
    gmin = float(np.nanmin(gm))
    thr = gmin + CRITICAL_BAND_FRACTION * (1.0 - gmin)
    plots["critical_band"] = Series(
        title="Critical band: the coupler condition (c-ii) within 10 % of its minimum",
        x=w.tolist(), x_label="ω [rad/s]", y_label="g(ω) = t(ω²)/|t|(ω²) [1]", log_x=True,
        lines={"nominal (posterior median)": _clean(gm), "10 % threshold (nominal)": [thr] * w.size},
        bands={"5-95 % over the draws": (_clean(q05), _clean(q95))},
        points={"worst (nominal)": (float(w[int(np.nanargmin(gm))]), gmin),
                "critical band, low edge (over the draws)": (float(band[0]), thr),
                "critical band, high edge (over the draws)": (float(band[1]), thr)},
        hline=0.0)


def _clean(a: np.ndarray) -> list[float | None]:
    return [float(x) if math.isfinite(x) else None for x in np.asarray(a, float)]


def _bode_plot(plots: dict[str, Series], model: str, params: Mapping[str, Any], draws: Mapping[str, np.ndarray],
               seed: int, units: str | None = None, cmap: Any = None) -> None:
    """|entry (1,1)| of the network over the posterior: median and 90 % band (60 draws). With the
    robust stage's measured coefficient map ``cmap`` (general networks: coefficients affine in the
    drawn parameters, checked to 1e-9 relative at exact builds), the entry's coefficients of every
    draw come from the map instead of one exact network build per draw."""
    rng = np.random.default_rng(seed + 1)
    n = len(next(iter(draws.values())))
    pick = rng.choice(n, size=min(60, n), replace=False)
    try:
        tm0 = build_network(model, {**params, **{k: float(np.mean(v)) for k, v in draws.items()}})
    except HilError:
        return
    from hil.stability.criteria import _freq_range

    lo, hi = _freq_range(tm0.entries)
    w = np.geomspace(lo, hi, 300)
    mags = []
    if cmap is not None and set(cmap.names) == set(draws):
        X = np.column_stack([np.asarray(draws[k], float)[pick] for k in cmap.names])
        num, den = cmap.coefficients(X)  # (N, n, n, L), lowest degree first
        from numpy.polynomial.polynomial import polyval  # Horner, per draw: (N, n_w)

        mags = list(np.abs(polyval(1j * w, num[:, 0, 0].T) / polyval(1j * w, den[:, 0, 0].T)))
        pick = pick[:0]
    for i in pick:
        q = dict(params)
        q.update({k: float(v[i]) for k, v in draws.items()})
        try:
            mags.append(np.abs(build_network(model, q)[0, 0].freq(w)))
        except HilError:
            continue
    if not mags:
        return
    M = np.array(mags)
    q05, q50, q95 = np.quantile(M, [0.05, 0.5, 0.95], axis=0)
    db = lambda a: (20 * np.log10(np.maximum(a, 1e-300))).tolist()  # noqa: E731
    from hil.certify.figures import immittance_db_label

    plots["bode"] = Series(title=f"|{tm0.kind} entry (1,1)| over the posterior", x=w.tolist(), x_label="ω [rad/s]",
                           y_label=immittance_db_label(tm0.kind, units), log_x=True,
                           lines={"median": db(q50)},
                           bands={"90 % credible": (db(q05), db(q95))})


def _headroom_plot(plots: dict[str, Series], cert_cfg: Any, params: Mapping[str, Any],
                   draws: Mapping[str, np.ndarray], policy: Policy, design: Design) -> None:
    """P(stable) against the design parameter, requirement crossing marked; see
    :func:`hil.certify.figures.headroom_plot`."""
    from hil.certify.figures import headroom_plot

    headroom_plot(plots, cert_cfg, params, draws, policy, design)
