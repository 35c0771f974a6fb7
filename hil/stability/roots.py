"""The roots of an exact polynomial, isolated rigorously and located to double precision.

Every pole the stability core names (a right-half-plane pole in the evidence of condition C, the
poles behind C's margin) is a root of an exact denominator (``flint.fmpq_poly``: the float
coefficients read as the binary rationals they are). :func:`isolate_roots` classifies each root
exactly and locates it numerically:

* the count in each region is exact: the order of the root at s = 0 from the trailing zero
  coefficients; for every squarefree factor f of the rest (FLINT's squarefree decomposition gives
  the multiplicities), the open right-half-plane count and the imaginary-axis pairs from
  :func:`hil.stability.exact.exact_poles` (Routh-Hurwitz in Cauchy-index form, gcd of the even and
  odd parts; no rounding);
* the locations come from FLINT/Arb's rigorous complex root isolation of f's integer polynomial
  (``fmpz_poly.complex_roots``: disjoint balls, one root each). A ball whose real part is certainly
  positive (negative) holds a right-half-plane (left-half-plane) root. The working precision is
  doubled (53, 106, ... 4096 bits) until the certified counts equal the exact ones; the balls left
  uncertain are then exactly the imaginary-axis roots, reported with real part 0.

So a right-half-plane pole at 1e-13 of its modulus from the axis, which ``numpy.roots`` places on
either side, is named on the right side, and none is ever confused with the pole at s = 0 (issue
31, item 1). The values are the balls' midpoints (each within the ball's radius, far below double
precision, of the root).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any, Literal, cast

from flint import ctx, fmpq_poly

from hil.errors import ModelError

logger = logging.getLogger(__name__)

__all__ = ["Root", "isolate_roots", "rhp_roots"]

Region = Literal["rhp", "lhp", "axis", "origin"]

#: working precisions (bits) tried in turn by :func:`isolate_roots`
_PRECISIONS = (53, 106, 212, 424, 848, 1696, 4096)


@dataclass(frozen=True)
class Root:
    """One distinct root: ``value`` (the midpoint of its isolating ball; real part exactly 0 for
    an imaginary-axis root and 0 for the root at the origin), its ``multiplicity`` in the
    polynomial and its exact ``region``."""

    value: complex
    multiplicity: int
    region: Region


def _balls(z: Any, prec: int) -> list[Any]:
    """Arb's isolating balls of the squarefree integer polynomial ``z`` at working precision
    ``prec`` (the context precision restored afterwards)."""
    old = ctx.prec
    ctx.prec = prec
    try:
        return [r for r, _m in cast("list[tuple[Any, int]]", z.complex_roots())]
    finally:
        ctx.prec = old


def _factor_roots(f: fmpq_poly, mult: int, hurwitz: bool) -> list[Root]:
    """The roots of a squarefree factor f (f(0) ≠ 0), classified exactly (see the module);
    ``hurwitz``: f is known to be strictly Hurwitz (every root in the open left-half plane)."""
    from hil.stability.exact import exact_poles

    if hurwitz:
        n_axis = n_rhp = 0
    else:
        ep = exact_poles(f)
        n_axis, n_rhp = 2 * len(ep.axis), ep.n_rhp
    n_lhp = f.degree() - n_rhp - n_axis
    z = f.numer()
    for prec in _PRECISIONS:
        rhp, lhp, axis = [], [], []
        for r in _balls(z, prec):
            v = complex(float(r.real.mid()), float(r.imag.mid()))
            if r.real > 0:
                rhp.append(v)
            elif r.real < 0:
                lhp.append(v)
            else:
                axis.append(complex(0.0, v.imag))
        if (len(rhp), len(lhp), len(axis)) == (n_rhp, n_lhp, n_axis):
            return ([Root(v, mult, "rhp") for v in rhp] + [Root(v, mult, "lhp") for v in lhp]
                    + [Root(v, mult, "axis") for v in axis])
    raise ModelError(f"the roots of a degree-{f.degree()} denominator could not be separated from the imaginary "
                     f"axis at {_PRECISIONS[-1]} bits")  # pragma: no cover - roots closer than 2^-4000


def isolate_roots(d: fmpq_poly, hurwitz: bool = False) -> list[Root]:
    """Every distinct root of the exact polynomial ``d`` (in s) with its multiplicity and exact
    region (``rhp``: open right-half plane, ``lhp``: open left-half plane, ``axis``: s = ±jω with
    ω > 0, ``origin``: s = 0), located to double precision; sorted by region, then by value.
    ``hurwitz``: the caller has proved d/s^k strictly Hurwitz (the exact counts are then known)."""
    if d.is_zero():
        raise ModelError("the zero polynomial has no isolated roots")
    k0 = 0
    while d[k0] == 0:
        k0 += 1
    out: list[Root] = [Root(0j, k0, "origin")] if k0 else []
    rest = d // fmpq_poly([0] * k0 + [1]) if k0 else d
    if rest.degree() > 0:
        _c, facs = rest.factor_squarefree()
        for f, e in facs:
            out += _factor_roots(f, int(e), hurwitz)
    order = {"rhp": 0, "axis": 1, "origin": 2, "lhp": 3}
    return sorted(out, key=lambda r: (order[r.region], -r.value.real, r.value.imag))


def rhp_roots(d: fmpq_poly) -> list[complex]:
    """The open right-half-plane roots of ``d``, each repeated by its multiplicity, rightmost
    first (exact count, exact classification, double-precision values)."""
    return [r.value for r in isolate_roots(d) if r.region == "rhp" for _ in range(r.multiplicity)]
