"""The frequency-domain margin of the stability core: its certified computation (definition:
docs/VERDICTS.md, "The frequency-domain margin").

For a frequency condition p (a principal minor, L1, L2: an exact polynomial in x = ω², *before*
imaginary-axis pole factors are cancelled) with magnitude polynomial m (the same sums of products
on absolute values, :mod:`hil.stability.jpoly`: |p_i| ≤ m_i),

    μ = min over x ≥ 0 of p(x)/m_r(x),   m_r = m restricted to p's exact degree range [a, b].

:func:`frequency_margin` finds the minimizer in floats (interior critical points, each negative
band, the limits), evaluates p exactly there, and then *certifies* the value with one exact sign
decision: p - (1 ∓ 10⁻⁶)·μ·m_r ≥ 0 on x ≥ 0 (its coefficients are exact binary rationals). When
the certificate fails, its negative bands hold a smaller value, which is searched (exactly
evaluated) and certified in turn. So the reported μ is the global minimum to 10⁻⁶ relative,
however small |μ| is and whatever the minimization grid saw, and -- computed from the
frequency-normalized network, whose coefficients are the same floats for every power-of-two
scaling of frequency and impedance -- bit-for-bit invariant under those scalings (issue 31,
item 6).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from fractions import Fraction

import numpy as np
from flint import fmpq, fmpq_poly
from numpy.polynomial import polynomial as P

from hil.stability.results import StabilityResult

logger = logging.getLogger(__name__)

__all__ = ["CERTIFY_RTOL", "CRITICAL_BAND_FRACTION", "band_of", "critical_band", "frequency_margin", "restricted"]

#: the certified relative accuracy of a frequency-domain margin (see the module docstring)
CERTIFY_RTOL = 1e-6


# ----------------------------------------------------------------------------------------------
# frequency conditions


def _exact_ratio(p: fmpq_poly, M: np.ndarray, x: float) -> float:
    """p(x)/M(x) with p evaluated exactly at the float x (no cancellation), M in floats; the
    limits at x = 0 and x = ∞ are p_a/M_a and p_b/M_b."""
    nzm = np.flatnonzero(M)
    if x == 0.0:
        a = int(nzm[0])
        return float(Fraction(int(p[a].p), int(p[a].q)) / Fraction(float(M[a])))
    if not math.isfinite(x):
        b = int(nzm[-1])
        return float(Fraction(int(p[b].p), int(p[b].q)) / Fraction(float(M[b])))
    xq = fmpq(*float(x).as_integer_ratio())
    v = p(xq)
    if x <= 1.0:
        mv = float(P.polyval(x, M))
    else:  # M(x)/x^n and p(x)/x^n: no overflow at huge x (Horner in 1/x)
        n = M.size - 1
        mv = float(P.polyval(1.0 / x, M[::-1]))
        v = v / xq**n
    if not (mv > 0 and math.isfinite(mv)):  # pragma: no cover - M under/overflows even so
        return _exact_ratio(p, M, math.inf) if x > 1 else _exact_ratio(p, M, 0.0)
    return float(Fraction(int(v.p), int(v.q)) / Fraction(mv))


def _q_of(M: np.ndarray) -> fmpq_poly:
    return fmpq_poly([fmpq(*float(v).as_integer_ratio()) for v in M])


def _band_search(p: fmpq_poly, M: np.ndarray, bands: Sequence[tuple[float, float]]) -> tuple[float, float]:
    """The smallest exact ratio over each band (x_lo, x_hi): 65 log- and 65 linearly spaced points,
    the band's ends (0 and ∞ as limits), then a golden-section refinement around the best one."""
    best = (math.inf, math.nan)
    for a, b in bands:
        lo = a if a > 0 else (b * 1e-9 if math.isfinite(b) else 1e-9)
        hi = b if math.isfinite(b) else max(lo, 1.0) * 1e9
        xs = [float(v) for v in np.unique(np.concatenate([np.geomspace(lo, hi, 65), np.linspace(lo, hi, 65)]))]
        pts = [(_exact_ratio(p, M, x), x) for x in xs if x > 0]
        if a == 0:
            pts.append((_exact_ratio(p, M, 0.0), 0.0))
        if not math.isfinite(b):
            pts.append((_exact_ratio(p, M, math.inf), math.inf))
        v, x = min(pts)
        if 0 < x < math.inf:
            i = xs.index(x)
            lo_i = xs[i - 1] if i > 0 else x / 2
            hi_i = xs[i + 1] if i + 1 < len(xs) else x * 2
            v, x = _golden(p, M, lo_i, hi_i, (v, x))
        if v < best[0]:
            best = (v, x)
    return best


