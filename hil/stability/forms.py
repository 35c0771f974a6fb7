"""Exact formation of the frequency conditions of the criteria over Q (python-flint).

Every frequency condition (principal minors of G(jω) + G(jω)ᴴ, Llewellyn's L1 and L2, the minors
of Re Z'(jω)) is a real polynomial p(x) in x = ω² once the entries are put over their common
denominator D; it is formed here exactly, with imaginary-axis poles cancelled, alongside its
float magnitude polynomial (docs/VERDICTS.md)."""

from __future__ import annotations

import itertools
import logging
from collections.abc import Iterable
from dataclasses import dataclass
from typing import cast

import numpy as np
from flint import fmpq_poly

from hil.errors import ModelError
from hil.stability.exact import strictly_hurwitz
from hil.stability.jpoly import JPoly, XPoly
from hil.stability.rational import Rational
from hil.stability.residues import _xq  # N(jω) = a(x) + jω·b(x), shared with the residue tests

logger = logging.getLogger(__name__)


# ------------------------------------------------------------------------------------------
# polynomial conditions


def _qpoly_float(p: fmpq_poly) -> np.ndarray:
    """Ascending float coefficients of an exact polynomial, each correctly rounded."""
    from hil.stability.rational import _qpoly_floats

    return np.array(_qpoly_floats(p) or [0.0])


# -- exact formation of the frequency conditions -----------------------------------------------
#
# Every frequency condition (principal minors of G(jω) + G(jω)ᴴ, Llewellyn's L1 and L2) is a real
# polynomial in x = ω² once the entries are put over a common denominator D. It is formed EXACTLY
# over Q: the float coefficients are exact binary rationals, D is the lcm of the denominators over
# Q[s] and u_ij = n_ij·(D/d_ij) is an exact quotient (python-flint fmpq_poly). The sign decision
# (exact.decide_exact) is therefore free of rounding: a violation the given coefficients have is
# found however shallow it is, and equality / touching is recognised exactly.
#
# Imaginary-axis poles. A pole of G at s = ±jω_p (ω_p > 0) makes D(jω) vanish at x_p = ω_p², so
# every condition polynomial p(x) = (condition)·|D(jω)|^(2k) carries the factor (x - x_p)^(2k): a
# double root that would be read as "touching" although the condition itself (e.g. Re Z = 1 for
# Z = 1 + s/(s² + 1)) is strictly positive. The axis factor h(x) is found exactly: D(jω) = E(x) +
# jω O(x), and jω_p is a root iff x_p is a common root of E and O, so h is the squarefree part of
# gcd(E, O) over Q, without the factor x (s = 0 sits at the boundary x = 0). p is divided by h² as
# often as it is exactly divisible, at most as often as h² divides |D|^(2k). Dividing by a square
# keeps the sign of p at every frequency that is not a pole; at the pole frequency the frequency
# condition is undefined and the pole is judged by its residue condition D[ω=ω_p].
#
# Magnitude polynomial m. Alongside the exact p, the same construction is carried out on absolute
# values in floats (hil.stability.jpoly): m(x) ≥ Σ |terms of p(x)| for x ≥ 0, with terms the
# monomials in the coefficients of u and D. It bounds the effect of relative perturbations of those
# coefficients (|Δp(x)| ≤ ((1+r)^K - 1)·m(x) for relative perturbations ≤ r, K the number of
# coefficient factors per term) and normalizes the frequency-domain margin (docs/VERDICTS.md).


_X = fmpq_poly([0, 1])


def _jmul(u: tuple[fmpq_poly, fmpq_poly], v: tuple[fmpq_poly, fmpq_poly]) -> tuple[fmpq_poly, fmpq_poly]:
    return u[0] * v[0] - _X * u[1] * v[1], u[0] * v[1] + u[1] * v[0]


def _jfloat(u: tuple[fmpq_poly, fmpq_poly]) -> JPoly:
    """The float image of an exact (even, odd) pair, magnitudes = |coefficients|."""
    re, im = _qpoly_float(u[0]), _qpoly_float(u[1])
    return JPoly(re, im, np.abs(re), np.abs(im))


@dataclass
class _Setup:
    """Exact values at s = jω of the entries over their common denominator D (see above)."""

    u: list[list[tuple[fmpq_poly, fmpq_poly]]]
    Dc: tuple[fmpq_poly, fmpq_poly]  # conj(D(jω))
    h: fmpq_poly | None  # imaginary-axis factor of D in x (None: no axis pole with ω > 0)
    mu: int  # multiplicity of h in gcd(E, O)
    uf: list[list[JPoly]]  # float images (for the magnitude polynomials; empty without them)
    Dcf: JPoly


QEntries = tuple[list[list["fmpq_poly | None"]], list[list[fmpq_poly]]]


