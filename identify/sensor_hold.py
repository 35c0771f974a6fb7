"""Outputs measured by a sensor slower than the loop: the sample-and-hold seen in the record.

A force sensor streaming at r < fs (e.g. a Bota serial sensor at 51200/sinc ≈ 1004 Hz read by a
2 kHz loop, the most its 460 800 baud link carries) leaves each value in the record for one or more
ticks. Record sample i then holds the value measured ``a_i`` ticks earlier, ``a_i`` its *age*: 0
where the value is new, 1, 2, ... while it is held. When the sensor's clock drifts against the
loop's (it is not phase-locked), the ages are independent of the signal, and the held channel is,
in expectation, the true one through the linear filter

    A(ω) = Σ_k p_k · exp(-jωk/fs)

with ``p_k`` the fraction of samples of age k (at r = fs/2 exactly: (1 + e^{-jω/fs})/2, a half-tick
delay and a magnitude cos(ω/(2fs))). Unmodelled, this filter biases the identified damping of a
stiff spring: at 200 Hz and fs = 2 kHz it is a 0.16 rad lag, which the fit reads as less spring
damping B_f and more motor damping B (their sum is unaffected).

The FRF path divides the H1 estimate of a held output by A(ω) (and its standard deviation by
|A(ω)|); |A| ≥ cos(πf/fs·k_max) stays well away from zero below fs/4 for ages up to 1. A constant
latency of the sensor itself (its filter's group delay, the transport) leaves no trace in the
record and is not estimated here: measure it and set it in the scene.

A channel counts as held when more than :data:`HELD_FRACTION` of its samples repeat the previous
value exactly (a measured, noisy signal does not repeat in float arithmetic) and it is not constant.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

logger = logging.getLogger(__name__)

__all__ = ["HELD_FRACTION", "MAX_AGE", "age_distribution", "compensate_frf", "held_outputs", "hold_response",
           "quantized_repeats"]

#: fraction of exact repeats above which a channel is treated as sampled-and-held
HELD_FRACTION = 0.05
#: ages (ticks) beyond which a channel is a stalled sensor rather than a slower one (not compensated)
MAX_AGE = 8


def ages(y: ArrayLike) -> NDArray[np.int64]:
    """Per sample: ticks since the value last changed (0 where it is new). 1-D input."""
    y = np.asarray(y)
    n = y.shape[0]
    new = np.ones(n, dtype=bool)
    new[1:] = y[1:] != y[:-1]
    idx = np.where(new, np.arange(n), 0)
    last = np.maximum.accumulate(idx)
    return np.arange(n) - last


def age_distribution(y: ArrayLike) -> NDArray[np.float64] | None:
    """``p_k`` (k = 0..max age) of a held channel, or None when the channel is not held (fewer than
    :data:`HELD_FRACTION` repeats, constant, or held longer than :data:`MAX_AGE` ticks)."""
    y = np.asarray(y, dtype=float).ravel()
    if y.size < 16 or not np.all(np.isfinite(y)) or np.ptp(y) == 0:
        return None
    a = ages(y)
    if np.mean(a > 0) <= HELD_FRACTION or a.max() > MAX_AGE:
        return None
    return np.bincount(a).astype(float) / a.size


def quantized_repeats(y: ArrayLike, *, window: int = 64, p_min: float = 1e-6) -> bool:
    """True when the repeats of ``y`` are those of a quantized signal, not of a slower sensor: the
    values sit on a lattice (:func:`hil.identify.frf.lattice_step`: whole counts, e.g. the difference
    of an encoder position divided by the period) and the repeats are NOT spread evenly over time.
    A sensor slower than the loop repeats on its own clock, independently of the signal, so the
    fraction of repeats is the same in every window of ``window`` samples (binomial scatter); a
    quantized derivative repeats where the signal changes by less than a count per sample (slow
    acceleration), so that fraction varies with the motion. Homogeneity is a chi-square test over the
    windows (rejected at ``p_min``)."""
    from scipy import special

    from hil.identify.frf import lattice_step

    a = np.asarray(y, dtype=float).ravel()
    if a.size < 4 * window or lattice_step(a) is None:
        return False
    rep = np.zeros(a.size, dtype=bool)
    rep[1:] = a[1:] == a[:-1]
    m = a.size // window
    counts = rep[: m * window].reshape(m, window).sum(axis=1).astype(float)
    p = counts.sum() / (m * window)
    if not 0 < p < 1:
        return False
    chi2 = float(np.sum((counts - window * p) ** 2) / (window * p * (1 - p)))
    return bool(special.chdtrc(m - 1, chi2) < p_min)


def hold_response(p: ArrayLike, w: ArrayLike, fs: float) -> NDArray[np.complex128]:
    """A(ω) = Σ_k p_k exp(-jωk/fs) at the angular frequencies ``w`` [rad/s]."""
    p = np.asarray(p, dtype=float)
    k = np.arange(p.size)
    return np.exp(-1j * np.outer(np.asarray(w, dtype=float), k) / fs) @ p


def held_outputs(pairs: Sequence[tuple[NDArray[Any], NDArray[Any]]], names: Sequence[str]
                 ) -> dict[str, NDArray[np.float64]]:
    """Output name -> pooled age distribution over the experiments, for the held outputs."""
    out: dict[str, NDArray[np.float64]] = {}
    for o, name in enumerate(names):
        counts: list[NDArray[np.float64]] = []
        for _u, y in pairs:
            col = np.asarray(y)[:, o] if np.ndim(y) == 2 else np.asarray(y)
            p = None if quantized_repeats(col) else age_distribution(col)
            if p is None:
                counts = []
                break
            counts.append(p * col.size)
        if counts:
            m = max(c.size for c in counts)
            tot = np.sum([np.pad(c, (0, m - c.size)) for c in counts], axis=0)
            out[name] = tot / tot.sum()
    return out


def compensate_frf(est: Any, held: Mapping[str, NDArray[np.float64]], fs: float) -> Any:
    """The FRF estimate with each held output's H divided by A(ω) and its std by |A(ω)|."""
    if not held:
        return est
    H = np.array(est.H, copy=True)
    sigma = np.array(est.sigma, copy=True)
    w = 2 * np.pi * np.asarray(est.f, dtype=float)
    for o, name in enumerate(est.output_names):
        if name in held:
            A = hold_response(held[name], w, fs)
            H[:, o, :] /= A[:, None]
            sigma[:, o, :] /= np.abs(A)[:, None]
            logger.info("output %s is sampled-and-held (mean age %.2f ticks): H1 compensated by A(ω)", name,
                     float(np.arange(held[name].size) @ held[name]))
    return dataclasses.replace(est, H=H, sigma=sigma)

