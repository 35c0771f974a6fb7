"""Output-error maximum likelihood on NON-periodic records: the exact sampled model with its transient.

Why not the H1 FRF. Cutting a one-shot record (a log chirp recorded by another tool) into Welch
segments leaves, in every segment, the free response to the state at the segment edges (leakage);
it swamps the coherence-based noise estimate and biases the FRF (measured: B_f +2.4 %, posterior sd
16-22 x the Cramer-Rao bound). This module fits the time-domain output-error likelihood instead.

Model (exact, no approximation). The plant behind the bench's zero-order hold at ``T = 1/fs`` is
``x_{t+1} = Phi x_t + Gamma u_t``, ``y_t = C x_t + v_t`` (``Phi = e^{AT}``; the sampled model of
:mod:`hil.identify.models` and :func:`hil.lti.zoh_matrices`), ``v_t`` white Gaussian noise of
variance ``sigma_o^2`` per output ``o`` (the fitted noise model). With the DFT over the ``N``
samples of one record, ``X_k = sum_t x_t z_k^-t`` at ``z_k = e^{j 2 pi k / N}``, summing the state
equation over the record and using ``z_k^N = 1``::

    Y_k = G(z_k) U_k + C (z_k I - Phi)^-1 z_k (x_0 - x_N) + V_k,    G(z) = C (z I - Phi)^-1 Gamma

EXACTLY, for any input (Pintelon & Schoukens, *System Identification: a frequency domain
approach*, 2nd ed., sec. 6.3: the "transient term" is a rational function with the plant's poles and
``n`` free real coefficients ``dx = x_0 - x_N``). The transient is linear in ``dx``; it is eliminated
per parameter vector by linear least squares (variable projection), so the initial state of the
record is estimated, not assumed zero. White ``v_t`` gives independent circular complex Gaussian
``V_k`` with ``E|V_k|^2 = N sigma_o^2``; by Parseval the negative log-likelihood over ALL bins is the
time-domain output-error cost ``sum_t |y_t - yhat_t|^2 / (2 sigma^2)``. Restricting to the bins of the
analysis band (default: ``0 < f <= 0.45 fs``; DC always dropped, which also removes sensor offsets)
keeps the likelihood exact for those bins. Continuous-time models (``zoh_fs=None``, data without a
hold) use ``G(j w)`` and the transient ``C (j w I - A)^-1 dx'`` -- exact only up to aliasing.

Noise model: one white variance per output, estimated jointly by ML (``sigma_o^2 = RSS_o / (N m_o)``,
``m_o`` complex bins) through iteratively reweighted Gauss-Newton
(:func:`scipy.optimize.least_squares`, trust-region reflective, z-space = log of the positive
parameters); the fixed point is the joint ML of (theta, sigma). For the posterior the variances are
integrated out under the Jeffreys prior: ``log L(theta) = - sum_o m_o log RSS_o(theta)`` (the
transient profiled), sampled with emcee (:func:`hil.identify.posterior.sample_posterior`, the same
convergence checks) or, with ``posterior="laplace"``, the Gaussian ``N(z_ML, F^-1)`` (fast; accurate
when the posterior is near-Gaussian, which the calibration test checks).

Cramer-Rao bound: ``F = J^T J`` with ``J`` the derivative of the weighted real residual vector
(real and imaginary parts, each of variance ``N sigma_o^2 / 2``) with respect to ``z``, the transient
coefficients projected out (Schur complement: the bound of an estimator that does not know the
initial state), evaluated for the ACTUAL recorded excitation ``U_k`` under the fitted noise model.
``cramer_rao_std = sqrt(diag F^-1)`` (delta method to physical units).

Which estimator (``method="auto"`` in :func:`hil.identify.api.identify_experiments`): a record with a
known ``period`` whose input repeats sample for sample with that period (relative RMS change below
``1e-5``) over at least two periods keeps the fast H1-FRF path (leakage-free, period-aligned
segments); every other record is identified by this module.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from hil.identify.errors import ConvergenceError, ModelSpecError
from hil.identify.fisher import normalized_pinv
from hil.identify.models import GreyBoxModel

logger = logging.getLogger(__name__)

__all__ = [
    "DftRecord",
    "MlLogPosterior",
    "MlResult",
    "dft_records",
    "fisher_dft",
    "fisher_ml",
    "fit_ml",
    "is_periodic",
    "laplace_posterior",
    "simulate_zoh",
]


@dataclass
class DftRecord:
    """DFT of one record on the analysis bins: ``k`` bin indices, ``f`` [Hz], ``U`` (m, n_in),
    ``Y`` (m, n_out) complex (``numpy.fft.rfft`` convention, unnormalized), ``n`` samples, ``fs`` [Hz]."""

    k: NDArray[np.int64]
    f: NDArray[np.float64]
    U: NDArray[np.complex128]
    Y: NDArray[np.complex128]
    n: int
    fs: float

    @property
    def w(self) -> NDArray[np.float64]:
        return 2 * np.pi * self.f


def dft_records(
    experiments: Sequence[tuple[ArrayLike, ArrayLike]], fs: float, band: tuple[float, float] | None = None
) -> list[DftRecord]:
    """DFTs of ``(u (n, n_in), y (n, n_out))`` records restricted to ``band`` [Hz] (default
    ``(0, 0.45 fs]``); DC and the Nyquist bin are always dropped."""
    out = []
    lo, hi = band if band is not None else (0.0, 0.45 * fs)
    for u_raw, y_raw in experiments:
        u = np.asarray(u_raw, float)
        y = np.asarray(y_raw, float)
        u = u[:, None] if u.ndim == 1 else u
        y = y[:, None] if y.ndim == 1 else y
        n = u.shape[0]
        f = np.fft.rfftfreq(n, 1.0 / fs)
        k = np.flatnonzero((f > 0) & (f >= lo) & (f <= hi) & (np.arange(f.size) < n / 2))
        out.append(DftRecord(k, np.asarray(f[k], float), np.fft.rfft(u, axis=0)[k], np.fft.rfft(y, axis=0)[k], n,
                             float(fs)))
    return out


def is_periodic(u: ArrayLike, n_period: int, rtol: float = 1e-5) -> bool:
    """True when ``u`` (n, n_in) holds at least two periods of ``n_period`` samples that repeat
    (RMS of ``u[P:] - u[:-P]`` below ``rtol`` times the RMS of ``u``; float32 rounding is ~1e-7)."""
    a = np.asarray(u, float)
    a = a[:, None] if a.ndim == 1 else a
    P = int(n_period)
    if P < 2 or a.shape[0] < 2 * P:
        return False
    scale = float(np.sqrt(np.mean(a**2)))
    if scale == 0:
        return False
    return float(np.sqrt(np.mean((a[P:] - a[:-P]) ** 2))) <= rtol * scale


def simulate_zoh(model: GreyBoxModel, theta: ArrayLike, u: ArrayLike, x0: ArrayLike | None = None) -> NDArray:
    """Noise-free outputs (n, n_out) of ``model`` behind a zero-order hold at ``model.zoh_fs`` for
    input samples ``u`` (n, n_in), using the suite's exact discretization
    (:meth:`hil.lti.StateSpace.discretize`); nuisance gains applied, delay not supported."""
    from hil.lti import StateSpace

    if model.zoh_fs is None:
        raise ModelSpecError("simulate_zoh needs a model built with zoh_fs")
    th = np.asarray(theta, float)
    A, Bm, C = model.state_space(th)
    uu = np.asarray(u, float)
    uu = uu[:, None] if uu.ndim == 1 else uu
    ss = StateSpace(A, Bm, C, np.zeros((C.shape[0], Bm.shape[1])))
    _, y = ss.discretize(1.0 / model.zoh_fs, "zoh").simulate(uu, None if x0 is None else np.asarray(x0, float))
    if model.has_gain:
        y = y * th[model.n_core : model.n_core + len(model.output_names)]
    return y


class _Problem:
    """The DFT-domain output-error problem of one or several records (shared parameters and noise
    variances; one transient ``dx`` per record). Vectorized over parameter batches."""

    def __init__(self, model: GreyBoxModel, recs: Sequence[DftRecord]) -> None:
        self.model = model
        self.recs = list(recs)
        self.w = np.concatenate([r.w for r in recs])
        self.splits = np.cumsum([r.k.size for r in recs])[:-1]
        self.no = len(model.output_names)
        # complex bins per output (all records)
        self.m_o = np.full(self.no, float(sum(r.k.size for r in recs)))
        if np.any(self.m_o < 1):
            raise ModelSpecError("no DFT bin in the analysis band")

    def _gain(self, th: NDArray[np.float64]) -> NDArray[np.float64]:
        m = self.model
        if m.has_gain:
            return th[..., m.n_core : m.n_core + self.no]
        return np.ones((*th.shape[:-1], self.no))

    def transient_basis(self, th: NDArray[np.float64]) -> list[NDArray[np.complex128]]:
        """Per record: (..., m_r, n_out, n_states) complex basis ``C (zI - Phi)^-1 z`` (ZOH) or
        ``C (jwI - A)^-1`` (continuous), times the sensor gains."""
        m = self.model
        A, _, C = m.state_space(th)
        lam, V = np.linalg.eig(A)
        W = np.linalg.inv(V)
        CV = C @ V  # (..., no, n)
        out = []
        for r in self.recs:
            if m.zoh_fs is not None:
                z = np.exp(1j * r.w / m.zoh_fs)
                mu = np.exp(lam / m.zoh_fs)
                coef = z[:, None] / (z[:, None] - mu[..., None, :])  # (..., m_r, n)
            else:
                coef = 1.0 / (1j * r.w[:, None] - lam[..., None, :])
            # C V diag(coef) W : (..., m_r, no, n)
            Bk = np.einsum("...on,...kn,...nj->...koj", CV, coef, W)
            out.append(Bk * self._gain(th)[..., None, :, None])
        return out

    def prediction(self, th: NDArray[np.float64]) -> list[NDArray[np.complex128]]:
        """``G(theta) U`` per record: (..., m_r, n_out)."""
        H = self.model.frf(th, self.w)  # (..., M, no, ni)
        parts = np.split(H, self.splits, axis=-3)
        return [np.einsum("...koi,ki->...ko", Hp, r.U) for Hp, r in zip(parts, self.recs, strict=True)]

    def residuals(
        self, th: NDArray[np.float64], sigma: NDArray[np.float64] | None = None, *, want_dx: bool = False
    ) -> tuple[list[NDArray[np.complex128]], list[NDArray[np.float64]]]:
        """Residuals ``Y - G U - T dx_hat`` per record (..., m_r, n_out) with the transient ``dx``
        fitted by (``sigma``-weighted) linear least squares, and the fitted ``dx`` (..., n)."""
        preds = self.prediction(th)
        bases = self.transient_basis(th)
        wgt = np.ones(self.no) if sigma is None else 1.0 / np.asarray(sigma, float)
        res, dxs = [], []
        for r, P, Bk in zip(self.recs, preds, bases, strict=True):
            E0 = (r.Y - P) * wgt  # (..., m, no)
            Bw = Bk * wgt[:, None]
            n = Bw.shape[-1]
            D = Bw.reshape(*Bw.shape[:-3], -1, n)  # (..., m*no, n)
            Dr = np.concatenate([D.real, D.imag], axis=-2)
            e = E0.reshape(*E0.shape[:-2], -1)
            er = np.concatenate([e.real, e.imag], axis=-1)
            Q, _ = np.linalg.qr(Dr)
            coef = np.einsum("...ij,...i->...j", Q, er)
            er_p = er - np.einsum("...ij,...j->...i", Q, coef)
            half = er_p.shape[-1] // 2
            Ep = (er_p[..., :half] + 1j * er_p[..., half:]).reshape(E0.shape) / wgt
            # dx itself (for reporting / diagnostics): least squares on the same design
            res.append(Ep)
            if want_dx:
                dxs.append(np.stack([np.linalg.lstsq(a, b, rcond=None)[0] for a, b in
                                     zip(Dr.reshape(-1, *Dr.shape[-2:]), er.reshape(-1, er.shape[-1]), strict=True)]))
        return res, dxs

    def rss(self, th: NDArray[np.float64]) -> NDArray[np.float64]:
        """Per output residual sum of squares ``sum_k |E_k|^2`` over all records (..., n_out),
        transient profiled with unit weights per output (the projection is per output-weighted
        design; outputs are coupled through dx, so the weights matter: use :meth:`rss_weighted`)."""
        E, _ = self.residuals(th)
        return sum(np.sum(np.abs(e) ** 2, axis=-2) for e in E)

    def _modal(self, th: NDArray[np.float64]) -> tuple[list[NDArray[np.complex128]], NDArray, NDArray, NDArray]:
        """Modal form, per record: the transient coefficients ``coef`` (..., m, n) (``z/(z - mu_i)``, or
        ``1/(jw - l_i)`` for continuous models), ``C V`` times the sensor gains (..., no, n), ``W = V^-1``
        and the input map ``g W B`` (..., n, ni) with ``g_i = (e^{l_i T} - 1)/l_i`` (ZOH) or 1: the
        transient basis is ``B_k = (CV diag(coef_k)) W`` and ``G(z_k) = CV diag(coef_k / z_k) g W B``
        (the model's exact sampled FRF, :meth:`GreyBoxModel._zoh_frf`)."""
        m = self.model
        A, Bm, C = m.state_space(th)
        lam, V = np.linalg.eig(A)
        W = np.linalg.inv(V)
        CV = (C @ V) * self._gain(th)[..., :, None]
        WB = W @ Bm
        coefs = []
        if m.zoh_fs is not None:
            T = 1.0 / m.zoh_fs
            lt = lam * T
            small = np.abs(lt) < 1e-8
            g = np.where(small, T * (1 + lt / 2), np.expm1(np.where(small, 1.0, lt)) / np.where(small, 1.0, lam))
            WB = WB * g[..., :, None]
        for r in self.recs:
            if m.zoh_fs is not None:
                z = np.exp(1j * r.w / m.zoh_fs)
                mu = np.exp(lam / m.zoh_fs)
                coefs.append(z[:, None] / (z[:, None] - mu[..., None, :]))
            else:
                coefs.append(1.0 / (1j * r.w[:, None] - lam[..., None, :]))
        return coefs, CV, W, WB

    def _fast_predictions(self, th: NDArray[np.float64], coefs: list, CV: NDArray, WB: NDArray) -> list:
        """``G(theta) U`` per record from the modal form (no delay nuisance; else :meth:`prediction`)."""
        if self.model.has_delay:
            return self.prediction(th)
        out = []
        CVT = np.swapaxes(CV, -1, -2)  # (..., n, no)
        WBT = np.swapaxes(WB, -1, -2)  # (..., ni, n)
        for r, coef in zip(self.recs, coefs, strict=True):
            uw = r.U @ WBT  # (..., m, n)
            a = coef * uw
            if self.model.zoh_fs is not None:
                a = a * np.exp(-1j * r.w / self.model.zoh_fs)[:, None]
            out.append(a @ CVT)
        return out

    def rss_weighted(self, th: NDArray[np.float64], sigma: NDArray[np.float64]) -> NDArray[np.float64]:
        """Per-output RSS (..., n_out) of the residual with the transient fitted by ``sigma``-weighted
        least squares, through the normal equations of the ``n``-column transient design in modal
        form (``Gram = Re W^H [(CV^* CV^T) o sum_k coef_k^* coef_k^T] W``; scaled to unit diagonal):
        the MCMC hot path (same result as :meth:`residuals`, checked in the tests)."""
        wgt = 1.0 / np.asarray(sigma, float)
        total = np.zeros((*th.shape[:-1], self.no))
        coefs, CV, W, WB = self._modal(th)
        CVw = CV * wgt[:, None]
        WH = np.swapaxes(W, -1, -2).conj()[..., None, :, :]  # (..., 1, n, n)
        preds = self._fast_predictions(th, coefs, CV, WB)
        for r, P, coef in zip(self.recs, preds, coefs, strict=True):
            E0 = (r.Y - P) * wgt  # (..., m, no)
            cH = np.swapaxes(coef, -1, -2).conj()  # (..., n, m)
            S = cH @ coef  # (..., n, n)
            Mo = CVw.conj()[..., :, :, None] * CVw[..., :, None, :] * S[..., None, :, :]  # (..., no, n, n)
            Go = (WH @ Mo @ W[..., None, :, :]).real
            t = np.swapaxes(cH @ E0, -1, -2)  # (..., no, n)
            bo = (WH @ (CVw.conj() * t)[..., None])[..., 0].real  # (..., no, n)
            e2 = np.sum(np.abs(E0) ** 2, axis=-2)  # (..., no)
            G = Go.sum(axis=-3)
            b = bo.sum(axis=-2)
            d = np.sqrt(np.maximum(np.diagonal(G, axis1=-2, axis2=-1), 1e-300))
            Gn = G / (d[..., :, None] * d[..., None, :]) + 1e-12 * np.eye(G.shape[-1])
            c = np.linalg.solve(Gn, (b / d)[..., None])[..., 0] / d
            rss = e2 - 2 * np.einsum("...on,...n->...o", bo, c) + np.einsum("...n,...onm,...m->...o", c, Go, c)
            total = total + rss / wgt**2
        return total

    def weighted_vector(self, th: NDArray[np.float64], sigma: NDArray[np.float64]) -> NDArray[np.float64]:
        """Real residual vector, each entry of unit variance under the noise model (real and
        imaginary parts of ``E_k / sqrt(N sigma_o^2 / 2)``)."""
        E, _ = self.residuals(th, sigma)
        parts = []
        for e, r in zip(E, self.recs, strict=True):
            s = np.sqrt(r.n * np.asarray(sigma, float) ** 2 / 2.0)
            q = (e / s).reshape(*e.shape[:-2], -1)
            parts += [q.real, q.imag]
        return np.concatenate(parts, axis=-1)


@dataclass
class MlResult:
    """Output-error ML estimate: ``theta``/``z``, noise std per output ``sigma`` (time-domain,
    output units), Fisher information ``fisher`` (z-space) and ``cov_z = F^-1``, ``crb_std``
    (physical), the transient ``dx`` per record, the fit's cost and iterations."""

    names: tuple[str, ...]
    theta: NDArray[np.float64]
    z: NDArray[np.float64]
    sigma: NDArray[np.float64]
    fisher: NDArray[np.float64]
    cov_z: NDArray[np.float64]
    cov_theta: NDArray[np.float64]
    crb_std: NDArray[np.float64]
    chi2: float
    dof: int
    success: bool
    message: str
    n_bins: int
    dx: list[NDArray[np.float64]] = field(default_factory=list)
    elapsed_s: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        return {
            "theta": dict(zip(self.names, map(float, self.theta), strict=True)),
            "noise_std": [float(s) for s in self.sigma],
            "cramer_rao_std": dict(zip(self.names, map(float, self.crb_std), strict=True)),
            "chi2": self.chi2,
            "dof": self.dof,
            "success": self.success,
            "message": self.message,
            "n_bins": self.n_bins,
        }


def _fd_jacobian(fun: Any, z: NDArray[np.float64], h: NDArray[np.float64]) -> NDArray[np.float64]:
    """Fourth-order central differences of ``fun`` (batched over its first axis) at ``z``."""
    p = z.size
    D = np.diag(h)
    Z = np.concatenate([z + 2 * D, z + D, z - D, z - 2 * D], axis=0)
    F = fun(Z)
    return ((-F[:p] + 8 * F[p : 2 * p] - 8 * F[2 * p : 3 * p] + F[3 * p :]) / (12 * h[:, None])).T


def fisher_ml(
    model: GreyBoxModel, recs: Sequence[DftRecord], theta: ArrayLike, sigma: ArrayLike
) -> NDArray[np.float64]:
    """Fisher information in z-space of the DFT-domain output-error model at ``theta`` for white
    noise of std ``sigma`` (per output, time domain), the transient coefficients projected out."""
    sig2 = np.asarray(sigma, float) ** 2
    return fisher_dft(model, recs, theta, [np.broadcast_to(r.n * sig2, (r.k.size, sig2.size)) for r in recs])


def fisher_dft(
    model: GreyBoxModel,
    recs: Sequence[DftRecord],
    theta: ArrayLike,
    noise_var: Sequence[ArrayLike],
    *,
    transient: bool = True,
) -> NDArray[np.float64]:
    """Fisher information in z-space of DFT data ``Y_k = G(theta) U_k [+ T_k dx] + V_k`` for the
    recorded inputs ``U_k`` and independent circular complex noise of variance ``E|V_k|^2 =
    noise_var[r][k, o]`` (per record, bin and output): ``F = sum 2 Re(dY^H dY) / var``, with the
    transient coefficients ``dx`` (one per record) projected out when ``transient`` (Schur
    complement). ``dY/dz`` by fourth-order central differences (steps 1e-4 in z)."""
    prob = _Problem(model, recs)
    th = np.asarray(theta, float)
    z = model.to_z(th)
    scales = [np.sqrt(np.asarray(v, float) / 2.0) for v in noise_var]  # std of real and imag parts
    h = np.where(model.log_mask, 1e-4, 1e-4 * np.maximum(np.abs(z), 1e-6))

    def pred_vec(Z: NDArray[np.float64]) -> NDArray[np.float64]:
        parts = []
        for P, sc in zip(prob.prediction(model.from_z(Z)), scales, strict=True):
            q = (P / sc).reshape(P.shape[0], -1)
            parts += [q.real, q.imag]
        return np.concatenate(parts, axis=-1)

    J = _fd_jacobian(pred_vec, z, h)  # (n_res, p), d(G U)/dz, weighted
    J = np.where(np.isfinite(J), J, 0.0)
    if not transient:
        return J.T @ J
    cols = []
    off = 0
    sizes = [2 * r.k.size * prob.no for r in recs]
    total = sum(sizes)
    for Bk, sc, sz in zip(prob.transient_basis(th), scales, sizes, strict=True):
        D = (Bk / sc[..., None]).reshape(-1, Bk.shape[-1])
        blk = np.zeros((total, D.shape[1]))
        # layout of pred_vec: per record [real (m*no), imag (m*no)]
        blk[off : off + sz // 2] = D.real
        blk[off + sz // 2 : off + sz] = D.imag
        cols.append(blk)
        off += sz
    T = np.concatenate(cols, axis=1)
    Q, _ = np.linalg.qr(T)
    Jp = J - Q @ (Q.T @ J)
    return Jp.T @ Jp


def fit_ml(
    model: GreyBoxModel,
    recs: Sequence[DftRecord],
    x0: ArrayLike,
    *,
    n_reweight: int = 4,
    max_nfev: int = 200,
) -> MlResult:
    """Joint ML of the parameters and the per-output white noise variances (module docstring),
    starting at ``x0`` (physical units; e.g. the H1-FRF least-squares estimate)."""
    t0 = time.perf_counter()
    prob = _Problem(model, recs)
    lo, hi = model.z_bounds()
    inner_lo, inner_hi = lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo)
    z = np.clip(model.to_z(np.asarray(x0, float)), inner_lo, inner_hi)
    n_tot = sum(r.n * r.k.size for r in recs)
    sigma = np.sqrt(np.maximum(prob.rss(model.from_z(z)[None])[0], 1e-300) / n_tot)
    big = 1e6
    sol = None
    for it in range(n_reweight):

        def resid(zz: NDArray[np.float64], sig: NDArray[np.float64] = sigma) -> NDArray[np.float64]:
            with np.errstate(all="ignore"):
                r = prob.weighted_vector(model.from_z(zz)[None], sig)[0]
            return np.where(np.isfinite(r), r, big)

        sol = least_squares(resid, z, bounds=(lo, hi), method="trf", x_scale="jac", max_nfev=max_nfev)
        z = np.clip(sol.x, inner_lo, inner_hi)
        rss = prob.rss_weighted(model.from_z(z)[None], sigma)[0]
        new = np.sqrt(np.maximum(rss, 1e-300) / n_tot)
        change = float(np.max(np.abs(new / sigma - 1)))
        sigma = new
        logger.debug("ML reweight %d: sigma %s (change %.2e), cost %.6g", it, sigma, change, sol.cost)
        if change < 1e-4:
            break
    if sol is None or not np.all(np.isfinite(z)):
        raise ConvergenceError("output-error ML fit failed")
    theta = model.from_z(z)
    F = fisher_ml(model, recs, theta, sigma)
    cov_z = normalized_pinv(F)
    d = np.where(model.log_mask, theta, 1.0)
    cov_theta = cov_z * np.outer(d, d)
    crb_std = np.sqrt(np.clip(np.diag(cov_theta), 0, None))
    r = prob.weighted_vector(theta[None], sigma)[0]
    n_states = model.state_space(theta)[0].shape[-1]
    dof = int(r.size - theta.size - n_states * len(recs))
    _, dxs = prob.residuals(theta[None], sigma, want_dx=True)
    logger.info("output-error ML %s: %d bins, noise std %s, %s", model.name, r.size // 2, sigma, sol.message)
    return MlResult(
        names=model.names,
        theta=theta,
        z=z,
        sigma=sigma,
        fisher=F,
        cov_z=cov_z,
        cov_theta=cov_theta,
        crb_std=crb_std,
        chi2=float(np.sum(r**2)),
        dof=dof,
        success=bool(sol.success),
        message=str(sol.message),
        n_bins=int(r.size // 2),
        dx=[np.asarray(x[0], float) for x in dxs],
        elapsed_s=time.perf_counter() - t0,
    )


class MlLogPosterior:
    """Vectorized log-posterior of the output-error model in z-space (duck-compatible with
    :class:`hil.identify.posterior.LogPosterior` for :func:`~hil.identify.posterior.sample_posterior`):
    uniform prior in z within the model bounds, noise variances integrated out under the Jeffreys
    prior, ``log L = - sum_o m_o log RSS_o`` (transient profiled; per-output weights fixed at the ML
    noise std, which only sets the relative weighting of the outputs in the projection)."""

    noise = "ml-white"

    def __init__(self, model: GreyBoxModel, recs: Sequence[DftRecord], sigma: ArrayLike, *, prob: Any = None) -> None:
        self.model = model
        #: the problem: ``rss_weighted(theta_batch, sigma)`` and ``m_o`` (the DFT problem of ``recs``, or
        #: :class:`hil.identify.held_ml.HeldProblem` for held outputs)
        self.prob = _Problem(model, recs) if prob is None else prob
        self.sigma = np.asarray(sigma, float)
        self.lo, self.hi = model.z_bounds()
        self.ndim = self.lo.size
        self.names = model.names

    def __call__(self, z: ArrayLike) -> NDArray[np.float64]:
        zz = np.atleast_2d(np.asarray(z, float))
        inside = np.all((zz >= self.lo) & (zz <= self.hi), axis=-1)
        out = np.full(zz.shape[0], -np.inf)
        if np.any(inside):
            with np.errstate(all="ignore"):
                rss = self.prob.rss_weighted(self.model.from_z(zz[inside]), self.sigma)
                ll = -np.sum(self.prob.m_o * np.log(rss), axis=-1)
            out[inside] = np.where(np.isfinite(ll), ll, -np.inf)
        return out


def laplace_posterior(model: GreyBoxModel, ml: MlResult, *, n_draws: int = 4000, seed: int = 0) -> Any:
    """Gaussian (Laplace) posterior ``N(z_ML, F^-1)`` in z-space as a
    :class:`~hil.identify.posterior.PosteriorResult` (draws outside the bounds are redrawn)."""
    from hil.identify.posterior import ConvergenceDiagnostics, PosteriorResult

    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    cov = ml.cov_z
    sd = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
    L = sd[:, None] * np.linalg.cholesky(cov / np.outer(sd, sd) + 1e-12 * np.eye(sd.size))
    lo, hi = model.z_bounds()
    draws = ml.z + rng.standard_normal((n_draws, sd.size)) @ L.T
    for _ in range(20):
        bad = ~np.all((draws >= lo) & (draws <= hi), axis=1)
        if not np.any(bad):
            break
        draws[bad] = ml.z + rng.standard_normal((int(bad.sum()), sd.size)) @ L.T
    draws = np.clip(draws, lo, hi)
    d = sd.size
    diag = ConvergenceDiagnostics(
        converged=True,
        reasons=[],
        tau=np.ones(d),
        n_steps=n_draws,
        burn=0,
        n_kept=n_draws,
        tau_multiple=float(n_draws),
        acceptance=1.0,
        acceptance_min=1.0,
        rhat=np.ones(d),
        n_walkers=1,
        elapsed_s=time.perf_counter() - t0,
        n_checks=0,
    )
    return PosteriorResult(
        names=model.names,
        samples=model.from_z(draws),
        chain_z=draws[:, None, :],
        log_prob=np.zeros((n_draws, 1)),
        diagnostics=diag,
        seed=seed,
        noise="ml-white (laplace)",
        extra={"posterior": "laplace"},
    )
