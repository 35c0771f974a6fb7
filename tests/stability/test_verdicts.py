"""Issue 11, defects 1, 3, 6: one meaning per verdict, exact conversions, a defined margin.

The reference used here is independent of the library: the condition Re Z(jω) ≥ 0 of a one-port
is formed with Python Fractions (the float coefficients read as the binary rationals they are)
and its sign structure on x = ω² ≥ 0 is decided by a Sturm sequence written below, in Fractions.
Random networks come from seeded numpy generators (no hypothesis).
"""

from __future__ import annotations

import itertools
import math
from fractions import Fraction

import numpy as np
import pytest

from hil.errors import ConversionError
from hil.stability.criteria import Tolerances, check, llewellyn, positive_real, two_port_passivity
from hil.stability.rational import Rational, S, TransferMatrix

# ------------------------------------------------------------------------------------------------
# independent exact reference (Fractions only)


def _re_poly(num_asc, den_asc) -> list[Fraction]:
    """Re(N(jω)·D(-jω)) as ascending Fraction coefficients in x = ω² (sign of Re Z, |D|² > 0)."""
    def split(c):
        a, b = {}, {}
        for k, v in enumerate(c):
            f = Fraction(float(v)) * (1 if (k // 2) % 2 == 0 else -1)
            (a if k % 2 == 0 else b)[k // 2] = f
        return a, b
    na, nb = split(num_asc)
    da, db = split(den_asc)
    out: dict[int, Fraction] = {}
    # N(jω) D(-jω) = (na + jω nb)(da - jω db): real part na·da + x·nb·db
    for i, u in na.items():
        for j, v in da.items():
            out[i + j] = out.get(i + j, Fraction(0)) + u * v
    for i, u in nb.items():
        for j, v in db.items():
            out[i + j + 1] = out.get(i + j + 1, Fraction(0)) + u * v
    n = max(out) + 1 if out else 1
    c = [out.get(k, Fraction(0)) for k in range(n)]
    while len(c) > 1 and c[-1] == 0:
        c.pop()
    return c


def _rem(a: list[Fraction], b: list[Fraction]) -> list[Fraction]:
    """Remainder of a by b over Q (ascending coefficient lists)."""
    a = list(a)
    while len(a) >= len(b) and any(a):
        f = a[-1] / b[-1]
        sh = len(a) - len(b)
        for i, v in enumerate(b):
            a[sh + i] -= f * v
        a.pop()
        while len(a) > 1 and a[-1] == 0:
            a.pop()
    return a or [Fraction(0)]


def _ev(p: list[Fraction], x: Fraction) -> Fraction:
    acc = Fraction(0)
    for v in reversed(p):
        acc = acc * x + v
    return acc


def _ref_negative_somewhere(c: list[Fraction]) -> bool:
    """Exact: is the polynomial c (ascending Fractions) negative somewhere on x > 0?

    Sturm's theorem counts the distinct roots in (a, b]; bisection at points that are not roots
    isolates them; p has one sign on each gap between consecutive roots, and every gap contains a
    bisection point (or is (0, r1), whose sign is p(0+) = sign of the lowest coefficient, or
    (rN, ∞), the sign of the leading one). p < 0 somewhere iff one of those signs is negative."""
    while len(c) > 1 and c[0] == 0:
        c = c[1:]
    if len(c) == 1:
        return c[0] < 0
    if c[0] < 0 or c[-1] < 0:
        return True
    seq = [c, [k * v for k, v in enumerate(c)][1:]]
    while len(seq[-1]) > 1:
        r = _rem(seq[-2], seq[-1])
        if not any(r):
            break
        seq.append([-v for v in r])

    def var(x: Fraction) -> int:
        sg = [v for v in (_ev(p, x) for p in seq) if v != 0]
        return sum(1 for u, w in itertools.pairwise(sg) if (u > 0) != (w > 0))

    bound = 1 + max(abs(v / c[-1]) for v in c[:-1])
    pts = {Fraction(0), Fraction(bound)}
    stack = [(Fraction(0), Fraction(bound))]
    while stack:
        lo, hi = stack.pop()
        if var(lo) - var(hi) <= 1:
            continue
        m = (lo + hi) / 2
        k = 3
        while _ev(c, m) == 0:  # bisection points must not be roots
            m = lo + (hi - lo) / k
            k += 1
        pts.add(m)
        stack += [(lo, m), (m, hi)]
    # every gap between consecutive distinct roots now contains a point of pts (a count-1 interval
    # (lo, hi] holds one root; its neighbours' points bound the gaps) -- except a root exactly at a
    # point, which cannot happen: bisection points are not roots and 0, bound are not roots
    return any(_ev(c, x) < 0 for x in pts if x > 0)


def _random_stable_den(rng, deg: int) -> np.ndarray:
    if deg <= 0:
        return np.array([1.0])
    roots = []
    while len(roots) < deg:
        if deg - len(roots) >= 2 and rng.random() < 0.6:
            w = 10 ** rng.uniform(-1, 1)
            z = 10 ** rng.uniform(-3, 0)
            wd = w * math.sqrt(max(1 - z * z, 0))
            roots += [complex(-z * w, wd), complex(-z * w, -wd)]
        else:
            roots.append(complex(-(10 ** rng.uniform(-1, 1)), 0))
    return np.real(np.poly(roots))[::-1]


def _min_re_over_abs(z: Rational) -> tuple[float, float]:
    w = np.geomspace(1e-3, 1e3, 40001)
    v = z.freq(w)
    r = v.real / np.abs(v)
    i = int(np.argmin(r))
    return float(r[i]), float(w[i])


def _scaled(z: Rational, a: float, b: float) -> Rational:
    """b·Z(s/a): impedance scaled by b, frequency by a."""
    return Rational(b * z.num / a ** np.arange(z.num.size), z.den / a ** np.arange(z.den.size))


# ------------------------------------------------------------------------------------------------
# defect 1: reproducers


@pytest.mark.parametrize("zeta", [1e-5, 1e-7, 1e-9, 1e-12])
@pytest.mark.parametrize("w0", [1e-3, 0.37, 1.0, 1e3])
@pytest.mark.parametrize("b", [1e-4, 1.0, 3e4])
def test_lightly_damped_negative_resonance_is_potentially_unstable(zeta, w0, b):
    # Z = b(1 - c·2ζω0 s/(s² + 2ζω0 s + ω0²)), c = 1.01: Re Z(jω0)/|Z| = -1 at ω0
    c = 1.01
    z = b * (1 - c * 2 * zeta * w0 * S / (S**2 + 2 * zeta * w0 * S + w0**2))
    r = positive_real(z)
    assert str(r.verdict) == "potentially_unstable", r.summary()
    assert r.failed_condition == "E{1}"
    # the independent exact reference agrees that Re Z < 0 somewhere
    assert _ref_negative_somewhere(_re_poly(z.num, z.den))
    (lo, hi), = r.condition("E{1}").evidence["negative_bands_rad_s"]
    assert lo <= w0 * (1 + 1e-9) and hi >= w0 * (1 - 1e-9)
    assert r.margin < 0


def test_active_two_port_with_tiny_negative_margin_is_potentially_unstable():
    # resistive coupling slightly too strong: b1 b2 - c² = 1 - (1 + 8.5e-7)² ≈ -1.7e-6
    c = 1 + 8.5e-7
    one = 1 + 0 * S
    tm = TransferMatrix([[0.2 * S + 1, c * one], [c * one, 0.5 * S + 1]], "impedance", (1, 1))
    for r in (two_port_passivity(tm), llewellyn(tm)):
        assert str(r.verdict) == "potentially_unstable", r.summary()
        assert r.failed_condition == "E{1,2}"
        # margin definition: p/m_r with p = 4(1 - c²), m = 4(1 + c²) (constant in x): the passivity
        # minor (2·1)(2·1) - (2c)² over its magnitude, and Llewellyn's L2 = (2 - c²)² - c⁴ over
        # 4·1·(1 + c²) -- the same ratio, ≈ -8.5e-7
        assert r.condition("E{1,2}").margin == pytest.approx((1 - c * c) / (1 + c * c), rel=1e-6)


def test_sdea_just_above_k22_max_is_potentially_unstable_and_just_below_stable():
    from hil.models.design import k22_max
    from hil.models.sdea import sdea_vsic

    km = k22_max(0.17, 1.0, "passivity").k22_max
    assert str(two_port_passivity(sdea_vsic(k22=km * (1 - 1e-6))).verdict) == "stable"
    r = two_port_passivity(sdea_vsic(k22=km * (1 + 1e-6)))
    assert str(r.verdict) == "potentially_unstable" and r.margin < 0


# ------------------------------------------------------------------------------------------------
# touching / equality is stable (weak where equality), never potentially_unstable


@pytest.mark.parametrize("z,weak", [
    (S / (S**2 + 1) + 1, False),  # LC tank plus resistor: Re Z = 1
    (S / (S**2 + 1), True),  # lossless: Re Z ≡ 0
    (Rational.from_desc([1.0, 0.0, 100.0], [1.0, 6.0, 100.0]), True),  # touches 0 at ω = 10
    ((S**2 + 4) / (S**2 + S + 4) + S / (S**2 + 1), True),  # touches at 2, tank at 1
    (2 * S + 3 / S, True),  # mass and spring: lossless
])
def test_touching_and_equality_are_stable(z, weak):
    r = positive_real(z)
    assert str(r.verdict) == "stable", r.summary()
    assert r.weak is weak


def test_exact_equality_case_study_is_weakly_stable():
    from hil.models.teleop import mcet_trilateral

    r = check(mcet_trilateral(k_vm1=64))
    assert str(r.verdict) == "stable" and r.weak


# ------------------------------------------------------------------------------------------------
# defect 3: exact conversions; the T-network in four forms


# T-network: z1 = 1 (damper, port 1), z2 = 2s (mass, port 2), z3 = 3/s (spring, shunt), derived by
# hand: Δ = z1 z2 + z1 z3 + z2 z3 = (2s² + 6s + 3)/s
T_FORMS = {
    "impedance": [[{"num": [1, 3], "den": [1, 0]}, {"num": [3], "den": [1, 0]}],
                  [{"num": [3], "den": [1, 0]}, {"num": [2, 0, 3], "den": [1, 0]}]],
    "admittance": [[{"num": [2, 0, 3], "den": [2, 6, 3]}, {"num": [-3], "den": [2, 6, 3]}],
                   [{"num": [-3], "den": [2, 6, 3]}, {"num": [1, 3], "den": [2, 6, 3]}]],
    "hybrid": [[{"num": [2, 6, 3], "den": [2, 0, 3]}, {"num": [3], "den": [2, 0, 3]}],
               [{"num": [-3], "den": [2, 0, 3]}, {"num": [1, 0], "den": [2, 0, 3]}]],
    "inverse_hybrid": [[{"num": [1, 0], "den": [1, 3]}, {"num": [-3], "den": [1, 3]}],
                       [{"num": [3], "den": [1, 3]}, {"num": [2, 6, 3], "den": [1, 3]}]],
}


@pytest.mark.parametrize("kind", list(T_FORMS))
def test_passive_t_network_is_stable_in_every_form(kind):
    tm = TransferMatrix.from_coefficients(T_FORMS[kind], kind)
    # the hand-derived form is the library's conversion of the impedance (independent check)
    z = TransferMatrix.from_coefficients(T_FORMS["impedance"], "impedance")
    s0 = 0.3 + 1.7j
    A = np.array([[e(s0) for e in row] for row in tm.entries])
    B = np.array([[e(s0) for e in row] for row in z.to(kind).entries])
    assert np.max(np.abs(A - B)) < 1e-12
    for r in (two_port_passivity(tm), llewellyn(tm), two_port_passivity(z.to(kind))):
        assert str(r.verdict) == "stable", r.summary()


def test_common_denominator_is_exact_lcm_and_refuses_near_divisibility():
    from hil.stability.criteria import _axis_factor
    from hil.stability.rational import _exact_quotient, _qpoly

    a = np.array([3.0, 4.0, 1.0])  # (s + 1)(s + 3)
    b = np.array([1.0, 1.0])
    assert np.array_equal(_exact_quotient(a, b), np.array([3.0, 1.0]))
    assert _exact_quotient(a + np.array([1e-13, 0, 0]), b) is None  # near-divisible is not divisible
    # the common denominator of the frequency conditions is the exact lcm over Q[s]
    D, _h, _mu = _axis_factor([_qpoly(a), _qpoly(b)])
    assert _qpoly(a) == D
    D2, _h, _mu = _axis_factor([_qpoly(a + np.array([1e-13, 0, 0])), _qpoly(b)])
    assert D2.degree() == 3  # the perturbed denominator does not contain (s + 1): the lcm is the product


def _random_two_port(rng, active: bool) -> TransferMatrix:
    m1, m2 = rng.uniform(0.1, 2, size=2)
    b1, b2, bc = rng.uniform(0.1, 2, size=3)
    kc = rng.uniform(1, 50)
    g = rng.uniform(0.0, 0.5)
    neg = rng.uniform(0.5, 2.0) if active else 0.0
    zc = (bc * S + kc) / S
    return TransferMatrix([[m1 * S + (b1 - neg * (b1 + bc)) + zc, -zc * (1 + g)],
                           [-zc * (1 - g), m2 * S + b2 + zc]], "impedance", (1, 1))


@pytest.mark.parametrize("seed", range(12))
def test_verdict_invariant_under_conversion_and_scaling(seed):
    rng = np.random.default_rng(1000 + seed)
    z = _random_two_port(rng, active=bool(seed % 2))
    base = {"p": two_port_passivity(z).verdict, "l": llewellyn(z).verdict}
    assert "marginal" not in base.values()
    for kind in ("admittance", "hybrid", "inverse_hybrid"):
        try:
            other = z.to(kind)
        except ConversionError:
            continue
        assert two_port_passivity(other).verdict == base["p"], kind
        assert llewellyn(other).verdict == base["l"], kind
    for _ in range(3):
        a, b = 10 ** rng.uniform(-6, 6), 10 ** rng.uniform(-6, 6)
        zs = TransferMatrix([[_scaled(e, a, b) for e in row] for row in z.entries], "impedance", (1, 1))
        assert two_port_passivity(zs).verdict == base["p"]
        assert llewellyn(zs).verdict == base["l"]


# ------------------------------------------------------------------------------------------------
# property: clear violations are always potentially_unstable; agreement with the reference


@pytest.mark.parametrize("seed", range(16))
def test_clear_violation_is_always_potentially_unstable_at_any_scale(seed):
    rng = np.random.default_rng(seed)
    for _attempt in range(50):
        den = _random_stable_den(rng, int(rng.integers(2, 6)))
        num = _random_stable_den(rng, den.size - 1) * 10 ** rng.uniform(-1, 1)
        z0 = Rational(num, den)
        rmin, _w = _min_re_over_abs(z0)
        # shift by a constant so that min Re Z/|Z| is clearly negative: depth 1e-8 .. 1e-3 below zero
        depth = 10 ** rng.uniform(-8, -3)
        zz = z0 - (rmin + depth) * float(np.min(np.abs(z0.freq(np.geomspace(1e-3, 1e3, 40001)))))
        if _min_re_over_abs(zz)[0] <= -1e-8:  # the grid confirms a clear violation
            break
    else:  # pragma: no cover
        raise AssertionError("no clear violation generated")
    assert _ref_negative_somewhere(_re_poly(zz.num, zz.den))
    for _ in range(4):
        a, b = 10 ** rng.uniform(-6, 6), 10 ** rng.uniform(-6, 6)
        r = positive_real(_scaled(zz, a, b))
        assert str(r.verdict) == "potentially_unstable", (a, b, r.summary())


@pytest.mark.parametrize("seed", range(40))
def test_real_part_condition_agrees_with_the_exact_reference(seed):
    rng = np.random.default_rng(500 + seed)
    den = _random_stable_den(rng, int(rng.integers(1, 6)))
    num = _random_stable_den(rng, den.size - 1 - int(rng.integers(0, 2))) * 10 ** rng.uniform(-2, 2)
    z0 = Rational(num, den)
    rmin, _ = _min_re_over_abs(z0)
    # boundary-near shifts: from 1e-3 on the passive side to 1e-3 on the active side
    shift = (rmin + float(rng.choice([-1, 1])) * 10 ** rng.uniform(-12, -3)) * float(
        np.min(np.abs(z0.freq(np.geomspace(1e-3, 1e3, 4001)))))
    zz = z0 - shift
    ref_bad = _ref_negative_somewhere(_re_poly(zz.num, zz.den))
    e = positive_real(zz).condition("E{1}")
    assert (e.status == "violated") is ref_bad, (e.status, e.evidence["polynomial_x_desc"])


# ------------------------------------------------------------------------------------------------
# defect 6: the frequency-domain margin (docs/VERDICTS.md) and its defining properties


def test_margin_goes_to_zero_at_the_boundary_and_is_monotone():
    # Z_ε = (s² + ε s + 1)/(s² + s + 1): Re(N D*) = (1 - x)² + ε x, touching at ε = 0
    # (ε = 1 would be (s² + s + 1)/(s² + s + 1) = 1: reduced first, a resistor, margin 1)
    eps = [0.9, 0.3, 1e-1, 1e-2, 1e-4, 1e-6, 1e-9]
    ms = [positive_real(Rational.from_desc([1.0, e, 1.0], [1.0, 1.0, 1.0])).condition("E{1}").margin for e in eps]
    assert all(0 < m <= 1 for m in ms)
    assert all(a > b for a, b in itertools.pairwise(ms))
    assert ms[-1] < 1e-8
    # closed form: p = x² + (ε - 2)x + 1, m = x² + (ε + 2)x + 1 (same degree range); the minimum of
    # p/m over x ≥ 0 is at x = 1 by symmetry (p/m is invariant under x -> 1/x): ε/(ε + 4)
    for e, m in zip(eps, ms, strict=True):
        assert m == pytest.approx(e / (e + 4), rel=1e-6)
    assert positive_real(Rational.from_desc([1.0, 0.0, 1.0], [1.0, 1.0, 1.0])).condition("E{1}").status == "equality"
    r = positive_real(Rational.from_desc([1.0, -1e-6, 1.0], [1.0, 1.0, 1.0]))
    assert str(r.verdict) == "potentially_unstable" and r.margin < 0


def test_margin_factors_out_structural_zeros_exactly():
    # Z = (m s² + b s + k)/s: Re Z·|s|² = b x vanishes at x = 0 by structure; its margin is p/m_r = 1
    r = positive_real((0.5 * S**2 + 2 * S + 7) / S)
    assert r.condition("E{1}").margin == pytest.approx(1.0)
    # a grid starting at 1e-2 × the smallest pole/zero would have reported Re Z/|Z| ≈ 0 instead
    z = (0.5 * S**2 + 2 * S + 7) / S
    v = z.freq(np.array([1e-4]))
    assert v.real / abs(v) < 1e-3


@pytest.mark.parametrize("a", [2.0**-20, 1e-6, 0.37, 1e3, 2.0**19, 1e6])
@pytest.mark.parametrize("b", [2.0**-20, 1e-6, 3.1, 1e6])
def test_margin_is_invariant_under_frequency_and_impedance_scaling(a, b):
    z = Rational.from_desc([1.0, 0.3, 2.0], [1.0, 1.0, 1.0])
    m0 = positive_real(z).condition("E{1}").margin
    m1 = positive_real(_scaled(z, a, b)).condition("E{1}").margin
    assert m1 == pytest.approx(m0, rel=1e-9)


def test_sdea_margin_tends_to_zero_at_k22_max_and_is_monotone():
    from hil.models.design import k22_max
    from hil.models.sdea import sdea_vsic

    km = k22_max(0.17, 1.0, "passivity").k22_max
    ks = [50.0, 100.0, 200.0, 300.0, 400.0, km * (1 - 1e-3), km * (1 - 1e-5), km * (1 - 1e-7)]
    ms = [two_port_passivity(sdea_vsic(k22=k)).margin for k in ks]
    assert all(m > 0 for m in ms)
    assert all(x > y for x, y in itertools.pairwise(ms)), ms
    assert ms[-1] < 1e-3 * ms[3]  # near k22_max the margin is a vanishing fraction of the nominal one
    assert two_port_passivity(sdea_vsic(k22=km * (1 + 1e-5))).margin < 0


def test_rtol_marginal_means_the_verdict_can_flip():
    z = Rational.from_desc([1.0, 1e-6, 1.0], [1.0, 1.0, 1.0])  # margin 1e-6/(4 + 1e-6)
    assert str(positive_real(z).verdict) == "stable"
    # Re-condition K = 2 coefficient factors per term: a flip needs (1 + r)² - 1 ≥ margin
    assert str(positive_real(z, Tolerances(rtol=1e-6)).verdict) == "marginal"
    assert str(positive_real(z, Tolerances(rtol=1e-9)).verdict) == "stable"
    bad = Rational.from_desc([1.0, -1e-6, 1.0], [1.0, 1.0, 1.0])
    assert str(positive_real(bad, Tolerances(rtol=1e-6)).verdict) == "marginal"
    assert str(positive_real(bad, Tolerances(rtol=1e-9)).verdict) == "potentially_unstable"


def test_margin_curve_minimum_is_the_reported_margin():
    from hil.models.sdea import sdea_vsic
    from hil.stability.criteria import margin_curve

    z = Rational.from_desc([1.0, 0.3, 2.0], [1.0, 1.0, 1.0])
    e = positive_real(z).condition("E{1}")
    f = margin_curve(z, "E{1}")
    w = np.geomspace(1e-4, 1e4, 20001)
    v = f(w)
    assert np.all(v >= e.margin - 1e-12) and np.all(np.abs(v) <= 1)
    assert float(f(np.array([e.worst_frequency]))[0]) == pytest.approx(e.margin, rel=1e-9)
    # the SDEA's binding condition: the curve's value near ω = 0 approaches the margin
    tm = sdea_vsic()
    r = two_port_passivity(tm)
    g = margin_curve(tm, "E{1,2}")
    assert float(g(np.array([1e-6]))[0]) == pytest.approx(r.condition("E{1,2}").margin, rel=1e-3)


@pytest.mark.parametrize("seed", range(20))
def test_exact_pole_classification_matches_roots_by_construction(seed):
    # d(s) = s^k0 · ∏(s - r) · ∏(s² + w²)^e · ∏((s - a)² + b²) with chosen roots (dyadic values,
    # so the float coefficients are exact): the counts are known by construction
    from flint import fmpq, fmpq_poly

    from hil.stability.exact import exact_poles

    rng = np.random.default_rng(seed)
    d = fmpq_poly([1])
    n_rhp, axis = 0, {}
    k0 = int(rng.integers(0, 2))
    d *= fmpq_poly([0] * k0 + [1])
    for _ in range(int(rng.integers(1, 4))):
        r = fmpq(int(rng.integers(-64, 65)) or 1, 16)
        d *= fmpq_poly([-r, 1])
        n_rhp += r > 0
    for _ in range(int(rng.integers(0, 3))):
        w2 = fmpq(int(rng.integers(1, 200)), 8)
        e = int(rng.integers(1, 3))
        d *= fmpq_poly([w2, 0, 1]) ** e
        axis[float(w2)] = axis.get(float(w2), 0) + e
    for _ in range(int(rng.integers(0, 3))):
        a, b = fmpq(int(rng.integers(-40, 41)) or 3, 8), fmpq(int(rng.integers(1, 40)), 8)
        d *= fmpq_poly([a * a + b * b, -2 * a, 1])
        n_rhp += 2 * (a > 0)
    ep = exact_poles(d)
    assert ep.n_rhp == n_rhp and ep.n_zero == k0
    got = {}
    for x, mult in ep.axis:
        key = min(axis, key=lambda w: abs(w - x)) if axis else x
        assert abs(key - x) <= 1e-9 * key
        got[key] = got.get(key, 0) + mult
    assert got == axis
