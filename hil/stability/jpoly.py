"""Polynomial algebra on the imaginary axis, with a running round-off bound.

Every real polynomial ``N(s)`` evaluated at ``s = jω`` splits into an even and an odd part::

    N(jω) = a(x) + jω · b(x),      x = ω²,

with real polynomials ``a`` and ``b`` in ``x``. Sums and products of such numbers stay of that
form (the ring R[x][y]/(y² + x) with y = jω), so every frequency condition in the papers
(real parts, Hermitian minors, Llewellyn's η) becomes a *real polynomial in x* whose sign on
x ≥ 0 is then decided exactly (:mod:`hil.stability.exact`).

Round-off bound. Each coefficient is computed in floating point from products and sums of the
model's coefficients. Alongside every polynomial we carry a *magnitude polynomial* ``m`` built by
the same operations on absolute values (|a·b| ≤ |a|·|b| coefficient-wise, |a + b| ≤ |a| + |b|).
Then ``|p_i(computed) - p_i(exact)| ≤ c·eps·m_i`` and, for x ≥ 0, ``|p(x) - p_exact(x)| ≤ c·eps·m(x)``.
The ratio ``p(x)/m(x)`` in [-1, 1] is the *normalized margin* used throughout: it is invariant
under rescaling of frequency (x → c·x) and of impedance (p, m → k·p, k·m), so verdicts do not
depend on units.

Coefficient arrays are in **ascending** powers of x internally (numpy.polynomial convention).
The public file formats use descending powers of s; conversion happens in :mod:`rational`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.polynomial import polynomial as P

if TYPE_CHECKING:
    from flint import fmpq_poly

__all__ = ["JPoly", "XPoly", "jpoly_from_s"]


def trim_back(c: np.ndarray) -> np.ndarray:
    """Drop trailing zero coefficients (highest powers) of an ascending array; keeps one zero for
    the zero polynomial. Same result as ``np.trim_zeros(c, "b")`` but ~10x cheaper on the short
    arrays of this package (it runs thousands of times per verdict)."""
    nz = np.flatnonzero(c)
    return c[: nz[-1] + 1] if nz.size else c[:0]


def _trim(c: np.ndarray) -> np.ndarray:
    c = np.atleast_1d(np.asarray(c, dtype=float))
    if c.size == 0:
        return np.zeros(1)
    nz = np.nonzero(c)[0]
    if nz.size == 0:
        return np.zeros(1)
    return c[: nz[-1] + 1]


def _add(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    n = max(a.size, b.size)
    out = np.zeros(n)
    out[: a.size] += a
    out[: b.size] += b
    return out


def _mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Product of ascending coefficient arrays (np.convolve: same as polymul, less overhead)."""
    return np.convolve(a, b)


def _mulx(a: np.ndarray) -> np.ndarray:
    """Multiply an ascending coefficient array by x."""
    return np.concatenate(([0.0], a))


@dataclass(frozen=True)
class XPoly:
    """A real polynomial in x = ω² with its magnitude bound ``m`` (both ascending).

    ``exact`` (optional, a ``flint.fmpq_poly``) is the exact polynomial that ``c`` rounds, when it
    was formed exactly (:func:`hil.stability.criteria.hermitian_minor_poly`, ``llewellyn_polys``):
    :func:`hil.stability.exact.decide_nonnegative` then decides on it without any tolerance."""

    c: np.ndarray
    m: np.ndarray
    exact: fmpq_poly | None = None

    @staticmethod
    def const(v: float) -> XPoly:
        return XPoly(np.array([float(v)]), np.array([abs(float(v))]))

    def __add__(self, o: XPoly) -> XPoly:
        return XPoly(_add(self.c, o.c), _add(self.m, o.m))

    def __sub__(self, o: XPoly) -> XPoly:
        return XPoly(_add(self.c, -o.c), _add(self.m, o.m))

    def __neg__(self) -> XPoly:
        return XPoly(-self.c, self.m)

    def __mul__(self, o: XPoly | float) -> XPoly:
        if not isinstance(o, XPoly):
            o = XPoly.const(o)
        return XPoly(_mul(self.c, o.c), _mul(self.m, o.m))

    __rmul__ = __mul__

    def mulx(self) -> XPoly:
        return XPoly(_mulx(self.c), _mulx(self.m))

    def __call__(self, x: np.ndarray | float) -> np.ndarray:
        return np.asarray(P.polyval(x, self.c))

    def magnitude(self, x: np.ndarray | float) -> np.ndarray:
        return np.asarray(P.polyval(x, self.m))

    @property
    def degree(self) -> int:
        return _trim(self.c).size - 1


