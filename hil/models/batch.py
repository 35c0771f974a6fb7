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

A cubic with p3 < 0 (for t: b22 > 4 B_f) is unbounded below; its normalized value
p(x)/|p|(x) (|p|(x) = Σ|p_i| xⁱ) tends to sign(p3) = -1 as x → ∞, and -1 is its exact infimum
(|p(x)| ≤ |p|(x)), so such a draw gets the finite margin -1 and is decided without the exact
path (only a p3 within ``tol`` of zero, i.e. b22 within ``tol`` of 4 B_f, is re-decided exactly).

The **critical band** of a draw (``band_lo``, ``band_hi``, rad/s) is the frequency interval around
the minimum of g(ω) = t(ω²)/|t|(ω²), the normalized (c-ii) coupler condition, where
g(ω) - g_min ≤ f·(1 - g_min), f = :data:`CRITICAL_BAND_FRACTION` (10 %): the frequencies where the
binding condition lies within 10 % of the way from its minimum to the top of its scale (g ≤ 1).
It is evaluated on :data:`BAND_GRID_RAD_S` (ω from 1 to 10⁶ rad/s, 60 points per decade) with the
edges interpolated linearly in log ω, so it has positive width whenever g is not constant; an edge
at the end of the grid (e.g. for b22 > 4 B_f, where g → -1 as ω → ∞) is reported as that end.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from hil.models.sdea import SDEA_TABLE1, sdea_polynomials

__all__ = ["BAND_GRID_RAD_S", "CRITICAL_BAND_FRACTION", "critical_band", "sdea_passivity_batch"]

_KEYS = tuple(SDEA_TABLE1)

#: the fraction f of the critical band's definition (see the module docstring)
CRITICAL_BAND_FRACTION = 0.10
#: the frequency grid (rad/s) on which the critical band and the worst frequency are evaluated
BAND_GRID_RAD_S = np.geomspace(1.0, 1e6, 361)


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
                         fixed: Mapping[str, float] | None = None, band: bool = False,
                         exact_fallback: bool = True) -> dict[str, np.ndarray]:
    """Two-port passivity of the SDEA for N parameter draws at once.

    ``draws`` maps parameter names (those of :data:`SDEA_TABLE1`) to arrays of length N; missing
    parameters take ``fixed`` values or the Table I defaults. Returns ``passive`` (bool, N),
    ``margin`` (the smallest normalized deciding value: t_min / scale etc.), ``exact_rechecked``
    (bool, N: decided by the exact criterion because the closed form was within ``tol``),
    ``worst_omega`` (rad/s, N: where the coupler condition (c-ii) is smallest) and the critical
    band's edges ``band_lo``, ``band_hi`` (rad/s) when ``band=True``; by default (``band=False``) these
    three are not computed (verdicts and margins only: the band costs ~15× the verdicts, and most
    callers -- searches, P(stable) curves, sweeps -- discard it). ``exact_fallback=False`` keeps the
    closed form's sign for the draws within ``tol`` of the boundary (still flagged in
    ``exact_rechecked``): for searches that converge onto the boundary (FORM), whose end points the
    caller checks exactly.
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
        # a cubic unbounded below (p3 < 0): its normalized value's exact infimum is -1 (x → ∞)
        m_r = np.where(r3 < 0, -1.0, m_r)
        m_t = np.where(t3 < 0, -1.0, m_t)
    margin = np.minimum(np.minimum(m_a, m_r), m_t)
    margin = np.where(pos & (b22 > 0) & (b22 <= 4 * Bf), margin, np.minimum(margin, -1.0))
    passive = margin > tol
    # b22 within tol of 4 B_f: the sign of t3 is not resolved by the float coefficients
    edge = np.abs(4 * Bf - b22) <= tol * np.abs(4 * Bf + b22)
    ambiguous = (np.abs(margin) <= tol) | ~np.isfinite(margin) | edge
    if exact_fallback and np.any(ambiguous):
        from hil.models.sdea import sdea_vsic
        from hil.stability.criteria import two_port_passivity

        for i in np.nonzero(ambiguous)[0]:
            r = two_port_passivity(sdea_vsic({k: float(q[k][i]) for k in _KEYS}))
            passive[i] = r.verdict == "stable"
    # where the coupler-dependent passivity condition (c-ii) is closest to failing, and the band
    # around it (module docstring): g(ω) = t(x)/|t|(x), x = ω²
    if not band:
        return {"passive": passive, "margin": margin, "exact_rechecked": ambiguous}
    worst, lo, hi = critical_band((t0, t1, t2, t3))
    return {"passive": passive, "margin": margin, "exact_rechecked": ambiguous, "worst_omega": worst,
            "band_lo": lo, "band_hi": hi}


def critical_band(t: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
                  fraction: float = CRITICAL_BAND_FRACTION,
                  grid: np.ndarray = BAND_GRID_RAD_S) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ω_worst, ω_lo, ω_hi) in rad/s per draw for the cubics t(x) = t0 + t1 x + t2 x² + t3 x³
    (ascending coefficients, arrays of length N): the grid frequency where g(ω) = t(ω²)/|t|(ω²)
    is smallest, and the edges of the contiguous interval around it where
    g - g_min ≤ ``fraction``·(1 - g_min), interpolated linearly in log ω between grid points
    (the grid's ends when the interval reaches them)."""
    t0, t1, t2, t3 = (np.atleast_1d(np.asarray(c, float)) for c in t)
    x = (grid * grid)[:, None]
    tv = ((t3 * x + t2) * x + t1) * x + t0
    tm = ((np.abs(t3) * x + np.abs(t2)) * x + np.abs(t1)) * x + np.abs(t0)
    with np.errstate(invalid="ignore", divide="ignore"):
        g = np.where(tm > 0, tv / tm, 1.0)  # t ≡ 0 at a point: no information there
    m, n = g.shape
    k = np.argmin(g, axis=0)
    cols = np.arange(n)
    gmin = g[k, cols]
    thr = gmin + fraction * (1.0 - gmin)
    below = g <= thr[None, :]
    lw = np.log(grid)
    # the contiguous run of `below` containing k: walk outwards with cumulative "first break"
    idx = np.arange(m)[:, None]
    brk_lo = np.where(~below & (idx < k[None, :]), idx, -1).max(axis=0)  # last grid point above thr left of k
    brk_hi = np.where(~below & (idx > k[None, :]), idx, m).min(axis=0)  # first one right of k

    def edge(i_out: np.ndarray, i_in: np.ndarray) -> np.ndarray:
        go, gi = g[i_out, cols], g[i_in, cols]
        with np.errstate(invalid="ignore", divide="ignore"):
            a = np.clip(np.where(go != gi, (thr - gi) / (go - gi), 0.0), 0.0, 1.0)
        return np.asarray(np.exp(lw[i_in] + a * (lw[i_out] - lw[i_in])))

    io = np.clip(brk_lo, 0, m - 2)
    lo = np.where(brk_lo < 0, grid[0], edge(io, io + 1))
    io = np.clip(brk_hi, 1, m - 1)
    hi = np.where(brk_hi >= m, grid[-1], edge(io, io - 1))
    return grid[k], lo, hi
