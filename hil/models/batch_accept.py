"""Rigorous vectorized *acceptance* of parameter draws: a draw is accepted only when a sufficient
condition for the exact criterion's ``stable`` verdict is certified for it in float64 arithmetic
with rigorous error bounds, for all draws at once (numpy). Used by
:func:`hil.models.batch_general.screened_stability`; draws neither accepted here nor rejected by
its screen go to the exact per-draw criterion.

Error model (why the bounds are rigorous)
-----------------------------------------
Every quantity is a pair (v, e) of float arrays over the draws with |v − v*| ≤ e, v* the value in
exact real arithmetic from the draw's true coefficients. The inputs are the coefficients the
affine coefficient map predicts (:class:`hil.models.batch_general.CoefficientMap`) with the map's
per-coefficient bound (e = 0 for coefficients that are constant over the draws: structural zeros
and fixed parameters stay exact). Each operation propagates the input bounds exactly as in
interval arithmetic (first and second order terms: |ab − ãb̃| ≤ |ã|e_b + |b̃|e_a + e_a e_b) and adds
its own rounding error *exactly*: every sum is computed with Knuth's TwoSum and every product with
Dekker's TwoProduct (Veltkamp splitting), error-free transformations that return the rounding
error t of the float result exactly (a + b = fl(a + b) + t, a·b = fl(a·b) + t; exact for finite
results, TwoProduct when the factors are below 2^995 and the product above 2^-960 or a factor is
0; elsewhere we use the standard bound 2u·|result| + η, u = 2⁻⁵³, η = 2⁻¹⁰⁷⁴). So a product of
small integers, or a sum that cancels exactly, adds nothing to the bound: exact inputs give
exact results wherever the float operations happen to be exact, and identically-zero
conditions (Llewellyn's η ≡ 0 of the MCET) are certified as exact zeros. The bound itself is
computed in floats (sums of non-negative numbers, each rounding by at most a factor 1 + u, and
products that may underflow by ≤ η): every computed bound is multiplied by :data:`INFL` = 1 + 2⁻⁴⁰,
which exceeds (1 + u)^k for k up to 8000 operations, and 8η is added per product of factors not
both certainly zero. Quotients (residues only) use the interval quotient with the 2u bound.
A sum or product whose inputs are exact zeros (v = 0, e = 0) is an exact zero: structural zeros
stay certified. Overflow or NaN anywhere makes the draw undecided (never accepted).

What is certified (sufficient conditions; docs/VERDICTS.md defines the exact ones)
-------------------------------------------------------------------------------
Let the distinct (structurally, over the draws) entry denominators be t_1 … t_r and D̃ = ∏ t_k,
u_ij = n_ij · D̃ / d_ij (formed as a product, no division).

* **Poles (C, D[ω=ω_p]).** Every t_k = s^a·q(s) with a ∈ {0, 1} (its low coefficients exact zeros)
  and q *strictly* Hurwitz: all coefficients of one sign beyond their bounds and, for degree ≥ 3,
  every first-column entry of the fraction-free Routh table (rows scaled by the previous pivot,
  a positive factor) positive beyond its bound. Then no entry (reduced or not) has a pole in the
  closed RHP except at most a simple pole at s = 0, so C holds and the only axis condition is
  D[ω=0], with residue matrix K_ij = n_ij(0)/q_ij(0) (0 for entries without the pole).
* **Residues at 0 and ∞.** K (above) and R = lim G(s)/s (entries of degree excess 1:
  ratio of leading coefficients; excess ≥ 2 possible → undecided) must be admissible:
  ``hermitian`` (positive realness): K_ij, K_ji the same expression in the map (or both exact
  zeros), and either every leading principal minor positive beyond its bound (positive definite,
  Sylvester) or, when all entries are exact (e = 0), all principal minors ≥ 0 decided in exact
  rational arithmetic (:class:`fractions.Fraction`) on the floats, cached per distinct matrix;
  ``minors`` (Llewellyn, Theorem 1): k_ij·k_ji ≥ 0 certified and every principal minor positive
  beyond its bound, or the exact rational check when all entries are exact.
* **Frequency conditions** on x = ω² > 0 (the sign of a condition times the positive factor
  |D̃(jω)|^(2k) is the sign of the exact path's polynomial, which uses D = lcm instead: both
  factors are positive for ω > 0 because D̃ has no root on the imaginary axis besides s = 0):

  * ``positive_real`` / ``passivity`` of a 2×2 G: Re g_ii > 0 and the 2×2 minor > 0 on x > 0,
    formed over each entry's own denominators (:func:`_two_port_hermitian`: cancellations such as
    the SDEA's h_12 + conj(h_21) ~ s² stay exact zeros);
  * ``positive_real`` / ``passivity`` of a larger G: every *leading* principal minor of
    (G(jω) + G(jω)ᴴ)|D̃(jω)|² > 0 for all x > 0: the Hermitian matrix is then positive definite at
    every ω > 0 (Sylvester), so every principal minor (the exact conditions) is > 0;
  * ``llewellyn``: Re(u_11 D̃*) > 0, Re(u_22 D̃*) > 0 and L2 > 0 on x > 0 (L2 of
    :func:`hil.stability.criteria.llewellyn_polys` over D̃; with a = A1·A2 > 0, L2 > 0 implies
    L1 = 2a − Re c > 0, so η > 0 and Re p_ii > 0); L2 ≡ 0 as an exact zero is accepted too
    (then L1 = |c| ≥ 0: η ≡ 0, the exact path's ``equality``, still ``stable``);
  * ``absolute_stability`` (Theorem 1): precondition B (diagonal blocks symmetric) and A (cycle
    products) certified structurally: z_ij and z_ji the same expression, or a cycle product with
    a structurally zero factor on both sides. The coupling graph (z_ij z_ji ≢ 0) is certified
    (every entry either structurally zero or nonzero beyond its bound in every coefficient set),
    components of size 1 use Re z_ii > 0, of size 2 Llewellyn as above, of size ≥ 3 only when
    the block is structurally symmetric and complete (then the exact path's Z' is D·Z·D with a
    signature D, and Re Z' has the principal minors of Re Z): leading minors of Re Z > 0.

  A polynomial p(x) is certified > 0 on x > 0 after dividing out the powers of x whose
  coefficients are exact zeros (structural zeros at ω = 0 and ω = ∞): its lowest and highest
  remaining coefficients positive beyond their bounds, and either all coefficients ≥ 0 beyond
  their bounds, or (Pólya) p(λy)·(1 + y)^m with λ a power of two (exact scaling) and
  m ≤ :data:`POLYA_MAX` (the binomials C(m, k)/2^m as floats with their rounding bound) has all
  coefficients ≥ 0 and its constant one > 0 beyond their bounds; Pólya's theorem says this holds
  for some m whenever p > 0 on [0, ∞) with p(0) > 0 and a positive leading coefficient, so
  draws well inside the region are accepted, and draws near the boundary go to the exact path.

The certificates are *sufficient*: ``weak`` stability (conditions holding with equality) and
draws near the boundary are left to the exact path. The one assumption outside the arithmetic is
the coefficient map's (hil.models.batch_general): the model's builder computes each coefficient as
an affine function of the drawn parameters up to a relative rounding below the map's bound, and
its parameter constraints are intervals per parameter (checked by building at each parameter's
extreme draws).
"""

