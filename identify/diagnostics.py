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
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy import special  # beta.ppf(q, a, b) = betaincinv(a, b, q), without scipy.stats

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
    "quantization_step",
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


#: :func:`quantization_step`: largest departure of a sample from the detected grid, in steps
GRID_TOLERANCE = 0.01
#: :func:`check_saturation`: margin on the flat-top length quantization explains (the curvature is
#: estimated from a few quantized samples: ~10 % error for the shortest runs, doubled)
QUANT_RUN_MARGIN = 1.25
#: :func:`check_saturation`: how far (in steps) the flanks reach from a flat top's level: far enough
#: that the parabola's curvature is set by several levels, near enough that the peak is parabolic
#: (a sine of amplitude A departs from its parabola by (4 steps / A) / 6 of the departure)
QUANT_FLANK_STEPS = 4.0
#: :func:`check_saturation`: largest rms residual (in steps) of the flanks' parabola: rounding
#: alone leaves q / sqrt(12) = 0.29 steps; a clipped flank (a corner, the opposite limit) leaves more
QUANT_FIT_STEPS = 0.6
#: :func:`check_saturation`: largest rise (in steps) of the flanks' parabola above the flat level
#: that quantization explains: the true peak of a quantized flat top lies within half a step of
#: its level; one more step covers the fit's error (a parabola through a fast sine peak's flanks,
#: 8 samples reaching 9 steps down, overshoots the peak by up to 0.7 step)
QUANT_PEAK_STEPS = 1.5


#: :func:`quantization_step`: most steps a detected grid may span (the grid test resolves a
#: hundredth of a step up to 2^24 steps in float64; a finer "grid" is a float format's own spacing)
MAX_GRID_STEPS = 1 << 24


def quantization_step(x: ArrayLike, *, tol: float = GRID_TOLERANCE) -> float:
    """The step ``q`` of a quantized signal: all samples on a uniform grid ``x0 + n q`` (within
    ``tol`` steps), as an integer wire quantity decoded to SI (CiA 402 per-mille torque, a 12-bit
    CubeMars field, counts of an encoder). ``0.0`` when the samples are not on such a grid or the
    grid would span more than :data:`MAX_GRID_STEPS` steps (a float signal: no common step can be
    shown from its values). A float32 signal is on the grid of its smallest spacing; that step is
    no coarser than the format's own rounding, so neither use of it (saturation, rounding floor)
    changes for float signals."""
    a = np.asarray(x, float).ravel()
    a = a[np.isfinite(a)]
    u = np.unique(a)
    if u.size < 3:
        return 0.0
    q0 = float(np.min(np.diff(u)))
    span = float(u[-1] - u[0])
    n_steps = round(span / q0)
    if q0 <= 0.0 or n_steps > MAX_GRID_STEPS:
        return 0.0
    q = span / n_steps  # the span over the whole number of steps: q0 refined by the grid's extent
    r = (u - u[0]) / q
    return q if bool(np.all(np.abs(r - np.round(r)) <= tol)) else 0.0


