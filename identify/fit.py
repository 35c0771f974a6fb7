"""Weighted nonlinear least squares on complex FRF residuals.

Residual vector (real and imaginary parts stacked, weighted by the per-component FRF std from
:mod:`hil.identify.frf`)::

    r(z) = [Re(H(theta(z), w) - H_meas) / sigma,  Im(H(theta(z), w) - H_meas) / sigma]

minimized with :func:`scipy.optimize.least_squares` (trust-region reflective, bounded) over z-space
(log of the positive parameters). Covariance from the Jacobian at the optimum:
``cov_z = (J^T J)^-1`` (inverted in correlation form; the weights already carry the noise level, so
it is not rescaled by the reduced chi^2 -- that ratio is reported as a model-adequacy check
instead); physical std by the delta method.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from hil.identify.errors import ConvergenceError
from hil.identify.fisher import frf_jacobian, normalized_pinv
from hil.identify.frf import FrfEstimate
from hil.identify.models import GreyBoxModel

logger = logging.getLogger(__name__)

__all__ = ["LsResult", "fit_least_squares"]


@dataclass
class LsResult:
    """Least-squares estimate: ``theta`` (physical), ``z``, covariances, ``std`` (physical)."""

    names: tuple[str, ...]
    theta: NDArray[np.float64]
    z: NDArray[np.float64]
    cov_z: NDArray[np.float64]
    cov_theta: NDArray[np.float64]
    std: NDArray[np.float64]
    chi2: float
    dof: int
    success: bool
    message: str
    n_starts: int

    @property
    def reduced_chi2(self) -> float:
        return self.chi2 / max(self.dof, 1)

    def to_dict(self) -> dict[str, object]:
        return {
            "theta": dict(zip(self.names, map(float, self.theta), strict=True)),
            "std": dict(zip(self.names, map(float, self.std), strict=True)),
            "cov": self.cov_theta.tolist(),
            "chi2": self.chi2,
            "dof": self.dof,
            "reduced_chi2": self.reduced_chi2,
            "success": self.success,
            "message": self.message,
        }


def _data(
    est: FrfEstimate,
) -> tuple[NDArray[np.float64], NDArray[np.complex128], NDArray[np.float64], NDArray[np.bool_]]:
    ok = np.isfinite(est.H) & np.isfinite(est.sigma) & (est.sigma > 0)
    return est.w, est.H, est.sigma, ok


def fit_least_squares(
    model: GreyBoxModel,
    est: FrfEstimate,
    *,
    x0: ArrayLike | None = None,
    n_starts: int = 4,
    seed: int = 0,
    max_nfev: int = 500,
) -> LsResult:
    """Weighted NLS of ``model`` on ``est`` (channels must match ``model.output_names`` order).

    Starts from ``x0`` (physical; default: model nominal) and ``n_starts - 1`` extra starts drawn
    (seeded) log-uniformly within a factor ~3 of it (at most 200 evaluations each); keeps the lowest
    cost. Iterations use second-order difference Jacobians, the covariance fourth-order ones.
    """
    if est.H.shape[1:] != (len(model.output_names), len(model.input_names)):
        raise ValueError(f"FRF shape {est.H.shape[1:]} does not match model outputs/inputs")
    w, H, sig, ok = _data(est)
    lo_z, hi_z = model.z_bounds()
    span = hi_z - lo_z
    # Optimize in the model's sampling coordinates (identity unless the model defines them): a
    # combination pinned down far better than the rest is then a coordinate, not a curved ridge.
    tr = model.has_sampling_transform
    n = lo_z.size
    if tr:
        a, b = model.to_sampling(lo_z), model.to_sampling(hi_z)
        lo, hi = np.minimum(a, b), np.maximum(a, b)
    else:
        lo, hi = lo_z, hi_z
    inner_lo, inner_hi = lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo)
    big = 1e10  # residual outside the model's domain (trust region shrinks back)

    def to_z(x: NDArray[np.float64]) -> NDArray[np.float64]:
        return model.from_sampling(x)[0] if tr else x

    def resid(x: NDArray[np.float64]) -> NDArray[np.float64]:
        z = to_z(x)
        if not np.all(np.isfinite(z)):
            return np.full(2 * int(ok.sum()), big)
        E = (model.frf(model.from_z(z), w) - H)[ok] / sig[ok]
        r = np.concatenate([E.real, E.imag])
        return np.where(np.isfinite(r), r, big)

    def jac_z(z: NDArray[np.float64], order: int = 2) -> NDArray[np.float64]:
        J = frf_jacobian(model, model.from_z(z), w, order=order)[ok] / sig[ok][:, None]
        return np.concatenate([J.real, J.imag], axis=0)

    def jac(x: NDArray[np.float64]) -> NDArray[np.float64]:
        z = to_z(x)
        if not np.all(np.isfinite(z)):
            return np.zeros((2 * int(ok.sum()), n))
        if not tr:
            return jac_z(z)
        h = 1e-7
        E = np.eye(n) * h
        dz_du = ((model.from_sampling(x + E)[0] - model.from_sampling(x - E)[0]) / (2 * h)).T
        return jac_z(z) @ np.nan_to_num(dz_du)

    rng = np.random.default_rng(seed)
    z0 = model.to_z(model.nominal if x0 is None else np.asarray(x0, float))
    starts = [z0]
    for _ in range(max(n_starts, 1) - 1):
        pert = np.where(model.log_mask, rng.uniform(-1.1, 1.1, z0.size), rng.uniform(-0.1, 0.1, z0.size) * span)
        starts.append(z0 + pert)
    best = None
    for k, zs in enumerate(starts):
        xs = np.clip(model.to_sampling(np.clip(zs, lo_z, hi_z)) if tr else zs, inner_lo, inner_hi)
        budget = max_nfev if k == 0 else min(max_nfev, 200)  # the given start gets the larger budget
        try:
            sol = least_squares(resid, xs, jac=jac, bounds=(lo, hi), method="trf", x_scale="jac", max_nfev=budget)
        except (ValueError, np.linalg.LinAlgError) as exc:  # pragma: no cover - defensive
            logger.debug("LS start failed: %s", exc)
            continue
        if np.all(np.isfinite(to_z(sol.x))) and (best is None or sol.cost < best.cost):
            best = sol
    if best is None:
        raise ConvergenceError("least squares failed from every start")
    best.x = to_z(best.x)

    J = jac_z(best.x, order=4)  # covariance: fourth-order differences
    cov_z = normalized_pinv(J.T @ J)
    theta = model.from_z(best.x)
    D = np.diag(np.where(model.log_mask, theta, 1.0))
    cov_theta = D @ cov_z @ D
    chi2 = float(2 * best.cost)
    dof = int(2 * ok.sum() - theta.size)
    logger.info("LS fit %s: chi2/dof = %.3f (%s)", model.name, chi2 / max(dof, 1), best.message)
    return LsResult(
        names=model.names,
        theta=theta,
        z=best.x,
        cov_z=cov_z,
        cov_theta=cov_theta,
        std=np.sqrt(np.clip(np.diag(cov_theta), 0, None)),
        chi2=chi2,
        dof=dof,
        success=bool(best.success),
        message=str(best.message),
        n_starts=len(starts),
    )
