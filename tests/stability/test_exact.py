"""Exact sign decisions on x >= 0 against independent derivations (known roots, closed forms)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.polynomial import polynomial as P

from hil.stability.exact import decide_nonnegative, sturm_count_positive
from hil.stability.jpoly import JPoly, XPoly, jpoly_from_s


def X(c):
    c = np.asarray(c, float)
    return XPoly(c, np.abs(c))


roots_st = st.lists(st.floats(min_value=-50, max_value=50, allow_nan=False).filter(lambda r: abs(r) > 1e-3),
                    min_size=1, max_size=7)


@given(roots_st)
@settings(max_examples=60, deadline=None)
def test_sturm_counts_distinct_positive_roots(roots):
    # the count is exact: compare with the roots we built the polynomial from
    rs = sorted(set(round(r, 6) for r in roots))
    c = P.polyfromroots(rs)
    expected = sum(1 for r in rs if r > 0)
    assert sturm_count_positive(c) == expected


def test_touching_double_root_is_marginal_not_violated():
    d = decide_nonnegative(X(P.polyfromroots([2.0, 2.0, -1.0])))  # (x-2)^2 (x+1) >= 0, touches at 2
    assert d.status == "marginal"
    assert d.touching and d.touching[0] == pytest.approx(2.0, rel=1e-6)


def test_negative_band_located_exactly():
    # (x-1)^2 - 1e-6 < 0 exactly on (1 - 1e-3, 1 + 1e-3)
    d = decide_nonnegative(X([1 - 1e-6, -2.0, 1.0]))
    assert d.status == "violated"
    (lo, hi), = d.negative_bands
    assert lo == pytest.approx(1 - 1e-3, rel=1e-12) and hi == pytest.approx(1 + 1e-3, rel=1e-12)


def test_identically_zero_with_roundoff_is_equality():
    # the same quantity computed two ways and subtracted: zero up to round-off
    a = jpoly_from_s(np.array([160.0, 64.0])) * jpoly_from_s(np.array([120.0, 48.0]))
    b = jpoly_from_s(np.array([120.0, 48.0])) * jpoly_from_s(np.array([160.0, 64.0 * (1 + 2**-52)]))
    diff = (a - b).real()
    assert np.max(np.abs(diff.c)) > 0  # really not exactly zero in floating point
    assert decide_nonnegative(diff).status == "equality"


def test_dip_below_roundoff_is_marginal():
    # (x-1e4)^2 - eps^2 with a depth of ~1e-13 relative: below the 1e-10 tolerance
    c = X([1e8 - 1e-4, -2e4, 1.0])
    d = decide_nonnegative(c)
    assert d.status == "marginal"
    assert d.negative_bands  # the band exists exactly, but its depth is within round-off


def test_everywhere_negative_reports_full_band():
    d = decide_nonnegative(X([-1.0, 0.0, -2.0]))
    assert d.status == "violated" and d.negative_bands == [(0.0, math.inf)]


@given(st.lists(st.floats(min_value=0.01, max_value=1e3), min_size=1, max_size=4),
       st.floats(min_value=0.1, max_value=10))
@settings(max_examples=40, deadline=None)
def test_sum_of_squares_times_positive_never_violated(roots, k):
    # k * prod (x - r)^2 * (x + 1): non-negative on x >= 0 by construction
    c = np.array([k])
    for r in roots:
        c = P.polymul(c, P.polyfromroots([r, r]))
    c = P.polymul(c, [1.0, 1.0])
    assert decide_nonnegative(X(c)).status in ("satisfied", "marginal")


def test_jpoly_matches_direct_evaluation():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=5), rng.normal(size=4)
    w = np.geomspace(0.1, 10, 7)
    ja, jb = jpoly_from_s(a), jpoly_from_s(b)
    va, vb = P.polyval(1j * w, a), P.polyval(1j * w, b)
    np.testing.assert_allclose((ja * jb)(w), va * vb, rtol=1e-12)
    np.testing.assert_allclose((ja * jb.conj())(w), va * np.conj(vb), rtol=1e-12)
    np.testing.assert_allclose(ja.abs2()(w * w), np.abs(va) ** 2, rtol=1e-12)
    assert isinstance(JPoly.one(), JPoly)


@pytest.mark.parametrize("seed", range(30))
def test_descartes_subdivision_count_agrees_with_sturm_and_constructed_roots(seed):
    """The exact positive-root count (Descartes/continued fractions over Z, exact._vas_count) against
    polynomials built from known roots (positive ones over 12 decades, clustered pairs, negative
    and complex ones) and against an independent Sturm count over Q."""
    from fractions import Fraction

    from flint import fmpq, fmpq_poly

    from hil.stability.exact import _sturm_count_q, _vas_count

    rng = np.random.default_rng(seed)
    f = fmpq_poly([int(rng.integers(1, 9))])
    n_pos = int(rng.integers(0, 5))
    roots = set()
    for _ in range(n_pos):
        r = Fraction(10.0 ** rng.uniform(-6, 6)).limit_denominator(10**12)
        while r in roots:
            r *= 2
        roots.add(r)
        f *= fmpq_poly([fmpq(-r.numerator, r.denominator), 1])
        if rng.random() < 0.3:  # a close partner: relative separation 1e-9
            r2 = r * (1 + Fraction(1, 10**9))
            roots.add(r2)
            f *= fmpq_poly([fmpq(-r2.numerator, r2.denominator), 1])
    for _ in range(int(rng.integers(0, 3))):
        q = Fraction(10.0 ** rng.uniform(-3, 3)).limit_denominator(10**9)
        f *= fmpq_poly([fmpq(q.numerator, q.denominator), 1])  # a negative root
    for _ in range(int(rng.integers(0, 3))):
        a, b = rng.uniform(-5, 5), 10.0 ** rng.uniform(-2, 2)  # complex pair (x - a)² + b²
        c0, c1 = Fraction(a * a + b * b), Fraction(-2 * a)
        f *= fmpq_poly([fmpq(c0.numerator, c0.denominator), fmpq(c1.numerator, c1.denominator), 1])
    assert _vas_count(f.numer()) == len(roots)
    assert _sturm_count_q(f) == len(roots)
