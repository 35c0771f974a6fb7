"""Output-error ML when an output comes from a sensor slower than the loop (sample-and-hold in the record).

A held output (:mod:`hil.identify.sensor_hold`) repeats its last value until the sensor delivers a new
one: record sample ``i`` holds the value measured at tick ``i - a_i`` (``a_i`` its age, 0 where the value is
new). The hold is an operator on the predicted output, ``yhat_held[i] = yhat[i - a_i]``, with the ages
read from the record's repeats; the noise is held with the value, so the repeats carry no new
information: the likelihood of a held output is that of its NEW samples alone,

    y[i] = C x_i + v_i   for the ticks i where the value is new,   v_i white, variance sigma_o^2,

with ``x_{t+1} = Phi x_t + Gamma u_t`` the exact zero-order-hold sampled model (the same one as
:mod:`hil.identify.timedomain`). Outputs that are not held are observed at every tick. This is exact
for any hold pattern (regular, drifting, jittered ages), where the FRF path's expected hold filter
``A(w)`` (:func:`hil.identify.sensor_hold.compensate_frf`) holds only in expectation over the ages.

The DFT-domain likelihood of :mod:`hil.identify.timedomain` cannot carry a per-sample observation
pattern, so this problem is solved in the time domain: the forced response ``yhat(theta)`` from rest by
the modal recursion ``xi_{t+1} = mu xi_t + g W B u_t`` (``mu = e^{lambda T}``, ``g = (mu - 1)/lambda``; a causal
convolution per mode, by FFT, batched over parameter vectors), the initial state ``x_0`` (its free response
``C V mu^t W``) and a constant offset per output (sensor offsets; the DFT path drops DC instead) as
nuisance parameters that enter linearly and are projected out per parameter vector (variable
projection, as the DFT path does with its transient). Noise variances by reweighting
(``sigma_o^2 = RSS_o / m_o``, ``m_o`` observed samples of output ``o``); the Cramér-Rao bound from the
Jacobian of the weighted prediction on the observed samples with the nuisance projected out (Schur
complement), for the recorded input. The emcee posterior integrates the variances out under the
Jeffreys prior: ``log L = -sum_o (m_o / 2) log RSS_o`` (:class:`hil.identify.timedomain.MlLogPosterior`
with this problem; its ``m_o`` holds the complex-bin equivalents ``m_o / 2``).

Needs a zero-order-hold model (``zoh_fs``) without a delay nuisance.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from hil.identify.errors import ConvergenceError, ModelSpecError
from hil.identify.fisher import normalized_pinv
from hil.identify.models import GreyBoxModel
from hil.identify.sensor_hold import ages
from hil.identify.timedomain import MlResult, _fd_jacobian

logger = logging.getLogger(__name__)

__all__ = ["HeldProblem", "HeldRecord", "check_held_fit", "fit_held_ml", "held_records"]


@dataclass
class HeldRecord:
    """One record: inputs ``u`` (n, n_in), outputs ``y`` (n, n_out) as recorded (held values repeated) and
    ``obs`` (n, n_out) bool, True where the output sample is new (always True for outputs not held)."""

    u: NDArray[np.float64]
    y: NDArray[np.float64]
    obs: NDArray[np.bool_]


def held_records(pairs: Sequence[tuple[ArrayLike, ArrayLike]], output_names: Sequence[str],
                 held: Mapping[str, Any]) -> list[HeldRecord]:
    """:class:`HeldRecord` s of ``(u, y)`` pairs; the outputs named in ``held`` are observed where their
    age (:func:`hil.identify.sensor_hold.ages`) is 0."""
    out = []
    for u_raw, y_raw in pairs:
        u = np.asarray(u_raw, float)
        y = np.asarray(y_raw, float)
        u = u[:, None] if u.ndim == 1 else u
        y = y[:, None] if y.ndim == 1 else y
        obs = np.ones(y.shape, dtype=bool)
        for o, name in enumerate(output_names):
            if name in held:
                obs[:, o] = ages(y[:, o]) == 0
        out.append(HeldRecord(u, y, obs))
    return out


class HeldProblem:
    """The time-domain output-error problem of :class:`HeldRecord` s (module docstring): shared parameters
    and noise variances, one initial state and one offset per output per record (nuisance)."""

    def __init__(self, model: GreyBoxModel, recs: Sequence[HeldRecord]) -> None:
        if model.zoh_fs is None:
            raise ModelSpecError("a held output needs the zero-order-hold sampled model (sampling 'zoh')")
        if model.has_delay:
            raise ModelSpecError("a held output with a delay nuisance is not supported")
        self.model = model
        self.recs = list(recs)
        self.no = len(model.output_names)
        self.n_obs = np.sum([r.obs.sum(axis=0) for r in self.recs], axis=0).astype(float)  # per output
        if np.any(self.n_obs < 1):
            raise ModelSpecError("an output has no observed sample")
        #: complex-bin equivalents of the observed real samples (MlLogPosterior: -sum m_o log RSS_o)
        self.m_o = self.n_obs / 2.0

    def _gain(self, th: NDArray[np.float64]) -> NDArray[np.float64]:
        m = self.model
        if m.has_gain:
            return th[..., m.n_core: m.n_core + self.no]
        return np.ones((*th.shape[:-1], self.no))

    def responses(self, th: ArrayLike) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
        """Per record: forced response from rest (B, n, n_out) and free-response basis (B, n, n_out,
        n_states), both times the sensor gains, for a batch ``th`` (B, p) of parameter vectors. The modal
        recursion as a causal convolution ``xi_k = h_k * d_k`` with ``h_k[j] = mu_k^(j-1)`` (j >= 1), by FFT
        (batched over parameter vectors and modes)."""
        thb = np.atleast_2d(np.asarray(th, float))
        A, Bm, C = self.model.state_space(thb)
        lam, V = np.linalg.eig(A)  # (B, nx), (B, nx, nx)
        W = np.linalg.inv(V)
        T = 1.0 / float(self.model.zoh_fs)  # type: ignore[arg-type]  # checked in __init__
        lt = lam * T
        small = np.abs(lt) < 1e-8
        g = np.where(small, T * (1 + lt / 2), np.expm1(np.where(small, 1.0, lt)) / np.where(small, 1.0, lam))
        CV = (C @ V) * self._gain(thb)[:, :, None]  # (B, no, nx)
        WB = (W @ Bm) * g[:, :, None]  # (B, nx, ni)
        out = []
        for r in self.recs:
            n = r.u.shape[0]
            L = 1 << int(np.ceil(np.log2(2 * n)))
            drive = WB @ r.u.T  # (B, nx, n)
            P = np.exp(lt[:, :, None] * np.arange(n)[None, None, :])  # mu^t, (B, nx, n)
            h = np.zeros_like(P)
            h[..., 1:] = P[..., :-1]
            xi = np.fft.ifft(np.fft.fft(h, L) * np.fft.fft(drive, L))[..., :n]  # (B, nx, n)
            forced = np.swapaxes((CV @ xi).real, -1, -2)  # (B, n, no)
            # free[b, t, o, j] = sum_k CV[b, o, k] mu_k^t W[b, k, j]
            Pt = np.swapaxes(P, -1, -2)  # (B, n, nx)
            free = np.zeros((P.shape[0], n, CV.shape[1], W.shape[-1]))
            for k in range(lam.shape[-1]):  # few modes: a sum of rank-one terms beats a batched tiny matmul
                free += ((CV[:, None, :, k] * Pt[:, :, k, None])[..., None] * W[:, None, None, k, :]).real
            out.append((forced, free))
        return out

    def _design(self, th: ArrayLike, sigma: NDArray[np.float64]
                ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(weighted residual before projection (B, N), weighted nuisance design (B, N, q)) on the N
        observed samples (records, then outputs), for a batch ``th`` (B, p)."""
        wgt = 1.0 / np.asarray(sigma, float)
        res, blocks = [], []
        for r, (forced, free) in zip(self.recs, self.responses(th), strict=True):
            nx = free.shape[-1]
            rows_e, rows_d = [], []
            for o in range(self.no):
                m = r.obs[:, o]
                rows_e.append((r.y[m, o][None, :] - forced[:, m, o]) * wgt[o])
                d = np.zeros((forced.shape[0], int(m.sum()), nx + self.no))
                d[..., :nx] = free[:, m, o, :] * wgt[o]
                d[..., nx + o] = wgt[o]  # offset of output o
                rows_d.append(d)
            res.append(np.concatenate(rows_e, axis=1))
            blocks.append(np.concatenate(rows_d, axis=1))
        e = np.concatenate(res, axis=1)
        D = np.zeros((*e.shape, sum(b.shape[-1] for b in blocks)))
        i = j = 0
        for b in blocks:  # one nuisance block per record
            D[:, i: i + b.shape[1], j: j + b.shape[2]] = b
            i, j = i + b.shape[1], j + b.shape[2]
        return e, D

    @staticmethod
    def _project(D: NDArray[np.float64], X: NDArray[np.float64]) -> NDArray[np.float64]:
        """``X`` (B, N, k) minus its least-squares fit on the columns of ``D`` (B, N, q)."""
        d = np.sqrt(np.maximum(np.sum(D**2, axis=-2, keepdims=True), 1e-300))
        Q, _ = np.linalg.qr(D / d)
        return X - Q @ (np.swapaxes(Q, -1, -2) @ X)

    def weighted_residual(self, th: ArrayLike, sigma: ArrayLike) -> NDArray[np.float64]:
        """Residual on the observed samples over ``sigma`` (unit variance under the noise model), the
        nuisance (initial states, offsets) fitted by weighted least squares and removed: (N,) for one
        parameter vector, (B, N) for a batch."""
        th_a = np.asarray(th, float)
        e, D = self._design(th_a, np.asarray(sigma, float))
        r = self._project(D, e[..., None])[..., 0]
        return r[0] if th_a.ndim == 1 else r

    def _per_output(self, v: NDArray[np.float64]) -> list[NDArray[np.float64]]:
        """Split stacked observed-sample vectors (..., N) into per-output pieces (records pooled)."""
        parts: list[list[NDArray[np.float64]]] = [[] for _ in range(self.no)]
        i = 0
        for r in self.recs:
            for o in range(self.no):
                m = int(r.obs[:, o].sum())
                parts[o].append(v[..., i: i + m])
                i += m
        return [np.concatenate(p, axis=-1) for p in parts]

    def rss_weighted(self, th: ArrayLike, sigma: ArrayLike) -> NDArray[np.float64]:
        """Per-output RSS (..., n_out) in output units for parameter vectors (..., p) (the MCMC hot path:
        batched)."""
        sig = np.asarray(sigma, float)
        th_a = np.asarray(th, float)
        thb = th_a.reshape(-1, th_a.shape[-1])
        out = np.empty((thb.shape[0], self.no))
        for s0 in range(0, thb.shape[0], 64):  # bounded memory: (64, n, n_out, n_states) free responses
            r = self.weighted_residual(thb[s0: s0 + 64], sig)
            r = r[None] if r.ndim == 1 else r
            out[s0: s0 + 64] = np.stack([np.sum(p**2, axis=-1) for p in self._per_output(r)], axis=-1)
        return out.reshape(*th_a.shape[:-1], self.no) * sig**2

    def fisher(self, th: NDArray[np.float64], sigma: NDArray[np.float64]) -> NDArray[np.float64]:
        """Fisher information in z-space (module docstring), nuisance projected out."""
        model = self.model
        z = model.to_z(th)
        h = np.where(model.log_mask, 1e-4, 1e-4 * np.maximum(np.abs(z), 1e-6))

        def pred(Z: NDArray[np.float64]) -> NDArray[np.float64]:
            parts = []
            for r, (forced, _free) in zip(self.recs, self.responses(model.from_z(Z)), strict=True):
                for o in range(self.no):
                    parts.append(forced[:, r.obs[:, o], o] / sigma[o])
            return np.concatenate(parts, axis=1)

        J = _fd_jacobian(pred, z, h)  # (N, p)
        _, D = self._design(th[None], sigma)
        Jp = self._project(D, J[None])[0]
        return Jp.T @ Jp


