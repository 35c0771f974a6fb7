"""Robust certification: identified parameters (posterior draws) through the stability conditions
into a GO / MARGINAL / NO-GO decision, kept apart from ERROR.

Pieces (each usable on its own):

* :func:`probability_of_stability` -- the fraction of posterior draws that are stable, with an
  exact (Clopper-Pearson) confidence interval for the Monte Carlo estimate; the interval assumes
  independent draws, so a correlated MCMC chain is first thinned by its integrated
  autocorrelation time (:func:`autocorrelation_time`, :func:`thin_indices`): the interval then
  rests on about n_steps·n_walkers/τ draws, the chain's effective sample size, never on
  resampled duplicates;
* :func:`worst_case_margin` -- the smallest margin over a credible region of the posterior (the
  Mahalanobis ellipsoid of the draws' mean and covariance at the requested credibility), found by
  multi-start bounded optimization, not only by sampling;
* :func:`max_safe_parameter` -- design guidance: the largest value of a free design parameter
  (e.g. the virtual-coupler stiffness k22) that keeps the probability of stability at the
  required level;
* :class:`Policy` and :func:`decide` -- the verdict policy.

Verdict policy (defaults in :class:`Policy`, overridable per scene):

* **ERROR** when the evidence is missing or broken: no draws, NaN/inf in draws or margins, a
  failed identification. NaN never yields GO.
* **GO** when the nominal verdict is stable with a positive margin, the posterior converged, and
  the confidence interval of P(stable) lies above ``required_probability`` (its lower bound clears it).
* **NO-GO** when the nominal network is potentially unstable, or the interval lies below the
  requirement (its upper bound does not reach it).
* **MARGINAL** otherwise: the interval straddles the requirement (near the boundary: more draws or
  better identification may settle it), the nominal verdict is marginal, the nominal margin is not
  positive, or the posterior did not converge (the numbers may be right; the evidence is not
  sufficient).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np

from hil.errors import HilError

log = logging.getLogger(__name__)

__all__ = [
    "Certificate",
    "Decision",
    "Policy",
    "autocorrelation_time",
    "decide",
    "max_safe_parameter",
    "probability_of_stability",
    "thin_indices",
    "worst_case_margin",
]


class Decision(StrEnum):
    GO = "GO"
    MARGINAL = "MARGINAL"
    NO_GO = "NO-GO"
    ERROR = "ERROR"


@dataclass(frozen=True)
class Policy:
    """The verdict policy. ``required_probability``: P(stable) the lower confidence bound must
    clear; ``confidence``: level of the Clopper-Pearson interval; ``credible``: level of the
    credible region for the worst-case margin."""

    required_probability: float = 0.95
    confidence: float = 0.95
    credible: float = 0.90

    def __post_init__(self) -> None:
        for k in ("required_probability", "confidence", "credible"):
            v = getattr(self, k)
            if not 0.0 < v < 1.0:
                raise HilError(f"policy.{k} must lie in (0, 1), got {v}")


def probability_of_stability(stable: np.ndarray, confidence: float = 0.95) -> tuple[float, float, float]:
    """(p̂, lower, upper): fraction of stable draws and its exact two-sided Clopper-Pearson
    interval at ``confidence``. Draws must be independent: thin a correlated MCMC chain with
    :func:`thin_indices` by its :func:`autocorrelation_time` before calling this (an unthinned
    chain gives an interval about √τ times too narrow)."""
    from scipy.stats import beta

    s = np.asarray(stable, dtype=bool)
    n = s.size
    if n == 0:
        raise HilError("no posterior draws: the probability of stability is undefined")
    k = int(s.sum())
    a = 1.0 - confidence
    lo = 0.0 if k == 0 else float(beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1 - a / 2, k + 1, n - k))
    return k / n, lo, hi


def autocorrelation_time(chain: np.ndarray) -> float:
    """The largest integrated autocorrelation time τ (in steps) of a chain, over its parameters,
    by ``emcee.autocorr.integrated_time`` (``tol=0``: no length check; a chain shorter than ~50 τ
    gives an underestimate, which the identification's convergence check already flags).

    ``chain``: (n_steps,), (n_steps, n_walkers) or (n_steps, n_walkers, d); walkers are averaged
    as emcee does. Returns at least 1."""
    import emcee

    c = np.asarray(chain, float)
    if c.ndim == 1:
        c = c[:, None, None]
    elif c.ndim == 2:
        c = c[:, :, None]
    if c.ndim != 3 or c.shape[0] < 2:
        raise HilError(f"autocorrelation time needs a chain of shape (n_steps, n_walkers, d), got {c.shape}")
    tau = np.asarray(emcee.autocorr.integrated_time(c, tol=0), float)
    tau = tau[np.isfinite(tau)]
    return max(1.0, float(tau.max())) if tau.size else 1.0


def thin_indices(n_steps: int, n_walkers: int, tau: float) -> np.ndarray:
    """Indices, into the flattened chain (row ``step·n_walkers + walker``, emcee's
    ``get_chain(flat=True)`` order), of the samples kept when every walker is thinned to one sample
    per ⌈τ⌉ steps: about n_steps·n_walkers/τ approximately independent draws (the chain's
    effective sample size)."""
    if n_steps < 1 or n_walkers < 1:
        raise HilError("thinning needs at least one step and one walker")
    step = max(1, math.ceil(float(tau))) if math.isfinite(float(tau)) else n_steps
    return (np.arange(0, n_steps, step)[:, None] * n_walkers + np.arange(n_walkers)[None, :]).ravel()


def worst_case_margin(margin_fn: Callable[[np.ndarray], np.ndarray], draws: np.ndarray, credible: float = 0.90,
                      n_starts: int = 8, seed: int = 0, maxiter: int = 80,
                      axis_starts: bool = True) -> tuple[float, np.ndarray]:
    """Minimum of ``margin_fn`` over the credible ellipsoid {θ: (θ-μ)ᵀΣ⁻¹(θ-μ) ≤ χ²_d(credible)}.

    ``margin_fn`` maps an (n, d) array of parameter vectors to n margins (vectorized). The search
    runs in whitened coordinates (unit ball), starting from the draws inside the region with the
    smallest margins and from the ellipsoid's axis ends, with SLSQP under the ball constraint.
    Returns (margin, θ*)."""
    from scipy.optimize import minimize
    from scipy.stats import chi2

    X = np.asarray(draws, float)
    if X.ndim != 2 or X.shape[0] < X.shape[1] + 2:
        raise HilError("worst-case margin needs at least d + 2 draws of a d-parameter vector")
    mu = X.mean(axis=0)
    C = np.cov(X, rowvar=False) + 1e-18 * np.eye(X.shape[1])
    L = np.linalg.cholesky(np.atleast_2d(C))
    r = math.sqrt(chi2.ppf(credible, X.shape[1]))
    Linv = np.linalg.inv(L)

    def to_theta(z: np.ndarray) -> np.ndarray:
        return mu + (L @ (r * z).T).T

    inside = np.einsum("ij,ij->i", (X - mu) @ Linv.T, (X - mu) @ Linv.T) <= r * r
    Z_in = ((X[inside] - mu) @ Linv.T) / r
    m_in = margin_fn(X[inside]) if inside.any() else np.zeros(0)
    starts = list(Z_in[np.argsort(m_in)[: n_starts // 2]]) if m_in.size else []
    d = X.shape[1]
    if axis_starts:
        for i in range(d):
            for sgn in (1.0, -1.0):
                e = np.zeros(d)
                e[i] = 0.95 * sgn
                starts.append(e)
    rng = np.random.default_rng(seed)
    while len(starts) < n_starts + (2 * d if axis_starts else 0):
        v = rng.normal(size=d)
        starts.append(0.9 * v / np.linalg.norm(v))
    best_v, best_t = math.inf, mu
    for z0 in starts:
        res = minimize(lambda z: float(margin_fn(to_theta(z[None, :]))[0]), np.asarray(z0, float), method="SLSQP",
                       constraints=[{"type": "ineq", "fun": lambda z: 1.0 - z @ z}], options={"maxiter": maxiter})
        z = res.x / max(1.0, np.linalg.norm(res.x))
        v = float(margin_fn(to_theta(z[None, :]))[0])
        if v < best_v:
            best_v, best_t = v, to_theta(z[None, :])[0]
    if m_in.size and float(m_in.min()) < best_v:  # never report worse than a sampled point
        i = int(np.argmin(m_in))
        best_v, best_t = float(m_in[i]), X[inside][i]
    return best_v, best_t


def max_safe_parameter(stable_fn: Callable[[float], np.ndarray], lo: float, hi: float, required: float = 0.95,
                       confidence: float = 0.95, rtol: float = 1e-4) -> tuple[float, float]:
    """Largest x in [lo, hi] with the lower confidence bound of P(stable | x) ≥ ``required``,
    by bisection (P(stable) is assumed non-increasing in x, as for a coupler stiffness).
    ``stable_fn(x)`` returns the boolean stability of every posterior draw at design value x.
    Returns (x, P̂ at x); x = lo - 0 (i.e. ``nan``) if even ``lo`` fails."""
    def ok(x: float) -> bool:
        return probability_of_stability(stable_fn(x), confidence)[1] >= required

    if not ok(lo):
        return math.nan, probability_of_stability(stable_fn(lo), confidence)[0]
    if ok(hi):
        return hi, probability_of_stability(stable_fn(hi), confidence)[0]
    a, b = lo, hi
    while b - a > rtol * max(abs(b), 1e-12):
        m = 0.5 * (a + b)
        a, b = (m, b) if ok(m) else (a, m)
    return a, probability_of_stability(stable_fn(a), confidence)[0]


@dataclass
class Certificate:
    """Everything a reviewer needs to sign (or refuse) one network's certificate."""

    decision: Decision
    reasons: list[str]
    nominal: dict[str, Any]
    probability: dict[str, float] | None = None
    worst_case: dict[str, Any] | None = None
    design: dict[str, Any] | None = None
    evidence: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"decision": str(self.decision), "reasons": self.reasons, "nominal": self.nominal,
                "probability": self.probability, "worst_case": self.worst_case, "design": self.design,
                "evidence": self.evidence}


