"""Identifiability before the run: Fisher information of an FRF experiment and the Cramér-Rao bound.

The FRF-domain measurement model is ``H_meas[k, o, i] = H(theta, w_k)[o, i] + e`` with independent
real and imaginary errors of std ``sigma[k, o, i]``. Its Fisher information in z-space (log of the
positive parameters, see :mod:`hil.identify.models`) is::

    F = sum_{k,o,i} Re( conj(J_koi) J_koi^T ) / sigma_koi^2,   J = dH/dz  (complex)

and the Cramér-Rao bound on the covariance of an unbiased estimate of ``z`` is ``F^-1``; in
physical units ``cov(theta) ~ D F^-1 D`` with ``D = diag(dtheta/dz)`` (delta method). Since ``z`` is
a log for positive parameters, ``sqrt(diag F^-1)`` is directly the relative standard deviation.

``J`` is computed by fourth-order central differences in z-space (steps ~1e-3 in z, truncation
~1e-13 relative) evaluated as ONE batched model call (4p parameter vectors): records whose best
channel is precise to 1e-8 (float32 rounding of a noise-free simulated velocity) would otherwise see
the differencing error as information along directions the data are blind to.

Identifiability: the Fisher matrix is normalized to a correlation-like matrix
``C = F_ij / sqrt(F_ii F_jj)`` (its eigen-decomposition taken from the SVD of the column-normalized
weighted Jacobian, which keeps eigenvalues down to ~1e-30 of the largest accurate). An eigenvalue
of ``C`` below ``rank_tol`` flags a direction of parameter space that the data see far less than
the others; it is declared NOT identifiable (the involved parameters are named, with a
model-specific fix) when the data also leave it absolutely undetermined: the (conditional) CRB std
along it exceeds ``null_frac`` of the prior range. The second test keeps a direction that one
channel measures to 1e-3 while another measures the rest to 1e-9 (a badly conditioned but
identifiable experiment: flagged ill-conditioned, not rejected). A condition number of ``C`` above
``cond_warn`` or a relative CRB std above ``rel_std_warn`` flags poorly identified parameters. The
CRB itself is inverted in the normalized form (``cov = D^-1 C^-1 D^-1``), which keeps such badly
scaled but regular matrices invertible.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.identify.errors import ModelSpecError, NotIdentifiableError
from hil.identify.models import GreyBoxModel

logger = logging.getLogger(__name__)

__all__ = [
    "ExperimentPlan",
    "IdentifiabilityReport",
    "check_identifiability",
    "crb",
    "fisher_information",
    "frf_jacobian",
    "normalized_pinv",
    "weighted_jacobian",
]


def _fd_steps(model: GreyBoxModel, z: NDArray[np.float64]) -> NDArray[np.float64]:
    lo, hi = model.z_bounds()
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    return np.where(model.log_mask, 1e-3, 1e-3 * np.maximum(np.abs(z), 1e-3 * span))


def frf_jacobian(model: GreyBoxModel, theta: ArrayLike, w: ArrayLike, *, order: int = 4) -> NDArray[np.complex128]:
    """dH/dz at ``theta`` (physical units): complex array (n_f, n_out, n_in, p), z-space derivative
    (central differences of ``order`` 4 (default) or 2 -- half the model evaluations, for search
    directions -- in one batched model call)."""
    z = model.to_z(np.asarray(theta, float))
    h = _fd_steps(model, z)
    p = z.size
    if order == 2:
        h = h * 1e-2  # truncation ~h^2 ~1e-10
        Z = np.concatenate([z + np.diag(h), z - np.diag(h)], axis=0)
        H = model.frf(model.from_z(Z), w)
        return np.moveaxis((H[:p] - H[p:]) / (2.0 * h[:, None, None, None]), 0, -1)
    D = np.diag(h)
    Z = np.concatenate([z + 2 * D, z + D, z - D, z - 2 * D], axis=0)  # (4p, p)
    H = model.frf(model.from_z(Z), w)  # (4p, nf, no, ni)
    J = (-H[:p] + 8.0 * H[p : 2 * p] - 8.0 * H[2 * p : 3 * p] + H[3 * p :]) / (12.0 * h[:, None, None, None])
    return np.moveaxis(J, 0, -1)


def normalized_pinv(F: NDArray[np.float64], rcond: float = 1e-13) -> NDArray[np.float64]:
    """Pseudo-inverse of a symmetric PSD matrix through its correlation form ``D^-1 pinv(C) D^-1``
    (scale-invariant: parameters measured to very different precisions stay resolved)."""
    d = np.sqrt(np.clip(np.diag(F), 0, None))
    dead = d <= 1e-300
    dn = np.where(dead, 1.0, d)
    C = F / np.outer(dn, dn)
    C[dead, :] = 0.0
    C[:, dead] = 0.0
    Ci = np.linalg.pinv(C, rcond=rcond, hermitian=True)
    return Ci / np.outer(dn, dn)


def fisher_information(model: GreyBoxModel, theta: ArrayLike, w: ArrayLike, sigma: ArrayLike) -> NDArray[np.float64]:
    """Fisher information in z-space for FRF data with per-component std ``sigma`` (n_f, n_out, n_in).

    Bins with non-finite or non-positive sigma are ignored.
    """
    Jr = weighted_jacobian(model, theta, w, sigma)
    return Jr.T @ Jr


def weighted_jacobian(model: GreyBoxModel, theta: ArrayLike, w: ArrayLike, sigma: ArrayLike) -> NDArray[np.float64]:
    """``dH/dz / sigma`` of the usable bins as a real matrix (2N, p): real parts, then imaginary
    parts; ``F = J^T J``. Its SVD resolves information ratios down to ~1e-30 where ``eig(F)`` stops
    at ~1e-16."""
    J = frf_jacobian(model, theta, w)
    s = np.asarray(sigma, float)
    s = np.broadcast_to(s, J.shape[:-1])
    ok = np.isfinite(s) & (s > 0) & np.all(np.isfinite(J), axis=-1)
    Jw = J[ok] / s[ok][:, None]  # (N, p)
    return np.concatenate([Jw.real, Jw.imag], axis=0)


def crb(
    model: GreyBoxModel, theta: ArrayLike, F: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Cramér-Rao covariance in z-space and the physical std (delta method). Pseudo-inverse if singular."""
    cov_z = normalized_pinv(F)
    th = np.asarray(theta, float)
    d = np.where(model.log_mask, th, 1.0)
    std = np.sqrt(np.clip(np.diag(cov_z), 0, None)) * np.abs(d)
    return cov_z, std


