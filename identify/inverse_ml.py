"""Inverse-dynamics maximum likelihood (IDIM-ML) with honest intervals: friction parameters from
position-only records, in open or closed loop.

Model. The decimated inverse model of :mod:`hil.identify.idim` (regressors from the band-pass
filtered derivatives of the measured position, force decimated the same way; the force aligned
with the double central difference of a held input, ``hold=True``)::

    y_d = X(v_s) beta + w

``beta`` the parameters entering linearly (``M, B, F_c, F_s, F_0``), ``v_s`` (Stribeck) inside the
regressor. The estimate is the least-squares one -- the maximum likelihood for a white Gaussian
equation error, the benchmark's own weighting -- found by :func:`scipy.optimize.least_squares` in z
(log of the positive parameters; ``v_s`` nonlinear).

Honest intervals. The equation error of a real axis is coloured (unmodelled dynamics, cogging, the
controller's reaction to disturbances): the white-residual formula ``s^2 (X^T X)^-1`` (what the
benchmark publishes) is then too narrow -- on EMPS by 1.7x (M) to 6x (F_0). The covariance reported
is the sandwich ``(J^T J)^-1 [sum_k J_k^H S_k J_k / n] (J^T J)^-1`` with the equation error's own
spectrum ``S`` (periodogram smoothed over ``2 n^(1/3) + 1`` bins, :func:`residual_spectrum`): the
covariance of the LS estimate whatever the colour. A generalized (noise-weighted) LS would be more
efficient under a correct model, but on a real axis it moves the estimates by several standard
deviations (EMPS: B +7 %, F_c -23 % with an AR(23) weighting: the weighting favours the
high-frequency band where the rigid-body model is least true), so the LS weighting is kept and
the colour is accounted for in the intervals. ``crb_std`` is the Cramér-Rao bound of the data in
the band the decimation keeps (below 0.8 of its Nyquist frequency) for a Gaussian equation error of
spectrum ``S``: the Whittle information ``sum_k J_k^H J_k / S_k`` -- the best any estimator could do
with that noise.

Why the inverse model. The EMPS axis -- and any position-controlled bench -- runs in closed loop:
the force is computed from past positions. An output-error fit that simulates the plant from the
recorded force and treats the output error as white noise is then biased by the feedback, which
correlates the force with the disturbance (Ljung, *System Identification*, 2nd ed., sec. 13.4;
measured on EMPS: B -5.3 %, F_c +6 % against the published values; with an AR noise model on the
position error, a one-step prediction error, worse: B +21 %, F_c -15 %, as the predictor follows the
encoder rather than the plant). The inverse model is regressed on the MEASURED motion: a disturbance
enters its regressors only through the encoder noise, which the 100 Hz filter removes, so it stays
consistent in closed loop; it is the benchmark's reference (IDIM-LS) with honest intervals. The
output-error simulation is what judges a model on held-out data
(:func:`hil.identify.friction_api.simulation_error`).

Encoder quantization: a whole-count encoder adds a white error of variance ``q^2/12`` to the
position; through the filter and the two differences it adds to the equation error, which the
sandwich and the innovation variance contain.

Posterior: emcee (:func:`hil.identify.posterior.sample_posterior`) on the white-noise likelihood
``-(m/2) log RSS`` (``sigma`` integrated out, Jeffreys prior; uniform prior in z within the bounds),
its samples then moved to the sandwich covariance (:func:`sandwich_adjust`, the curvature adjustment
of a misspecified likelihood). Stribeck's ``v_s`` moves on a log grid of precomputed regressors (200
points, linear interpolation) so that a walker step costs matrix products only.

Adequacy (on the AR innovations ``e``): whiteness (Ljung-Box) and a Lagrange-multiplier (score)
test for the friction terms the model lacks (``coulomb``, ``offset``): the whitened omitted columns
``X_x``, projected off the fitted ones, against ``e``: ``S = e^T X_x (X_x^T X_x)^-1 X_x^T e /
sigma_e^2 ~ chi^2(k)``. A linear (viscous-only) fit of a real axis fails it by orders of magnitude.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import optimize, stats
from scipy.signal import lfilter

from hil.identify.adequacy import AdequacyReport, AdequacyTest, whiteness_test
from hil.identify.errors import ConvergenceError
from hil.identify.fisher import normalized_pinv
from hil.identify.friction import FrictionModel, normalize_friction
from hil.identify.idim import IdimResult, idim_columns, idim_design, idim_ls

logger = logging.getLogger(__name__)

__all__ = ["AR_MAX", "ArNoise", "InverseFit", "InverseLogPosterior", "check_inverse_fit", "fit_ar", "fit_inverse_ml"]

#: largest AR order of the equation-error noise model (BIC chooses 0..AR_MAX)
AR_MAX = 30
#: Stribeck velocity grid (log-spaced points between the bounds) for the posterior
_VS_GRID = 200


@dataclass
class ArNoise:
    """``w_k = sum a_i w_{k-i} + e_k``: coefficients ``a`` (p,), innovation std ``sigma``. No constant:
    the equation error has zero mean under the model (a constant is the offset term ``F_0``, and its
    absence is what the omitted-friction test detects)."""

    a: NDArray[np.float64]
    sigma: float

    @property
    def order(self) -> int:
        return int(self.a.size)

    def whiten(self, w: NDArray[np.float64]) -> NDArray[np.float64]:
        """Innovations (..., n - p) of a sequence (..., n): the filter ``A(q^-1)`` applied."""
        A = np.concatenate([[1.0], -self.a])
        return np.asarray(lfilter(A, [1.0], w, axis=-1)[..., self.order :], float)


def fit_ar(w: ArrayLike, p_max: int = AR_MAX) -> ArNoise:
    """AR(p) of ``w`` by least squares, order by BIC over ``0..p_max`` (common sample range)."""
    ww = np.asarray(w, float)
    n = ww.size
    y = ww[p_max:]
    best: tuple[float, ArNoise] | None = None
    for p in range(p_max + 1):
        X = np.column_stack([ww[p_max - i : n - i] for i in range(1, p + 1)]) if p else np.zeros((y.size, 0))
        coef = np.linalg.lstsq(X, y, rcond=None)[0] if p else np.zeros(0)
        s2 = max(float(np.mean((y - X @ coef) ** 2)), 1e-300)
        bic = y.size * np.log(s2) + p * np.log(y.size)
        if best is None or bic < best[0]:
            best = (bic, ArNoise(np.asarray(coef, float), float(np.sqrt(s2))))
    assert best is not None
    return best[1]


class InverseProblem:
    """The decimated inverse model of one or several records (stacked; one AR model) for a model."""

    def __init__(self, model: FrictionModel, parts: Sequence[tuple[NDArray, NDArray, NDArray, int]]) -> None:
        self.model = model
        self.terms = model.terms
        self.parts = list(parts)
        self.y = [p[2] for p in self.parts]
        self.has_vs = "stribeck" in self.terms
        self.lin = [i for i, n in enumerate(model.names) if n != "v_s"]
        self.i_vs = model.names.index("v_s") if self.has_vs else -1
        if self.has_vs:
            lo, hi = model.lower[self.i_vs], model.upper[self.i_vs]
            self.grid = np.geomspace(lo, hi, _VS_GRID)
            self.cols = [np.stack([self._X(p, float(g)) for g in self.grid]) for p in self.parts]
        else:
            self.cols = [self._X(p, 1.0) for p in self.parts]

    def _X(self, part: tuple[NDArray, NDArray, NDArray, int], v_s: float) -> NDArray:
        v, a, _, r = part
        return idim_columns(v, a, self.terms, r, v_s)

    def design(self, theta: NDArray[np.float64]) -> list[NDArray]:
        """Per record: the regressors (B, n_d, p_lin) at each parameter vector's ``v_s``."""
        nb = theta.shape[0]
        if not self.has_vs:
            return [np.broadcast_to(c, (nb, *c.shape)) for c in self.cols]
        lv = np.log(np.clip(theta[:, self.i_vs], self.grid[0], self.grid[-1]))
        pos = np.interp(lv, np.log(self.grid), np.arange(self.grid.size))
        i0 = np.minimum(np.floor(pos).astype(int), self.grid.size - 2)
        fr = (pos - i0)[:, None, None]
        return [c[i0] * (1 - fr) + c[i0 + 1] * fr for c in self.cols]

    def residuals(self, theta: ArrayLike) -> list[NDArray[np.float64]]:
        """Equation errors ``y_d - X beta`` (B, n_d) per record."""
        th = np.atleast_2d(np.asarray(theta, float))
        beta = th[:, self.lin]
        return [y - np.einsum("bnk,bk->bn", X, beta) for y, X in zip(self.y, self.design(th), strict=True)]

    def innovations(self, theta: ArrayLike, ar: ArNoise) -> NDArray[np.float64]:
        """Whitened equation errors (B, m), records concatenated."""
        return np.concatenate([ar.whiten(w) for w in self.residuals(theta)], axis=-1)