from __future__ import annotations

import functools
import itertools
import logging
import math
from fractions import Fraction
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from hil.models.batch_general import CoefficientMap

logger = logging.getLogger(__name__)

__all__ = ["INFL", "Poly", "accept", "certify_positive", "hurwitz"]

_U = 2.0**-53
_ETA = 2.0**-1074
#: inflation of every computed error bound (covers the rounding of the bound's own computation)
INFL = 1.0 + 2.0**-40
#: largest Pólya exponent tried (m = d, 2d, 4d, … ≤ this)
POLYA_MAX = 512


class Poly:
    """Polynomials with interval coefficients over N draws: ``v``, ``e`` arrays (N, L), ascending
    powers, |v − v*| ≤ e coefficient-wise (module docstring)."""

    __slots__ = ("e", "v")

    def __init__(self, v: np.ndarray, e: np.ndarray) -> None:
        self.v = v
        self.e = e

    @staticmethod
    def const(c: float, N: int) -> Poly:
        return Poly(np.full((N, 1), float(c)), np.zeros((N, 1)))

    @property
    def L(self) -> int:
        return int(self.v.shape[1])

    def _pad(self, L: int) -> Poly:
        if self.L >= L:
            return self
        z = np.zeros((self.v.shape[0], L - self.L))
        return Poly(np.hstack([self.v, z]), np.hstack([self.e, z]))

    def __add__(self, o: Poly) -> Poly:
        L = max(self.L, o.L)
        a, b = self._pad(L), o._pad(L)
        v, t = _two_sum(a.v, b.v)
        e = (a.e + b.e + np.abs(t)) * INFL
        return Poly(v, e)

    def __neg__(self) -> Poly:
        return Poly(-self.v, self.e)

    def __sub__(self, o: Poly) -> Poly:
        return self + (-o)

    def scale(self, c: float) -> Poly:
        """c·p for an exact float constant c."""
        return self * Poly(np.full((self.v.shape[0], 1), float(c)), np.zeros((self.v.shape[0], 1)))

    def mulx(self, k: int = 1) -> Poly:
        """x^k·p (exact)."""
        z = np.zeros((self.v.shape[0], k))
        return Poly(np.hstack([z, self.v]), np.hstack([z, self.e]))

    def __mul__(self, o: Poly) -> Poly:
        N = self.v.shape[0]
        L = self.L + o.L - 1
        v = np.zeros((N, L))
        rnd = np.zeros((N, L))  # exact rounding errors of the products and sums (|.| summed)
        prop = np.zeros((N, L))
        cnt = np.zeros((N, L))
        for j in range(self.L):
            aj, ej = self.v[:, j:j + 1], self.e[:, j:j + 1]
            t, tp = _two_prod(aj, o.v)
            sl = slice(j, j + o.L)
            v[:, sl], ts = _two_sum(v[:, sl], t)
            rnd[:, sl] += np.abs(tp) + np.abs(ts)
            prop[:, sl] += np.abs(aj) * o.e + np.abs(o.v) * ej + ej * o.e
            cnt[:, sl] += ((aj != 0) & (o.e > 0)) | ((ej > 0) & (o.v != 0)) | ((ej > 0) & (o.e > 0))
        e = (prop + rnd) * INFL + 8 * _ETA * cnt
        return Poly(v, e)

    def take(self, idx: np.ndarray) -> Poly:
        return Poly(self.v[idx], self.e[idx])

    def trimmed(self) -> Poly:
        """Without the trailing coefficients that are exact zeros in every draw."""
        nz = np.nonzero(np.any((self.v != 0) | (self.e > 0), axis=0))[0]
        top = int(nz[-1]) + 1 if nz.size else 1
        return Poly(self.v[:, :top], self.e[:, :top])