def fit_held_ml(model: GreyBoxModel, recs: Sequence[HeldRecord], x0: ArrayLike, *, n_reweight: int = 4,
                max_nfev: int = 200) -> tuple[MlResult, HeldProblem]:
    """Joint ML of the parameters and per-output noise variances on held records (module docstring),
    from ``x0`` (physical units). Returns the :class:`~hil.identify.timedomain.MlResult` (``n_bins``:
    observed samples / 2) and the problem (for the posterior and the adequacy tests)."""
    t0 = time.perf_counter()
    prob = HeldProblem(model, recs)
    lo, hi = model.z_bounds()
    inner_lo, inner_hi = lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo)
    z = np.clip(model.to_z(np.asarray(x0, float)), inner_lo, inner_hi)
    sigma = np.sqrt(np.maximum(prob.rss_weighted(model.from_z(z), np.ones(prob.no)), 1e-300) / prob.n_obs)
    big = 1e6
    sol = None
    for it in range(n_reweight):

        def resid(zz: NDArray[np.float64], sig: NDArray[np.float64] = sigma) -> NDArray[np.float64]:
            with np.errstate(all="ignore"):
                try:
                    r = prob.weighted_residual(model.from_z(zz), sig)
                except np.linalg.LinAlgError:
                    return np.full(int(prob.n_obs.sum()), big)
            return np.where(np.isfinite(r), r, big)

        sol = least_squares(resid, z, bounds=(lo, hi), method="trf", x_scale="jac", max_nfev=max_nfev)
        z = np.clip(sol.x, inner_lo, inner_hi)
        new = np.sqrt(np.maximum(prob.rss_weighted(model.from_z(z), sigma), 1e-300) / prob.n_obs)
        change = float(np.max(np.abs(new / sigma - 1)))
        sigma = new
        logger.debug("held ML reweight %d: sigma %s (change %.2e), cost %.6g", it, sigma, change, sol.cost)
        if change < 1e-4:
            break
    if sol is None or not np.all(np.isfinite(z)):
        raise ConvergenceError("output-error ML fit (held outputs) failed")
    theta = model.from_z(z)
    F = prob.fisher(theta, sigma)
    cov_z = normalized_pinv(F)
    dd = np.where(model.log_mask, theta, 1.0)
    cov_theta = cov_z * np.outer(dd, dd)
    crb_std = np.sqrt(np.clip(np.diag(cov_theta), 0, None))
    r = prob.weighted_residual(theta, sigma)
    n_states = model.state_space(theta)[0].shape[-1]
    dof = int(r.size - theta.size - (n_states + prob.no) * len(recs))
    logger.info("output-error ML %s on held outputs: %d observed samples, noise std %s, %s", model.name, r.size,
                sigma, sol.message)
    return MlResult(names=model.names, theta=theta, z=z, sigma=sigma, fisher=F, cov_z=cov_z, cov_theta=cov_theta,
                    crb_std=crb_std, chi2=float(np.sum(r**2)), dof=dof, success=bool(sol.success),
                    message=str(sol.message), n_bins=int(r.size // 2),
                    elapsed_s=time.perf_counter() - t0), prob


def check_held_fit(prob: HeldProblem, theta: ArrayLike, sigma: ArrayLike, *, alpha: float = 1e-3) -> Any:
    """Adequacy of a held-output fit: whiteness of each output's normalized residual sequence on its
    observed samples and its cross-correlation with each input at those samples
    (:func:`hil.identify.adequacy.whiteness_test`, :func:`~hil.identify.adequacy.cross_correlation_test`,
    Bonferroni over outputs and tests). No reduced chi^2: the noise variance is fitted to the same
    residuals (there is no independent noise estimate in the time domain)."""
    from scipy import special

    from hil.identify.adequacy import AdequacyReport, AdequacyTest, cross_correlation_test, whiteness_test

    th = np.asarray(theta, float)
    sig = np.asarray(sigma, float)
    per = prob._per_output(prob.weighted_residual(th, sig))
    model = prob.model
    a = alpha / (2 * prob.no)
    rep = AdequacyReport()
    for o, name in enumerate(model.output_names):
        e = per[o]
        rep.tests.append(whiteness_test(e, alpha=a, channel=name))
        S, dof = 0.0, 0
        u_obs = np.concatenate([r.u[r.obs[:, o]] for r in prob.recs])
        for i in range(u_obs.shape[1]):
            ui = u_obs[:, i] - np.mean(u_obs[:, i])
            if np.any(ui):
                c = cross_correlation_test(e, ui, alpha=a)
                S += c.statistic
                dof += c.details["dof"]
        if dof:
            p = float(special.chdtrc(dof, S))
            rep.tests.append(AdequacyTest("input_residual_correlation", name, S, p >= a, p, None, a, {"dof": dof}))
    if rep.misfit:
        logger.warning("model %s does not fit the (held) data: %s", model.name, "; ".join(rep.reasons))
    return rep
