"""Issue 11: residues at finite imaginary-axis poles are decided exactly (hil.stability.residues):
realness / Hermitian symmetry by exact remainders modulo the irreducible axis factor f(x), signs by
a Sturm-Tarski query at the isolated root. Compared with closed-form residues in Fractions."""

from fractions import Fraction

import pytest
from flint import fmpq, fmpq_poly

from hil.stability.criteria import Tolerances, absolute_stability, llewellyn, positive_real
from hil.stability.rational import Rational, S, TransferMatrix
from hil.stability.residues import axis_poles, positive_root_intervals, sign_at_root


def _axis_conds(r):
    return [c for c in r.conditions if c.name.startswith("D[ω=") and c.name != "D[ω=∞]"]


def test_tank_plus_resistor_residue_is_exactly_one_half():
    r = positive_real(1 + S / (S**2 + 1))
    assert str(r.verdict) == "stable" and not r.weak
    (d,) = _axis_conds(r)
    assert d.status == "satisfied"
    # closed form: s/(s² + 1) at s = j has residue j/(2j) = 1/2, real
    assert d.evidence["residues_exact"] == [[{"re": "1/2", "im_over_omega": "0"}]]
    assert d.evidence["decision"].startswith("exact")


@pytest.mark.parametrize("a", [1e-6, 3.7e-4, 1.0, 0.3, 2.9e3, 1e6])
@pytest.mark.parametrize("b", [1e-6, 0.1, 7.0, 1e6])
@pytest.mark.parametrize("c", [1.0, 2.0, 0.3])
def test_scaled_lossless_foster_is_weakly_stable_with_the_exact_residue(a, b, c):
    # Z(s) = b·(a s)/((a s)² + c): the float coefficients n1 = fl(a b), d2 = fl(a²), d0 = c are the
    # network; the pole s0² = -d0/d2 is rational and the residue n1 s0/(2 d2 s0) = n1/(2 d2)
    # exactly (hand derivation in Fractions, no rounding)
    n1, d2 = a * b, a * a
    z = Rational.from_desc([n1, 0.0], [d2, 0.0, c])
    r = positive_real(z)
    assert str(r.verdict) == "stable" and r.weak, r.summary()  # Re Z ≡ 0: equality
    (d,) = _axis_conds(r)
    assert d.status == "satisfied"
    ex = d.evidence["residues_exact"][0][0]
    assert Fraction(ex["re"]) == Fraction(n1) / (2 * Fraction(d2))
    assert Fraction(ex["im_over_omega"]) == 0
    assert float(d.name[4:-1]) == pytest.approx(float(Fraction(c) / Fraction(d2)) ** 0.5, rel=1e-5)


def test_negative_residue_is_potentially_unstable():
    r = positive_real(1 - S / (S**2 + 1))
    assert str(r.verdict) == "potentially_unstable" and r.failed_condition == "D[ω=1]"
    (d,) = _axis_conds(r)
    assert d.status == "violated" and d.margin < 0
    assert d.evidence["residues_exact"] == [[{"re": "-1/2", "im_over_omega": "0"}]]
    # the frequency condition alone holds: Re Z(jω) = 1
    assert r.condition("E{1}").status == "satisfied"


def test_complex_residue_is_potentially_unstable():
    # (s + 2)/(s² + 1) + 3: residue at j is (j + 2)/(2j) = 1/2 - j, not real
    z = (S + 2) / (S**2 + 1) + 3
    r = positive_real(z)
    assert str(r.verdict) == "potentially_unstable"
    (d,) = _axis_conds(r)
    assert d.status == "violated" and "not real" in d.detail
    ex = d.evidence["residues_exact"][0][0]
    # Re K = 1/2, Im K = ω0·(-1) with ω0 = 1
    assert Fraction(ex["re"]) == Fraction(1, 2) and Fraction(ex["im_over_omega"]) == -1