@dataclass(frozen=True)
class JPoly:
    """The value of a real polynomial (or a product of them) at s = jω: ``re(x) + jω·im(x)``.

    ``mre`` and ``mim`` are the magnitude bounds of ``re`` and ``im``.
    """

    re: np.ndarray
    im: np.ndarray
    mre: np.ndarray
    mim: np.ndarray

    @staticmethod
    def const(v: float) -> JPoly:
        v = float(v)
        return JPoly(np.array([v]), np.zeros(1), np.array([abs(v)]), np.zeros(1))

    @staticmethod
    def zero() -> JPoly:
        return JPoly.const(0.0)

    @staticmethod
    def one() -> JPoly:
        return JPoly.const(1.0)

    def __add__(self, o: JPoly) -> JPoly:
        return JPoly(_add(self.re, o.re), _add(self.im, o.im), _add(self.mre, o.mre), _add(self.mim, o.mim))

    def __sub__(self, o: JPoly) -> JPoly:
        return JPoly(_add(self.re, -o.re), _add(self.im, -o.im), _add(self.mre, o.mre), _add(self.mim, o.mim))

    def __neg__(self) -> JPoly:
        return JPoly(-self.re, -self.im, self.mre, self.mim)

    def __mul__(self, o: JPoly | float) -> JPoly:
        if not isinstance(o, JPoly):
            o = JPoly.const(o)
        # (a1 + y b1)(a2 + y b2) with y² = -x:  re = a1a2 - x b1b2,  im = a1b2 + a2b1
        re = _add(_mul(self.re, o.re), -_mulx(_mul(self.im, o.im)))
        im = _add(_mul(self.re, o.im), _mul(self.im, o.re))
        mre = _add(_mul(self.mre, o.mre), _mulx(_mul(self.mim, o.mim)))
        mim = _add(_mul(self.mre, o.mim), _mul(self.mim, o.mre))
        return JPoly(re, im, mre, mim)

    __rmul__ = __mul__

    def conj(self) -> JPoly:
        """Complex conjugate on the real frequency axis (N(-jω) for real-coefficient N)."""
        return JPoly(self.re, -self.im, self.mre, self.mim)

    def real(self) -> XPoly:
        """Real part, a polynomial in x."""
        return XPoly(self.re, self.mre)

    def imag_over_omega(self) -> XPoly:
        """Imaginary part divided by ω, a polynomial in x (the imaginary part is ω times it)."""
        return XPoly(self.im, self.mim)

    def abs2(self) -> XPoly:
        """|·|² = re² + x·im², a polynomial in x."""
        r, i = self.real(), self.imag_over_omega()
        return r * r + (i * i).mulx()

    def __call__(self, w: np.ndarray | float) -> np.ndarray:
        w = np.asarray(w, dtype=float)
        x = w * w
        return np.asarray(P.polyval(x, self.re) + 1j * w * P.polyval(x, self.im))


def jpoly_from_s(coeffs_ascending: np.ndarray) -> JPoly:
    """Split a real polynomial in s (ascending coefficients) into its value at s = jω.

    ``N(jω) = Σ n_k (jω)^k``: even k contribute ``n_k (-1)^(k/2) x^(k/2)`` to the real part,
    odd k contribute ``n_k (-1)^((k-1)/2) x^((k-1)/2)`` to ``im`` (the imaginary part over ω).
    """
    n = np.asarray(coeffs_ascending, dtype=float)
    even = n[0::2].copy()
    odd = n[1::2].copy()
    even *= (-1.0) ** np.arange(even.size)
    odd *= (-1.0) ** np.arange(odd.size)
    if odd.size == 0:
        odd = np.zeros(1)
    return JPoly(even, odd, np.abs(even), np.abs(odd))
