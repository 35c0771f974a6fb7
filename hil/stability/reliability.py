"""Reliability of a stability verdict over a posterior: the first-order reliability index β (FORM)
and an importance-sampling estimate of the (rare) probability of instability around its design
point.

Coordinates (docs/CERTIFICATION.md, "Reliability index β"): *posterior-standardized* with the
full covariance, u = L⁻¹(θ − μ), where μ is the posterior mean and Σ = L Lᵀ (Cholesky) the
posterior covariance of the independent draws. The posterior centre is u = 0; correlated
parameters are decorrelated (not merely scaled one by one); a Gaussian posterior N(μ, Σ) becomes
the standard normal N(0, I).

* :func:`form` -- β = ‖u*‖, the distance from u = 0 to the nearest point u* where the network
  stops being stable (``stable_fn`` turns False), found with the verdict alone (no gradient of a
  margin): along a ray the first unstable point of a grid is bracketed and bisected; rays start
  from the ± coordinate axes, random directions and the caller's hints (e.g. the directions of
  unstable draws), and the best ray is refined by fitting the tangent hyperplane of the boundary
  through neighbouring crossings (a sign-only Hasofer-Lind iteration: exact in one step for a
  linear limit state). β is signed: negative when the centre itself is not stable (then ‖u*‖ is
  the distance to the nearest stable point). Φ(β) is the FORM approximation of P(stable): exact
  when the posterior is Gaussian and the limit state linear in u.
* :func:`importance_sampling` -- P_f = P(not stable) under N(0, I) by importance sampling with the
  proposal N(u*, I) (weights φ(u)/φ(u − u*) = exp(−u·u* + ‖u*‖²/2)), with a two-sided
  normal-approximation confidence interval from the weighted samples' standard error; a rare-event
  path for requirements such as P(stable) ≥ 1 − 10⁻⁶, which plain Monte Carlo could only certify
  with ~10⁷ draws.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from hil.errors import HilError

logger = logging.getLogger(__name__)

__all__ = ["FormResult", "ISResult", "Standardization", "form", "importance_sampling"]

StableFn = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Standardization:
    """θ = μ + L u: the posterior-standardized coordinates (μ the mean, L the Cholesky factor of
    the covariance of the draws)."""

    mu: np.ndarray
    L: np.ndarray

    @classmethod
    def from_draws(cls, X: np.ndarray) -> Standardization:
        """From an (n, d) array of independent posterior draws (n ≥ d + 2)."""
        X = np.asarray(X, float)
        if X.ndim != 2 or X.shape[0] < X.shape[1] + 2:
            raise HilError("the reliability index needs at least d + 2 draws of a d-parameter vector")
        mu = X.mean(axis=0)
        C = np.atleast_2d(np.cov(X, rowvar=False))
        # a tiny ridge (relative to each variance) keeps a degenerate parameter from breaking Cholesky
        C = C + np.diag(1e-12 * np.maximum(np.diag(C), 1e-300))
        return cls(mu, np.linalg.cholesky(C))

    def to_theta(self, U: np.ndarray) -> np.ndarray:
        return np.asarray(self.mu + np.atleast_2d(U) @ self.L.T)

    def to_u(self, T: np.ndarray) -> np.ndarray:
        return np.linalg.solve(self.L, (np.atleast_2d(T) - self.mu).T).T


@dataclass
class FormResult:
    """β (signed), its design point u* (standardized) and the search's bookkeeping."""

    beta: float
    design_point_u: np.ndarray
    bracket: tuple[float, float]  # the crossing lies between these distances along u*'s ray
    censored: bool  # no crossing within r_max: β ≥ r_max (reported as r_max)
    evaluations: int
    directions: int

    @property
    def phi_beta(self) -> float:
        """Φ(β): the FORM approximation of P(stable)."""
        from scipy.special import ndtr  # Φ (scipy.stats costs 0.5 s to import)

        return float(ndtr(self.beta))


@dataclass
class ISResult:
    """Importance-sampling estimate of P_f = P(not stable) under N(0, I)."""

    p_failure: float
    std_error: float
    lower: float  # confidence interval on P_f
    upper: float
    confidence: float
    n: int
    n_fail: int
    ess: float  # effective sample size of the weights of the failing samples, (Σw)²/Σw²
    reliable: bool  # ≥ MIN_FAILURES failing samples and ESS ≥ MIN_ESS: the standard error is meaningful

    @property
    def p_stable(self) -> float:
        return 1.0 - self.p_failure

    @property
    def p_stable_lower(self) -> float:
        return 1.0 - self.upper


#: fewer failing proposal samples than this: the IS standard error is not trusted
MIN_FAILURES = 10
#: a smaller effective sample size of the failing samples' weights: a few samples carry the
#: estimate (the failure set has mass far from the design point, e.g. around a sphere): not trusted
MIN_ESS = 30.0


