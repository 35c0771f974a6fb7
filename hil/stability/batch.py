"""Vectorized verdicts over many parameter draws (posterior samples) of the SDEA model.

For the SDEA under VSIC with the eq. (11) coupler, two-port passivity reduces (Theorem 5 of paper
002, re-derived in ``hil.models.sdea`` and cross-checked against the general criterion in the
tests) to:

* (a) h11's characteristic quartic a(s) Hurwitz: all a_i > 0 and a1(a2a3 - a1a4) - a0a3² > 0;
* (c-i) r(x) = r3x³ + r2x² + r1x + r0 ≥ 0 on x ≥ 0 (Re h11 ≥ 0, eq. 34);
* (c-ii) 0 < b22 ≤ 4B_f and t(x) = t3x³ + t2x² + t1x + t0 ≥ 0 on x ≥ 0 (eq. 36).

Each cubic is decided in closed form, vectorized: non-negative on x ≥ 0 iff p3 ≥ 0, p0 ≥ 0 and
p is non-negative at its positive critical points (roots of 3p3x² + 2p2x + p1). Draws whose
deciding value is within ``tol`` of zero (relative to the magnitudes of its terms) are re-decided
one by one with the exact general criterion (:func:`two_port_passivity`), so the batch never
flips a boundary case on round-off.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from hil.models.sdea import SDEA_TABLE1, sdea_polynomials

__all__ = ["sdea_passivity_batch"]

_KEYS = tuple(SDEA_TABLE1)


def _cubic_min(p3: np.ndarray, p2: np.ndarray, p1: np.ndarray,
               p0: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(min over x ≥ 0 of the cubic, the magnitude scale there, the minimizing x), vectorized.

    Returns -inf where p3 < 0 (unbounded below)."""
    n = p3.shape[0]
    best = p0.copy()
    scale = np.abs(p0).copy()
    xbest = np.zeros(n)
    A, B, C = 3 * p3, 2 * p2, p1
    disc = B * B - 4 * A * C
    with np.errstate(invalid="ignore", divide="ignore"):
        sq = np.sqrt(np.where(disc >= 0, disc, np.nan))
        # numerically stable quadratic roots
        q = -0.5 * (B + np.copysign(sq, B))
        r1 = q / A
        r2 = C / q
    for r in (r1, r2):
        ok = np.isfinite(r) & (r > 0)
        x = np.where(ok, r, 0.0)
        v = ((p3 * x + p2) * x + p1) * x + p0
        s = ((np.abs(p3) * x + np.abs(p2)) * x + np.abs(p1)) * x + np.abs(p0)
        better = ok & (v < best)
        best = np.where(better, v, best)
        scale = np.where(better, s, scale)
        xbest = np.where(better, x, xbest)
    # linear/quadratic degenerate cases (p3 == 0): fall back to the exact path via tiny scale
    deg = p3 == 0
    best = np.where(p3 < 0, -np.inf, best)
    scale = np.where(deg, 0.0, scale)
    assert best.shape == (n,)
    return best, scale, xbest


def sdea_passivity_batch(draws: Mapping[str, np.ndarray] | np.ndarray, tol: float = 1e-9,
                         fixed: Mapping[str, float] | None = None) -> dict[str, np.ndarray]:
    """Two-port passivity of the SDEA for N parameter draws at once.

    ``draws`` maps parameter names (those of :data:`SDEA_TABLE1`) to arrays of length N; missing
    parameters take ``fixed`` values or the Table I defaults. Returns ``passive`` (bool, N),
    ``margin`` (the smallest normalized deciding value: t_min / scale etc.), ``exact_rechecked``
    (bool, N: decided by the exact criterion because the closed form was within ``tol``),
    ``worst_omega`` (rad/s, N: where the coupler condition (c-ii) is smallest).
    """
    base = {**SDEA_TABLE1, **(fixed or {})}
    d = dict(draws)
    n = len(next(iter(d.values())))
    q = {k: np.asarray(d.get(k, np.full(n, base[k])), dtype=float) for k in _KEYS}
    polys = sdea_polynomials(q)
    a4, a3, a2, a1, a0 = polys["a"]
    r0, r1, r2, r3 = polys["r"]
    t0, t1, t2, t3 = polys["t"]
    Bf, b22 = q["B_f"], q["b22"]
    hur = a1 * (a2 * a3 - a1 * a4) - a0 * a3 * a3
    hur_s = np.abs(a1 * a2 * a3) + np.abs(a1 * a1 * a4) + np.abs(a0 * a3 * a3)
    pos = (a4 > 0) & (a3 > 0) & (a2 > 0) & (a1 > 0) & (a0 > 0)
    rmin, rs, _ = _cubic_min(r3, r2, r1, r0)
    tmin, ts, _ = _cubic_min(t3, t2, t1, t0)
    with np.errstate(invalid="ignore", divide="ignore"):
        m_a = np.where(hur_s > 0, hur / hur_s, -1.0)
        m_r = np.where(rs > 0, rmin / rs, np.where(np.isneginf(rmin), -1.0, 0.0))
        m_t = np.where(ts > 0, tmin / ts, np.where(np.isneginf(tmin), -1.0, 0.0))
    margin = np.minimum(np.minimum(m_a, m_r), m_t)
    margin = np.where(pos & (b22 > 0) & (b22 <= 4 * Bf), margin, np.minimum(margin, -1.0))
    passive = margin > tol
    ambiguous = (np.abs(margin) <= tol) | ~np.isfinite(margin)
    if np.any(ambiguous):
        from hil.models.sdea import sdea_vsic
        from hil.stability.criteria import two_port_passivity

        for i in np.nonzero(ambiguous)[0]:
            r = two_port_passivity(sdea_vsic({k: float(q[k][i]) for k in _KEYS}))
            passive[i] = r.verdict == "stable"
    # where the coupler-dependent passivity condition (c-ii) is closest to failing: the minimum over
    # a log grid of ω of t(x)/|t|(x) (value over its magnitude), x = ω²
    x = np.geomspace(1.0, 1e12, 241)[:, None]
    tv = ((t3 * x + t2) * x + t1) * x + t0
    tm = ((np.abs(t3) * x + np.abs(t2)) * x + np.abs(t1)) * x + np.abs(t0)
    with np.errstate(invalid="ignore", divide="ignore"):
        k = np.argmin(np.where(tm > 0, tv / tm, np.inf), axis=0)
    worst = np.sqrt(x[k, 0])
    return {"passive": passive, "margin": margin, "exact_rechecked": ambiguous, "worst_omega": worst}