def decide(nominal_verdict: str | None, nominal_margin: float | None, stable_draws: np.ndarray | None,
           policy: Policy = Policy(), converged: bool = True,
           evidence_errors: list[str] | None = None) -> tuple[Decision, list[str], dict[str, float] | None]:
    """Apply the verdict policy; returns (decision, reasons, probability summary)."""
    reasons: list[str] = []
    if evidence_errors:
        return Decision.ERROR, list(evidence_errors), None
    if nominal_verdict is None or nominal_margin is None or not math.isfinite(float(nominal_margin)):
        return Decision.ERROR, ["nominal verdict or margin missing or not finite"], None
    if stable_draws is None or np.asarray(stable_draws).size == 0:
        return Decision.ERROR, ["no posterior draws"], None
    s = np.asarray(stable_draws)
    if s.dtype != bool and not np.all(np.isin(s, (0, 1))):
        return Decision.ERROR, ["stability of some draws is undefined (NaN)"], None
    p, lo, hi = probability_of_stability(s.astype(bool), policy.confidence)
    prob = {"p": p, "lower": lo, "upper": hi, "n": int(s.size), "confidence": policy.confidence,
            "required": policy.required_probability}
    if nominal_verdict == "potentially_unstable":
        reasons.append("the nominal (posterior-mean) network is potentially unstable")
        return Decision.NO_GO, reasons, prob
    if nominal_verdict in ("not_applicable",):
        return Decision.ERROR, ["the criterion does not apply to the nominal network"], prob
    req = policy.required_probability
    if lo >= req and nominal_verdict == "stable" and nominal_margin > 0 and converged:
        reasons.append(f"P(stable) ≥ {lo:.4f} (lower {policy.confidence:.0%} bound) clears {req:.2f}; "
                       f"nominal margin {nominal_margin:.3g} > 0")
        return Decision.GO, reasons, prob
    if hi < req:
        reasons.append(f"P(stable) = {p:.4f}: its upper {policy.confidence:.0%} bound {hi:.4f} is below {req:.2f}")
        return Decision.NO_GO, reasons, prob
    if not converged:
        reasons.append("the posterior did not converge: evidence insufficient")
    if nominal_verdict == "marginal":
        reasons.append("the nominal network sits within tolerance of the stability boundary")
    if lo < req <= hi:
        reasons.append(f"P(stable) = {p:.4f} with {policy.confidence:.0%} interval [{lo:.4f}, {hi:.4f}] "
                       f"straddles {req:.2f}: near the boundary (more draws or data may settle it)")
    if nominal_margin <= 0 and nominal_verdict == "stable":
        reasons.append("the nominal margin is not positive")
    return Decision.MARGINAL, reasons or ["near the boundary"], prob


def _finite_draws(draws: Mapping[str, np.ndarray]) -> list[str]:
    errs = []
    for k, v in draws.items():
        a = np.asarray(v, float)
        if a.size == 0:
            errs.append(f"parameter {k}: no draws")
        elif not np.all(np.isfinite(a)):
            errs.append(f"parameter {k}: {int(np.sum(~np.isfinite(a)))} non-finite draws")
    return errs