class _Counted:
    def __init__(self, fn: StableFn, budget: int | None) -> None:
        self.fn, self.n, self.budget = fn, 0, budget

    def __call__(self, U: np.ndarray) -> np.ndarray:
        U = np.atleast_2d(U)
        self.n += U.shape[0]
        out = np.asarray(self.fn(U), bool).reshape(-1)
        if out.shape[0] != U.shape[0]:
            raise HilError("stable_fn must return one verdict per point")
        return out

    @property
    def exhausted(self) -> bool:
        return self.budget is not None and self.n >= self.budget


def _crossings(fn: _Counted, V: np.ndarray, grid: np.ndarray, n_bisect: int) -> tuple[np.ndarray, np.ndarray]:
    """(r_lo, r_hi) per unit direction: the first grid point where ``fn`` is False, bisected with
    the last grid point before it (r_lo = 0 when the first grid point already fails); both inf when
    no grid point fails."""
    m, g = V.shape[0], grid.size
    pts = (grid[None, :, None] * V[:, None, :]).reshape(m * g, -1)
    ok = fn(pts).reshape(m, g)
    bad = ~ok
    has = bad.any(axis=1)
    j = np.argmax(bad, axis=1)
    r_hi = np.where(has, grid[j], np.inf)
    r_lo = np.where(has, np.where(j > 0, grid[np.maximum(j - 1, 0)], 0.0), np.inf)
    idx = np.nonzero(has)[0]
    for _ in range(n_bisect):
        if idx.size == 0:
            break
        mid = 0.5 * (r_lo[idx] + r_hi[idx])
        s = fn(mid[:, None] * V[idx])
        r_lo[idx] = np.where(s, mid, r_lo[idx])
        r_hi[idx] = np.where(s, r_hi[idx], mid)
    return r_lo, r_hi


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def form(stable_fn: StableFn, d: int, *, hints: Sequence[np.ndarray] | np.ndarray | None = None,
         r_max: float = 8.0, n_random: int = 64, n_grid: int = 33, n_bisect: int = 30, refine_iter: int = 12,
         n_refine_starts: int = 3, seed: int = 0, budget: int | None = None,
         r_limit: float | None = None) -> FormResult:
    """The reliability index β for a verdict ``stable_fn`` ((n, d) standardized points → n bools;
    vectorized if it can be) around the centre u = 0 (module docstring). ``hints``: extra start
    directions (any length; e.g. whitened unstable draws). ``r_max``: the search radius (a β
    beyond it is reported as r_max with ``censored``); ``n_grid`` grid points per ray on (0, r_max]
    before ``n_bisect`` bisection steps; ``budget``: an upper limit on the number of verdicts (the
    refinement stops when it is spent); ``r_limit`` (> r_max): when nothing is found within r_max,
    the search is repeated with the radius ×8 up to this limit (a very tight posterior)."""
    if d < 1:
        raise HilError("the reliability index needs at least one parameter")
    centre_ok = bool(np.asarray(stable_fn(np.zeros((1, d))), bool).reshape(-1)[0])
    # search for the first point whose verdict differs from the centre's
    fn = _Counted(lambda U: np.asarray(stable_fn(U), bool).reshape(-1) == centre_ok, budget)
    fn.n = 1
    sign = 1.0 if centre_ok else -1.0
    grid = np.linspace(r_max / n_grid, r_max, n_grid)
    rng = np.random.default_rng(seed)
    starts = [np.eye(d), -np.eye(d)]
    if n_random:
        starts.append(_unit(rng.standard_normal((n_random, d))))
    if hints is not None and len(hints):
        h = np.atleast_2d(np.asarray(hints, float))
        h = h[np.linalg.norm(h, axis=1) > 0]
        if h.size:
            starts.append(_unit(h))
    V = np.vstack(starts)
    r_lo, r_hi = _crossings(fn, V, grid, n_bisect)
    n_dirs = V.shape[0]
    # linear-boundary estimate from the axis crossings: the plane through them has normal Σ sᵢ eᵢ / rᵢ
    ax = np.full(d, np.inf)
    sg = np.ones(d)
    for i in range(d):
        rp, rm = r_hi[i], r_hi[d + i]
        ax[i], sg[i] = (rp, 1.0) if rp <= rm else (rm, -1.0)
    nvec = np.where(np.isfinite(ax), sg / ax, 0.0)
    if np.any(nvec != 0):
        v = _unit(nvec)[None, :]
        a, b = _crossings(fn, v, grid, n_bisect)
        V, r_lo, r_hi = np.vstack([V, v]), np.r_[r_lo, a], np.r_[r_hi, b]
        n_dirs += 1
    if not np.isfinite(r_hi).any():
        if r_limit is not None and r_max * 8 <= r_limit and not fn.exhausted:
            res = form(stable_fn, d, hints=hints, r_max=r_max * 8, n_random=n_random, n_grid=n_grid,
                       n_bisect=n_bisect, refine_iter=refine_iter, n_refine_starts=n_refine_starts, seed=seed,
                       budget=None if budget is None else budget - fn.n, r_limit=r_limit)
            res.evaluations += fn.n
            return res
        logger.info("FORM: no %s point within r_max = %g", "unstable" if centre_ok else "stable", r_max)
        return FormResult(sign * r_max, np.zeros(d), (r_max, math.inf), True, fn.n, n_dirs)
    best = []
    for i in np.argsort(r_hi)[:n_refine_starts]:
        if np.isfinite(r_hi[i]):
            best.append((float(r_hi[i]), float(r_lo[i]), V[i]))
    results = []
    for r, rl, v in best:
        r, rl, v, k = _refine(fn, v, r, rl, grid, n_bisect, refine_iter, d)
        n_dirs += k
        results.append((r, rl, v))
        if fn.exhausted:
            break
    r, rl, v = min(results, key=lambda t: t[0])
    return FormResult(sign * r, r * v, (rl, r), False, fn.n, n_dirs)


