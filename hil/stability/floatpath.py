"""The float path of the sign decision (:func:`decide_nonnegative` on an :class:`XPoly` without its
exact polynomial): for polynomials *formed in floating point* (e.g. from derived, rounded entries).
Coefficients below ``tol`` times their round-off bound ``m_i`` are zero, a negative band shallower
than ``tol`` relative to the bound (or a touching root) is **marginal**, deeper bands are
**violated**; the positive roots are counted with an integer Sturm sequence and isolated by
bisection. An ``XPoly`` that carries its exact polynomial is decided on the exact path
(:func:`hil.stability.exact.decide_exact`)."""

from __future__ import annotations

import itertools
import logging
import math
from collections.abc import Sequence
from fractions import Fraction

import numpy as np
from numpy.polynomial import polynomial as P

from hil.stability.exact import DEFAULT_TOL, SignDecision, Status
from hil.stability.jpoly import XPoly, trim_back
from hil.stability.minimize import _band_min, _cauchy_bound, _margin_min, _positive_real_roots, _Ratio

logger = logging.getLogger(__name__)


# ----------------------------------------------------------------------------------------------
# exact integer polynomial helpers (descending coefficient lists of Python ints)


def _content_normalize(p: list[int]) -> list[int]:
    g = 0
    for c in p:
        g = math.gcd(g, c)
    if g > 1:
        p = [c // g for c in p]
    return p


def _strip(p: list[int]) -> list[int]:
    i = 0
    while i < len(p) - 1 and p[i] == 0:
        i += 1
    return p[i:]


def _deriv(p: list[int]) -> list[int]:
    n = len(p) - 1
    return _strip([c * (n - i) for i, c in enumerate(p[:-1])]) if n > 0 else [0]


def _sign_prem(a: list[int], b: list[int]) -> list[int]:
    """Remainder of a by b up to a *positive* factor (|lc(b)|^k), so Sturm signs are preserved."""
    r = list(a)
    lb = b[0]
    slb = 1 if lb > 0 else -1
    alb = abs(lb)
    while len(r) >= len(b) and any(r):
        r0 = r[0]
        # r <- |lb| r - sgn(lb) r0 b x^(deg r - deg b); leading term cancels
        shifted = b + [0] * (len(r) - len(b))
        r = [alb * ri - slb * r0 * bi for ri, bi in zip(r, shifted, strict=True)][1:]
        r = _strip(r) if r else [0]
        if len(r) == 1 and r[0] == 0:
            break
    return _strip(r) if r else [0]


def _sturm_sequence(p: list[int]) -> list[list[int]]:
    seq = [p, _content_normalize(_deriv(p))]
    while len(seq[-1]) > 1:
        r = _sign_prem(seq[-2], seq[-1])
        if len(r) == 1 and r[0] == 0:
            break
        seq.append(_content_normalize([-c for c in r]))
    return seq


def _eval_sign(p: list[int], t: Fraction) -> int:
    """Exact sign of p(t) for rational t = n/d, d > 0 (evaluates d^deg · p(n/d) in integers)."""
    n, d = t.numerator, t.denominator
    deg = len(p) - 1
    acc = 0
    npow = [1] * (deg + 1)
    for i in range(1, deg + 1):
        npow[i] = npow[i - 1] * n
    dpow = 1
    for i in range(deg + 1):  # p[i] multiplies x^(deg-i): term p[i] n^(deg-i) d^i
        acc += p[i] * npow[deg - i] * dpow
        dpow *= d
    return (acc > 0) - (acc < 0)


def _variations(signs: list[int]) -> int:
    s = [x for x in signs if x != 0]
    return sum(1 for a, b in itertools.pairwise(s) if a != b)


def _var_at(seq: list[list[int]], t: Fraction | None) -> int:
    """Sign variations of the Sturm sequence at t (None = +∞)."""
    if t is None:
        return _variations([(q[0] > 0) - (q[0] < 0) for q in seq])
    if t == 0:
        return _variations([(q[-1] > 0) - (q[-1] < 0) for q in seq])
    return _variations([_eval_sign(q, t) for q in seq])


def _to_int_poly(c_asc: np.ndarray) -> list[int]:
    """Exact integer polynomial (descending) proportional (positive factor) to float coefficients."""
    fr = [Fraction(float(v)) for v in c_asc[::-1]]
    den = 1
    for f in fr:
        den = den * f.denominator // math.gcd(den, f.denominator)
    return _content_normalize(_strip([int(f * den) for f in fr]))


def _int_poly_exact(c_asc: Sequence[Fraction]) -> list[int]:
    """Integer polynomial (descending) proportional, by a positive factor, to exact rationals."""
    fr = [Fraction(v) for v in c_asc[::-1]]
    den = 1
    for f in fr:
        den = den * f.denominator // math.gcd(den, f.denominator)
    return _content_normalize(_strip([int(f * den) for f in fr]))


def sturm_count_positive(c_asc: np.ndarray) -> int:
    """Number of distinct real roots of a float-coefficient polynomial in (0, ∞), exactly."""
    c = trim_back(np.asarray(c_asc, dtype=float))
    if c.size <= 1:
        return 0
    k = 0
    while c[k] == 0:
        k += 1
    ip = _to_int_poly(c[k:])
    if len(ip) <= 1:
        return 0
    seq = _sturm_sequence(ip)
    return _var_at(seq, Fraction(0)) - _var_at(seq, None)


def decide_nonnegative(p: XPoly, tol: float = DEFAULT_TOL, margin: bool = True,
                       exact: Sequence[Fraction] | None = None, _m_rep: np.ndarray | None = None) -> SignDecision:
    """Decide ``p(x) ≥ 0`` for all x ≥ 0 exactly (up to the documented tolerance policy).

    ``margin=False`` skips the (numerical) search for the minimum of the normalized margin when the
    polynomial has no positive root; the decision itself is unchanged. ``exact`` (ascending
    rational coefficients) is the exact polynomial that ``p.c`` rounds: the Sturm sequence and the
    root isolation then use it instead of the float coefficients (callers that formed the
    condition exactly, e.g. after cancelling imaginary-axis poles, pass it with ``p.m = |p.c|``).
    """
    if exact is None and p.exact is not None:
        from hil.stability.exact import decide_exact

        d = decide_exact(p.exact, p.m, margin=margin)
        if d.status == "touching":  # holds, with equality at isolated frequencies
            d.status = "equality"
        return d
    c = np.asarray(p.c, dtype=float).copy()
    m = np.zeros(max(c.size, p.m.size))
    m[: p.m.size] = np.abs(p.m)
    cc = np.zeros(m.size)
    cc[: c.size] = c
    if not np.all(np.isfinite(cc)) or not np.all(np.isfinite(m)):
        raise FloatingPointError("non-finite coefficient in a condition polynomial")
    # 1. cleaning: coefficients below tol x their own round-off bound are zero; so are
    #    coefficients 1e-250 below the largest (they cannot matter at any physical frequency
    #    and would overflow the balancing of the root finder)
    if exact is None:
        cc[np.abs(cc) <= tol * m] = 0.0
        big = float(np.max(m)) if m.size else 0.0
        cc[np.abs(cc) < 1e-250 * big] = 0.0
    if not np.any(cc):
        return SignDecision("equality", 0.0, 0.0, method="identically zero", coefficients=cc)
    ratio = _Ratio(cc, m)  # classification: value over its full round-off bound
    # Reporting: the bound restricted to p's own degree range, so structural zeros at x -> 0 or
    # x -> inf (e.g. Re Z ∝ ω² for a mass-spring at DC) do not pin the reported margin to 0.
    nzc = np.nonzero(cc)[0]
    m_rep = m.copy()
    m_rep[: nzc[0]] = 0.0
    m_rep[nzc[-1] + 1:] = 0.0
    if _m_rep is not None:
        m_rep = np.asarray(_m_rep, float)
    rep = _Ratio(cc, m_rep)

    # 2. exact root structure on (0, inf)
    k = int(np.nonzero(cc)[0][0])
    q = trim_back(cc[k:])
    sign0 = 1 if q[0] > 0 else -1
    roots_info: list[tuple[float, int, int]] = []  # (x, sign_left, sign_right)
    n_roots = 0
    if np.all(q >= 0) or np.all(q <= 0):
        # Descartes: no sign change among the coefficients -> no positive root; sign is sign(q0)
        if sign0 > 0 and not margin:
            return SignDecision("satisfied", math.nan, math.nan, n_roots=0, method="descartes", coefficients=cc)
        ip = [0]
    elif exact is not None:
        ip = _int_poly_exact(list(exact)[k: k + q.size])
    else:
        ip = _to_int_poly(q)
    if len(ip) > 1:
        seq = _sturm_sequence(ip)
        n_roots = _var_at(seq, Fraction(0)) - _var_at(seq, None)
        if n_roots > 0:
            roots_info = _isolate(ip, seq, q, n_roots)
    # segments between sign-changing roots
    bands: list[tuple[float, float]] = []
    touching: list[float] = []
    cur_sign = sign0
    seg_start = 0.0
    for x, sl, sr in roots_info:
        if sl == sr:
            if sl > 0:
                touching.append(x)
            continue
        if cur_sign < 0:
            bands.append((seg_start, x))
        cur_sign = sr
        seg_start = x
    if cur_sign < 0:
        bands.append((seg_start, math.inf))

    # 3. depth of each band and interior minima of the normalized margin
    depths = [_band_min(ratio, a, b, cc, m)[1] for a, b in bands]
    margin_v, worst_x = math.nan, math.nan
    if margin:
        margin_v, worst_x = _margin_min(rep, cc, m_rep, bands, touching, [x for x, _, _ in roots_info])
    if any(d < -tol for d in depths):
        status: Status = "violated"
    elif bands or touching:
        status = "marginal"
    else:
        status = "satisfied"
    return SignDecision(status, float(margin_v), float(worst_x), bands, [float(d) for d in depths],
                        touching, n_roots, "sturm", cc)


def _isolate(ip: list[int], seq: list[list[int]], q: np.ndarray, n_roots: int) -> list[tuple[float, int, int]]:
    """Isolate the n_roots distinct positive roots; return (x approx, sign left, sign right)."""
    cand = _positive_real_roots(q)
    # candidate breakpoints: geometric midpoints between sorted candidates, plus 0 and an upper bound
    ub = Fraction(_cauchy_bound(q) * 2.0)
    pts: list[Fraction] = [Fraction(0)]
    for a, b in itertools.pairwise(cand):
        if b > a * (1 + 1e-15):
            pts.append(Fraction(float(math.sqrt(a * b))))
    pts.append(ub)
    pts = sorted(set(p for p in pts if 0 <= p <= ub))

    def nudge(t: Fraction) -> Fraction:
        # breakpoints must not be roots themselves
        while t != 0 and _eval_sign(ip, t) == 0:
            t = t * Fraction(1000001, 1000000)
        return t

    pts = [nudge(t) for t in pts]
    var = {t: _var_at(seq, t) for t in pts}
    intervals: list[tuple[Fraction, Fraction]] = []
    stack = [(pts[i], pts[i + 1]) for i in range(len(pts) - 1)]
    guard = 0
    while stack:
        a, b = stack.pop()
        cnt = var[a] - var[b]
        if cnt == 0:
            continue
        if cnt == 1:
            intervals.append((a, b))
            continue
        guard += 1
        if guard > 4000:  # pragma: no cover - pathological clusters
            logger.warning("root isolation did not converge; %d roots in one interval", cnt)
            intervals.append((a, b))
            continue
        mid = nudge((a + b) / 2 if a == 0 or b / a < 4 else Fraction(float(math.sqrt(float(a) * float(b)))))
        if not (a < mid < b):
            mid = nudge((a + b) / 2)
        var[mid] = _var_at(seq, mid)
        stack.extend([(a, mid), (mid, b)])
    intervals.sort()
    if sum(var[a] - var[b] for a, b in intervals) != n_roots:  # pragma: no cover - defensive
        logger.warning("root isolation count mismatch")
    out = []
    for a, b in intervals:
        sl = _eval_sign(ip, a) if a != 0 else (1 if ip[-1] > 0 else -1)
        sr = _eval_sign(ip, b)
        xa, xb = float(a), float(b)
        x = _refine_root(q, xa, xb, sl, sr, cand)
        out.append((x, sl, sr))
    return out


def _refine_root(q: np.ndarray, a: float, b: float, sl: int, sr: int, cand: np.ndarray) -> float:
    from scipy.optimize import brentq

    if sl != sr and sl != 0 and sr != 0:
        lo = a if a > 0 else min(b * 1e-12, b / 2)
        try:
            return float(brentq(lambda x: P.polyval(x, q), lo, b, xtol=1e-300, rtol=4e-16, maxiter=500))
        except ValueError:
            pass
    inside = cand[(cand > a) & (cand < b)]
    if inside.size:
        return float(inside[0])
    return float(math.sqrt(a * b)) if a > 0 else b / 2