@dataclass
class InverseFit:
    """IDIM-ML of one model: ``theta``, ``z``, AR noise, Fisher (z), ``cov_z``, ``cov_theta``,
    ``crb_std`` (physical), AR innovations ``e`` and their Jacobian ``J`` (de/dz), the IDIM-LS start."""

    model: FrictionModel
    problem: InverseProblem
    theta: NDArray[np.float64]
    z: NDArray[np.float64]
    ar: ArNoise
    fisher: NDArray[np.float64]
    cov_z: NDArray[np.float64]
    cov_theta: NDArray[np.float64]
    crb_std: NDArray[np.float64]
    e: NDArray[np.float64]
    J: NDArray[np.float64]
    idim: IdimResult
    n_rounds: int
    elapsed_s: float
    #: equation error (unweighted) and its z-derivative: the LS fit the estimate minimizes
    w: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    Jw: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 0)))

    @property
    def n(self) -> int:
        """Decimated samples of the equation error (records stacked)."""
        return int(self.w.size)

    @property
    def k(self) -> int:
        """Free parameters of the model."""
        return int(self.theta.size)

    @property
    def bic(self) -> float:
        """Bayesian information criterion of the fit's own (white Gaussian) likelihood of the equation
        error, ``n log(RSS/n) + k log n`` (lower: better supported). With a coloured equation error the
        effective sample size is smaller than ``n``, so differences are overstated in favour of the richer
        model: the model choice also reports the held-out simulation error."""
        return float(self.n * np.log(np.mean(self.w**2)) + self.k * np.log(self.n))

    @property
    def aic(self) -> float:
        """Akaike information criterion ``n log(RSS/n) + 2 k``."""
        return float(self.n * np.log(np.mean(self.w**2)) + 2 * self.k)