def _refine(fn: _Counted, v: np.ndarray, r: float, rl: float, grid: np.ndarray, n_bisect: int, iters: int,
            d: int) -> tuple[float, float, np.ndarray, int]:
    """Sign-only Hasofer-Lind refinement: crossings on rays tilted by ±δ in every tangent direction,
    the least-squares plane nᵀp = 1 through them and the current point, then the ray along n (the
    foot of the perpendicular of that plane); δ shrinks when it does not improve."""
    if d == 1:
        return r, rl, v, 0
    delta, used = 0.2, 0
    for _ in range(iters):
        if fn.exhausted or delta < 1e-5:
            break
        # orthonormal tangent basis at v
        Q, _ = np.linalg.qr(np.column_stack([v, np.eye(d)]))
        T = Q[:, 1:d].T
        P = _unit(np.vstack([v + delta * T, v - delta * T]))
        lo, hi = _crossings(fn, P, grid, n_bisect)
        used += P.shape[0]
        ok = np.isfinite(hi)
        pts = np.vstack([r * v, hi[ok, None] * P[ok]])
        if pts.shape[0] < d:
            delta *= 0.5
            continue
        n, *_ = np.linalg.lstsq(pts, np.ones(pts.shape[0]), rcond=None)
        cand = [(float(hi[i]), float(lo[i]), P[i]) for i in np.nonzero(ok)[0]]
        if np.linalg.norm(n) > 0:
            vn = _unit(n)[None, :]
            a, b = _crossings(fn, vn, grid, n_bisect)
            used += 1
            if np.isfinite(b[0]):
                cand.append((float(b[0]), float(a[0]), vn[0]))
        rb, lb, vb = min(cand, key=lambda t: t[0])
        if rb < r * (1 - 1e-9):
            step = float(np.linalg.norm(vb - v))
            r, rl, v = rb, lb, vb
            delta = min(0.2, max(2 * step, delta * 0.5))
        else:
            delta *= 0.25
    return r, rl, v, used


def importance_sampling(stable_fn: StableFn, design_point_u: np.ndarray, n: int = 4000, confidence: float = 0.95,
                        seed: int = 0) -> ISResult:
    """P_f = P(``stable_fn`` False) for u ~ N(0, I) by importance sampling from N(u*, I) (module
    docstring). Interval: p̂ ± z·se, z the two-sided normal quantile at ``confidence``, se the
    standard error of the weighted indicator, clipped to [0, 1]; asymptotic (CLT), flagged
    unreliable with fewer than :data:`MIN_FAILURES` failing samples or an effective sample size
    of their weights below :data:`MIN_ESS` (the interval is then [0, 1]: nothing certified)."""
    from scipy.special import ndtri  # Φ⁻¹

    u_star = np.asarray(design_point_u, float).reshape(-1)
    d = u_star.size
    rng = np.random.default_rng(seed)
    U = u_star + rng.standard_normal((n, d))
    logw = -U @ u_star + 0.5 * float(u_star @ u_star)
    fail = ~np.asarray(stable_fn(U), bool).reshape(-1)
    w = np.exp(logw)
    Y = np.where(fail, w, 0.0)
    p = float(Y.mean())
    se = float(Y.std(ddof=1) / math.sqrt(n)) if n > 1 else math.inf
    k = int(fail.sum())
    lf = logw[fail]
    wf = np.exp(lf - lf.max()) if k else lf  # scale-free: the ESS does not change with a common factor
    ess = float(wf.sum() ** 2 / (wf * wf).sum()) if k else 0.0
    z = float(ndtri(0.5 + confidence / 2))
    reliable = k >= MIN_FAILURES and ess >= MIN_ESS
    lo, hi = (max(0.0, p - z * se), min(1.0, p + z * se)) if reliable else (0.0, 1.0)
    return ISResult(p, se, lo, hi, confidence, n, k, ess, reliable)