def _explained_by_quantization(a: np.ndarray, start: int, end: int, level: float, sign: float, q: float) -> bool:
    """Whether the flat run ``a[start:end]`` at an extreme ``level`` (``sign`` +1 at the max, -1 at
    the min) of a signal quantized with step ``q`` is a rounded smooth peak rather than clipping.

    A smooth peak ``x(d) = A - c d^2 / 2`` (``d`` in samples from the peak, ``c`` its curvature)
    rounds to its level ``L`` (``|A - L| <= q/2``) on the samples with ``x > L - q/2``, i.e. where
    ``A - x < q``: at most ``2 sqrt(2 q / c) + 1`` samples. The peak's parabola is the least-squares
    one through its flanks (the samples either side of the run, which clipping does not touch, out
    to where the signal has left the level by :data:`QUANT_FLANK_STEPS` steps, and at least as many
    as the run has). The run is explained iff the flanks reach that far, the parabola fits them to
    within quantization (rms residual <= :data:`QUANT_FIT_STEPS` steps), is concave towards the
    level, has its vertex in the run (or beyond the record's edge the run touches), rises at most
    :data:`QUANT_PEAK_STEPS` above the level, and the run is at most :data:`QUANT_RUN_MARGIN` times
    the bound (+1). A clipped peak has lost its top: the flanks' parabola rises above the level by
    what was cut, and the run outlasts the bound, as soon as the cut exceeds about one step (a
    smaller cut is indistinguishable from rounding and biases a fit less than the rounding does).
    """
    k = end - start
    first, last = start == 0, end == a.size
    depart = QUANT_FLANK_STEPS * q
    cap = a.size  # a peak that barely reaches its level stays on the level below for long
    n_min = max(k, 4)  # a fast peak's flank leaves the level within a few samples
    sides = []
    for flank, at_edge in ((a[max(0, start - cap):start][::-1], start < cap), (a[end:end + cap], end + cap > a.size)):
        y = sign * (flank - level)  # <= 0 on the flanks, 0 at the level
        gone = np.flatnonzero(y <= -depart)
        if gone.size == 0 and not at_edge:  # the signal never leaves the level: a plateau, not a peak
            return False
        sides.append(y.size if gone.size == 0 else min(y.size, max(n_min, int(gone[0]) + 1)))
    n_left, n_right = sides
    if n_left + n_right < 4:
        return False
    idx = np.r_[start - n_left:start, end:end + n_right]
    d = idx - 0.5 * (start + end - 1)
    y = sign * (a[idx] - level)
    coef = np.polyfit(d, y, 2)
    c = -2.0 * float(coef[0])  # curvature towards the level (> 0 at a peak)
    d_vertex = -float(coef[1]) / (2.0 * float(coef[0])) if coef[0] != 0.0 else math.inf
    half = 0.5 * k  # the vertex lies in the run, or (a run the record cuts) beyond the edge it touches
    if (first or last) and ((d_vertex > half and first and not last) or (d_vertex < -half and last and not first)):
        # one flank pins the vertex poorly: the best parabola with its vertex at the run's inner end
        d_vertex = half if first else -half
        sol, *_ = np.linalg.lstsq(np.c_[np.ones_like(d), (d - d_vertex) ** 2], y, rcond=None)
        c = -2.0 * float(sol[1])
        coef = np.array([-0.5 * c, c * d_vertex, float(sol[0]) - 0.5 * c * d_vertex**2])
    resid = y - np.polyval(coef, d)
    if not np.isfinite(c) or c <= 0.0 or float(np.sqrt(np.mean(resid**2))) > QUANT_FIT_STEPS * q:
        return False
    rise = float(np.polyval(coef, min(max(d_vertex, -half), half)))  # the top within the record
    if (d_vertex > half + 1.0 and not last) or (d_vertex < -half - 1.0 and not first) or rise > QUANT_PEAK_STEPS * q:
        return False
    return k <= QUANT_RUN_MARGIN * 2.0 * math.sqrt(2.0 * q / c) + 1.0


def check_saturation(
    signals: Mapping[str, ArrayLike],
    *,
    max_fraction: float = 0.002,
    min_run: int = 3,
    rel_tol: float = 1e-9,
    steps: Mapping[str, float] | None = None,
) -> list[Diagnosis]:
    """Clipping: samples sitting at the signal's own max/min in runs of >= ``min_run`` (flat tops).

    A smooth signal touches its extreme once per peak; a clipped one stays there. Flagged when the
    fraction of such samples exceeds ``max_fraction``.

    A quantized signal (an integer wire unit: ``steps[name]``, 0 for none; else
    :func:`quantization_step` detects it from the samples) sits on its extreme level for a few
    samples at every slow peak
    without being clipped; such runs do not count when the peak's curvature explains them
    (:func:`_explained_by_quantization`: at most ``2 sqrt(2 q / c) + 1`` samples for step ``q``
    and curvature ``c`` per sample^2). A limit that cuts more than about one step off a peak still
    counts. Unquantized (float) signals are judged as before (step 0: nothing is explained).
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
        q = float(steps[name]) if steps is not None and name in steps else quantization_step(a)
        frac_total = 0.0
        levels = []
        n_explained = 0
        for level, sign in ((hi, 1.0), (lo, -1.0)):
            at = np.abs(a - level) <= tol
            # runs of consecutive samples at the level
            edges = np.diff(np.concatenate([[0], at.astype(np.int8), [0]]))
            starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
            long = (ends - starts) >= min_run
            if q > 0.0:
                for i in np.flatnonzero(long):
                    if _explained_by_quantization(a, int(starts[i]), int(ends[i]), level, sign, q):
                        long[i] = False
                        n_explained += 1
            n_flat = int(np.sum((ends - starts)[long]))
            if n_flat:
                levels.append(level)
            frac_total += n_flat / a.size
        if n_explained:
            logger.debug("%s: %d flat peaks explained by its quantization step %.4g", name, n_explained, q)
        if frac_total > max_fraction:
            out.append(
                Diagnosis(
                    "saturation",
                    "error",
                    f"{name}: {frac_total:.1%} of samples are clipped flat at {levels} (saturated run): "
                    "reduce the excitation amplitude or raise the limit; a linear fit would be biased",
                    channel=name,
                    details={"fraction": frac_total, "levels": levels, "quantization_step": q},
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
    thr = float(special.betaincinv(q, n - q, 0.99))
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