def _rational_band_search(p: fmpq_poly, Mq: fmpq_poly, bands: Sequence[tuple[float, float]]
                          ) -> tuple[float, float]:
    """The smallest ratio p/M_r over each finite band, evaluated at exact rational points (both
    polynomials exact): for bands only a few doubles wide, where the minimizer lies between
    doubles and :func:`_band_search` (which evaluates at doubles) cannot reach it. 33 equally
    spaced points over the band widened by one double either side, then 100 steps of ternary search
    around the best one. Returns (value, x) as floats; (∞, NaN) without a finite band."""
    best = (math.inf, math.nan)

    def ratio(xq: fmpq) -> fmpq:
        return p(xq) / Mq(xq)

    for a, b in bands:
        if not (math.isfinite(b) and a > 0):
            continue
        lo, hi = fmpq(*math.nextafter(a, 0.0).as_integer_ratio()), fmpq(*math.nextafter(b, math.inf).as_integer_ratio())
        xs = [lo + (hi - lo) * fmpq(k, 32) for k in range(33)]
        vals = [ratio(x) for x in xs]
        i = min(range(33), key=lambda k: vals[k])
        u, w = xs[max(i - 1, 0)], xs[min(i + 1, 32)]
        for _ in range(100):
            m1, m2 = u + (w - u) / 3, w - (w - u) / 3
            if ratio(m1) <= ratio(m2):
                w = m2
            else:
                u = m1
        xm = (u + w) / 2
        v = min(ratio(xm), vals[i])
        if float(v) < best[0]:
            best = (float(v), float(xm))
    return best


def _golden(p: fmpq_poly, M: np.ndarray, lo: float, hi: float, start: tuple[float, float],
            iters: int = 60) -> tuple[float, float]:
    """Golden-section minimization of the exact ratio on [lo, hi] in log x."""
    g = (math.sqrt(5.0) - 1.0) / 2.0
    a, b = math.log(lo), math.log(hi)
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = _exact_ratio(p, M, math.exp(c)), _exact_ratio(p, M, math.exp(d))
    best = start
    for _ in range(iters):
        if fc <= fd:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = _exact_ratio(p, M, math.exp(c))
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = _exact_ratio(p, M, math.exp(d))
        if b - a < 1e-14 * max(1.0, abs(a)):
            break
    for v, x in ((fc, math.exp(c)), (fd, math.exp(d))):
        if v < best[0]:
            best = (v, x)
    return best


def _log2_abs(q: fmpq) -> float:
    """log2 |q| of a non-zero exact rational (big integers through math.log2)."""
    return math.log2(abs(int(q.p))) - math.log2(int(q.q))


def restricted(p: fmpq_poly, M: np.ndarray) -> np.ndarray:
    """m_r: the magnitude polynomial M restricted to p's exact degree range [a, b] (ascending
    floats, zero outside), and at least |p_i| inside (float products may round below it)."""
    from hil.stability.rational import _qpoly_floats

    c = np.array(_qpoly_floats(p))
    n = c.size
    a = next(i for i in range(n) if p[i] != 0)
    Mm = np.abs(np.asarray(M, float))
    Mr = np.zeros(n)
    Mr[a:n] = Mm[a:n] if Mm.size >= n else np.pad(Mm, (0, n - Mm.size))[a:n]
    Mr = np.asarray(np.maximum(Mr, np.abs(c)), dtype=float)
    Mr[:a] = 0.0
    return Mr