def _jacobian(prob: InverseProblem, ar: ArNoise, z: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
    m = prob.model
    h = np.where(m.log_mask, 1e-6, 1e-6 * np.maximum(np.abs(z), 1e-3 * (m.upper - m.lower)))
    Z = np.concatenate([z[None], z + np.diag(h), z - np.diag(h)])
    E = prob.innovations(m.from_z(Z), ar)
    p = z.size
    return E[0], ((E[1 : p + 1] - E[p + 1 :]) / (2 * h[:, None])).T


def residual_spectrum(w: NDArray[np.float64]) -> NDArray[np.float64]:
    """Two-sided power spectrum (n,) of a residual on its n-point DFT grid: the periodogram
    ``|W_k|^2 / n`` smoothed by a Daniell (moving-average) window of ``2 m + 1`` bins, ``m =
    round(n^(1/3))`` (circular): consistent for a spectrum smooth on that scale, the usual
    bandwidth rate of a lag-window (HAC) estimate."""
    from scipy.ndimage import uniform_filter1d

    n = w.size
    m = max(2, round(n ** (1.0 / 3.0)))
    return np.asarray(uniform_filter1d(np.abs(np.fft.fft(w)) ** 2 / n, 2 * m + 1, mode="wrap"), float)


def fit_inverse_ml(
    records: Sequence[tuple[ArrayLike, ArrayLike]], fs: float, friction: Sequence[str] | str = ("coulomb", "offset"),
    *, units: str = "linear", theta0: dict[str, float] | None = None, ar_max: int = AR_MAX, hold: bool = True,
) -> InverseFit:
    """IDIM-ML (module docstring) of the friction model ``friction`` from records ``[(q, u), ...]``:
    position ``q`` [m or rad] and force ``u`` [N or N.m] at ``fs`` [Hz]; ``hold``: the force is held
    over each period after the position is sampled (:func:`hil.identify.idim.idim_design`)."""
    t0 = time.perf_counter()
    terms = normalize_friction(friction)
    recs = [(np.asarray(q, float), np.asarray(u, float)) for q, u in records]
    idim = idim_ls(*recs[0], fs, terms) if len(recs) == 1 else idim_ls(
        np.concatenate([q for q, _ in recs]), np.concatenate([u for _, u in recs]), fs, terms)
    start = idim.as_dict()
    scale = float(max(np.std(np.concatenate([u for _, u in recs])), 1e-12))
    start["M"], start["B"] = abs(start["M"]), abs(start["B"])
    for n in ("F_c", "F_s"):
        if n in start:
            start[n] = max(start[n], 1e-4 * scale)
    start.update(theta0 or {})
    model = FrictionModel(terms, nominal=start, units=units, output="position", zoh_fs=fs,
                          force_scale=float(max(np.max(np.abs(u)) for _, u in recs)))
    prob = InverseProblem(model, [idim_design(q, u, fs, hold=hold) for q, u in recs])
    lo, hi = model.z_bounds()
    inner = (lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
    white = ArNoise(np.zeros(0), 1.0)

    def resid(zz: NDArray[np.float64]) -> NDArray[np.float64]:
        e = prob.innovations(model.from_z(zz), white)[0]
        return np.where(np.isfinite(e), e, 1e6)

    sol = optimize.least_squares(resid, np.clip(model.to_z(model.nominal), *inner), bounds=(lo, hi), method="trf",
                                 x_scale="jac", jac=lambda zz: _jacobian(prob, white, zz)[1], max_nfev=200)
    z = np.clip(sol.x, *inner)
    if not np.all(np.isfinite(z)):
        raise ConvergenceError("inverse-dynamics ML did not converge")
    theta = model.from_z(z)
    w, Jw = _jacobian(prob, white, z)  # equation error and its z-derivative (records stacked)
    ar = fit_ar(w, ar_max)
    # sandwich: cov of the LS estimate under the equation error's own spectrum (frequency domain)
    nw = int(w.size)
    Sf = residual_spectrum(w)
    JF = np.fft.fft(Jw, axis=0)
    meat = np.real(JF.conj().T @ (JF * Sf[:, None])) / nw
    bread = normalized_pinv(Jw.T @ Jw)
    cov_z = bread @ meat @ bread
    e, J = _jacobian(prob, ar, z)  # innovations (adequacy tests)
    ar = ArNoise(ar.a, float(np.sqrt(np.mean(e**2))))
    # Cramer-Rao bound of the band the decimation keeps (|f| < 0.8 of its Nyquist; above it data and
    # regressors are both filtered away): Whittle information sum J_k^H J_k / S_k with the smoothed spectrum
    fk = np.abs(np.fft.fftfreq(nw))
    keep = fk < 0.8 * 0.5
    F = np.real(JF[keep].conj().T @ (JF[keep] / np.maximum(Sf[keep], 1e-300)[:, None])) / nw
    d = np.where(model.log_mask, theta, 1.0)
    cov_theta = cov_z * np.outer(d, d)
    crb_std = np.sqrt(np.clip(np.diag(normalized_pinv(F)), 0, None)) * d
    logger.info("IDIM-ML %s: %s (sd %s), residual AR(%d), sigma_e %.4g", model.names, np.round(theta, 4),
                np.round(np.sqrt(np.diag(cov_theta)), 4), ar.order, ar.sigma)
    return InverseFit(model, prob, theta, z, ar, F, cov_z, cov_theta, np.abs(crb_std), e, J, idim, 1,
                      time.perf_counter() - t0, w=w, Jw=Jw)


class InverseLogPosterior:
    """Vectorized log-posterior in z for :func:`hil.identify.posterior.sample_posterior` (module
    docstring): white-noise Gaussian likelihood of the equation error, ``-(m/2) log RSS`` (sigma
    integrated out under the Jeffreys prior), uniform prior in z within the bounds."""

    noise = "equation error, white likelihood; samples sandwich-adjusted for its spectrum"

    def __init__(self, fit: InverseFit) -> None:
        self.model = fit.model
        self.prob = fit.problem
        self.white = ArNoise(np.zeros(0), 1.0)
        self.lo, self.hi = self.model.z_bounds()
        self.ndim = self.lo.size
        self.names = self.model.names
        self.m = fit.w.size

    def __call__(self, z: ArrayLike) -> NDArray[np.float64]:
        zz = np.atleast_2d(np.asarray(z, float))
        inside = np.all((zz >= self.lo) & (zz <= self.hi), axis=-1)
        out = np.full(zz.shape[0], -np.inf)
        if np.any(inside):
            with np.errstate(all="ignore"):
                e = self.prob.innovations(self.model.from_z(zz[inside]), self.white)
                ll = -0.5 * self.m * np.log(np.sum(e**2, axis=-1))
            out[inside] = np.where(np.isfinite(ll), ll, -np.inf)
        return out


def sandwich_adjust(fit: InverseFit, chain_z: NDArray[np.float64]) -> NDArray[np.float64]:
    """Posterior samples (n, p) in z moved to the sandwich covariance: ``z_ML + C (z - z_ML)`` with
    ``C = L_s L_w^-1`` (Cholesky factors of the sandwich and of the white-likelihood covariance
    ``sigma_w^2 (J^T J)^-1``): the curvature adjustment of Ribatet, Cooley, Davison, *Statistica
    Sinica* 22 (2012) 813 (a white-noise likelihood of coloured data is too sharp by exactly this)."""
    s2 = float(np.mean(fit.w**2))
    cw = s2 * normalized_pinv(fit.Jw.T @ fit.Jw)
    d = np.sqrt(np.clip(np.diag(cw), 1e-300, None))
    ds = np.sqrt(np.clip(np.diag(fit.cov_z), 1e-300, None))
    eye = 1e-12 * np.eye(d.size)
    Lw = d[:, None] * np.linalg.cholesky(cw / np.outer(d, d) + eye)
    Ls = ds[:, None] * np.linalg.cholesky(fit.cov_z / np.outer(ds, ds) + eye)
    C = Ls @ np.linalg.inv(Lw)
    return np.asarray(fit.z + (chain_z - fit.z) @ C.T, float)


def _score(e: NDArray, X: NDArray, J: NDArray, sigma: float) -> tuple[float, int]:
    Q, _ = np.linalg.qr(J)
    Xp = X - Q @ (Q.T @ X)
    coef, *_ = np.linalg.lstsq(Xp, e, rcond=None)
    return float(e @ (Xp @ coef)) / sigma**2, int(np.linalg.matrix_rank(Xp))


def check_inverse_fit(fit: InverseFit, *, alpha: float = 1e-3, lags: int = 20) -> AdequacyReport:
    """Whiteness of the innovations and the omitted-friction score test (module docstring);
    Bonferroni over the tests."""
    missing = [t for t in ("coulomb", "offset") if t not in fit.model.terms]
    a = alpha / (1 + bool(missing))
    tests = [whiteness_test(fit.e, lags=lags, alpha=a, channel="force (inverse model)")]
    if missing:
        cols = []
        for part in fit.problem.parts:
            v, _, _, r = part
            extra = []
            if "coulomb" in missing:
                extra.append(np.sign(v))
            if "offset" in missing:
                extra.append(np.ones_like(v))
            from hil.identify.idim import decimate

            X = np.column_stack([decimate(c, r) for c in extra])
            cols.append(np.column_stack([fit.ar.whiten(X[:, j]) for j in range(X.shape[1])]))
        S, k = _score(fit.e, np.concatenate(cols), fit.J, fit.ar.sigma)
        p = float(stats.chi2.sf(S, max(k, 1)))
        tests.append(AdequacyTest("omitted_friction", "force (inverse model)", S, p >= a, p, None, a,
                                  {"terms": missing, "dof": k}))
    rep = AdequacyReport(tests)
    if rep.misfit:
        logger.warning("friction model %s: %s", fit.model.terms or "linear", "; ".join(rep.reasons))
    return rep


def summary_row(fit: InverseFit) -> dict[str, Any]:
    """Estimates, CRB std, AR order, innovation std [force unit], BIC/AIC of a fit (for model choice)."""
    return {"friction": list(fit.model.terms), "parameters": dict(zip(fit.model.names, map(float, fit.theta),
                                                                     strict=True)),
            "crb_std": dict(zip(fit.model.names, map(float, fit.crb_std), strict=True)),
            "ar_order": fit.ar.order, "innovation_std": fit.ar.sigma, "n_equation_error": fit.n, "k": fit.k,
            "bic": fit.bic, "aic": fit.aic}
