"""Inverse-dynamics maximum likelihood (IDIM-ML) with honest intervals: friction parameters from
position-only records, in open or closed loop.

Model. The decimated inverse model of :mod:`hil.identify.inverse_design` (regressors from the
band-pass filtered derivatives of the measured positions, forces decimated the same way; a held
force aligned with the double central difference, ``hold=True``), for any model of
:mod:`hil.identify.inverse_models` (the ``mbk`` joints, the SDEA): per equation ``e``::

    y_e = X_e(v_s) beta + w_e

``beta`` the parameters entering linearly (``M, B, K``, ``K_f, B_f``, ``F_c, F_s, F_0``, ...), the
Stribeck velocities ``v_s`` inside the regressors. A model whose point columns or friction velocity
feel the held force's acceleration steps (the SDEA: :meth:`InverseDynamicsModel.held_input`,
:mod:`hil.identify.held_kinematics`) has its records rebuilt with the steps at the LS start's values
(and the LS start recomputed) before the fit. The estimate is the least-squares one, every
equation scaled by its residual standard deviation (iterated: the maximum likelihood for white
Gaussian equation errors of unknown variances; one equation: the benchmark's own weighting), found by
:func:`scipy.optimize.least_squares` in z (log of the positive parameters; ``v_s`` nonlinear).

Honest intervals. The equation error of a real axis is coloured (unmodelled dynamics, cogging, the
controller's reaction to disturbances): the white-residual formula ``s^2 (X^T X)^-1`` (what the
benchmark publishes) is then too narrow -- on EMPS by 1.7x (M) to 6x (F_0). The covariance reported
is the sandwich ``(J^T J)^-1 [sum_k J_k^H S_k J_k / n] (J^T J)^-1`` with the (scaled) equation errors'
own spectral matrix ``S`` (cross-periodogram smoothed over ``2 n^(1/3) + 1`` bins,
:func:`residual_spectrum`; ``n_e x n_e`` per bin): the covariance of the LS estimate whatever the colour
and whatever the correlation between equations. A generalized (noise-weighted) LS would be more
efficient under a correct model, but on a real axis it moves the estimates by several standard
deviations (EMPS: B +7 %, F_c -23 % with an AR(23) weighting: the weighting favours the
high-frequency band where the rigid-body model is least true), so the LS weighting is kept and
the colour is accounted for in the intervals. ``crb_std`` is the Cramér-Rao bound of the data in
the band the decimation keeps (below 0.8 of its Nyquist frequency) for a Gaussian equation error of
spectrum ``S``: the Whittle information ``sum_k J_k^H S_k^-1 J_k`` -- the best any estimator could do
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
``-sum_e (m/2) log RSS_e`` (each equation's ``sigma`` integrated out, Jeffreys prior; uniform prior in
z within the bounds),
its samples then moved to the sandwich covariance (:func:`sandwich_adjust`, the curvature adjustment
of a misspecified likelihood). Stribeck's ``v_s`` moves on a log grid of precomputed regressors (200
points, linear interpolation) so that a walker step costs matrix products only.

Adequacy (on the AR innovations ``e`` of each equation, normalized by their std): whiteness (Ljung-Box,
per equation) and a Lagrange-multiplier (score) test for the friction terms the model lacks
(``coulomb``, ``offset``, on every friction joint): the whitened omitted columns ``X_x``, projected off
the fitted ones, against ``e``: ``S = e^T X_x (X_x^T X_x)^-1 X_x^T e ~ chi^2(k)``, Bonferroni over the
tests. A linear (viscous-only) fit of a real axis fails it by orders of magnitude.
"""

from __future__ import annotations

import itertools
import logging
import time
from collections.abc import Callable, Sequence
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
from hil.identify.idim import IdimResult, idim_ls
from hil.identify.inverse_design import InverseProblem, InverseRecord, inverse_ls, inverse_part
from hil.identify.inverse_models import InverseDynamicsModel

logger = logging.getLogger(__name__)

__all__ = ["AR_MAX", "ArNoise", "InverseFit", "InverseLogPosterior", "check_inverse_fit", "fit_ar", "fit_inverse",
           "fit_inverse_ml"]

#: largest AR order of the equation-error noise model (BIC chooses 0..AR_MAX)
AR_MAX = 60


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