def frequency_margin(p: fmpq_poly, M: np.ndarray, touching: Sequence[float] = (),
                     bands: Sequence[tuple[float, float]] = ()) -> tuple[float, float]:
    """(μ, x*) for a condition p (exact, x = ω², not identically zero) with magnitude polynomial
    M (ascending floats, |p_i| ≤ M_i): μ = min over x ≥ 0 of p/M_r (module docstring), certified
    to :data:`CERTIFY_RTOL` relative; x* the minimizer (0 or ∞ for the limits; NaN when p/M_r is
    constant in x: attained everywhere). ``touching``: zeros of p on x > 0 where it does not
    change sign (p ≥ 0 there; then μ = 0 at the first); ``bands``: p's negative bands (x).
    |p| ≤ M_r, so μ ∈ [-1, 1]; M_r(x) is summed in floats, which can round it below |p(x)| by an
    ulp (a constant ratio 1 evaluated as 1.0000000000000002): the value is clipped to [-1, 1]."""
    mu, x = _certified_margin(p, M, touching, bands)
    return min(max(mu, -1.0), 1.0), x


def _certified_margin(p: fmpq_poly, M: np.ndarray, touching: Sequence[float],
                      bands: Sequence[tuple[float, float]]) -> tuple[float, float]:
    """:func:`frequency_margin` before the clipping to [-1, 1]."""
    from hil.stability.exact import decide_exact, exact_sign
    from hil.stability.minimize import _margin_min, _Ratio, ratio_is_constant
    from hil.stability.rational import _qpoly_floats

    c = np.array(_qpoly_floats(p))
    Mr = restricted(p, M)
    nz = [i for i in range(c.size) if p[i] != 0]
    if not (np.all(np.isfinite(Mr)) and np.all(Mr[nz] > 0) and np.all(np.isfinite(c))):
        # coefficients beyond double range (e.g. 1e-308 next to 1): the float magnitude polynomial
        # under- or overflowed. p is scaled exactly by a power of two to a largest coefficient of
        # 1 (the ratio is unchanged) and its own |coefficients| stand in for m, each at least the
        # smallest double: a bound of the same kind as for a cancelled axis factor
        top = max(_log2_abs(p[i]) for i in nz)
        p = p * fmpq(2) ** (-round(top))
        c = np.array(_qpoly_floats(p))
        Mr = np.zeros(c.size)
        Mr[nz] = np.maximum(np.abs(c[nz]), 5e-324)
        c[nz] = np.where(c[nz] == 0, np.copysign(5e-324, [float(p[i] > 0) - 0.5 for i in nz]), c[nz])
    if ratio_is_constant(c, Mr):
        return _exact_ratio(p, Mr, 1.0), math.nan
    if touching:
        return 0.0, float(touching[0])
    # (the ratio this margin minimizes, for the critical band)
    mu, x = _margin_min(_Ratio(c, Mr), c, Mr, list(bands), list(touching), [], check_constant=False)
    if x != x:  # constant in floats only
        x = 1.0
    mu = _exact_ratio(p, Mr, x)
    for lim in (0.0, math.inf):  # the limits, exactly: a minimum there is reported there
        v = _exact_ratio(p, Mr, lim)
        if v <= mu:
            mu, x = v, lim
    Mq = _q_of(Mr)
    for _ in range(4):
        if mu == 0.0:
            return mu, x
        t = mu * (1.0 - CERTIFY_RTOL) if mu > 0 else mu * (1.0 + CERTIFY_RTOL)
        q = p - fmpq(*float(t).as_integer_ratio()) * Mq
        if exact_sign(q).status != "violated":
            return mu, x  # p/M_r ≥ t everywhere: μ ∈ [t, mu]
        d = decide_exact(q, margin=False)
        v, xb = _band_search(p, Mr, d.negative_bands or [(0.0, math.inf)])
        if not v < mu:
            # the band is a few doubles wide (its minimizer lies between doubles): search it in exact
            # rationals
            v, xb = _rational_band_search(p, Mq, d.negative_bands)
        if not v < mu:  # pragma: no cover - the certificate's band holds a smaller value by construction
            logger.warning("margin certification did not find a smaller value (%r >= %r)", v, mu)
            return mu, x
        mu, x = v, xb
    logger.warning("margin certified only after 4 refinements (μ = %r)", mu)  # pragma: no cover
    return mu, x  # pragma: no cover