def test_complex_residue_of_relative_size_1e_minus_16_is_still_complex():
    # the imaginary part of the residue is n0 - n2·ω0² over 2ω0: 2^-50 relative here, far below any
    # float tolerance, and decided exactly
    eps = 2.0**-50
    z = Rational.from_desc([1.0, 1.0, 1.0 + eps], [1.0, 0.0, 1.0])  # 1 + (s + eps)/(s² + 1)
    (d,) = _axis_conds(positive_real(z))
    assert d.status == "violated"
    assert Fraction(d.evidence["residues_exact"][0][0]["im_over_omega"]) == -Fraction(eps) / 2
    # with a tolerance on the inputs far above 2^-50 it is marginal
    (dm,) = _axis_conds(positive_real(z, Tolerances(rtol=1e-12)))
    assert dm.status == "marginal"


def test_residue_signs_differ_at_two_roots_of_one_irreducible_factor():
    # s²-roots of s⁴ + 4s² + 1: ω² = 2 ∓ √3 (one irreducible factor x² - 4x + 1 over Q). Foster:
    # s(s² + c)/((s² + a)(s² + b)) has residues (c - a)/(2(b - a)) at j√a and (b - c)/(2(b - a)) at
    # j√b (a < b): both ≥ 0 iff a ≤ c ≤ b
    a, b = 2 - 3**0.5, 2 + 3**0.5
    for c, ok in ((2.0, (True, True)), (0.0, (False, True)), (3.9, (True, False))):
        r = positive_real(Rational.from_desc([1.0, 0.0, c, 0.0], [1.0, 0.0, 4.0, 0.0, 1.0]))
        ds = _axis_conds(r)
        assert len(ds) == 2
        assert [float(x.name[4:-1]) for x in ds] == pytest.approx([a**0.5, b**0.5], rel=1e-5)
        assert [x.status == "satisfied" for x in ds] == list(ok)
        k = [complex(x.evidence["residues"][0][0]) for x in ds]
        assert k[0] == pytest.approx((c - a) / (2 * (b - a)), abs=1e-12)
        assert k[1] == pytest.approx((b - c) / (2 * (b - a)), abs=1e-12)
        assert "residues_exact" not in ds[0].evidence  # x0 irrational
        assert str(r.verdict) == ("stable" if all(ok) else "potentially_unstable")


def test_matrix_residue_psd_singular_and_indefinite():
    t = S / (S**2 + 1)
    # residue matrix [[1/2, 1/2], [1/2, 1/2]]: PSD and singular -> equality (weak)
    r = positive_real(TransferMatrix([[1 + t, t], [t, 1 + t]], "impedance", (2,)))
    (d,) = _axis_conds(r)
    assert d.status == "equality" and d.margin == 0.0
    assert d.evidence["residues_exact"] == [[{"re": "1/2", "im_over_omega": "0"}] * 2] * 2
    # [[1/2, 1/4], [1/4, 1/2]]: positive definite; eigenvalues 1/4, 3/4 over max |k| = 1/2
    r = positive_real(TransferMatrix([[1 + t, 0.5 * t], [0.5 * t, 1 + t]], "impedance", (2,)))
    (d,) = _axis_conds(r)
    assert d.status == "satisfied" and d.margin == pytest.approx(0.5)
    # [[1/2, 1], [1, 1/2]]: det = 1/4 - 1 < 0
    r = positive_real(TransferMatrix([[1 + t, 2 * t], [2 * t, 1 + t]], "impedance", (2,)))
    (d,) = _axis_conds(r)
    assert d.status == "violated" and "{1,2}" in d.detail
    # a skew part j·(1/4)·[[0, 1], [-1, 0]]·(2/s)… : k12 = 1/2 + j/4·2, k21 = 1/2 - ... is Hermitian;
    # k12 = k21 (both complex) is not
    z12 = (S + 0.5) / (S**2 + 1)
    r = positive_real(TransferMatrix([[1 + t, z12], [z12, 1 + t]], "impedance", (2,)))
    (d,) = _axis_conds(r)
    assert d.status == "violated" and "not Hermitian" in d.detail


