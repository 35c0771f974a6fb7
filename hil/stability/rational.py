"""Rational transfer functions and transfer matrices of LTI networks.

Conventions
-----------
* Coefficients are real, SI units. Public constructors take coefficients in **descending**
  powers of s (as in the network file format and MATLAB/scipy); internally they are stored
  ascending (numpy.polynomial convention).
* An *immittance matrix* relates port efforts (forces/torques) and flows (velocities):

  - ``impedance``  z:  F = Z V
  - ``admittance`` y:  V = Y F
  - ``hybrid``     h:  [F1; V2] = H [V1; F2]
  - ``inverse_hybrid`` g: [V1; F2] = G [F1; V2]

  with velocities oriented *into* the ports so that power into the network is Re(F^H V)
  (the papers' convention). For an n-port with m DOFs per port, entries are ordered port by
  port (block (i, j) is m×m), as in paper 000 eq. (11)-(12).
* Common factors of numerator and denominator: powers of s are cancelled exactly; the algebra's
  shortcuts (a denominator dividing another, a numerator equal to a denominator) are taken only
  on exact divisibility over Q[s] (:func:`_exact_quotient`); conversions between immittance types
  run entirely in exact arithmetic and their results stay exact (:meth:`TransferMatrix.to`,
  :meth:`Rational.of_exact`).
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from flint import fmpq, fmpq_poly
from numpy.polynomial import polynomial as P

from hil.errors import ConversionError, ModelError
from hil.stability.jpoly import trim_back

logger = logging.getLogger(__name__)

ImmittanceKind = Literal["impedance", "admittance", "hybrid", "inverse_hybrid"]
KINDS: tuple[str, ...] = ("impedance", "admittance", "hybrid", "inverse_hybrid")

__all__ = ["KINDS", "ImmittanceKind", "Rational", "S", "TransferMatrix"]


def _clean(c: Sequence[float] | np.ndarray) -> np.ndarray:
    a = np.atleast_1d(np.asarray(c, dtype=float))
    if a.ndim != 1:
        raise ModelError("polynomial coefficients must be a flat list of numbers")
    if not np.all(np.isfinite(a)):
        raise ModelError("polynomial coefficients must be finite numbers")
    nz = np.nonzero(a)[0]
    return a[: nz[-1] + 1] if nz.size else np.zeros(1)


@dataclass(frozen=True)
class Rational:
    """A real rational function n(s)/d(s); ``num`` and ``den`` ascending, ``den`` not zero."""

    num: np.ndarray
    den: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "num", _clean(self.num))
        object.__setattr__(self, "den", _clean(self.den))
        if not np.any(self.den):
            raise ModelError("denominator is identically zero")

    # -- constructors ---------------------------------------------------------------------
    @staticmethod
    def trusted(num: np.ndarray, den: np.ndarray) -> Rational:
        """Internal: a Rational from ascending float arrays the caller guarantees to be clean (1-D,
        finite, last coefficient non-zero, den ≠ 0), without re-validating them."""
        r = object.__new__(Rational)
        object.__setattr__(r, "num", num)
        object.__setattr__(r, "den", den)
        return r

    @staticmethod
    def from_desc(num: Sequence[float], den: Sequence[float] = (1.0,)) -> Rational:
        """From coefficients in descending powers of s, e.g. ``[m, b, k], [1, 0]`` = (ms²+bs+k)/s."""
        return Rational(np.asarray(num, float)[::-1], np.asarray(den, float)[::-1]).cancel_s()

    @staticmethod
    def const(v: float) -> Rational:
        return Rational(np.array([float(v)]), np.array([1.0]))

    @staticmethod
    def from_zpk(zeros: Sequence[complex], poles: Sequence[complex], gain: float) -> Rational:
        """From zeros, poles (conjugate pairs complete) and gain."""
        n = np.real_if_close(P.polyfromroots(list(zeros)) if len(zeros) else np.array([1.0]), tol=1e6)
        d = np.real_if_close(P.polyfromroots(list(poles)) if len(poles) else np.array([1.0]), tol=1e6)
        if np.iscomplexobj(n) or np.iscomplexobj(d):
            raise ModelError("zeros and poles must come in complex-conjugate pairs")
        return Rational(gain * np.asarray(n, float), np.asarray(d, float))

    # -- algebra ----------------------------------------------------------------------------
    def _combine(self, o: Rational, sign: float) -> Rational:
        """self + sign·o over the smallest common denominator found without root finding:
        equal denominators (up to scale), or one dividing the other; else their product."""
        if o.is_zero:
            return self
        if self.is_zero:
            return Rational(sign * o.num, o.den)
        q = _exact_quotient(o.den, self.den)  # o.den = self.den · q ?
        if q is not None:
            return Rational(P.polyadd(P.polymul(self.num, q), sign * o.num), o.den).cancel_s()
        q = _exact_quotient(self.den, o.den)
        if q is not None:
            return Rational(P.polyadd(self.num, sign * P.polymul(o.num, q)), self.den).cancel_s()
        num = P.polyadd(P.polymul(self.num, o.den), sign * P.polymul(o.num, self.den))
        return Rational(num, P.polymul(self.den, o.den)).cancel_s()

    def __add__(self, o: Rational | float) -> Rational:
        return self._combine(_as_rational(o), 1.0)

    __radd__ = __add__

    def __sub__(self, o: Rational | float) -> Rational:
        return self._combine(_as_rational(o), -1.0)

    def __rsub__(self, o: Rational | float) -> Rational:
        return _as_rational(o)._combine(self, -1.0)

    def __neg__(self) -> Rational:
        return Rational(-self.num, self.den)

    def __mul__(self, o: Rational | float) -> Rational:
        o = _as_rational(o)
        if self.is_zero or o.is_zero:
            return Rational(np.zeros(1), np.array([1.0]))
        # cancel a numerator that equals the other factor's denominator (common in conversions)
        num1, den2 = self.num, o.den
        q = _exact_quotient(num1, den2)
        if q is not None and q.size == 1:
            return Rational(P.polymul(q, o.num), self.den).cancel_s()
        q = _exact_quotient(o.num, self.den)
        if q is not None and q.size == 1:
            return Rational(P.polymul(q, self.num), o.den).cancel_s()
        return Rational(P.polymul(self.num, o.num), P.polymul(self.den, o.den)).cancel_s()

    def scaled(self, w0: float) -> Rational:
        """The function of the normalized variable s̃ = s/w0: coefficients c_k·w0^k, renormalized."""
        num = self.num * w0 ** np.arange(self.num.size)
        den = self.den * w0 ** np.arange(self.den.size)
        sc = float(np.max(np.abs(den)))
        return Rational(num / sc, den / sc)

    __rmul__ = __mul__

    def __pow__(self, n: int) -> Rational:
        if not isinstance(n, int) or n < 0:
            raise ModelError("only non-negative integer powers of a transfer function are supported")
        out = Rational.const(1.0)
        for _ in range(n):
            out = out * self
        return out

    def inv(self) -> Rational:
        if not np.any(self.num):
            raise ConversionError("cannot invert an identically zero transfer function")
        return Rational(self.den, self.num)

    def __truediv__(self, o: Rational | float) -> Rational:
        return self * _as_rational(o).inv()

    def __rtruediv__(self, o: Rational | float) -> Rational:
        return _as_rational(o) * self.inv()

    # -- properties ---------------------------------------------------------------------------
    @property
    def is_zero(self) -> bool:
        n = self.num  # _clean leaves the zero polynomial as [0.0]
        return n.size == 1 and n[0] == 0.0

    def is_proper(self) -> bool:
        return self.num.size <= self.den.size

    def poles(self) -> np.ndarray:
        return self._poles

    def zeros(self) -> np.ndarray:
        return self._zeros

    @staticmethod
    def of_exact(num: fmpq_poly, den: fmpq_poly) -> Rational:
        """The entry n/d given exactly over Q (e.g. an immittance conversion's result, whose
        coefficients need not be binary rationals): ``num``/``den`` are its coefficients rounded
        to the nearest floats (for evaluation, plots, files), and :attr:`exact` is (n, d) itself,
        so every exact decision of the stability core sees the unrounded entry. Raises
        :class:`ConversionError` when a coefficient does not fit in a float or rounds to zero (the
        rounded entry would not even have the same degrees)."""
        try:
            n_ = np.array(_qpoly_floats(num) or [0.0])
            d_ = np.array(_qpoly_floats(den))
        except OverflowError:
            raise ConversionError("a converted coefficient does not fit in a float") from None
        lost = [(c, q) for c, q in ((n_, num), (d_, den)) for k in range(q.degree() + 1) if q[k] != 0 and c[k] == 0]
        if lost or not np.all(np.isfinite(n_)) or not np.all(np.isfinite(d_)):
            raise ConversionError("a converted coefficient does not fit in a float")
        r = Rational.trusted(n_, d_)
        r.__dict__["exact"] = (num, den)  # the cached_property's slot: the exact entry itself
        r.__dict__["_exact_given"] = True
        return r

    @property
    def exact_given(self) -> bool:
        """Whether :attr:`exact` was given (:meth:`of_exact`) rather than read from the floats."""
        return bool(self.__dict__.get("_exact_given", False))

    @functools.cached_property
    def exact(self) -> tuple[fmpq_poly, fmpq_poly]:
        """(num, den) as exact rational polynomials: the binary rationals the floats are, or the
        entry given exactly (:meth:`of_exact`, whose floats are its rounding); computed once per
        object; callers must not modify them in place."""
        return _qpoly(self.num), _qpoly(self.den)

    @functools.cached_property
    def exact_reduced(self) -> tuple[fmpq_poly, fmpq_poly]:
        """(num, den) exactly, divided by their gcd over Q[s] (a zero numerator: den unchanged)."""
        num, den = self.exact
        if not num.is_zero():
            g = num.gcd(den)
            if g.degree() > 0:
                num, den = num // g, den // g
        return num, den

    @functools.cached_property
    def _poles(self) -> np.ndarray:
        return _roots_asc(self.den)

    @functools.cached_property
    def _zeros(self) -> np.ndarray:
        return _roots_asc(self.num)

    def cancel_s(self) -> Rational:
        """Cancel common powers of s exactly (zero constant coefficients of both polynomials)."""
        num, den = self.num, self.den
        if not np.any(num):
            return Rational(np.zeros(1), np.array([1.0]))
        k = 0
        while k < min(num.size, den.size) - 1 and num[k] == 0 and den[k] == 0:
            k += 1
        return self if k == 0 else Rational(num[k:], den[k:])

    # -- evaluation ---------------------------------------------------------------------------
    def __call__(self, s: np.ndarray | complex) -> np.ndarray:
        s = np.asarray(s, dtype=complex)
        return np.asarray(P.polyval(s, self.num) / P.polyval(s, self.den))

    def freq(self, w: np.ndarray | float) -> np.ndarray:
        """Frequency response at s = jω (ω in rad/s), vectorized."""
        return self(1j * np.asarray(w, dtype=float))

    def to_dict(self) -> dict[str, Any]:
        return {"num": self.num[::-1].tolist(), "den": self.den[::-1].tolist()}

    def __repr__(self) -> str:
        return f"Rational(num={self.num[::-1].tolist()}, den={self.den[::-1].tolist()})"


def _as_rational(o: Rational | float | int) -> Rational:
    return o if isinstance(o, Rational) else Rational.const(float(o))


def _exact_quotient(a: np.ndarray, b: np.ndarray, rtol: float = 0.0) -> np.ndarray | None:
    """q with a = b·q EXACTLY (the float coefficients read as the exact binary rationals they are,
    divided over Q[s] with python-flint), rounded to floats once; None when b does not divide a.

    Near-divisibility is never accepted: a polynomial that differs from a multiple of b by rounding
    is a different polynomial. ``rtol`` is accepted for backward compatibility and ignored."""
    a = trim_back(np.asarray(a, float))
    b = trim_back(np.asarray(b, float))
    if a.size == 0:
        return np.zeros(1)
    if a.size < b.size or b.size == 0:
        return None
    if b.size == 1:
        if b[0] == 0:
            return None
        qa = _qpoly(a) / fmpq(*float(b[0]).as_integer_ratio())
    else:
        qa, r = divmod(_qpoly(a), _qpoly(b))
        if not r.is_zero():
            return None
    try:
        return np.array([_qfloat(qa[k]) for k in range(qa.degree() + 1)] or [0.0])
    except OverflowError:
        return None


def _roots_asc(c: np.ndarray) -> np.ndarray:
    c = trim_back(np.asarray(c, float))
    if c.size <= 1:
        return np.zeros(0, complex)
    return np.roots(c[::-1]).astype(complex)


#: the Laplace variable s as a Rational, for building models by formula: ``m*S**2 + b*S + k``
S = Rational(np.array([0.0, 1.0]), np.array([1.0]))


@dataclass
class TransferMatrix:
    """A square matrix of :class:`Rational` entries with its immittance type and port structure.

    ``port_dofs`` gives the number of DOFs of each port, in order; ``sum(port_dofs) == n``.
    """

    entries: list[list[Rational]]
    kind: ImmittanceKind = "impedance"
    port_dofs: tuple[int, ...] = field(default_factory=tuple)
    name: str = ""

    def __post_init__(self) -> None:
        n = len(self.entries)
        if n == 0 or any(len(r) != n for r in self.entries):
            raise ModelError("a transfer matrix must be square and non-empty")
        self.entries = [[_as_rational(e) for e in row] for row in self.entries]
        if self.kind not in KINDS:
            raise ModelError(f"unknown immittance type {self.kind!r}; expected one of {', '.join(KINDS)}")
        if not self.port_dofs:
            self.port_dofs = (1,) * n
        self.port_dofs = tuple(int(d) for d in self.port_dofs)
        if sum(self.port_dofs) != n or any(d < 1 for d in self.port_dofs):
            raise ModelError(f"port DOFs {list(self.port_dofs)} do not add up to the matrix size {n}")
        if self.kind in ("hybrid", "inverse_hybrid") and len(self.port_dofs) != 2:
            raise ModelError("hybrid and inverse-hybrid matrices are defined for two-ports only")
        for i, row in enumerate(self.entries):
            for j, e in enumerate(row):
                if not e.is_proper():
                    logger.debug("entry (%d, %d) is improper (degree num > den)", i, j)

    # -- constructors ---------------------------------------------------------------------------
    @staticmethod
    def from_coefficients(rows: Sequence[Sequence[dict[str, Any]]], kind: ImmittanceKind = "impedance",
                          port_dofs: Sequence[int] | None = None, name: str = "") -> TransferMatrix:
        """From rows of ``{"num": [...], "den": [...]}`` (descending powers of s)."""
        ent = [[Rational.from_desc(e["num"], e.get("den", [1.0])) for e in row] for row in rows]
        return TransferMatrix(ent, kind, tuple(port_dofs or ()), name)

    @staticmethod
    def from_zpk(zpk_rows: Sequence[Sequence[tuple[Any, ...]]], kind: ImmittanceKind = "impedance",
                 port_dofs: Sequence[int] | None = None, name: str = "") -> TransferMatrix:
        ent = [[Rational.from_zpk(*e) for e in row] for row in zpk_rows]
        return TransferMatrix(ent, kind, tuple(port_dofs or ()), name)

    # -- basic properties -------------------------------------------------------------------------
    @property
    def n(self) -> int:
        return len(self.entries)

    @property
    def n_ports(self) -> int:
        return len(self.port_dofs)

    def __getitem__(self, ij: tuple[int, int]) -> Rational:
        return self.entries[ij[0]][ij[1]]

    def freq(self, w: np.ndarray | float) -> np.ndarray:
        """Vectorized frequency response, shape (len(w), n, n), at s = jω."""
        w = np.atleast_1d(np.asarray(w, dtype=float))
        out = np.empty((w.size, self.n, self.n), dtype=complex)
        for i, row in enumerate(self.entries):
            for j, e in enumerate(row):
                out[:, i, j] = e.freq(w)
        return out

    def poles(self) -> np.ndarray:
        """Union of the poles of all entries (with repetitions across entries removed)."""
        ps: list[complex] = []
        for row in self.entries:
            for e in row:
                for p in e.poles():
                    if not any(abs(p - q) <= 1e-9 * max(1.0, abs(p)) for q in ps):
                        ps.append(p)
        return np.array(ps, dtype=complex)

    def to_dict(self) -> dict[str, Any]:
        return {"type": self.kind, "ports": list(self.port_dofs),
                "matrix": [[e.to_dict() for e in row] for row in self.entries]}

    # -- immittance conversions --------------------------------------------------------------------
    def to(self, kind: ImmittanceKind) -> TransferMatrix:
        """Convert to another immittance type.

        Impedance ↔ admittance exist for any n-port (matrix inverse). Hybrid and inverse hybrid
        are two-port forms (each port may have m DOFs: then the formulas hold blockwise):

        * z → h:  h11 = z11 - z12 z22⁻¹ z21,  h12 = z12 z22⁻¹,  h21 = -z22⁻¹ z21,  h22 = z22⁻¹
        * g = h⁻¹

        Raises :class:`ConversionError` when the needed inverse does not exist (identically
        singular block). The whole chain (e.g. g → z → h) runs in exact arithmetic over Q(s), and
        the result stays exact: each entry is :meth:`Rational.of_exact` of the exact quotient, so
        the stability criteria decide the converted network itself; its float coefficients (for
        evaluation, plots and :meth:`to_dict`) are the nearest floats (a file written from them
        holds the rounded network, which can have another verdict on a boundary: issue 31,
        item 5). Arithmetic on converted entries uses their floats.
        """
        if kind not in KINDS:
            raise ModelError(f"unknown immittance type {kind!r}")
        if kind == self.kind:
            return self
        if kind in ("hybrid", "inverse_hybrid") and len(self.port_dofs) != 2:
            raise ConversionError("hybrid forms exist for two-ports only")
        Q = _to_rf(self.entries)
        pair = {"impedance": "admittance", "admittance": "impedance", "hybrid": "inverse_hybrid",
                "inverse_hybrid": "hybrid"}
        if pair[self.kind] == kind:  # z <-> y, h <-> g: one inverse
            out = _rf_inv(Q, _SINGULAR)
        else:
            m1 = self.port_dofs[0]
            if self.kind == "impedance":
                z = Q
            elif self.kind == "admittance":
                z = _rf_inv(Q, _SINGULAR)
            else:
                # h -> z is the same map as z -> h with the roles of the ports swapped:
                # z11 = h11 - h12 h22^-1 h21, z12 = h12 h22^-1, z21 = -h22^-1 h21, z22 = h22^-1
                z = _rf_z_to_h(Q if self.kind == "hybrid" else _rf_inv(Q, _SINGULAR), m1)
            if kind == "impedance":
                out = z
            elif kind == "admittance":
                out = _rf_inv(z, _SINGULAR)
            else:
                h = _rf_z_to_h(z, m1)
                out = h if kind == "hybrid" else _rf_inv(h, _SINGULAR)
        return TransferMatrix(_from_rf(out), kind, self.port_dofs, self.name)


# ---------------------------------------------------------------------------------------------
# conversions in exact rational arithmetic
#
# Float coefficients are exact binary rationals (float.as_integer_ratio), so the conversion
# formulas can be evaluated exactly over Q(s): python-flint's fmpq_poly carries the polynomials,
# _RF the field of rational functions (gcd-reduced, monic denominator), and the matrices are at
# most ~6x6, so plain Gauss-Jordan elimination is cheap. Factors shared by the entries (e.g. the
# characteristic polynomial of an SDEA) then cancel exactly instead of leaving near-cancelling
# pole/zero pairs; the results are kept exact (Rational.of_exact), with their floats rounded once.


class _RF:
    """An exact rational function n(s)/d(s) over Q: gcd(n, d) = 1, d monic, 0 = 0/1."""

    __slots__ = ("d", "n")

    def __init__(self, n: fmpq_poly, d: fmpq_poly, reduced: bool = False) -> None:
        if not reduced:
            if d.is_zero():
                raise ConversionError("division by an identically zero transfer function")
            if n.is_zero():
                n, d = fmpq_poly([]), fmpq_poly([1])
            else:
                g = n.gcd(d)
                if g.degree() > 0:
                    n, d = n // g, d // g
                lc = d[d.degree()]
                if lc != 1:
                    n, d = n / lc, d / lc
        self.n, self.d = n, d

    @staticmethod
    def of(r: Rational) -> _RF:
        return _RF(*r.exact)

    @property
    def is_zero(self) -> bool:
        return self.n.is_zero()

    # Henrici's algorithms: gcds of the small factors instead of one gcd of the full product,
    # which keeps the intermediate polynomials (and the Gauss-Jordan elimination) small.
    def __add__(self, o: _RF) -> _RF:
        if o.is_zero:
            return self
        if self.is_zero:
            return o
        g = self.d.gcd(o.d)
        if g.is_one():  # coprime denominators: the sum is already reduced
            return _RF(self.n * o.d + o.n * self.d, self.d * o.d, reduced=True)
        d1, d2 = self.d // g, o.d // g
        t = self.n * d2 + o.n * d1
        if t.is_zero():
            return _ZERO
        h = t.gcd(g)  # gcds are monic (FLINT), so is the denominator
        return _RF(t // h, d1 * d2 * (g // h), reduced=True)

    def __neg__(self) -> _RF:
        return _RF(-self.n, self.d, reduced=True)

    def __sub__(self, o: _RF) -> _RF:
        return self + (-o)

    def __mul__(self, o: _RF) -> _RF:
        if self.is_zero or o.is_zero:
            return _ZERO
        g1, g2 = self.n.gcd(o.d), o.n.gcd(self.d)
        return _RF((self.n // g1) * (o.n // g2), (self.d // g2) * (o.d // g1), reduced=True)

    def inv(self) -> _RF:
        if self.is_zero:
            raise ConversionError("division by an identically zero transfer function")
        lc = self.n[self.n.degree()]
        return _RF(self.d / lc, self.n / lc, reduced=True)

    def __truediv__(self, o: _RF) -> _RF:
        return self * o.inv()

    def to_rational(self) -> Rational:
        """The entry, exact: num and den divided (exactly) by den's largest |coefficient|, carried
        as exact polynomials with their floats the nearest ones (:meth:`Rational.of_exact`)."""
        sc = max(abs(self.d[k]) for k in range(self.d.degree() + 1))
        return Rational.of_exact(self.n / sc, self.d / sc)


_ZERO = _RF(fmpq_poly([]), fmpq_poly([1]), reduced=True)
_ONE = _RF(fmpq_poly([1]), fmpq_poly([1]), reduced=True)


def _qpoly(c: np.ndarray) -> fmpq_poly:
    """The exact rational polynomial (ascending coefficients) of float coefficients."""
    return fmpq_poly([fmpq(*float(v).as_integer_ratio()) for v in c])


def _qfloat(q: fmpq) -> float:
    """The float nearest to q (Python's int / int is correctly rounded)."""
    return int(q.p) / int(q.q)


def _qpoly_floats(p: fmpq_poly) -> list[float]:
    """The ascending coefficients of p, each the float nearest to it (as :func:`_qfloat`, from the
    integer numerator over the common denominator: one call into FLINT instead of one per
    coefficient); [] for the zero polynomial."""
    d = int(p.denom())
    return [int(v) / d for v in p.numer().coeffs()]


def _to_rf(M: Sequence[Sequence[Rational]]) -> list[list[_RF]]:
    return [[_RF.of(e) for e in row] for row in M]


def _from_rf(M: Sequence[Sequence[_RF]]) -> list[list[Rational]]:
    return [[e.to_rational() for e in row] for row in M]


def _rf_inv(A: Sequence[Sequence[_RF]], what: str) -> list[list[_RF]]:
    """Gauss-Jordan inverse over Q(s). Pivots: the nonzero entry of lowest total degree in the
    column (keeps intermediate expressions small; any nonzero pivot is exact). Raises
    :class:`ConversionError` naming ``what`` when the matrix is identically singular."""
    n = len(A)
    M = [list(A[i]) + [(_ONE if j == i else _ZERO) for j in range(n)] for i in range(n)]
    for c in range(n):
        cand = [r for r in range(c, n) if not M[r][c].is_zero]
        if not cand:
            raise ConversionError(what)
        p = min(cand, key=lambda r: M[r][c].n.degree() + M[r][c].d.degree())
        M[c], M[p] = M[p], M[c]
        piv = M[c][c]
        M[c] = [e / piv for e in M[c]]
        for r in range(n):
            f = M[r][c]
            if r != c and not f.is_zero:
                M[r] = [a - f * b for a, b in zip(M[r], M[c], strict=True)]
    return [row[n:] for row in M]


def _rf_det(A: Sequence[Sequence[_RF]]) -> _RF:
    """Determinant over Q(s) by Gaussian elimination (exactly zero for a singular matrix)."""
    M = [list(r) for r in A]
    n = len(M)
    det = _ONE
    for c in range(n):
        p = next((r for r in range(c, n) if not M[r][c].is_zero), None)
        if p is None:
            return _ZERO
        if p != c:
            M[c], M[p] = M[p], M[c]
            det = -det
        piv = M[c][c]
        det = det * piv
        for r in range(c + 1, n):
            f = M[r][c]
            if not f.is_zero:
                q = f / piv
                M[r] = [a - q * b for a, b in zip(M[r], M[c], strict=True)]
    return det


def _rf_matmul(A: Sequence[Sequence[_RF]], B: Sequence[Sequence[_RF]]) -> list[list[_RF]]:
    out = []
    for row in A:
        new = []
        for j in range(len(B[0])):
            acc = _ZERO
            for k, a in enumerate(row):
                if not a.is_zero and not B[k][j].is_zero:
                    acc = acc + a * B[k][j]
            new.append(acc)
        out.append(new)
    return out


_SINGULAR = "the matrix is identically singular: this immittance form does not exist"


def _rf_z_to_h(Q: list[list[_RF]], m1: int) -> list[list[_RF]]:
    """Block hybrid conversion over Q(s) (the same map also takes h to z):
    h11 = Z11 - Z12 Z22⁻¹ Z21, h12 = Z12 Z22⁻¹, h21 = -Z22⁻¹ Z21, h22 = Z22⁻¹."""
    Z11 = [r[:m1] for r in Q[:m1]]
    Z12 = [r[m1:] for r in Q[:m1]]
    Z21 = [r[:m1] for r in Q[m1:]]
    Z22 = [r[m1:] for r in Q[m1:]]
    Z22i = _rf_inv(Z22, "Z22 is identically singular: the hybrid form does not exist")
    H12 = _rf_matmul(Z12, Z22i)
    H11 = [[a - b for a, b in zip(ra, rb, strict=True)] for ra, rb in zip(Z11, _rf_matmul(H12, Z21), strict=True)]
    H21 = [[-e for e in r] for r in _rf_matmul(Z22i, Z21)]
    return [a + b for a, b in zip(H11, H12, strict=True)] + [a + b for a, b in zip(H21, Z22i, strict=True)]