# ----------------------------------------------------------------------------------------------
# the critical band

#: the fraction f of the critical band's definition (the same 10 % as the SDEA's coupler band)
CRITICAL_BAND_FRACTION = 0.10


def band_of(p: fmpq_poly, Mr: np.ndarray, mu: float, fraction: float = CRITICAL_BAND_FRACTION
            ) -> tuple[float, float]:
    """(x_lo, x_hi): the smallest interval containing every x ≥ 0 where p(x)/m_r(x) ≤ θ, with
    θ = μ + f·(1 - μ) (within the fraction f of the way from the minimum μ to the top of the scale,
    1) and, for a violated condition (μ < 0), θ at least 0 (the whole violation). Decided exactly:
    the region is where q = p - θ·m_r ≤ 0 (q exact: θ and m_r are binary rationals), its ends the
    isolated roots of q, widened outward by 1e-12 relative; x_hi = ∞ when q ≤ 0 for large x."""
    from hil.stability.exact import decide_exact, exact_sign

    theta = mu + fraction * (1.0 - mu)
    if mu < 0:
        theta = max(theta, 0.0)
    q = p - fmpq(*float(theta).as_integer_ratio()) * _q_of(Mr)
    es = exact_sign(q)
    if es.status == "equality":
        return 0.0, math.inf
    d = decide_exact(q, margin=False)
    pts = [x for band in d.negative_bands for x in band] + list(d.touching)
    if not pts:  # the region is a single point the isolation did not resolve: the minimizer only
        return math.nan, math.nan
    lo, hi = min(pts), max(pts)
    return lo * (1.0 - 1e-12), hi * (1.0 + 1e-12) if math.isfinite(hi) else math.inf


def critical_band(result: StabilityResult, fraction: float = CRITICAL_BAND_FRACTION) -> tuple[float, float] | None:
    """The critical band of a stability result (rad/s; docs/VERDICTS.md): around the minimum of its
    binding frequency condition -- among the frequency conditions that decide the verdict (the
    violated ones when there are, else all), the one with the smallest margin -- the smallest
    interval containing every frequency where that condition's normalized ratio p/m_r is within
    ``fraction`` of the way from its minimum μ to 1, and, when it is violated, every frequency where
    it is negative. It always contains the worst frequency. None without such a condition
    (verdict-only results, a network decided by poles alone)."""
    conds = [c for c in result.conditions if c.ratio is not None and c.margin == c.margin]
    bad = [c for c in conds if c.status == "violated"]
    conds = bad or conds
    if not conds:
        return None
    c = min(conds, key=lambda c: c.margin)
    p, Mr = c.ratio
    lo, hi = band_of(p, Mr, c.margin, fraction)
    if lo != lo:  # pragma: no cover - defensive: a degenerate region
        x = (c.worst_frequency or 0.0) / float(result.network.get("omega_scale", 1.0))
        lo = hi = x * x
    w0 = float(result.network.get("omega_scale", 1.0))
    return math.sqrt(lo) * w0, (math.sqrt(hi) * w0 if math.isfinite(hi) else math.inf)
