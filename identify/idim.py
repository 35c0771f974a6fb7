"""IDIM-LS: inverse-dynamics least squares from band-pass filtered derivatives of the position.

The robotics community's reference method (Gautier, Khalil; the EMPS benchmark's own estimator:
Janot, Gautier, Brunot, "Data set and reference models of EMPS", Nonlinear System Identification
Benchmarks workshop 2019, sec. 3.4 and its ``Script_IDIM_LS.m``), reproduced step by step:

1. the measured position ``q`` is low-pass filtered forward and backward (zero phase) with a
   Butterworth filter of order 4 at ``f_filter`` (default ``5 * f_dyn``, ``f_dyn`` = 20 Hz: the
   benchmark's 100 Hz at 1 kHz);
2. velocity and acceleration are central differences of the filtered position (the edge samples
   one-sided), and ``n_border`` = 50 samples are dropped at the start;
3. the inverse model ``u = M q'' + B q' + F_c sgn(q') + F_0`` is linear in the parameters: every
   column of the observation matrix and the measured force are decimated by ``r =
   round(0.8 (fs/2) / (2 f_dyn))`` (= 10 at 1 kHz) with an order-8 Chebyshev type-I low-pass
   (ripple 0.05 dB, cut-off ``0.8 / r`` of Nyquist) applied forward and backward, as MATLAB's
   ``decimate`` does (the samples kept are aligned on the last one, as there);
4. ordinary least squares; the standard deviations are the benchmark's
   ``std(e) sqrt(diag((X^T X)^-1))`` (white-residual formula: the residual of the decimated
   equation error is close to white at 100 Hz; it is the number the benchmark publishes).

Stribeck (``F_s exp(-(v/v_s)^2) sgn(v)``) is linear in ``F_s`` for a given ``v_s``: ``v_s`` is found
by a 1-D search of the residual sum of squares (bounded, log scale) with the rest solved linearly.

Closed loop: the regressors are built from the measured motion, not simulated from the force, so a
position controller feeding back the encoder does not bias the equation error the way it biases an
open-loop output-error fit (noise on ``q`` only enters through the heavily filtered derivatives).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import optimize, signal

from hil.identify.errors import DataQualityError
from hil.identify.friction import normalize_friction, parameter_names

logger = logging.getLogger(__name__)

__all__ = ["IdimResult", "decimate", "diffcent", "filtered_derivatives", "idim_columns", "idim_design", "idim_ls"]

#: the benchmark's dynamics bandwidth [Hz]: Butterworth at 5x, decimation to 2x of it
F_DYN = 20.0


def diffcent(y: ArrayLike, dt: float) -> NDArray[np.float64]:
    """Central differences ``(y[k+1] - y[k-1]) / (2 dt)``, one-sided at both ends (MATLAB ``diffcent``)."""
    yy = np.asarray(y, float)
    return np.concatenate([[yy[1] - yy[0]], (yy[2:] - yy[:-2]) / 2.0, [yy[-1] - yy[-2]]]) / dt


def decimate(x: ArrayLike, r: int) -> NDArray[np.float64]:
    """MATLAB's ``decimate(x, r)``: Chebyshev-I order 8, 0.05 dB, cut-off ``0.8/r``, forward-backward,
    keeping samples ``nbeg, nbeg + r, ...`` with ``nbeg = r - (r * ceil(n/r) - n)`` (1-based)."""
    xx = np.asarray(x, float)
    if r <= 1:
        return xx.copy()
    b, a = signal.cheby1(8, 0.05, 0.8 / r)
    y = signal.filtfilt(b, a, xx, padtype="odd", padlen=3 * (max(len(a), len(b)) - 1))
    n = xx.size
    nbeg = r - (r * int(np.ceil(n / r)) - n)
    return np.asarray(y[nbeg - 1 :: r], float)


def filtered_derivatives(q: ArrayLike, fs: float, f_filter: float | None = None
                         ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """``(q_f, v, a)``: the zero-phase Butterworth-filtered position (order 4, ``f_filter`` [Hz],
    default ``min(5 F_DYN, 0.4 fs)``) and its central-difference velocity and acceleration."""
    qq = np.asarray(q, float)
    fc = float(f_filter) if f_filter else min(5 * F_DYN, 0.4 * fs)
    if not 0 < fc < fs / 2:
        raise DataQualityError(f"IDIM filter cut-off {fc:g} Hz outside (0, {fs / 2:g}) Hz")
    b, a = signal.butter(4, fc / (fs / 2))
    qf = signal.filtfilt(b, a, qq, padlen=3 * (max(len(a), len(b)) - 1))
    dt = 1.0 / fs
    v = diffcent(qf, dt)
    return qf, v, diffcent(v, dt)


@dataclass
class IdimResult:
    """IDIM-LS estimate: ``theta`` (names of :func:`hil.identify.friction.parameter_names`), ``std``
    (the benchmark's formula), the decimation factor, the relative error ``100 |e| / |y|`` [%], the
    residual std [N], and ``cov`` (std^2-scaled (X^T X)^-1)."""

    names: tuple[str, ...]
    theta: NDArray[np.float64]
    std: NDArray[np.float64]
    cov: NDArray[np.float64]
    decimation: int
    relative_error_pct: float
    residual_std: float
    n: int
    f_filter: float

    def as_dict(self) -> dict[str, float]:
        return dict(zip(self.names, map(float, self.theta), strict=True))

    def to_dict(self) -> dict[str, Any]:
        return {"estimate": self.as_dict(), "std": dict(zip(self.names, map(float, self.std), strict=True)),
                "decimation": self.decimation, "relative_error_pct": self.relative_error_pct,
                "residual_std": self.residual_std, "n_samples": self.n, "filter_hz": self.f_filter}


def _columns(v: NDArray, a: NDArray, terms: Sequence[str], v_s: float) -> list[NDArray]:
    cols = [a, v]
    sg = np.sign(v)
    if "coulomb" in terms:
        cols.append(sg)
    if "stribeck" in terms:
        cols.append(np.exp(-((v / v_s) ** 2)) * sg)
    if "offset" in terms:
        cols.append(np.ones_like(v))
    return cols


def idim_design(q: ArrayLike, u: ArrayLike, fs: float, *, f_filter: float | None = None, n_border: int = 50,
                decimation: int | None = None, hold: bool = False) -> tuple[NDArray, NDArray, NDArray, int]:
    """``(v, a, y_d, r)``: the full-rate filtered velocity and acceleration after ``n_border`` (steps 1-2 of
    the module docstring), the decimated force ``y_d`` and the decimation factor ``r``.

    ``hold``: the force sample ``u_k`` acts over ``[t_k, t_k+1)`` (a zero-order hold, positions sampled
    before it: the suite's bench convention). The central difference ``q_k+1 - 2 q_k + q_k-1`` of a held
    mass makes the double central difference of :func:`filtered_derivatives` (over ``k-2..k+2``) equal to
    ``(u_k-2 + 3 u_k-1 + 3 u_k + u_k+1) / (8 M)`` exactly, so that FIR of the force is what the acceleration
    is regressed on; the benchmark's script (``hold=False``) uses ``u_k``, half a sample early (measured on a
    simulated axis: M +0.26 %, B -0.6 %, several standard deviations)."""
    qq = np.asarray(q, float)
    uu = np.asarray(u, float)
    if hold and uu.size > 3:  # the force seen by diffcent(diffcent(q)) at k: (u_k-2 + 3 u_k-1 + 3 u_k + u_k+1) / 8
        uu = np.convolve(np.pad(uu, (2, 1), mode="edge"), np.array([1.0, 3.0, 3.0, 1.0]) / 8.0, mode="valid")
    if qq.shape != uu.shape or qq.ndim != 1:
        raise DataQualityError(f"IDIM needs 1-D position and force of one length, got {qq.shape} and {uu.shape}")
    r = int(decimation) if decimation else max(round(0.8 * (fs / 2) / (2 * F_DYN)), 1)
    if qq.size < max(4 * n_border, 40 * r):
        raise DataQualityError(f"IDIM: {qq.size} samples are too few (need >= {max(4 * n_border, 40 * r)})")
    _, v, a = filtered_derivatives(qq, fs, f_filter)
    sl = slice(n_border - 1, None)  # MATLAB's n_border:N (1-based)
    return v[sl], a[sl], decimate(uu[sl], r), r


def idim_columns(v: NDArray, a: NDArray, terms: Sequence[str], r: int, v_s: float = 1.0) -> NDArray:
    """Decimated observation matrix (n_d, p-without-v_s) of the inverse model (module docstring)."""
    return np.column_stack([decimate(c, r) for c in _columns(v, a, terms, v_s)])


def idim_ls(
    q: ArrayLike, u: ArrayLike, fs: float, friction: Sequence[str] | str = ("coulomb", "offset"), *,
    f_filter: float | None = None, n_border: int = 50, decimation: int | None = None,
) -> IdimResult:
    """IDIM-LS of ``u = M q'' + B q' [+ F_c sgn q'] [+ F_s e^{-(q'/v_s)^2} sgn q'] [+ F_0]`` from the
    position ``q`` [m or rad] and the force ``u`` [N or N.m] sampled at ``fs`` [Hz] (module docstring)."""
    terms = normalize_friction(friction)
    v, a, yd, r = idim_design(q, u, fs, f_filter=f_filter, n_border=n_border, decimation=decimation)

    def solve(v_s: float) -> tuple[NDArray, NDArray, NDArray]:
        X = idim_columns(v, a, terms, r, v_s)
        beta, *_ = np.linalg.lstsq(X, yd, rcond=None)
        return beta, X, yd - X @ beta

    names = parameter_names(terms)
    v_s = 1.0
    if "stribeck" in terms:
        vmax = float(np.max(np.abs(v)))
        res = optimize.minimize_scalar(lambda lv: float(np.sum(solve(float(np.exp(lv)))[2] ** 2)),
                                       bounds=(np.log(vmax * 1e-3), np.log(vmax)), method="bounded",
                                       options={"xatol": 1e-3})
        v_s = float(np.exp(res.x))
    beta, X, e = solve(v_s)
    s_e = float(np.std(e, ddof=1))
    cov_b = s_e**2 * np.linalg.inv(X.T @ X)
    theta = list(beta)
    std = list(np.sqrt(np.diag(cov_b)))
    if "stribeck" in terms:  # insert v_s after F_s (std not from the linear fit: reported as NaN)
        i = names.index("v_s")
        theta.insert(i, v_s)
        std.insert(i, float("nan"))
        cov = np.full((len(names), len(names)), np.nan)
        keep = [j for j in range(len(names)) if j != i]
        cov[np.ix_(keep, keep)] = cov_b
    else:
        cov = cov_b
    rel = float(100 * np.linalg.norm(e) / np.linalg.norm(yd))
    logger.info("IDIM-LS %s: %s (relative error %.2f %%)", names, np.round(theta, 4), rel)
    return IdimResult(names, np.asarray(theta, float), np.asarray(std, float), cov, r, rel, s_e, int(yd.size),
                      float(f_filter or min(5 * F_DYN, 0.4 * fs)))