def _q_entries(sub: list[list[Rational]]) -> QEntries:
    """The exact reduced (numerator or None for a zero entry, denominator) of the entries: a common
    factor written into an entry is cancelled first, so every condition (and its margin) is that
    of the rational functions, whatever their written form (issue 31, item 3)."""

    n = len(sub)
    nums: list[list[fmpq_poly | None]] = [[None if sub[i][j].is_zero else sub[i][j].exact_reduced[0]
                                           for j in range(n)] for i in range(n)]
    dens = [[sub[i][j].exact_reduced[1] for j in range(n)] for i in range(n)]
    return nums, dens


#: the placeholder float image of a setup built without magnitude polynomials (never read)
_NO_M = JPoly.zero()


def _setup(sub: list[list[Rational]], need_m: bool = True, q: QEntries | None = None) -> _Setup:
    """``q``: the entries given exactly (then ``sub`` is only used for its size)."""
    nums, dens = q if q is not None else _q_entries(sub)
    n = len(nums)
    D, h, mu = _axis_factor([dens[i][j] for i in range(n) for j in range(n) if nums[i][j] is not None])
    E, O = _xq(D)
    Dc = (E, -O)
    zero = (fmpq_poly([]), fmpq_poly([]))
    u = [[zero if (nij := nums[i][j]) is None else _xq(nij * (D // dens[i][j])) for j in range(n)] for i in range(n)]
    if not need_m:
        return _Setup(u, Dc, h, mu, [], _NO_M)
    uf = [[_jfloat(e) for e in row] for row in u]
    return _Setup(u, Dc, h, mu, uf, _jfloat(Dc))


def _lcm(dens: list[fmpq_poly]) -> fmpq_poly:
    """The common denominator D of the entries: the running product D·d / gcd(D, d) from D = 1
    (FLINT's gcd is monic, so D is an lcm up to a constant factor). A denominator equal to the
    running D (the common case: entries over one denominator) gives D·lc(D), the same polynomial
    as D·d / gcd(D, d) = D²/(D/lc(D)), without the gcd."""
    D = fmpq_poly([1])
    first = True
    for d in dens:
        if first:
            D, first = d * 1, False  # 1·d / gcd(1, d) = d (a copy: callers never mutate, but safe)
        elif d == D:
            D = D * D[D.degree()]
        else:
            D = D * d // D.gcd(d)
    return D


def _axis_factor(dens: list[fmpq_poly]) -> tuple[fmpq_poly, fmpq_poly | None, int]:
    """(common denominator D = lcm, axis factor h or None, multiplicity μ of h in gcd(E, O))."""
    D = _lcm(dens)
    if D.degree() < 2:
        return D, None, 0
    dz = D.numer().coeffs()
    k0 = 0
    while dz[k0] == 0:
        k0 += 1
    if strictly_hurwitz(dz[k0:]):  # D = s^k0·(strictly Hurwitz): no axis pole at ω > 0 (exact, cheap)
        return D, None, 0
    E, O = _xq(D)
    g = E.gcd(O)
    while g.degree() > 0 and g[0] == 0:  # drop the factor x (poles at s = 0)
        g = g // _X
    if g.degree() < 1:
        return D, None, 0
    h = g // g.gcd(g.derivative())
    if h.degree() < 1:
        return D, None, 0
    mu, t = 0, g
    while t.degree() >= h.degree() and (t % h).is_zero():
        t, mu = t // h, mu + 1
    return D, h, max(mu, 1)


def _cancel(p: fmpq_poly, h: fmpq_poly | None, cap: int) -> tuple[fmpq_poly, int]:
    if h is None:
        return p, 0
    h2 = h * h
    cut = 0
    while not p.is_zero() and cut < cap and (p % h2).is_zero():
        p, cut = p // h2, cut + 1
    return p, cut


@dataclass(frozen=True)
class CondPoly:
    """One frequency condition formed exactly: ``p`` with ``cut`` squared axis factors h²
    divided out (its sign decides the status), ``full`` the polynomial before the division
    (p·h^(2·cut); the margin is taken on it) and ``m`` the magnitude polynomial of ``full``
    (ascending floats; None when not asked for)."""

    p: fmpq_poly
    cut: int
    full: fmpq_poly
    m: np.ndarray | None


def _exact_minor_polys(sub: list[list[Rational]], need_m: bool = True, q: QEntries | None = None,
                       entrywise_real: bool = False) -> dict[tuple[int, ...], CondPoly]:
    """Every principal minor of (G + Gᴴ)(jω)·|D(jω)|^(2k), formed exactly over Q, divided by the
    squared axis factor where present (:class:`CondPoly` by index tuple), with the magnitude
    polynomial of the uncancelled minor when ``need_m``.
    ``q``: the entries given exactly instead of ``sub``. ``entrywise_real``: minors of the
    entrywise real part 2·Re G(jω) instead (equal to G + Gᴴ for a symmetric G; Theorem 1's Z' is
    handled up to a diagonal similarity, which keeps the minors of Re Z' but not its symmetry)."""
    st = _setup(sub, need_m, q)
    n = len(st.u)
    zero = (fmpq_poly([]), fmpq_poly([]))
    A = [[_jmul(st.u[i][j], st.Dc) for j in range(n)] for i in range(n)]
    if entrywise_real:
        Pm = [[(2 * A[i][j][0], fmpq_poly([])) for j in range(n)] for i in range(n)]
    else:
        Pm = [[(A[i][j][0] + A[j][i][0], A[i][j][1] - A[j][i][1]) for j in range(n)] for i in range(n)]
    Pf: list[list[JPoly]] = []
    if need_m:
        Af = [[st.uf[i][j] * st.Dcf for j in range(n)] for i in range(n)]
        if entrywise_real:
            Pf = [[JPoly(2.0 * Af[i][j].re, np.zeros(1), 2.0 * Af[i][j].mre, np.zeros(1)) for j in range(n)]
                  for i in range(n)]
        else:
            Pf = [[Af[i][j] + Af[j][i].conj() for j in range(n)] for i in range(n)]
    memo: dict[tuple[tuple[int, ...], tuple[int, ...]], tuple[fmpq_poly, fmpq_poly]] = {}
    memof: dict[tuple[tuple[int, ...], tuple[int, ...]], JPoly] = {}

    def det(rows: tuple[int, ...], cols: tuple[int, ...]) -> tuple[fmpq_poly, fmpq_poly]:
        if len(rows) == 1:
            return Pm[rows[0]][cols[0]]
        if (rows, cols) in memo:
            return memo[(rows, cols)]
        acc = zero
        for k, c in enumerate(cols):
            t = _jmul(Pm[rows[0]][c], det(rows[1:], cols[:k] + cols[k + 1:]))
            acc = (acc[0] + t[0], acc[1] + t[1]) if k % 2 == 0 else (acc[0] - t[0], acc[1] - t[1])
        memo[(rows, cols)] = acc
        return acc

    def detf(rows: tuple[int, ...], cols: tuple[int, ...]) -> JPoly:
        if len(rows) == 1:
            return Pf[rows[0]][cols[0]]
        key = (rows, cols)
        if key in memof:
            return memof[key]
        acc = JPoly.zero()
        for k, c in enumerate(cols):
            t = Pf[rows[0]][c] * detf(rows[1:], cols[:k] + cols[k + 1:])
            acc = acc + t if k % 2 == 0 else acc - t
        memof[key] = acc
        return acc

    memor: dict[tuple[tuple[int, ...], tuple[int, ...]], fmpq_poly] = {}

    def detr(rows: tuple[int, ...], cols: tuple[int, ...]) -> fmpq_poly:
        """det for entrywise_real: every entry is real (imaginary part the zero polynomial), so
        the complex products of ``det`` reduce to real ones (the same polynomials, exactly)."""
        if len(rows) == 1:
            return Pm[rows[0]][cols[0]][0]
        key = (rows, cols)
        if key in memor:
            return memor[key]
        acc = fmpq_poly([])
        for k, c in enumerate(cols):
            a = Pm[rows[0]][c][0]
            if a.is_zero():
                continue
            t = a * detr(rows[1:], cols[:k] + cols[k + 1:])
            acc = acc + t if k % 2 == 0 else acc - t
        memor[key] = acc
        return acc

    out = {}
    for k in range(1, n + 1):
        for idx in itertools.combinations(range(n), k):
            full = detr(idx, idx) if entrywise_real else det(idx, idx)[0]
            p, cut = _cancel(full, st.h, k * st.mu)
            out[idx] = CondPoly(p, cut, full, detf(idx, idx).real().m if need_m else None)
    return out


def _exact_llewellyn_polys(sub: list[list[Rational]], need_m: bool = True, _st: list[_Setup] | None = None
                           ) -> tuple[CondPoly, CondPoly]:
    """(L1, L2) of :func:`llewellyn_polys` formed exactly over Q with the squared imaginary-axis
    factor divided out where present (L1 carries |D|⁴, L2 |D|⁸), as :class:`CondPoly` (magnitude
    polynomials when ``need_m``). ``_st``: a list that receives the setup (the caller reads its
    axis factor)."""
    st = _setup(sub, need_m)
    if _st is not None:
        _st.append(st)
    u, Dc = st.u, st.Dc
    A1 = _jmul(u[0][0], Dc)[0]
    A2 = _jmul(u[1][1], Dc)[0]
    C = _jmul(_jmul(_jmul(u[0][1], u[1][0]), Dc), Dc)
    a = A1 * A2
    L1 = 2 * a - C[0]
    L2 = 4 * a * (a - C[0]) - _X * C[1] * C[1]
    m1 = m2 = None
    if need_m:
        uf, Dcf = st.uf, st.Dcf
        a1f = (uf[0][0] * Dcf).real()
        a2f = (uf[1][1] * Dcf).real()
        cf = uf[0][1] * uf[1][0] * Dcf * Dcf
        af = a1f * a2f
        cr, ci = cf.real(), cf.imag_over_omega()
        m1 = (af * 2.0 - cr).m
        m2 = (af * (af - cr) * 4.0 - (ci * ci).mulx()).m
    p1, c1 = _cancel(L1, st.h, 2 * st.mu)
    p2, c2 = _cancel(L2, st.h, 4 * st.mu)
    return CondPoly(p1, c1, L1, m1), CondPoly(p2, c2, L2, m2)


def hermitian_minor_poly(entries: list[list[Rational]], idx: tuple[int, ...]) -> XPoly:
    """The principal minor ``idx`` of G(jω)+G(jω)ᴴ times |D(jω)|^(2k), D the exact lcm of the
    denominators, as a polynomial in x = ω²: formed exactly over Q and rounded once (``c``), with
    its magnitude polynomial ``m`` (no imaginary-axis cancellation)."""
    sub = [[entries[i][j] for j in idx] for i in idx]
    st = _setup(sub)
    n = len(sub)
    A = [[_jmul(st.u[i][j], st.Dc) for j in range(n)] for i in range(n)]
    Pm = [[(A[i][j][0] + A[j][i][0], A[i][j][1] - A[j][i][1]) for j in range(n)] for i in range(n)]
    Af = [[st.uf[i][j] * st.Dcf for j in range(n)] for i in range(n)]
    Pf = [[Af[i][j] + Af[j][i].conj() for j in range(n)] for i in range(n)]
    if n == 1:
        return XPoly(_qpoly_float(Pm[0][0][0]), Pf[0][0].real().m, Pm[0][0][0])
    if n == 2:
        p = _jmul(Pm[0][0], Pm[1][1])[0] - _jmul(Pm[0][1], Pm[1][0])[0]
        return XPoly(_qpoly_float(p), (Pf[0][0] * Pf[1][1] - Pf[0][1] * Pf[1][0]).real().m, p)
    raise ModelError("hermitian_minor_poly supports 1x1 and 2x2 minors; use _hermitian_minors for larger ones")


def llewellyn_polys(entries: list[list[Rational]], i: int = 0, j: int = 1) -> tuple[XPoly, XPoly]:
    """(L1, L2) with η_ij ≥ 0 ⟺ L1 ≥ 0 and L2 ≥ 0, formed exactly over Q (no axis cancellation)
    and rounded once, with their magnitude polynomials.

    η_ij = 2 Re p_ii Re p_jj - Re(p_ij p_ji) - |p_ij p_ji|. With the common denominator D (p = u/D):
    a = Re(u_ii D*) Re(u_jj D*), c = u_ij u_ji D*², all over |D|⁴ > 0. Then η ≥ 0 ⟺
    L1 = 2a - Re c ≥ 0 and L2 = (2a - Re c)² - |c|² = 4a(a - Re c) - x·(Im c/ω)² ≥ 0
    (L2 alone decides where a > 0; L1 matters only where a = 0).
    """
    sub = [[entries[a][b] for b in (i, j)] for a in (i, j)]
    st = _setup(sub)
    u, Dc = st.u, st.Dc
    a = _jmul(u[0][0], Dc)[0] * _jmul(u[1][1], Dc)[0]
    C = _jmul(_jmul(_jmul(u[0][1], u[1][0]), Dc), Dc)
    L1 = 2 * a - C[0]
    L2 = 4 * a * (a - C[0]) - _X * C[1] * C[1]
    uf, Dcf = st.uf, st.Dcf
    af = (uf[0][0] * Dcf).real() * (uf[1][1] * Dcf).real()
    cf = uf[0][1] * uf[1][0] * Dcf * Dcf
    cr, ci = cf.real(), cf.imag_over_omega()
    return (XPoly(_qpoly_float(L1), (af * 2.0 - cr).m, L1),
            XPoly(_qpoly_float(L2), (af * (af - cr) * 4.0 - (ci * ci).mulx()).m, L2))


def _desc(c: np.ndarray) -> list[float]:
    return cast("list[float]", np.asarray(c, float)[::-1].tolist())


def _lbl(idx: Iterable[int]) -> str:
    return "{" + ",".join(str(i + 1) for i in idx) + "}"