def test_llewellyn_minor_test_on_residues():
    t = S / (S**2 + 1)
    zero = 0.0 * S
    # k11 = k22 = 1/2, k12 k21 = 1/4 · 1/2 · ... : products real ≥ 0, det = 1/4 - 1/8 > 0
    r = llewellyn(TransferMatrix([[1 + t, 0.5 * t], [t + zero, 1 + t]], "impedance", (1, 1)))
    (d,) = _axis_conds(r)
    assert d.status == "satisfied"
    # k12·k21 < 0: not admissible
    r = llewellyn(TransferMatrix([[1 + t, 0.5 * t], [-0.5 * t, 1 + t]], "impedance", (1, 1)))
    (d,) = _axis_conds(r)
    assert d.status == "violated" and "not real and ≥ 0" in d.detail
    # det = 1/4 - 1/4 = 0: equality
    r = llewellyn(TransferMatrix([[1 + t, 0.5 * t], [2 * t, 1 + t]], "impedance", (1, 1)))
    (d,) = _axis_conds(r)
    assert d.status == "equality"


def test_theorem1_uses_the_exact_minor_test():
    t = S / (S**2 + 1)
    z = 0.0 * S
    tm = TransferMatrix([[1 + t, 0.5 * t, z], [0.5 * t, 1 + t, z], [z, z, 1 + t]], "impedance", (1, 1, 1))
    (d,) = _axis_conds(absolute_stability(tm))
    assert d.status == "satisfied"


def test_root_isolation_and_tarski_sign_against_closed_forms():
    f = fmpq_poly([1, -4, 1])  # x² - 4x + 1, roots 2 ∓ √3
    ivs = positive_root_intervals(f)
    assert len(ivs) == 2
    r3 = 3**0.5
    for (lo, hi), x0 in zip(ivs, (2 - r3, 2 + r3), strict=True):
        assert float(lo) < x0 < float(hi)
    # sign of x - 2 at each root: -1, +1; of (x - 2)² - 3 = f: 0; of x² - 4x (= -1 mod f): -1, -1
    assert [sign_at_root(fmpq_poly([-2, 1]), f, iv) for iv in ivs] == [-1, 1]
    assert [sign_at_root(f, f, iv) for iv in ivs] == [0, 0]
    assert [sign_at_root(fmpq_poly([0, -4, 1]), f, iv) for iv in ivs] == [-1, -1]
    # a rational root is a point interval
    assert positive_root_intervals(fmpq_poly([-3, 2])) == [(fmpq(3, 2), fmpq(3, 2))]


def test_axis_poles_multiplicities_are_exact():
    # s² (s² + 1)² (s² + 2)(s + 1): s = 0 double, ±j double, ±j√2 simple
    d = fmpq_poly([0, 0, 1]) * fmpq_poly([1, 0, 1]) ** 2 * fmpq_poly([2, 0, 1]) * fmpq_poly([1, 1])
    ps = axis_poles(d)
    assert [(float(p.x0), p.multiplicity) for p in ps] == [(0.0, 2), (1.0, 2), (2.0, 1)]


@pytest.mark.parametrize("seed", range(20))
def test_rational_residues_at_zero_fast_path_agrees_with_the_general_one(seed):
    """The verdict-only path decides the residue matrix at s = 0 in Q directly (k_ij = n_ij(0)/d_ij'(0));
    the full path goes through Q[x]/(x). Same statuses for symmetric, asymmetric, singular, indefinite K."""
    import numpy as np

    from hil.stability.criteria import check

    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 4))
    K = rng.integers(-2, 4, size=(n, n)).astype(float)
    if seed % 3 == 0:
        K = K @ K.T  # PSD (often singular)
    if seed % 3 == 1:
        K = (K + K.T) / 2
    rows = [[(K[i, j] + (1.0 if i == j else 0.0) * S) / S if K[i, j] or i == j else 0.0 * S for j in range(n)]
            for i in range(n)]
    tm = TransferMatrix(rows, "impedance", (1,) * n)
    for crit in ("positive_real", "absolute_stability"):
        full, fast = check(tm, crit), check(tm, crit, margins=False)
        sf = {c.name: c.status for c in full.conditions}
        for c in fast.conditions:
            assert c.status == sf[c.name], (crit, c.name, K)
        assert fast.verdict == full.verdict