@dataclass
class InverseFit:
    """IDIM-ML of one model: ``theta``, ``z``, per-equation AR noise ``ars`` and scales, Fisher (z),
    ``cov_z``, ``cov_theta``, ``crb_std`` (physical), the normalized AR innovations ``e`` (equations
    one after the other) and their Jacobian ``J`` (de/dz), the LS start ``idim``."""

    model: InverseDynamicsModel
    problem: InverseProblem
    theta: NDArray[np.float64]
    z: NDArray[np.float64]
    ars: list[ArNoise]
    fisher: NDArray[np.float64]
    cov_z: NDArray[np.float64]
    cov_theta: NDArray[np.float64]
    crb_std: NDArray[np.float64]
    e: NDArray[np.float64]
    J: NDArray[np.float64]
    idim: IdimResult
    n_rounds: int
    elapsed_s: float
    #: equation errors (n_d, n_e) (unscaled) and their z-derivative (n_d, n_e, p): the LS fit the estimate minimizes
    w: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 1)))
    Jw: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 1, 0)))
    #: per equation, the innovations' slice of ``e``
    slices: list[slice] = field(default_factory=list)

    @property
    def ar(self) -> ArNoise:
        """The AR noise model of the first equation (the actuator's)."""
        return self.ars[0]

    @property
    def n(self) -> int:
        """Decimated samples of the equation errors (records stacked, every equation)."""
        return int(self.w.size)

    @property
    def k(self) -> int:
        """Free parameters of the model."""
        return int(self.theta.size)

    @property
    def bic(self) -> float:
        """Bayesian information criterion of the fit's own (white Gaussian) likelihood of the equation
        errors, ``sum_e n_e log(RSS_e/n_e) + k log n`` (lower: better supported). With a coloured equation
        error the effective sample size is smaller than ``n``, so differences are overstated in favour of
        the richer model: the model choice also reports the held-out simulation error."""
        return float(self.w.shape[0] * np.sum(np.log(np.mean(self.w**2, axis=0))) + self.k * np.log(self.n))

    @property
    def aic(self) -> float:
        """Akaike information criterion ``sum_e n_e log(RSS_e/n_e) + 2 k``."""
        return float(self.w.shape[0] * np.sum(np.log(np.mean(self.w**2, axis=0))) + 2 * self.k)


