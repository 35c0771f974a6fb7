"""The minimum of a normalized condition ρ(x) = p(x)/m(x) over x ≥ 0, in floats: overflow-safe
evaluation (:class:`_Ratio`), interior extrema from the roots of p'm - pm', the limits at x → 0 and
x → ∞, and each negative band's minimum (the frequency-domain margin of docs/VERDICTS.md; the
exact path re-evaluates p exactly at the minimizer)."""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence

import numpy as np
from numpy.polynomial import polynomial as P

from hil.stability.jpoly import trim_back

logger = logging.getLogger(__name__)


class _Ratio:
    """Overflow-safe evaluation of ρ(x) = p(x)/m(x) for x in [0, ∞]."""

    def __init__(self, p: np.ndarray, m: np.ndarray) -> None:
        n = max(p.size, m.size)
        self.p = np.zeros(n)
        self.p[: p.size] = p
        self.m = np.zeros(n)
        self.m[: m.size] = m
        self.n = n - 1

    def __call__(self, x: np.ndarray | float) -> np.ndarray:
        x = np.atleast_1d(np.asarray(x, dtype=float))
        out = np.empty_like(x)
        small = x <= 1.0
        if np.any(small):
            xs = x[small]
            num = P.polyval(xs, self.p)
            den = P.polyval(xs, self.m)
            out[small] = _safe_div(num, den, self._limit0())
        big = ~small
        if np.any(big):
            y = 1.0 / x[big]  # p(x)/x^n = sum p_i y^(n-i)
            num = P.polyval(y, self.p[::-1])
            den = P.polyval(y, self.m[::-1])
            out[big] = _safe_div(num, den, self._limit_inf())
        return out

    def _limit0(self) -> float:
        return _lead_ratio(self.p, self.m)

    def _limit_inf(self) -> float:
        return _lead_ratio(self.p[::-1], self.m[::-1])


def _lead_ratio(p: np.ndarray, m: np.ndarray) -> float:
    """lim ρ as the variable → 0 for ascending arrays: ratio of the lowest-order terms."""
    nzm = np.nonzero(m)[0]
    if nzm.size == 0:
        return 0.0
    j = nzm[0]
    nzp = np.nonzero(p)[0]
    if nzp.size == 0 or nzp[0] > j:
        return 0.0
    return float(p[j] / m[j])


def _safe_div(num: np.ndarray, den: np.ndarray, fallback: float) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        r = num / den
    bad = ~np.isfinite(r)
    if np.any(bad):
        r[bad] = fallback
    return np.asarray(r)


def _positive_real_roots(c_asc: np.ndarray) -> np.ndarray:
    """Numerical positive (near-)real roots, with x-scaling for coefficient ranges of many decades."""
    c = trim_back(np.asarray(c_asc, float))
    if c.size <= 1:
        return np.zeros(0)
    k = 0
    while c[k] == 0:
        k += 1
    c = c[k:]
    if c.size <= 1:
        return np.zeros(0)
    n = c.size - 1
    # balance the coefficient range by x -> x0·y (computed in log space: no overflow)
    lx0 = (math.log(abs(c[0])) - math.log(abs(c[-1]))) / n if c[0] != 0 else 0.0
    with np.errstate(divide="ignore"):
        lg = np.log(np.abs(c)) + lx0 * np.arange(c.size)
    lg = np.where(np.isfinite(lg), lg, -np.inf)
    cs = np.sign(c) * np.exp(lg - np.max(lg))
    if not (np.all(np.isfinite(cs)) and math.isfinite(lx0)):  # coefficients beyond double range
        return np.zeros(0)
    with np.errstate(all="ignore"):
        r = np.roots(cs[::-1]) * math.exp(lx0)
    r = r[np.isfinite(r)]
    keep = (r.real > 0) & (np.abs(r.imag) <= 0.2 * np.abs(r.real))
    return np.sort(r.real[keep])


def _cauchy_bound(c_asc: np.ndarray) -> float:
    c = trim_back(np.asarray(c_asc, float))
    if c.size <= 1 or c[-1] == 0:
        return 1.0
    return 1.0 + float(np.max(np.abs(c[:-1] / c[-1])))


def _log_grid(lo: float, hi: float, n: int) -> np.ndarray:
    lo = max(lo, 1e-300)
    if not math.isfinite(hi):
        hi = lo * 1e12 if lo > 0 else 1e12
    if hi <= lo:
        return np.array([lo])
    return np.geomspace(lo, hi, n)