@dataclass(frozen=True)
class ExperimentPlan:
    """A planned chirp experiment, for the Fisher check BEFORE running it.

    One (periodic) linear chirp of peak ``amplitude`` (input units) sweeping ``chirp_band`` [Hz] is
    applied on each model input in turn, during ``duration`` [s] per input, sampled at ``fs`` [Hz];
    the FRF is estimated with Welch segments of ``nperseg`` samples (no overlap) and analysed in
    ``band`` [Hz]. ``noise_std`` is the white measurement-noise std of each measured output (a
    scalar for all, or a mapping output name -> std), in output units at the rate ``fs``.

    Per-bin FRF variance: input PSD ``Suu = A^2 / (2 (f1 - f0))`` (power ``A^2/2`` spread over the
    sweep), noise PSD ``Snn = 2 sd^2 / fs``, ``K = duration fs / nperseg`` averages:
    ``E|dH|^2 = Snn / (K Suu)``, i.e. per real/imag component ``sigma^2 = Snn / (2 K Suu)``.
    """

    band: tuple[float, float]
    fs: float
    duration: float
    amplitude: float | Sequence[float]
    noise_std: float | Mapping[str, float]
    nperseg: int
    chirp_band: tuple[float, float] | None = None

    def frequencies(self) -> NDArray[np.float64]:
        """Welch bin frequencies [Hz] inside the analysis band."""
        f = np.fft.rfftfreq(self.nperseg, 1.0 / self.fs)
        return np.asarray(f[(f >= self.band[0]) & (f <= self.band[1]) & (f > 0)], float)

    @property
    def n_averages(self) -> int:
        return int(self.duration * self.fs // self.nperseg)

    def frf_sigma(self, model: GreyBoxModel) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(f [Hz], sigma (n_f, n_out, n_in)) predicted for ``model``'s measured outputs."""
        f = self.frequencies()
        f0, f1 = self.chirp_band or self.band
        ni, no = len(model.input_names), len(model.output_names)
        amp = np.broadcast_to(np.asarray(self.amplitude, float), (ni,))
        if isinstance(self.noise_std, Mapping):
            missing = [o for o in model.output_names if o not in self.noise_std]
            if missing:
                raise ModelSpecError(f"noise_std lacks outputs {missing}")
            sd = np.array([self.noise_std[o] for o in model.output_names], float)
        else:
            sd = np.full(no, float(self.noise_std))
        K = self.n_averages
        if K < 2:
            raise ModelSpecError("plan gives fewer than 2 Welch averages: lengthen duration or shorten nperseg")
        Suu = amp**2 / (2.0 * (f1 - f0))  # (ni,)
        Snn = 2.0 * sd**2 / self.fs  # (no,)
        in_sweep = ((f >= f0) & (f <= f1)).astype(float)
        with np.errstate(divide="ignore"):
            var = Snn[None, :, None] / (2.0 * K * Suu[None, None, :] * in_sweep[:, None, None])
        return f, np.sqrt(var)


@dataclass
class IdentifiabilityReport:
    """Result of :func:`check_identifiability` (all quantities at the given ``theta``)."""

    names: tuple[str, ...]
    theta: NDArray[np.float64]
    fisher: NDArray[np.float64]
    crb_cov_z: NDArray[np.float64]
    crb_std: NDArray[np.float64]
    crb_rel_std: NDArray[np.float64]
    eigenvalues: NDArray[np.float64]
    condition: float
    rank: int
    unidentifiable: list[str] = field(default_factory=list)
    poorly_identified: list[str] = field(default_factory=list)
    messages: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """True when the Fisher matrix has full rank (every parameter is seen by the data)."""
        return self.rank == len(self.names)

    def raise_if_not_identifiable(self) -> None:
        if not self.ok:
            raise NotIdentifiableError("; ".join(self.messages), report=self)

    def to_dict(self) -> dict[str, object]:
        return {
            "ok": self.ok,
            "rank": self.rank,
            "n_params": len(self.names),
            "condition": self.condition,
            "crb_std": dict(zip(self.names, map(float, self.crb_std), strict=True)),
            "crb_rel_std": dict(zip(self.names, map(float, self.crb_rel_std), strict=True)),
            "unidentifiable": self.unidentifiable,
            "poorly_identified": self.poorly_identified,
            "messages": self.messages,
        }


def check_identifiability(
    model: GreyBoxModel,
    theta: ArrayLike | None = None,
    *,
    plan: ExperimentPlan | None = None,
    w: ArrayLike | None = None,
    sigma: ArrayLike | None = None,
    rank_tol: float = 1e-8,
    cond_warn: float = 1e6,
    rel_std_warn: float = 0.5,
    null_frac: float = 0.1,
    log_level: int = logging.WARNING,
) -> IdentifiabilityReport:
    """Fisher rank/condition check of an experiment, from a ``plan`` or from ``(w [rad/s], sigma)``.

    ``theta`` defaults to the model's nominal values (the check is local: use the best prior guess).
    The report's messages are logged at ``log_level`` (an identification that checks twice, before
    and after its fit, logs the first check at DEBUG so that each warning appears once).
    """
    th = model.nominal if theta is None else np.asarray(theta, float)
    if plan is not None:
        f, sig = plan.frf_sigma(model)
        ww = 2 * np.pi * f
    elif w is not None and sigma is not None:
        ww, sig = np.asarray(w, float), np.asarray(sigma, float)
    else:
        raise ModelSpecError("give either plan= or both w= and sigma=")
    Jr = weighted_jacobian(model, th, ww, sig)
    F = Jr.T @ Jr
    names = model.names
    d = np.sqrt(np.clip(np.diag(F), 0, None))
    dead = d <= 1e-300
    dn = np.where(dead, 1.0, d)
    Jn = Jr / dn
    Jn[:, dead] = 0.0
    # eigen-decomposition of C = Jn^T Jn through the SVD of Jn (accurate small eigenvalues)
    if Jn.shape[0] >= Jn.shape[1]:
        _, sv, vt = np.linalg.svd(Jn, full_matrices=False)
        ev, vec = (sv**2)[::-1], vt[::-1].T
    else:  # fewer observations than parameters
        ev, vec = np.linalg.eigh(Jn.T @ Jn)
    emax = max(float(ev[-1]), 1e-300)
    rel_ev = ev / emax
    # conditional CRB std along each eigen-direction, in units of the prior range of every coordinate
    lo_z, hi_z = model.z_bounds()
    zspan = np.where(np.isfinite(hi_z - lo_z), hi_z - lo_z, 1.0)
    dir_std = np.full(ev.size, np.inf)
    for k in range(ev.size):
        v = vec[:, k]
        if ev[k] > 0 and not np.any(dead & (np.abs(v) > 0.2 * np.max(np.abs(v)))):
            dir_std[k] = float(np.linalg.norm(v / dn / zspan) / np.sqrt(ev[k]))
    null = (rel_ev < rank_tol) & (dir_std > null_frac)
    rank = int(np.sum(~null))
    cond = float(emax / ev[0]) if ev[0] > 0 else float("inf")
    cov_z, std = crb(model, th, F)
    # relative std: in log units for positive parameters; as a fraction of the prior span otherwise (their
    # value may legitimately be ~0, e.g. a cross-coupling term)
    lo, hi = model.lower, model.upper
    rel = np.where(model.log_mask, np.sqrt(np.clip(np.diag(cov_z), 0, None)), std / (hi - lo))
    messages: list[str] = []
    unident: list[str] = []
    for kn in np.flatnonzero(null):
        v = vec[:, kn]
        involved = {names[i] for i in np.flatnonzero(np.abs(v) > 0.2 * np.max(np.abs(v)))}
        involved |= {names[i] for i in np.flatnonzero(dead)}
        unident += [n for n in names if n in involved and n not in unident]
        hint = model.identifiability_hint(involved)
        combo = " + ".join(f"{v[i]:+.2f}*dz({names[i]})" for i in np.argsort(-np.abs(v))[: len(involved)])
        msg = f"parameters {sorted(involved)} are not separately identifiable (data blind to {combo})"
        messages.append(f"{msg}: {hint}" if hint else f"{msg}: measure another channel or fix one of them")
    poor: list[str] = []
    if rank == len(names):
        for i, n in enumerate(names):
            if rel[i] > (rel_std_warn if model.log_mask[i] else 0.1):
                poor.append(n)
        if poor:
            messages.append(
                f"poorly identified (relative CRB std > {rel_std_warn:.0%}): {poor}; widen the band around the "
                "frequencies where they act, raise the amplitude or lengthen the experiment"
            )
        if cond > cond_warn:
            messages.append(
                f"Fisher matrix ill-conditioned (cond {cond:.2e}): strongly correlated parameters, or channels of "
                "very different precision"
            )
    for m in messages:
        # an ill-conditioned but regular Fisher matrix alone (every parameter identifiable and well
        # determined: e.g. channels of very different precision, as on every default sdea_bench run)
        # is information, not a warning: it is in the report, and in the log at INFO (hil --debug)
        alone = m.startswith("Fisher matrix ill-conditioned") and not poor and not unident
        logger.log(min(log_level, logging.INFO) if alone else log_level, "identifiability: %s", m)
    return IdentifiabilityReport(
        names=names,
        theta=th,
        fisher=F,
        crb_cov_z=cov_z,
        crb_std=std,
        crb_rel_std=rel,
        eigenvalues=ev,
        condition=cond,
        rank=rank,
        unidentifiable=unident,
        poorly_identified=poor,
        messages=messages,
    )
