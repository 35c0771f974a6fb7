"""Data checks before fitting: each problem becomes a :class:`Diagnosis`, never a confident wrong fit.

* :func:`check_timestamps` -- NaN/non-increasing timestamps, jitter, gaps (dropped samples);
* :func:`check_finite` -- NaN/inf samples (gaps inside a signal);
* :func:`check_saturation` -- clipped samples: flat tops at the signal's extreme values;
* :func:`check_dead` -- constant signals (actuator off, sensor unplugged);
* :func:`check_excitation` -- coherence at the noise-only level across the band ("no excitation /
  no response"). Under the null hypothesis of no linear relation, the estimated (multiple)
  coherence with ``n`` averages and ``q`` inputs is Beta(q, n - q) distributed; a band where the
  fraction of bins above its 99 % quantile is close to 1 % carries no usable response.

:func:`run_checks` runs the time-domain checks and returns a :class:`DataReport`;
``report.raise_if_failed()`` raises :class:`~hil.identify.errors.DataQualityError` listing every
failed diagnosis.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy import stats

from hil.identify.errors import DataQualityError
from hil.identify.frf import FrfEstimate

logger = logging.getLogger(__name__)

__all__ = [
    "DataReport",
    "Diagnosis",
    "check_dead",
    "check_excitation",
    "check_finite",
    "check_sample_times",
    "check_saturation",
    "check_timestamps",
    "run_checks",
]


@dataclass
class Diagnosis:
    """One finding. ``kind`` in {gaps, nonuniform_sampling, non_finite, saturation, dead_signal,
    no_excitation, ok}; ``severity`` in {error, warning, info}."""

    kind: str
    severity: str
    message: str
    channel: str | None = None
    details: dict[str, Any] = field(default_factory=dict)

    @property
    def failed(self) -> bool:
        return self.severity == "error"

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "severity": self.severity,
            "message": self.message,
            "channel": self.channel,
            "details": self.details,
        }


@dataclass
class DataReport:
    """All diagnoses of a record."""

    diagnoses: list[Diagnosis] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not any(d.failed for d in self.diagnoses)

    @property
    def failures(self) -> list[Diagnosis]:
        return [d for d in self.diagnoses if d.failed]

    def kinds(self) -> set[str]:
        return {d.kind for d in self.failures}

    def raise_if_failed(self) -> None:
        if not self.ok:
            raise DataQualityError(
                "data unfit for identification: " + " | ".join(d.message for d in self.failures), self.failures
            )


def check_timestamps(t: ArrayLike, *, rel_jitter: float = 1e-3, gap_factor: float = 1.5) -> list[Diagnosis]:
    """Timestamps [s] must be finite, strictly increasing and uniform (relative jitter <= ``rel_jitter``).

    A step larger than ``gap_factor`` times the median step is a gap (dropped samples).
    """
    tt = np.asarray(t, float)
    out: list[Diagnosis] = []
    if tt.ndim != 1 or tt.size < 3:
        return [Diagnosis("gaps", "error", f"need a 1-D time vector with >= 3 samples, got shape {tt.shape}")]
    nan = ~np.isfinite(tt)
    if np.any(nan):
        out.append(
            Diagnosis(
                "gaps",
                "error",
                f"{int(nan.sum())} non-finite timestamps (missing samples)",
                details={"n_bad": int(nan.sum()), "first_index": int(np.flatnonzero(nan)[0])},
            )
        )
        tt = tt[~nan]
    dt = np.diff(tt)
    if np.any(dt <= 0):
        out.append(
            Diagnosis(
                "gaps",
                "error",
                f"{int(np.sum(dt <= 0))} non-increasing timestamps (duplicated or reordered samples)",
                details={"first_index": int(np.flatnonzero(dt <= 0)[0])},
            )
        )
        return out
    med = float(np.median(dt))
    gaps = np.flatnonzero(dt > gap_factor * med)
    if gaps.size:
        lost = int(np.sum(np.round(dt[gaps] / med) - 1))
        out.append(
            Diagnosis(
                "gaps",
                "error",
                f"{gaps.size} gap(s) in the timestamps, ~{lost} dropped samples (first at t = {tt[gaps[0]]:.6g} s, "
                f"{dt[gaps[0]] / med:.1f} periods): spectra of a record with gaps are wrong; "
                "re-record or split the record",
                details={"n_gaps": int(gaps.size), "dropped_samples": lost, "first_gap_time": float(tt[gaps[0]])},
            )
        )
    ok = np.ones(dt.size, bool)
    ok[gaps] = False
    if ok.any():
        jitter = float(np.max(np.abs(dt[ok] - med)) / med)
        if jitter > rel_jitter:
            out.append(
                Diagnosis(
                    "nonuniform_sampling",
                    "error",
                    f"non-uniform sampling: max step deviation {jitter:.2%} of the median step "
                    f"({med:.3g} s); resample onto a uniform grid first",
                    details={"max_rel_jitter": jitter},
                )
            )
    return out


def check_finite(signals: Mapping[str, ArrayLike]) -> list[Diagnosis]:
    """NaN/inf samples in any signal (missing or corrupt samples)."""
    out = []
    for name, x in signals.items():
        a = np.asarray(x, float)
        bad = ~np.isfinite(a)
        if np.any(bad):
            out.append(
                Diagnosis(
                    "non_finite",
                    "error",
                    f"{name}: {int(bad.sum())} NaN/inf samples (first at index "
                    f"{int(np.flatnonzero(bad.ravel())[0])}): the record has gaps",
                    channel=name,
                    details={"n_bad": int(bad.sum())},
                )
            )
    return out


def check_saturation(
    signals: Mapping[str, ArrayLike], *, max_fraction: float = 0.002, min_run: int = 3, rel_tol: float = 1e-9
) -> list[Diagnosis]:
    """Clipping: samples sitting at the signal's own max/min in runs of >= ``min_run`` (flat tops).

    A smooth signal touches its extreme once per peak; a clipped one stays there. Flagged when the
    fraction of such samples exceeds ``max_fraction``.
    """
    out = []
    for name, x in signals.items():
        a = np.asarray(x, float).ravel()
        a = a[np.isfinite(a)]
        if a.size < 10:
            continue
        lo, hi = float(a.min()), float(a.max())
        if hi == lo:  # constant: reported by check_dead, not as clipping
            continue
        tol = rel_tol * max(hi - lo, abs(hi), abs(lo), 1e-300)
        frac_total = 0.0
        levels = []
        for level in (hi, lo):
            at = np.abs(a - level) <= tol
            # runs of consecutive samples at the level
            edges = np.diff(np.concatenate([[0], at.astype(np.int8), [0]]))
            starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
            long = (ends - starts) >= min_run
            n_flat = int(np.sum((ends - starts)[long]))
            if n_flat:
                levels.append(level)
            frac_total += n_flat / a.size
        if frac_total > max_fraction:
            out.append(
                Diagnosis(
                    "saturation",
                    "error",
                    f"{name}: {frac_total:.1%} of samples are clipped flat at {levels} (saturated run): "
                    "reduce the excitation amplitude or raise the limit; a linear fit would be biased",
                    channel=name,
                    details={"fraction": frac_total, "levels": levels},
                )
            )
    return out


def check_dead(signals: Mapping[str, ArrayLike], *, role: Mapping[str, str] | None = None) -> list[Diagnosis]:
    """Constant (zero-variance) signals: a dead input means no excitation, a dead output no response."""
    out = []
    for name, x in signals.items():
        a = np.asarray(x, float)
        a = a[np.isfinite(a)]
        if a.size and float(np.ptp(a)) <= 1e-12 * max(float(np.max(np.abs(a))), 1e-300):
            what = (role or {}).get(name, "signal")
            meaning = "no excitation" if what == "input" else "no response"
            out.append(
                Diagnosis(
                    "no_excitation",
                    "error",
                    f"{name} ({what}) is constant: {meaning} (actuator disabled / sensor unplugged?)",
                    channel=name,
                )
            )
    return out


def check_excitation(est: FrfEstimate, *, min_fraction: float = 0.2) -> list[Diagnosis]:
    """Noise-only data: coherence indistinguishable from its no-relation distribution across the band.

    With ``n`` effective averages and ``q`` inputs the null distribution of the multiple coherence is
    Beta(q, n - q). If fewer than ``min_fraction`` of the band's excited bins (where some input
    carries power, e.g. the lines of a multisine) exceed its 99 % quantile for an output, that output
    carries no response to the inputs.
    """
    q = est.H.shape[2]
    n = max(est.n_avg, q + 1.0)
    thr = float(stats.beta.ppf(0.99, q, n - q))
    out = []
    for o, name in enumerate(est.output_names):
        measured = np.any(np.isfinite(est.H[:, o, :]), axis=-1)  # bins where some input is excited
        coh = est.coherence[measured, o] if np.any(measured) else np.zeros(1)
        frac = float(np.mean(coh > thr))
        if frac < min_fraction:
            out.append(
                Diagnosis(
                    "no_excitation",
                    "error",
                    f"{name}: coherence at the noise-only level in {1 - frac:.0%} of the band (median "
                    f"{np.median(coh):.2f}, null 99% quantile {thr:.2f}): no excitation reached this output / no "
                    "response -- check the actuator is enabled, the sensor connected and the amplitude sufficient",
                    channel=name,
                    details={"fraction_above_null": frac, "null_q99": thr, "median_coherence": float(np.median(coh))},
                )
            )
    return out


def run_checks(
    t: ArrayLike, inputs: Mapping[str, ArrayLike], outputs: Mapping[str, ArrayLike], *, allow_idle_inputs: bool = False
) -> DataReport:
    """Time-domain checks of one record (timestamps, NaNs, saturation, dead signals).

    ``allow_idle_inputs``: in a multi-experiment MIMO test an input may be idle (zero) in some
    experiments; its "constant input" diagnosis is then only informational (the caller checks that
    every input is excited in at least one experiment).
    """
    sig = {**inputs, **outputs}
    role = {**dict.fromkeys(inputs, "input"), **dict.fromkeys(outputs, "output")}
    dead = check_dead(sig, role=role)
    if allow_idle_inputs:
        for d in dead:
            if role.get(d.channel or "") == "input":
                d.severity = "info"
    diags = check_timestamps(t) + check_finite(sig) + check_saturation(sig) + dead
    n = np.asarray(t).size
    for name, x in sig.items():
        if np.asarray(x).shape[0] != n:
            diags.append(
                Diagnosis("gaps", "error", f"{name} has {np.asarray(x).shape[0]} samples, t has {n}", channel=name)
            )
    for d in diags:
        logger.warning("data check: %s", d.message)
    return DataReport(diags)


#: :func:`check_sample_times`: largest tolerated departure of a tick's start from a constant delay
#: after its nominal time, as a fraction of the period (10 %: at a tenth of the sample rate, a
#: timing error of 0.1 period shifts the phase by at most 2π · 0.1 · 0.1 ≈ 3.6°)
SAMPLE_TIME_TOLERANCE = 0.1


def check_sample_times(
    t: ArrayLike, tick_start: ArrayLike, *, rate_hz: float, tolerance: float = SAMPLE_TIME_TOLERANCE
) -> list[Diagnosis]:
    """Recorded sample times against the rate the identification assumes.

    ``t``: nominal sample times ``k / rate_hz`` [s] (the record's ``/t``); ``tick_start``: when
    each tick actually started on the loop's clock, same origin [s] (``loop.tick_start``). The
    departure of tick k is ``d_k = (tick_start_k - t_k) - median(tick_start - t)`` (a constant delay
    is removed: every channel of a tick shares it). A record whose ``max |d_k|`` exceeds
    ``tolerance / rate_hz`` is flagged (``nonuniform_sampling``, error): treating it as uniformly
    sampled at ``rate_hz`` would bias the frequency response. NaN starts (ticks never timed) are
    ignored; none at all: no diagnosis.
    """
    tt = np.asarray(t, float).reshape(-1)
    ts = np.asarray(tick_start, float).reshape(-1)
    if tt.size != ts.size:
        return [Diagnosis("gaps", "error", f"loop.tick_start has {ts.size} samples, t has {tt.size}")]
    d = ts - tt
    d = d[np.isfinite(d)]
    if d.size == 0:
        return []
    dt = 1.0 / float(rate_hz)
    dev = np.abs(d - np.median(d))
    worst = float(dev.max())
    if worst <= tolerance * dt:
        return []
    k = int(np.argmax(dev))
    n_bad = int(np.count_nonzero(dev > tolerance * dt))
    return [
        Diagnosis(
            "nonuniform_sampling",
            "error",
            f"sample timing departs from {rate_hz:g} Hz: {n_bad} of {d.size} ticks off their nominal time by more "
            f"than {tolerance:.0%} of the period (worst {worst / dt:.2f} periods = {1e6 * worst:.0f} µs at sample "
            f"{k}); the identification assumes uniform sampling",
            channel="loop.tick_start",
            details={"max_rel_deviation": worst / dt, "n_bad": n_bad, "p99_rel_deviation": float(
                np.percentile(dev, 99) / dt), "tolerance": tolerance},
        )
    ]