def _fd(prob: InverseProblem, z: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
    """Equation errors (n, n_e) at ``z`` and their central-difference Jacobian (n, n_e, p) in z."""
    m = prob.model
    h = np.where(m.log_mask, 1e-6, 1e-6 * np.maximum(np.abs(z), 1e-3 * (m.upper - m.lower)))
    Z = np.concatenate([z[None], z + np.diag(h), z - np.diag(h)])
    W = prob.stacked(m.from_z(Z))
    p = z.size
    return W[0], np.moveaxis((W[1 : p + 1] - W[p + 1 :]) / (2 * h[:, None, None]), 0, -1)


def _innovations(prob: InverseProblem, ars: Sequence[ArNoise], x: NDArray) -> NDArray:
    """AR innovations of a stacked sequence ``x`` (n, n_e, ...) per record and equation, normalized by
    each equation's innovation std, equations one after the other (m_total, ...)."""
    out = []
    for e, ar in enumerate(ars):
        k0 = 0
        for part in prob.parts:
            k1 = k0 + part.y.shape[0]
            out.append(ar.whiten(np.moveaxis(x[k0:k1, e], 0, -1)).T / ar.sigma)
            k0 = k1
    return np.concatenate(out)


def residual_spectrum(w: NDArray[np.float64]) -> NDArray[np.complex128]:
    """Two-sided spectral matrix (n, n_e, n_e) of residuals (n,) or (n, n_e) on their n-point DFT grid:
    the cross-periodogram ``W_k W_k^H / n`` smoothed by a Daniell (moving-average) window of ``2 m + 1``
    bins, ``m = round(n^(1/3))`` (circular): consistent for a spectrum smooth on that scale, the usual
    bandwidth rate of a lag-window (HAC) estimate. One residual: the (n, 1, 1) smoothed periodogram."""
    from scipy.ndimage import uniform_filter1d

    ww = np.asarray(w, float).reshape(len(w), -1)
    n = ww.shape[0]
    m = max(2, round(n ** (1.0 / 3.0)))
    W = np.fft.fft(ww, axis=0)
    P = W[:, :, None] * W[:, None, :].conj() / n
    return np.asarray(uniform_filter1d(P.real, 2 * m + 1, axis=0, mode="wrap")
                      + 1j * uniform_filter1d(P.imag, 2 * m + 1, axis=0, mode="wrap"), complex)


def fit_inverse(
    make_model: Callable[[dict[str, float], dict[str, float]], InverseDynamicsModel], records: Sequence[InverseRecord],
    fs: float, *, f_dyn: float | None = None, hold: bool = True, theta0: dict[str, float] | None = None,
    ar_max: int = AR_MAX, start: IdimResult | None = None,
) -> InverseFit:
    """IDIM-ML (module docstring) of the model ``make_model(nominal, scale)`` (``nominal``: data-derived
    values, ``scale``: ranges of the parameters of any sign; ``({}, {})``: defaults) from records
    :class:`~hil.identify.inverse_design.InverseRecord` at ``fs`` [Hz]; ``f_dyn`` [Hz] the dynamics
    bandwidth (None: the benchmark's 20 Hz); ``start`` the LS start (default
    :func:`~hil.identify.inverse_design.inverse_ls`); ``theta0`` overrides it."""
    t0 = time.perf_counter()
    model0 = make_model({}, {})
    parts = [inverse_part(model0, r, fs, f_dyn=f_dyn, hold=hold) for r in records]
    idim = start if start is not None else inverse_ls(model0, parts)
    if hold and any(model0.held_input(idim.theta, r.Y) is not None for r in records):
        # the held force's acceleration jumps (point columns, velocity between samples) at the start's values
        parts = [inverse_part(model0, r, fs, f_dyn=f_dyn, hold=hold, theta=idim.theta) for r in records]
        if start is None:
            idim = inverse_ls(model0, parts)
    fscale = float(max(np.std(np.concatenate([p.y[:, 0] for p in parts])), 1e-12))
    nominal, scale = {}, {}
    for par, v, sd in zip(model0.parameters, idim.theta, idim.std, strict=True):
        if par.log:
            floor = 1e-4 * fscale if par.name[:3] in ("F_c", "F_s") else 1e-300
            nominal[par.name] = max(abs(float(v)), floor)
        else:
            nominal[par.name] = float(v)
            if np.isfinite(sd):
                scale[par.name] = 100.0 * float(sd)
    nominal.update(theta0 or {})
    model = make_model(nominal, scale)
    if model.names != model0.names:
        raise ConvergenceError(f"model parameters changed with the start: {model0.names} -> {model.names}")
    prob = InverseProblem(model, parts)
    n_e = len(model.equations)
    lo, hi = model.z_bounds()
    inner = (lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
    z = np.clip(model.to_z(model.nominal), *inner)
    sc = np.maximum(np.std(prob.stacked(model.nominal)[0], axis=0), 1e-300)
    rounds = 1 if n_e == 1 else 3  # several equations: reweight by each equation's residual std (iterated)
    for _ in range(rounds):
        def resid(zz: NDArray[np.float64], sc: NDArray = sc) -> NDArray[np.float64]:
            e = (prob.stacked(model.from_z(zz))[0] / sc).ravel()
            return np.where(np.isfinite(e), e, 1e6)

        def jac(zz: NDArray[np.float64], sc: NDArray = sc) -> NDArray[np.float64]:
            return (_fd(prob, zz)[1] / sc[None, :, None]).reshape(-1, zz.size)

        sol = optimize.least_squares(resid, z, bounds=(lo, hi), method="trf", x_scale="jac", jac=jac, max_nfev=200)
        z = np.clip(sol.x, *inner)
        if not np.all(np.isfinite(z)):
            raise ConvergenceError("inverse-dynamics ML did not converge")
        sc = np.maximum(np.sqrt(np.mean(prob.stacked(model.from_z(z))[0] ** 2, axis=0)), 1e-300)
    theta = model.from_z(z)
    w, Jw = _fd(prob, z)  # equation errors and their z-derivative (records stacked)
    # sandwich: cov of the (scaled) LS estimate under the equation errors' own spectral matrix
    wt, Jt = w / sc, Jw / sc[None, :, None]
    nw = int(w.shape[0])
    Sf = residual_spectrum(wt)
    JF = np.fft.fft(Jt, axis=0)  # (n, n_e, p)
    meat = np.real(np.einsum("fep,fed,fdq->pq", JF.conj(), Sf, JF)) / nw
    bread = normalized_pinv(np.einsum("nep,neq->pq", Jt, Jt))
    cov_z = bread @ meat @ bread
    # Cramer-Rao bound of the band the decimation keeps (|f| < 0.8 of its Nyquist; above it data and
    # regressors are both filtered away): Whittle information sum J_k^H S_k^-1 J_k with the smoothed spectrum
    keep = np.abs(np.fft.fftfreq(nw)) < 0.8 * 0.5
    Sk = Sf[keep] + 1e-300 * np.eye(n_e)
    F = np.real(np.einsum("fep,fed,fdq->pq", JF[keep].conj(), np.linalg.inv(Sk), JF[keep])) / nw
    d = np.where(model.log_mask, theta, 1.0)
    cov_theta = cov_z * np.outer(d, d)
    crb_std = np.sqrt(np.clip(np.diag(normalized_pinv(F)), 0, None)) * d
    ars = [fit_ar(w[:, k], ar_max) for k in range(n_e)]
    ars = [ArNoise(ar.a, 1.0) for ar in ars]
    raw = [_innovations(prob, [ar], w[:, k : k + 1]) for k, ar in enumerate(ars)]
    ars = [ArNoise(ar.a, float(np.sqrt(np.mean(r**2)))) for ar, r in zip(ars, raw, strict=True)]
    e, J = _innovations(prob, ars, w), _innovations(prob, ars, Jw)
    sizes = np.cumsum([0] + [r.size for r in raw])
    slices = [slice(int(a), int(b)) for a, b in itertools.pairwise(sizes)]
    logger.info("IDIM-ML %s: %s (sd %s), residual AR%s", model.names, np.round(theta, 5),
                np.round(np.sqrt(np.diag(cov_theta)), 5), [ar.order for ar in ars])
    return InverseFit(model, prob, theta, z, ars, F, cov_z, cov_theta, np.abs(crb_std), e, J, idim, rounds,
                      time.perf_counter() - t0, w=w, Jw=Jw, slices=slices)


def fit_inverse_ml(
    records: Sequence[tuple[ArrayLike, ArrayLike]], fs: float, friction: Sequence[str] | str = ("coulomb", "offset"),
    *, units: str = "linear", theta0: dict[str, float] | None = None, ar_max: int = AR_MAX, hold: bool = True,
    f_dyn: float | None = None,
) -> InverseFit:
    """IDIM-ML of the 1-DOF friction model ``friction`` from records ``[(q, u), ...]``: position ``q``
    [m or rad] and force ``u`` [N or N.m] at ``fs`` [Hz]; ``hold``: the force is held over each period
    after the position is sampled (:func:`hil.identify.idim.held_force`). The start is the benchmark's
    IDIM-LS (:func:`hil.identify.idim.idim_ls`)."""
    terms = normalize_friction(friction)
    recs = [(np.asarray(q, float), np.asarray(u, float)) for q, u in records]
    idim = idim_ls(*recs[0], fs, terms) if len(recs) == 1 else idim_ls(
        np.concatenate([q for q, _ in recs]), np.concatenate([u for _, u in recs]), fs, terms)
    umax = float(max(np.max(np.abs(u)) for _, u in recs))

    def make(nominal: dict[str, float], scale: dict[str, float]) -> InverseDynamicsModel:
        return FrictionModel(terms, nominal=nominal, units=units, output="position", zoh_fs=fs, force_scale=umax)

    return fit_inverse(make, [InverseRecord(q[:, None], u[:, None]) for q, u in recs], fs, f_dyn=f_dyn, hold=hold,
                       theta0=theta0, ar_max=ar_max, start=idim)


class InverseLogPosterior:
    """Vectorized log-posterior in z for :func:`hil.identify.posterior.sample_posterior` (module
    docstring): white-noise Gaussian likelihood of each equation's error, ``-sum_e (m/2) log RSS_e``
    (sigma integrated out under the Jeffreys prior), uniform prior in z within the bounds."""

    noise = "equation error, white likelihood; samples sandwich-adjusted for its spectrum"

    def __init__(self, fit: InverseFit) -> None:
        self.model = fit.model
        self.prob = fit.problem
        self.lo, self.hi = self.model.z_bounds()
        self.ndim = self.lo.size
        self.names = self.model.names
        self.m = fit.w.shape[0]

    def __call__(self, z: ArrayLike) -> NDArray[np.float64]:
        zz = np.atleast_2d(np.asarray(z, float))
        inside = np.all((zz >= self.lo) & (zz <= self.hi), axis=-1)
        out = np.full(zz.shape[0], -np.inf)
        if np.any(inside):
            with np.errstate(all="ignore"):
                w = self.prob.stacked(self.model.from_z(zz[inside]))
                ll = -0.5 * self.m * np.sum(np.log(np.sum(w**2, axis=1)), axis=-1)
            out[inside] = np.where(np.isfinite(ll), ll, -np.inf)
        return out


def sandwich_adjust(fit: InverseFit, chain_z: NDArray[np.float64]) -> NDArray[np.float64]:
    """Posterior samples (n, p) in z moved to the sandwich covariance: ``z_ML + C (z - z_ML)`` with
    ``C = L_s L_w^-1`` (Cholesky factors of the sandwich and of the white-likelihood covariance
    ``(sum_e J_e^T J_e / s_e^2)^-1``, ``s_e^2`` each equation's mean square error): the curvature
    adjustment of Ribatet, Cooley, Davison, *Statistica Sinica* 22 (2012) 813 (a white-noise likelihood
    of coloured data is too sharp by exactly this)."""
    s2 = np.mean(fit.w**2, axis=0)
    Jt = fit.Jw / np.sqrt(s2)[None, :, None]
    cw = normalized_pinv(np.einsum("nep,neq->pq", Jt, Jt))
    d = np.sqrt(np.clip(np.diag(cw), 1e-300, None))
    ds = np.sqrt(np.clip(np.diag(fit.cov_z), 1e-300, None))
    eye = 1e-12 * np.eye(d.size)
    Lw = d[:, None] * np.linalg.cholesky(cw / np.outer(d, d) + eye)
    Ls = ds[:, None] * np.linalg.cholesky(fit.cov_z / np.outer(ds, ds) + eye)
    C = Ls @ np.linalg.inv(Lw)
    return np.asarray(fit.z + (chain_z - fit.z) @ C.T, float)


def _score(e: NDArray, X: NDArray, J: NDArray) -> tuple[float, int]:
    Q, _ = np.linalg.qr(J)
    Xp = X - Q @ (Q.T @ X)
    coef, *_ = np.linalg.lstsq(Xp, e, rcond=None)
    return float(e @ (Xp @ coef)), int(np.linalg.matrix_rank(Xp))


def check_inverse_fit(fit: InverseFit, *, alpha: float = 1e-3, lags: int = 20) -> AdequacyReport:
    """Whiteness of each equation's innovations and the omitted-friction score test (module docstring);
    Bonferroni over the tests."""
    missing = [t for t in ("coulomb", "offset") if t not in fit.model.terms]
    eqs = fit.model.equations
    a = alpha / (len(eqs) + bool(missing))
    tests = [whiteness_test(fit.e[sl], lags=lags, alpha=a,
                            channel=f"{eq.name} (inverse model)" if len(eqs) > 1 else "force (inverse model)")
             for eq, sl in zip(eqs, fit.slices, strict=True)]
    if missing:
        Xs = np.concatenate(fit.problem.omitted(missing))  # (n, n_e, k)
        Xw = _innovations(fit.problem, fit.ars, Xs)
        S, k = _score(fit.e, Xw, fit.J)
        p = float(stats.chi2.sf(S, max(k, 1)))
        tests.append(AdequacyTest("omitted_friction", "force (inverse model)", S, p >= a, p, None, a,
                                  {"terms": missing, "dof": k}))
    rep = AdequacyReport(tests)
    if rep.misfit:
        logger.warning("friction model %s: %s", fit.model.terms or "linear", "; ".join(rep.reasons))
    return rep


def summary_row(fit: InverseFit) -> dict[str, Any]:
    """Estimates, CRB std, AR order (largest over the equations), innovation std [force unit] (first
    equation; ``innovation_std_by_equation``), BIC/AIC of a fit (for model choice)."""
    return {"friction": list(fit.model.terms), "parameters": dict(zip(fit.model.names, map(float, fit.theta),
                                                                     strict=True)),
            "crb_std": dict(zip(fit.model.names, map(float, fit.crb_std), strict=True)),
            "ar_order": max(ar.order for ar in fit.ars), "innovation_std": fit.ar.sigma,
            "innovation_std_by_equation": {eq.name: ar.sigma for eq, ar in zip(fit.model.equations, fit.ars,
                                                                                 strict=True)},
            "n_equation_error": fit.n, "k": fit.k, "bic": fit.bic, "aic": fit.aic}