def _band_min(ratio: _Ratio, a: float, b: float, cc: np.ndarray, m: np.ndarray) -> tuple[float, float]:
    from scipy.optimize import minimize_scalar

    lo = a if a > 0 else None
    hi = b if math.isfinite(b) else None
    scale = _cauchy_bound(cc)
    lo_v = lo if lo is not None else min(1e-12, (hi or scale) * 1e-12)
    hi_v = hi if hi is not None else max(scale, lo_v) * 1e6
    xs = _log_grid(lo_v, hi_v, 129)
    if lo is not None:
        xs = xs[(xs > a)]
    if hi is not None:
        xs = xs[(xs < b)]
    if xs.size == 0:
        xs = np.array([math.sqrt(a * b)]) if a > 0 and math.isfinite(b) else np.array([lo_v])
    vals = ratio(xs)
    i = int(np.argmin(vals))
    bx, bv = float(xs[i]), float(vals[i])
    lo_i = xs[i - 1] if i > 0 else (a if a > 0 else xs[i] / 10)
    hi_i = xs[i + 1] if i + 1 < xs.size else (b if math.isfinite(b) else xs[i] * 10)
    if hi_i > lo_i > 0:
        res = minimize_scalar(lambda u: float(ratio(math.exp(u))[0]), bounds=(math.log(lo_i), math.log(hi_i)),
                              method="bounded", options={"xatol": 1e-12})
        if res.fun < bv:
            bx, bv = float(math.exp(res.x)), float(res.fun)
    if not math.isfinite(b):
        lim = ratio._limit_inf()
        if lim < bv:
            bx, bv = math.inf, lim
    if a == 0:
        lim0 = ratio._limit0()
        if lim0 < bv:
            bx, bv = 0.0, lim0
    return bx, bv


def _margin_min(rep: _Ratio, c: np.ndarray, m: np.ndarray, bands: Sequence[tuple[float, float]],
                touching: Sequence[float], extra: list[float], check_constant: bool = True) -> tuple[float, float]:
    """(margin, x where it is attained): the smallest value of the normalized condition ``rep``
    over x ≥ 0 -- its global minimum, each negative band's minimum and the touching points
    (``check_constant=False``: the caller has ruled out a constant ratio)."""
    worst_x, margin_v = _global_min(rep, c, m, extra=extra, check_constant=check_constant)
    if worst_x != worst_x:  # ρ constant: the same value in every band and at every point
        return margin_v, worst_x
    for a, b in bands:
        bx, bv = _band_min(rep, a, b, c, m)
        if bv < margin_v:
            margin_v, worst_x = bv, bx
    for x in touching:
        v = float(rep(x)[0])
        if v < margin_v:
            margin_v, worst_x = v, x
    return margin_v, worst_x


def _der(c: np.ndarray) -> np.ndarray:
    """Derivative of an ascending coefficient array (cheaper than ``polyder`` on short arrays)."""
    return c[1:] * np.arange(1, c.size) if c.size > 1 else np.zeros(1)


def _wronskian(cc: np.ndarray, m: np.ndarray) -> np.ndarray:
    """p'm - pm' (ascending), with p and m scaled to unit maximum."""
    cc = cc / np.max(np.abs(cc))
    m = m / np.max(np.abs(m))
    a = np.convolve(_der(cc), m)
    b = np.convolve(cc, _der(m))
    out = np.zeros(max(a.size, b.size))
    out[: a.size] += a
    out[: b.size] -= b
    return out


def _critical_points(cc: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Positive real roots of p'm - pm' (interior extrema of ρ = p/m)."""
    d = _wronskian(cc, m)
    if d.size == 0 or not np.any(d):
        return np.zeros(0)
    return _positive_real_roots(d)


def ratio_is_constant(cc: np.ndarray, m: np.ndarray) -> bool:
    """Whether ρ = p/m is constant in x (p'm - pm' ≡ 0 up to the rounding of its float
    coefficients, ascending ``cc`` and ``m``): then the margin's minimum is attained at every
    frequency and no worst frequency is reported (docs/VERDICTS.md)."""
    cc = np.asarray(cc, dtype=float)
    m = np.asarray(m, dtype=float)
    if cc.size == 0 or m.size == 0 or not np.any(cc) or not np.any(m):
        return False
    d = _wronskian(cc, m)
    cc = cc / np.max(np.abs(cc))
    m = m / np.max(np.abs(m))
    n = max(cc.size, m.size)
    scale = (np.abs(_der(cc)).sum() * np.abs(m).sum() + np.abs(cc).sum() * np.abs(_der(m)).sum())
    return bool(np.max(np.abs(d), initial=0.0) <= 16.0 * n * np.finfo(float).eps * max(scale, 1.0))


def _global_min(ratio: _Ratio, cc: np.ndarray, m: np.ndarray, extra: list[float],
                check_constant: bool = True) -> tuple[float, float]:
    if check_constant and ratio_is_constant(cc, m):  # attained everywhere: the value, no single x
        return math.nan, float(ratio(np.array([1.0]))[0])
    xs = list(_critical_points(cc, m)) + list(extra)
    hi = max(_cauchy_bound(cc), _cauchy_bound(m), *(xs or [1.0]))
    grid = list(_log_grid(1e-9 / max(hi, 1.0), hi * 1e3, 97))
    cand = np.array([x for x in xs + grid if x > 0 and math.isfinite(x)])
    vals = ratio(cand)
    i = int(np.argmin(vals))
    bx, bv = float(cand[i]), float(vals[i])
    l0, li = ratio._limit0(), ratio._limit_inf()
    if l0 < bv:
        bx, bv = 0.0, l0
    if li < bv:
        bx, bv = math.inf, li
    return bx, bv
