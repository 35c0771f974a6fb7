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
  multi-start bounded optimization, not only by sampling; the centre is a candidate, so worst ≤
  nominal by construction when the nominal margin is the same function at the centre;
* :func:`max_safe_parameter` -- design guidance: the largest value of a free design parameter
  (e.g. the virtual-coupler stiffness k22) that keeps the probability of stability at the
  required level;
* :func:`posterior_limit` -- the value of the design parameter where the lower bound of
  P(stable) crosses the requirement, searched from the current value (the posterior headroom);
* :class:`Policy` and :func:`decide` -- the verdict policy.

Verdict policy (:func:`decide`; defaults in :class:`Policy`, overridable per scene; every input
defined in docs/CERTIFICATION.md):

* **ERROR** when the evidence is missing or broken: no draws, NaN/inf in draws, β or headroom, a
  failed identification. NaN never yields GO.
* **GO** when the nominal verdict is stable (weak included), the posterior converged, the lower
  confidence bound of P(stable) (Clopper-Pearson on independent draws, or importance sampling on
  the rare-event path) clears ``required_probability``, the reliability index β ≥ Φ⁻¹(required),
  and, where a design parameter exists, its headroom is positive at the nominal plant and over
  the posterior.
* **NO-GO** when the nominal network is potentially unstable, the nominal headroom is negative,
  or the upper bound of P(stable) is below the requirement.
* **MARGINAL** otherwise (the reasons name each unmet GO condition).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from hil.errors import HilError

logger = logging.getLogger(__name__)