_SPLIT = 2.0**27 + 1.0


def _two_sum(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(fl(a + b), t) with a + b = fl(a + b) + t exactly (Knuth's TwoSum; exact for finite
    results, including the subnormal range)."""
    s = a + b
    bb = s - a
    t = (a - (s - bb)) + (b - bb)
    return s, np.where(np.isfinite(s), t, np.inf)


def _two_prod(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(fl(a·b), t) with |a·b − fl(a·b)| ≤ |t|: Dekker's TwoProduct (Veltkamp splitting), exact
    when |a|, |b| < 2^995 and |fl(a·b)| ≥ 2^-960 or a factor is 0 (no overflow in the split, no
    underflow in the low parts); elsewhere the bound 2u·|fl(a·b)| + η."""
    p = a * b
    ca, cb = _SPLIT * a, _SPLIT * b
    ah = ca - (ca - a)
    al = a - ah
    bh = cb - (cb - b)
    bl = b - bh
    t = al * bl - (((p - ah * bh) - al * bh) - ah * bl)
    safe = (((np.abs(p) >= 2.0**-960) & (np.abs(a) < 2.0**995) & (np.abs(b) < 2.0**995))
            | (a == 0) | (b == 0))
    return p, np.where(safe & np.isfinite(t), t, 2.0 * _U * np.abs(p) + _ETA)


def _div(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Interval quotient (v, e) of scalars (N,); e = inf where |b| is not beyond its bound."""
    av, ae = a
    bv, be = b
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        v = np.where(bv != 0, av / np.where(bv != 0, bv, 1.0), 0.0)
        lo = (np.abs(bv) - be) * (1.0 - 4.0 * _U)
        e = np.where(lo > 0, (ae + np.abs(v) * be) / np.where(lo > 0, lo, 1.0) * INFL ** 2 + 2.0 * _U * np.abs(v)
                     + 8 * _ETA, np.inf)
        e = np.where((av == 0) & (ae == 0) & (lo > 0), 0.0, e)
    return v, e


def _pos(v: np.ndarray, e: np.ndarray) -> np.ndarray:
    return np.isfinite(v) & np.isfinite(e) & (v > e)


def hurwitz(q: Poly) -> np.ndarray:
    """(N,) bool: q (ascending, the trailing exact zeros trimmed) certified strictly Hurwitz (all
    roots in the open LHP), by signs and the fraction-free Routh table (module docstring)."""
    q = q.trimmed()
    d = q.L - 1
    N = q.v.shape[0]
    sign = np.sign(q.v[:, -1])
    v, e = q.v * sign[:, None], q.e
    ok = np.all(_pos(v, e), axis=1)
    if d <= 2 or not ok.any():
        return ok
    # Routh rows from the highest power: r0 = [q_d, q_{d-2}, …], r1 = [q_{d-1}, q_{d-3}, …]
    P = Poly(v, e)
    col = lambda k: Poly(P.v[:, k:k + 1], P.e[:, k:k + 1])  # noqa: E731
    r0 = [col(k) for k in range(d, -1, -2)]
    r1 = [col(k) for k in range(d - 1, -1, -2)]
    zero = Poly(np.zeros((N, 1)), np.zeros((N, 1)))
    for _ in range(d - 1):
        w = max(len(r0), len(r1) + 1)
        r0 = r0 + [zero] * (w - len(r0))
        r1 = r1 + [zero] * (w - len(r1))
        r2 = [r1[0] * r0[k + 1] - r0[0] * r1[k + 1] for k in range(w - 1)]
        while len(r2) > 1 and not np.any((r2[-1].v != 0) | (r2[-1].e > 0)):
            r2.pop()
        ok &= _pos(r2[0].v[:, 0], r2[0].e[:, 0])
        r0, r1 = r1, r2
    return ok


@functools.lru_cache(maxsize=32)
def _binomials(m: int) -> tuple[np.ndarray, np.ndarray]:
    """C(m, k)/2^m, k = 0 … m, correctly rounded to float (integer true division), with a bound
    on the rounding: 0 where exact, else u·value (normal range) + η (subnormal). Dividing by 2^m
    (a positive constant) keeps the values in range for any m."""
    vals = [math.comb(m, k) / (1 << m) for k in range(m + 1)]
    v = np.array(vals)
    exact = np.array([Fraction(x) == Fraction(math.comb(m, k), 1 << m) for k, x in enumerate(vals)])
    return v, np.where(exact, 0.0, _U * v + _ETA)


def certify_positive(p: Poly) -> np.ndarray:
    """(N,) bool: p(x) > 0 for every x > 0 certified (module docstring: exact-zero powers of x
    divided out, all coefficients ≥ 0, or Pólya's certificate after an exact power-of-two scaling)."""
    N = p.v.shape[0]
    live = np.any((p.v != 0) | (p.e > 0), axis=0)
    nz = np.nonzero(live)[0]
    if nz.size == 0:
        return np.zeros(N, bool)
    v, e = p.v[:, nz[0]:nz[-1] + 1], p.e[:, nz[0]:nz[-1] + 1]
    d = v.shape[1] - 1
    ends = _pos(v[:, 0], e[:, 0]) & _pos(v[:, -1], e[:, -1]) & np.all(np.isfinite(v) & np.isfinite(e), axis=1)
    lower = v - e
    ok = ends & np.all(lower >= 0, axis=1)
    todo = np.nonzero(ends & ~ok)[0]
    if todo.size == 0 or d < 2:
        return ok
    vv, ee = v[todo], e[todo]
    # x = λ·y, λ = 2^k ≈ (p_0/p_d)^(1/d): coefficients balanced, scaling exact (ldexp) in range
    with np.errstate(divide="ignore"):
        k = np.round((np.log2(vv[:, 0]) - np.log2(vv[:, -1])) / d).astype(int)
    pw = np.arange(d + 1)[None, :] * k[:, None]
    sv, se = np.ldexp(vv, pw), np.ldexp(ee, pw)
    normal = np.all(((sv == 0) | (np.abs(sv) >= 2.0**-1000)) & ((se == 0) | (se >= 2.0**-1000))
                    & np.isfinite(sv) & np.isfinite(se), axis=1)
    # draws whose p is certainly negative somewhere (at y = 2^-24 … 2^24, powers exact) skip
    # Pólya's escalation: |fl(Σ c_k y^k) − Σ c_k y^k| ≤ 2(d + 2)u·Σ|c_k|y^k, plus Σ e_k y^k
    Y = np.ldexp(1.0, np.arange(-24, 25, 2))[:, None] ** np.arange(d + 1)[None, :]  # (G, d + 1)
    with np.errstate(over="ignore", invalid="ignore"):
        val = sv @ Y.T
        err = ((2.0 * (d + 2) * _U) * (np.abs(sv) @ Y.T) + se @ Y.T) * INFL
        negative = np.any(np.isfinite(val) & np.isfinite(err) & (val + err < 0), axis=1)
    normal &= ~negative
    sub_ok = np.zeros(todo.size, bool)
    m = d
    while m <= POLYA_MAX:
        idx = np.nonzero(normal & ~sub_ok)[0]
        if idx.size == 0:
            break
        binom, berr = _binomials(m)
        B = Poly(np.tile(binom, (idx.size, 1)), np.tile(berr, (idx.size, 1)))
        r = Poly(sv[idx], se[idx]) * B
        good = np.all(r.v - r.e >= 0, axis=1) & _pos(r.v[:, 0], r.e[:, 0]) & np.all(np.isfinite(r.e), axis=1)
        sub_ok[idx[good]] = True
        m *= 2
    ok[todo[sub_ok]] = True
    return ok


def certainly_negative(p: Poly) -> np.ndarray:
    """(N,) bool: p(x0) < 0 certified at some sample x0 > 0 (x0 = λ·2^k, k = −40 … 40 step 2,
    λ a power of two near the geometric mean of the coefficient ratio, so x0^k is exact):
    |fl(Σ c_k x0^k) − Σ c_k x0^k| ≤ 2(d + 2)u·Σ|c_k|x0^k, plus Σ e_k x0^k for the coefficients'
    own bounds (inflated by INFL); a value whose upper bound is < 0 is negative."""
    N = p.v.shape[0]
    live = np.nonzero(np.any((p.v != 0) | (p.e > 0), axis=0))[0]
    if live.size == 0:
        return np.zeros(N, bool)
    v, e = p.v[:, :live[-1] + 1], p.e[:, :live[-1] + 1]
    d = v.shape[1] - 1
    lo, hi = np.abs(v[:, live[0]]), np.abs(v[:, -1])
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        k0 = np.where((lo > 0) & (hi > 0) & (d > live[0]),
                      np.round((np.log2(lo) - np.log2(hi)) / max(d - int(live[0]), 1)), 0.0)
        k0 = np.nan_to_num(k0).astype(int)
        out = np.zeros(N, bool)
        for k in range(-40, 41, 2):
            pw = np.ldexp(1.0, (k0 + k)[:, None] * np.arange(d + 1)[None, :])
            val = np.sum(v * pw, axis=1)
            err = (((2.0 * (d + 2) * _U) * np.sum(np.abs(v) * pw, axis=1) + np.sum(e * pw, axis=1)) * INFL
                   + 4 * (d + 1) * _ETA)
            exact_pw = np.all(np.isfinite(pw) & (pw > 0), axis=1)  # powers of two: exact unless out of range
            out |= np.isfinite(val) & np.isfinite(err) & exact_pw & (val + err < 0)
    return out


# ------------------------------------------------------------------------------------------
# entries over jω: pairs (A, B) meaning A(x) + jω·B(x)

Pair = tuple[Poly, Poly]


def _jw(c: Poly) -> Pair:
    """a(jω) = E(x) + jω·O(x) for a(s) with ascending coefficients (exact: signs only)."""
    N = c.v.shape[0]
    L = c.L
    def part(start: int) -> Poly:
        ks = np.arange(start, L, 2)
        if ks.size == 0:
            return Poly(np.zeros((N, 1)), np.zeros((N, 1)))
        sg = np.where((np.arange(ks.size) % 2) == 0, 1.0, -1.0)
        return Poly(c.v[:, ks] * sg, c.e[:, ks])
    return part(0), part(1)


def _zero(p: Poly) -> bool:
    """p is an exact zero polynomial in every draw."""
    return not (p.v.any() or p.e.any())


def _pmul(a: Pair, b: Pair) -> Pair:
    za, zb = _zero(a[1]), _zero(b[1])
    if za and zb:
        return a[0] * b[0], a[1]
    if za:
        return a[0] * b[0], a[0] * b[1]
    if zb:
        return a[0] * b[0], a[1] * b[0]
    return a[0] * b[0] - (a[1] * b[1]).mulx(), a[0] * b[1] + a[1] * b[0]


def _padd(a: Pair, b: Pair) -> Pair:
    return a[0] + b[0], a[1] + b[1]


def _pneg(a: Pair) -> Pair:
    return -a[0], -a[1]


def _conj(a: Pair) -> Pair:
    return a[0], -a[1]


def _leading_minors(M: list[list[Pair]]) -> list[Poly]:
    """Real parts of the leading principal minors (sizes 1 … n) of a matrix of pairs, by
    first-row cofactor expansion with memoized sub-determinants."""
    n = len(M)
    memo: dict[tuple[int, tuple[int, ...]], Pair] = {}

    def det(r: int, cols: tuple[int, ...]) -> Pair:
        if len(cols) == 1:
            return M[r][cols[0]]
        key = (r, cols)
        if key in memo:
            return memo[key]
        acc: Pair | None = None
        for k, c in enumerate(cols):
            t = _pmul(M[r][c], det(r + 1, cols[:k] + cols[k + 1:]))
            if k % 2:
                t = _pneg(t)
            acc = t if acc is None else _padd(acc, t)
        assert acc is not None
        memo[key] = acc
        return acc

    return [det(0, tuple(range(k)))[0] for k in range(1, n + 1)]


# ------------------------------------------------------------------------------------------
# residue matrices (s = 0, s = ∞)

def _scalar_det(K: list[list[tuple[np.ndarray, np.ndarray]]], idx: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Interval determinant of the principal submatrix ``idx`` of a scalar interval matrix."""
    N = K[0][0][0].shape[0]
    M = [[(Poly(K[i][j][0][:, None], K[i][j][1][:, None]), Poly(np.zeros((N, 1)), np.zeros((N, 1))))
          for j in idx] for i in idx]
    d = _leading_minors(M)[-1]
    return d.v[:, 0], d.e[:, 0]


def _exact_admissible(vals: tuple[tuple[float, float], ...], n: int, test: str) -> bool:
    """All principal minors ≥ 0 (and, ``minors``, k_ij·k_ji ≥ 0) of K_ij = num/den in exact
    rationals (den = 0: K_ij = 0)."""
    K = [[Fraction(vals[i * n + j][0]) / Fraction(vals[i * n + j][1]) if vals[i * n + j][1] != 0 else Fraction(0)
          for j in range(n)] for i in range(n)]
    if test == "hermitian" and any(K[i][j] != K[j][i] for i in range(n) for j in range(i + 1, n)):
        return False
    if test == "minors" and any(K[i][j] * K[j][i] < 0 for i in range(n) for j in range(i + 1, n)):
        return False

    def det(rows: tuple[int, ...], cols: tuple[int, ...]) -> Fraction:
        if len(rows) == 1:
            return K[rows[0]][cols[0]]
        acc = Fraction(0)
        for k, c in enumerate(cols):
            if K[rows[0]][c] != 0:
                t = K[rows[0]][c] * det(rows[1:], cols[:k] + cols[k + 1:])
                acc += -t if k % 2 else t
        return acc

    return all(det(idx, idx) >= 0 for k in range(1, n + 1) for idx in itertools.combinations(range(n), k))


def _residues_admissible(num: list[list[tuple[np.ndarray, np.ndarray]]], den: list[list[tuple[np.ndarray, np.ndarray]]],
                         same: np.ndarray, test: str) -> np.ndarray:
    """(N,) bool: the residue matrix K_ij = num_ij/den_ij (den exact 0 and num exact 0: K_ij = 0)
    certified admissible (module docstring). ``same[i, j]``: entries (i, j) and (j, i) are the
    same expression of the map (their residues are equal exactly)."""
    n = len(num)
    N = num[0][0][0].shape[0]
    K = [[_div(num[i][j], den[i][j]) if not _is_exact_zero(num[i][j]).all() else (np.zeros(N), np.zeros(N))
          for j in range(n)] for i in range(n)]
    ok = np.ones(N, bool)
    if test == "hermitian":
        for i in range(n):
            for j in range(i + 1, n):
                if not same[i, j]:
                    ok &= _is_exact_zero(K[i][j]) & _is_exact_zero(K[j][i])
    strict = ok.copy()
    if test == "hermitian":
        for k in range(1, n + 1):
            strict &= _pos(*_scalar_det(K, tuple(range(k))))
    else:
        for i in range(n):
            for j in range(i + 1, n):
                a, b = K[i][j], K[j][i]
                za, zb = _is_exact_zero(a), _is_exact_zero(b)
                same_sign = (_pos(*a) & _pos(*b)) | (_pos(-a[0], a[1]) & _pos(-b[0], b[1]))
                strict &= za | zb | same_sign
        for k in range(1, n + 1):
            for idx in itertools.combinations(range(n), k):
                if not strict.any():
                    break
                strict &= _pos(*_scalar_det(K, idx))
    # exact rational decision where strict fails and every input is exact (cached per matrix)
    exact_in = ok & ~strict
    for i in range(n):
        for j in range(n):
            exact_in &= (num[i][j][1] == 0) & (den[i][j][1] == 0)
    out = strict.copy()
    rows = np.nonzero(exact_in)[0]
    if rows.size:
        # one exact decision per distinct matrix (K_ij = 0 where num_ij = 0, whatever den_ij)
        cols = []
        for i in range(n):
            for j in range(n):
                nv = num[i][j][0][rows]
                cols += [nv, np.where(nv != 0, den[i][j][0][rows], 0.0)]
        table = np.column_stack(cols)
        if np.all(table == table[0]):  # the usual case: the residues do not depend on the draws
            uniq, inv = table[:1], np.zeros(rows.size, int)
        else:
            tv = np.ascontiguousarray(table).view(np.dtype((np.void, table.shape[1] * 8))).ravel()
            _, first, inv = np.unique(tv, return_index=True, return_inverse=True)
            uniq = table[first]
        verdict = np.array([_exact_admissible(tuple((float(u[2 * c]), float(u[2 * c + 1])) for c in range(n * n)),
                                              n, test) for u in uniq])
        out[rows] = verdict[np.asarray(inv).reshape(-1)]
    return out


def _is_exact_zero(a: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    return (a[0] == 0) & (a[1] == 0)


# ------------------------------------------------------------------------------------------
# the criteria

def _structure(cmap: CoefficientMap) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(zero (n, n): entry structurally zero; same (n, n): entries (i, j) and (j, i) the same
    expression of the map; den_id (n, n): index of the entry's structurally distinct denominator)."""
    n = cmap.num0.shape[0]
    zero = np.array([[not np.any(cmap.num0[i, j]) and not np.any(cmap.dnum[:, i, j]) for j in range(n)]
                     for i in range(n)])
    same = np.array([[bool(np.array_equal(cmap.num0[i, j], cmap.num0[j, i])
                           and np.array_equal(cmap.dnum[:, i, j], cmap.dnum[:, j, i])
                           and np.array_equal(cmap.den0[i, j], cmap.den0[j, i])
                           and np.array_equal(cmap.dden[:, i, j], cmap.dden[:, j, i])) for j in range(n)]
                     for i in range(n)])
    keys: dict[bytes, int] = {}
    den_id = np.full((n, n), -1)
    for i in range(n):
        for j in range(n):
            if zero[i, j]:
                continue
            key = cmap.den0[i, j].tobytes() + cmap.dden[:, i, j].tobytes()
            den_id[i, j] = keys.setdefault(key, len(keys))
    return zero, same, den_id


def accept_reject(cmap: CoefficientMap, X: np.ndarray, criterion: str) -> tuple[np.ndarray, np.ndarray]:
    """(accepted, rejected), (N,) bool each: draws (rows of X) whose exact ``criterion`` verdict is
    certified ``stable`` (module docstring), and draws where a frequency condition the exact
    path decides is certainly negative at a sample frequency (:func:`certainly_negative`; only
    for draws whose denominators are certified as above, so the sign is the exact condition's
    there: the exact verdict is then not ``stable``)."""
    test = {"positive_real": "hermitian", "passivity": "hermitian", "llewellyn": "minors",
            "absolute_stability": "minors"}.get(criterion)
    X = np.atleast_2d(np.asarray(X, float))
    N = X.shape[0]
    n = cmap.num0.shape[0]
    if test is None or (criterion == "llewellyn" and n != 2):
        return np.zeros(N, bool), np.zeros(N, bool)
    nv, ne, dv, de = cmap.intervals(X)
    zero, same, den_id = _structure(cmap)
    num = [[Poly(nv[:, i, j], ne[:, i, j]).trimmed() for j in range(n)] for i in range(n)]
    den = [[Poly(dv[:, i, j], de[:, i, j]).trimmed() for j in range(n)] for i in range(n)]
    ok = np.all(np.isfinite(nv), axis=(1, 2, 3)) & np.all(np.isfinite(ne), axis=(1, 2, 3))
    ok &= np.all(np.isfinite(dv), axis=(1, 2, 3)) & np.all(np.isfinite(de), axis=(1, 2, 3))
    # -- poles: every distinct denominator s^a·q, a ≤ 1, q strictly Hurwitz
    uniq: dict[int, tuple[int, int]] = {}
    for i in range(n):
        for j in range(n):
            if den_id[i, j] >= 0 and den_id[i, j] not in uniq:
                uniq[int(den_id[i, j])] = (i, j)
    shift: dict[int, int] = {}
    for k, (i, j) in uniq.items():
        t = den[i][j]
        exz = ~np.any((t.v != 0) | (t.e > 0), axis=0)
        a = int(np.argmin(exz)) if not exz.all() else t.L
        if a > 1:
            return np.zeros(N, bool), np.zeros(N, bool)
        shift[k] = a
        q = Poly(t.v[:, a:], t.e[:, a:])
        ok &= hurwitz(q)
    pole_ok = ok.copy()
    if not ok.any():
        return ok, np.zeros(N, bool)
    zN = (np.zeros(N), np.zeros(N))
    # residues at s = 0: K_ij = n_ij(0)/q_ij(0) for entries whose denominator has the factor s
    K_num = [[zN for _ in range(n)] for _ in range(n)]
    K_den = [[zN for _ in range(n)] for _ in range(n)]
    any_zero_pole = False
    for i in range(n):
        for j in range(n):
            if den_id[i, j] >= 0 and shift[int(den_id[i, j])] == 1:
                any_zero_pole = True
                K_num[i][j] = (num[i][j].v[:, 0], num[i][j].e[:, 0])
                K_den[i][j] = (den[i][j].v[:, 1], den[i][j].e[:, 1])
    if any_zero_pole:
        ok &= _residues_admissible(K_num, K_den, same, test)
    # residue at s = ∞: degree excess ≤ 1, R_ij = lead(n)/lead(d) where the excess is 1
    R_num = [[zN for _ in range(n)] for _ in range(n)]
    R_den = [[zN for _ in range(n)] for _ in range(n)]
    any_inf = False
    for i in range(n):
        for j in range(n):
            if zero[i, j]:
                continue
            dd = den[i][j].L - 1
            if not np.all(_pos(np.abs(den[i][j].v[:, -1]), den[i][j].e[:, -1])):
                ok &= _pos(np.abs(den[i][j].v[:, -1]), den[i][j].e[:, -1])
            if dd + 1 < num[i][j].L - 1:
                return np.zeros(N, bool), np.zeros(N, bool)  # an excess ≥ 2 is possible
            if dd + 1 == num[i][j].L - 1:
                any_inf = True
                R_num[i][j] = (num[i][j].v[:, -1], num[i][j].e[:, -1])
                R_den[i][j] = (den[i][j].v[:, -1], den[i][j].e[:, -1])
    if any_inf:
        ok &= _residues_admissible(R_num, R_den, same, test)
    # -- frequency conditions over D̃ = ∏ distinct denominators (for rejection also where a
    # residue condition was not certified)
    idx = np.nonzero(pole_ok)[0]
    num_s = [[num[i][j].take(idx) for j in range(n)] for i in range(n)]
    den_s = {k: den[i][j].take(idx) for k, (i, j) in uniq.items()}
    M = idx.size
    one = Poly.const(1.0, M)
    Dt = one
    for t in den_s.values():
        Dt = Dt * t
    Dc = _conj(_jw(Dt))
    zero_pair = (Poly(np.zeros((M, 1)), np.zeros((M, 1))), Poly(np.zeros((M, 1)), np.zeros((M, 1))))
    A: list[list[Pair]] = [[zero_pair] * n for _ in range(n)]  # u_ij(jω)·conj(D̃(jω))
    U: list[list[Pair]] = [[zero_pair] * n for _ in range(n)]
    for i in range(n):
        for j in range(n):
            if zero[i, j]:
                continue
            u = num_s[i][j]
            for k, t in den_s.items():
                if k != den_id[i, j]:
                    u = u * t
            U[i][j] = _jw(u)
            A[i][j] = _pmul(U[i][j], Dc)
    freq_ok = np.ones(M, bool)
    neg = np.zeros(M, bool)
    if test == "hermitian" and n == 2:
        freq_ok &= _two_port_hermitian([[den[i][j].take(idx) for j in range(n)] for i in range(n)], num_s, neg)
    elif test == "hermitian":
        # where z_ij and z_ji are the same expression (always on the diagonal), the entry of the
        # Hermitian part is 2·Re(u_ij D̃*) exactly (its imaginary part cancels exactly)
        zp = Poly(np.zeros((M, 1)), np.zeros((M, 1)))
        H = [[(A[i][j][0].scale(2.0), zp) if same[i, j] else _padd(A[i][j], _conj(A[j][i])) for j in range(n)]
             for i in range(n)]
        for mnr in _leading_minors(H):
            freq_ok &= _chk(mnr, neg)
    elif criterion == "llewellyn":
        freq_ok &= _llewellyn_ok(A, U, Dc, 0, 1, neg)
    else:
        freq_ok &= _theorem1_ok(cmap, A, U, Dc, zero, same, num_s, neg)
    rejected = np.zeros(N, bool)
    rejected[idx] = neg
    ok[idx] &= freq_ok
    return ok & ~rejected, rejected


def accept(cmap: CoefficientMap, X: np.ndarray, criterion: str) -> np.ndarray:
    """(N,) bool: the draws :func:`accept_reject` accepts."""
    return accept_reject(cmap, X, criterion)[0]


def _chk(p: Poly, neg: np.ndarray) -> np.ndarray:
    """certify_positive(p), and neg |= certainly_negative(p) (in place) on the draws not
    certified positive."""
    pos = certify_positive(p)
    rest = np.nonzero(~pos & ~neg)[0]
    if rest.size:
        neg[rest] |= certainly_negative(p.take(rest))
    return pos


def _two_port_hermitian(den: list[list[Poly]], num: list[list[Poly]], neg: np.ndarray) -> np.ndarray:
    """G(jω) + G(jω)ᴴ ≻ 0 for all ω > 0 of a 2×2 G, over each entry's own denominator rather than
    D̃ (structural zeros at ω = 0, e.g. the SDEA's E{1,2} ~ ω⁴, then stay exact zeros):
    a_i = Re(n_ii d_ii*) = Re g_ii·|d_ii|² > 0, and with g_01 + conj(g_10) = N/Q,
    N = n_01·conj(d_10) + conj(n_10)·d_01, Q = d_01·conj(d_10), the 2×2 minor times the positive factor
    |d_00|²·|d_11|²·|Q|² is 4·a_0·a_1·|Q|² − |N|²·|d_00|²·|d_11|² > 0 on x > 0."""
    J = [[_jw(den[i][j]) for j in range(2)] for i in range(2)]
    Nj = [[_jw(num[i][j]) for j in range(2)] for i in range(2)]
    a = [_pmul(Nj[i][i], _conj(J[i][i]))[0] for i in range(2)]
    ok = _chk(a[0], neg) & _chk(a[1], neg)
    # (a zero entry has the exact denominator 1 and numerator 0)
    N = _padd(_pmul(Nj[0][1], _conj(J[1][0])), _pmul(_conj(Nj[1][0]), J[0][1]))
    Q2 = _pmul(J[0][1], _conj(J[0][1]))[0] * _pmul(J[1][0], _conj(J[1][0]))[0]
    N2 = _pmul(N, _conj(N))[0]
    D2 = _pmul(J[0][0], _conj(J[0][0]))[0] * _pmul(J[1][1], _conj(J[1][1]))[0]
    det = (a[0] * a[1] * Q2).scale(4.0) - N2 * D2
    return ok & _chk(det, neg)


def _llewellyn_ok(A: list[list[Pair]], U: list[list[Pair]], Dc: Pair, i: int, j: int, neg: np.ndarray) -> np.ndarray:
    a1, a2 = A[i][i][0], A[j][j][0]
    ok = _chk(a1, neg)
    ok &= _chk(a2, neg)
    a = a1 * a2
    c = _pmul(_pmul(_pmul(U[i][j], U[j][i]), Dc), Dc)
    L2 = (a * (a - c[0])).scale(4.0) - (c[1] * c[1]).mulx()
    # L2 ≡ 0 exactly (every coefficient 0 with bound 0: η ≡ 0, the exact path's ``equality``)
    # is admissible too: with a > 0, L2 ≥ 0 still gives L1 = 2a − Re c ≥ |c| ≥ 0
    # (L2 < 0 somewhere implies η < 0 there: L2 = (L1 − |c|)(L1 + |c|) with L1 + |c| ≥ L1 − |c|)
    return ok & (_chk(L2, neg) | np.all((L2.v == 0) & (L2.e == 0), axis=1))


def _theorem1_ok(cmap: CoefficientMap, A: list[list[Pair]], U: list[list[Pair]], Dc: Pair,
                 zero: np.ndarray, same: np.ndarray, num_s: list[list[Poly]], neg: np.ndarray) -> np.ndarray:
    n = len(A)
    M = A[0][0][0].v.shape[0]
    no = np.zeros(M, bool)
    # B: diagonal blocks symmetric (structurally)
    off = 0
    for m in cmap.port_dofs:
        for a in range(off, off + m):
            for b in range(a + 1, off + m):
                if not (same[a, b] or (zero[a, b] and zero[b, a])):
                    return no
        off += m
    # A: cycle products (structurally)
    for i, j, k in itertools.combinations(range(n), 3):
        lhs0 = zero[i, j] or zero[j, k] or zero[k, i]
        rhs0 = zero[j, i] or zero[k, j] or zero[i, k]
        if not ((lhs0 and rhs0) or (same[i, j] and same[j, k] and same[k, i])):
            return no
    # coupling graph: z_ij z_ji ≢ 0; an entry that is not structurally zero must be nonzero in
    # every draw (some coefficient beyond its bound)
    ok = np.ones(M, bool)
    nzm = np.zeros((n, n), bool)
    for i in range(n):
        for j in range(n):
            if i != j and not zero[i, j]:
                ok &= np.any(np.abs(num_s[i][j].v) > num_s[i][j].e, axis=1)
    for i in range(n):
        for j in range(i + 1, n):
            nzm[i, j] = nzm[j, i] = not (zero[i, j] or zero[j, i])
    seen: set[int] = set()
    for s0 in range(n):
        if s0 in seen:
            continue
        comp, stack = [], [s0]
        seen.add(s0)
        while stack:
            v = stack.pop()
            comp.append(v)
            for w in range(n):
                if nzm[v, w] and w not in seen:
                    seen.add(w)
                    stack.append(w)
        comp.sort()
        if len(comp) == 1:
            ok &= _chk(A[comp[0]][comp[0]][0], neg)
        elif len(comp) == 2:
            ok &= _llewellyn_ok(A, U, Dc, comp[0], comp[1], neg)
        else:
            if not all(nzm[a, b] and same[a, b] for a in comp for b in comp if a < b):
                return no
            R = [[(A[a][b][0], Poly(np.zeros((M, 1)), np.zeros((M, 1)))) for b in comp] for a in comp]
            for mnr in _leading_minors(R):
                ok &= _chk(mnr, neg)
    return ok