__all__ = [
    "Decision",
    "Policy",
    "autocorrelation_time",
    "beta_required",
    "decide",
    "max_safe_parameter",
    "posterior_limit",
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
    from scipy.special import betaincinv  # beta.ppf(q, a, b) = betaincinv(a, b, q), without scipy.stats (0.5 s)

    s = np.asarray(stable, dtype=bool)
    n = s.size
    if n == 0:
        raise HilError("no posterior draws: the probability of stability is undefined")
    k = int(s.sum())
    a = 1.0 - confidence
    lo = 0.0 if k == 0 else float(betaincinv(k, n - k + 1, a / 2))
    hi = 1.0 if k == n else float(betaincinv(k + 1, n - k, 1 - a / 2))
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
                      n_starts: int = 8, seed: int = 0, maxiter: int = 80, axis_starts: bool = True,
                      centre: np.ndarray | None = None, rank_fn: Callable[[np.ndarray], np.ndarray] | None = None,
                      n_screen: int = 0, n_local: int | None = None) -> tuple[float, np.ndarray]:
    """Minimum of ``margin_fn`` over the credible ellipsoid {θ: (θ-μ)ᵀΣ⁻¹(θ-μ) ≤ χ²_d(credible)}.

    ``margin_fn`` maps an (n, d) array of parameter vectors to n margins. μ is ``centre`` (default:
    the draws' mean), Σ the draws' covariance. The centre itself is always a candidate, so the
    result is ≤ ``margin_fn(centre)`` by construction: with the nominal margin defined as
    ``margin_fn`` at the posterior centre, worst ≤ nominal always holds. Further candidates: the
    draws inside the region (all of them, or, with ``rank_fn`` -- a cheap proxy ranking the draws
    from least to most stable -- the ``n_screen`` lowest-ranked ones), the ellipsoid's axis ends
    (``axis_starts``) and random points, and SLSQP local searches in whitened coordinates (unit
    ball) from the ``n_local`` lowest of these starts (all of them by default). The result is
    the smallest value evaluated: an upper bound on the true infimum over the region. A NaN
    margin counts as -inf (unknown is worst). Returns (margin, θ*)."""
    from scipy.optimize import minimize
    from scipy.special import chdtri  # χ²_d quantile p = chdtri(d, 1 - p)

    X = np.asarray(draws, float)
    if X.ndim != 2 or X.shape[0] < X.shape[1] + 2:
        raise HilError("worst-case margin needs at least d + 2 draws of a d-parameter vector")
    d = X.shape[1]
    mu = X.mean(axis=0) if centre is None else np.asarray(centre, float).reshape(d)
    C = np.cov(X, rowvar=False) + 1e-18 * np.eye(d)
    L = np.linalg.cholesky(np.atleast_2d(C))
    r = math.sqrt(chdtri(d, 1.0 - credible))
    Linv = np.linalg.inv(L)

    def to_theta(z: np.ndarray) -> np.ndarray:
        return mu + (L @ (r * np.atleast_2d(z)).T).T

    def value(T: np.ndarray) -> np.ndarray:
        v = np.asarray(margin_fn(np.atleast_2d(T)), float).reshape(-1)
        return np.where(np.isnan(v), -np.inf, v)

    best_v, best_t = float(value(mu[None, :])[0]), mu.copy()  # the centre: worst ≤ nominal
    W = (X - mu) @ Linv.T
    inside = np.einsum("ij,ij->i", W, W) <= r * r
    Xin, Z_in = X[inside], W[inside] / r
    if rank_fn is not None and Xin.shape[0]:
        order = np.argsort(np.asarray(rank_fn(Xin), float))[: max(n_screen, n_starts // 2)]
        Xin, Z_in = Xin[order], Z_in[order]
    m_in = value(Xin) if Xin.shape[0] else np.zeros(0)
    if m_in.size and float(m_in.min()) < best_v:
        i = int(np.argmin(m_in))
        best_v, best_t = float(m_in[i]), Xin[i].copy()
    starts = list(Z_in[np.argsort(m_in)[: n_starts // 2]]) if m_in.size else []
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
    z_vals = [float(value(to_theta(z))[0]) for z in starts]
    for v, z in zip(z_vals, starts, strict=True):
        if v < best_v:
            best_v, best_t = v, to_theta(z)[0]
    order = np.argsort(z_vals)[: (len(starts) if n_local is None else n_local)]
    for z0 in (starts[i] for i in order):
        def obj(z: np.ndarray) -> float:
            v = float(value(to_theta(z))[0])
            return v if math.isfinite(v) else -1e300

        res = minimize(obj, np.asarray(z0, float), method="SLSQP",
                       constraints=[{"type": "ineq", "fun": lambda z: 1.0 - z @ z}], options={"maxiter": maxiter})
        z = res.x / max(1.0, np.linalg.norm(res.x))
        v = float(value(to_theta(z))[0])
        if v < best_v:
            best_v, best_t = v, to_theta(z)[0]
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


def posterior_limit(stable_fn: Callable[[float], np.ndarray], x0: float, required: float = 0.95,
                    confidence: float = 0.95, rtol: float = 1e-6, span: float = 1e3) -> tuple[float, str]:
    """The value x* of a design parameter (e.g. the coupler stiffness k22) where the lower
    Clopper-Pearson bound of P(stable | x) crosses ``required``, searched outwards from the current
    value ``x0`` > 0 by doubling (when x0 passes) or halving (when it fails), then bisection to
    ``rtol``; P(stable) assumed non-increasing in x, as for a coupler stiffness. Returns (x*, kind):
    ``"exact"`` when bracketed, ``"at_least"`` when it still passes at ``span``·x0 (x* ≥ that),
    ``"at_most"`` when it fails even at x0/``span`` (x* ≤ that). The posterior headroom is
    x*/x0 − 1 (zero at the boundary, positive when x0 passes, negative when it fails)."""
    if not (math.isfinite(x0) and x0 > 0):
        raise HilError(f"the design parameter's current value must be finite and positive, got {x0}")

    def ok(x: float) -> bool:
        return probability_of_stability(stable_fn(x), confidence)[1] >= required

    if ok(x0):
        a, b = x0, 2 * x0
        while ok(b):
            if b >= span * x0:
                return b, "at_least"
            a, b = b, 2 * b
    else:
        a, b = x0 / 2, x0
        while not ok(a):
            if a <= x0 / span:
                return a, "at_most"
            a, b = a / 2, a
    while b - a > rtol * b:
        m = 0.5 * (a + b)
        a, b = (m, b) if ok(m) else (a, m)
    return a, "exact"


def beta_required(required: float) -> float:
    """The reliability index a GO needs: Φ⁻¹(required) (1.645 for 0.95, 4.753 for 1 − 10⁻⁶), the β
    at which the first-order approximation Φ(β) of P(stable) equals the requirement."""
    from scipy.special import ndtri  # Φ⁻¹

    return float(ndtri(required))


def decide(nominal_verdict: str | None, stable_draws: np.ndarray | None, policy: Policy = Policy(),
           converged: bool = True, evidence_errors: list[str] | None = None, *, nominal_weak: bool = False,
           beta: float | None = None, headroom_nominal: float | None = None,
           headroom_posterior: float | None = None, rare_event: tuple[float, float] | None = None,
           require_beta: bool = True) -> tuple[Decision, list[str], dict[str, float] | None]:
    """Apply the verdict policy (docs/CERTIFICATION.md "decision"); returns (decision, reasons,
    probability summary).

    Inputs, each a defined quantity:

    * the nominal verdict; ``nominal_weak``: a condition holds with equality (the criterion's ≥ 0
      allows it, so it is reported, not blocking);
    * the stability of every independent posterior draw (its Clopper-Pearson interval), or, on the
      rare-event path, ``rare_event`` = (lower, upper) of P(stable) by importance sampling (then
      that interval decides);
    * the reliability index ``beta``: GO needs β ≥ Φ⁻¹(required); with ``require_beta`` and no β,
      no GO;
    * the parametric headroom of a design parameter at the nominal plant and over the posterior:
      GO needs both > 0 where given; a negative nominal headroom is NO-GO.

    * ERROR: evidence errors, no nominal verdict, no draws, undefined (NaN) stability of a draw or
      a non-finite β or headroom, a criterion that does not apply;
    * NO-GO: the nominal network is potentially unstable, its headroom is negative, or the upper
      bound of P(stable) is below the requirement;
    * GO: nominal stable (weak included), converged, lower bound ≥ required, β ≥ Φ⁻¹(required),
      headrooms > 0;
    * MARGINAL: anything else (the reasons say which condition was not met).
    """
    reasons: list[str] = []
    if evidence_errors:
        return Decision.ERROR, list(evidence_errors), None
    if nominal_verdict is None:
        return Decision.ERROR, ["nominal verdict missing"], None
    if stable_draws is None or np.asarray(stable_draws).size == 0:
        return Decision.ERROR, ["no posterior draws"], None
    s = np.asarray(stable_draws)
    if s.dtype != bool and not np.all(np.isin(s, (0, 1))):
        return Decision.ERROR, ["stability of some draws is undefined (NaN)"], None
    for name, v in (("β", beta), ("nominal headroom", headroom_nominal), ("posterior headroom", headroom_posterior)):
        if v is not None and not math.isfinite(float(v)):
            return Decision.ERROR, [f"{name} is not finite"], None
    p, lo, hi = probability_of_stability(s.astype(bool), policy.confidence)
    prob = {"p": p, "lower": lo, "upper": hi, "n": int(s.size), "confidence": policy.confidence,
            "required": policy.required_probability}
    method = "Clopper-Pearson on independent draws"
    if rare_event is not None:
        lo, hi = float(rare_event[0]), float(rare_event[1])
        method = "importance sampling around the FORM design point"
        prob.update({"lower": lo, "upper": hi})
    if nominal_verdict == "not_applicable":
        return Decision.ERROR, ["the criterion does not apply to the nominal network"], prob
    if nominal_verdict == "potentially_unstable":
        reasons.append("at its nominal parameters (posterior medians) the network fails the exact stability "
                       "criterion: some passive operator and environment can make it unstable")
        return Decision.NO_GO, reasons, prob
    if headroom_nominal is not None and headroom_nominal < 0:
        reasons.append(f"the design parameter exceeds its limit at the nominal plant (headroom "
                       f"{headroom_nominal:+.3g})")
        return Decision.NO_GO, reasons, prob
    req = policy.required_probability
    if hi < req:
        reasons.append(f"P(stable) = {p:.4f}: its upper {policy.confidence:.0%} bound {hi:.4g} ({method}) "
                       f"is below {req:.6g}")
        return Decision.NO_GO, reasons, prob
    b_req = beta_required(req)
    checks = {
        "converged": converged,
        "nominal stable": nominal_verdict == "stable",
        "P(stable) bound": lo >= req,
        "β": (beta is not None and beta >= b_req) or (beta is None and not require_beta),
        "nominal headroom": headroom_nominal is None or headroom_nominal > 0,
        "posterior headroom": headroom_posterior is None or headroom_posterior > 0,
    }
    if all(checks.values()):
        reasons.append(f"P(stable) ≥ {lo:.6g} (lower {policy.confidence:.0%} bound, {method}) clears {req:.6g}")
        if nominal_weak:
            reasons.append("the nominal network is stable (weak: a condition holds with equality, as the "
                           "criterion allows; β measures how far instability is)")
        if beta is not None:
            reasons.append(f"reliability index β = {beta:.3g} ≥ Φ⁻¹({req:.6g}) = {b_req:.3g}")
        if headroom_posterior is not None:
            reasons.append(f"design headroom {headroom_posterior:+.3g} over the posterior"
                           + (f", {headroom_nominal:+.3g} at the nominal plant" if headroom_nominal is not None
                              else ""))
        return Decision.GO, reasons, prob
    if not checks["converged"]:
        reasons.append("the posterior did not converge: evidence insufficient")
    if nominal_verdict == "marginal":
        reasons.append("the nominal verdict is marginal: the rounding bound of its condition straddles zero")
    if not checks["P(stable) bound"]:
        reasons.append(f"P(stable) = {p:.4f} with {policy.confidence:.0%} interval [{lo:.4g}, {hi:.4g}] ({method}) "
                       f"straddles {req:.6g}: near the boundary (more draws or data may settle it)")
    if not checks["β"]:
        reasons.append("the reliability index β is unavailable" if beta is None else
                       f"the reliability index β = {beta:.3g} is below Φ⁻¹({req:.6g}) = {b_req:.3g}")
    if not checks["nominal headroom"]:
        reasons.append("the design parameter sits at its limit at the nominal plant (headroom 0)")
    if not checks["posterior headroom"]:
        reasons.append(f"the design parameter has no headroom over the posterior ({headroom_posterior:+.3g})")
    return Decision.MARGINAL, reasons or ["near the boundary"], prob

