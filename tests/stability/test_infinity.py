"""Poles at s = ∞ (issue 11, defect 2): an improper immittance must have at most a simple pole at
infinity with a positive semidefinite residue R = lim G(s)/s (classical positive realness)."""

import json
from fractions import Fraction

import numpy as np
import pytest

from hil.cli.main import EXIT_OK, EXIT_UNSTABLE, main
from hil.models.teleop import bilateral_1dof, mbk_impedance
from hil.stability.criteria import check, infinity_condition, llewellyn, positive_real
from hil.stability.rational import Rational, S, TransferMatrix


def negative_mass(a: float = 1.0, b: float = 1.0) -> Rational:
    """b·Z(a·s) with Z = -s + 1 + 10/s."""
    return b * (-(a * S) + 1 + 10 / (a * S))


def test_negative_mass_one_port_is_potentially_unstable():
    r = positive_real(negative_mass())
    assert str(r.verdict) == "potentially_unstable"
    assert r.failed_condition == "D[ω=∞]"
    c = r.condition("D[ω=∞]")
    assert c.evidence["degree_excess"] == [[1]]
    assert float(c.evidence["residue_inf"][0][0]) == -1.0
    assert c.margin < 0
    # the frequency-domain conditions alone hold (Re Z = 1, residue at s = 0 is +10): the
    # verdict rests on the new condition only
    assert all(x.status in ("satisfied", "equality") for x in r.conditions if x.name != "D[ω=∞]")


def test_negative_mass_with_a_passive_spring_has_a_rhp_closed_loop_pole():
    # independent derivation: Z + k/s = 0 with k = 1  <=>  -s² + s + 11 = 0, s = (1 + √45)/2
    k = 1.0
    char = (negative_mass() + k / S).num[::-1]  # descending coefficients of the numerator
    roots = np.roots(char)
    assert max(roots.real) == pytest.approx((1 + np.sqrt(45)) / 2, rel=1e-12)
    assert max(roots.real) == pytest.approx(3.854, abs=1e-3)
    # the spring alone is passive, so absolute stability would have excluded this
    assert str(positive_real(k / S).verdict) == "stable"


@pytest.mark.parametrize("a", [1e-6, 1e-3, 1.0, 1e3, 1e6])
@pytest.mark.parametrize("b", [1e-6, 1.0, 1e6])
def test_verdict_invariant_under_frequency_and_impedance_scaling(a, b):
    bad = positive_real(negative_mass(a, b))
    assert str(bad.verdict) == "potentially_unstable" and bad.failed_condition == "D[ω=∞]"
    assert bad.condition("D[ω=∞]").margin == pytest.approx(-1.0)
    good = positive_real(b * (a * S + 1 + 10 / (a * S)))
    assert str(good.verdict) == "stable"
    assert good.condition("D[ω=∞]").status == "satisfied"


@pytest.mark.parametrize("m", [-1e-300, -1e-9, -1.0, 0.0, 1e-300, 1e-9, 1.0])
def test_residue_condition_flips_exactly_when_the_mass_crosses_zero(m):
    z = Rational.from_desc([m, 1.0, 10.0], [1.0, 0.0])
    c = infinity_condition(TransferMatrix([[z]]))
    if m < 0:
        assert c.status == "violated"
    elif m == 0:
        assert c.status == "satisfied" and c.evidence["degree_excess"] == [[0]]
    else:
        assert c.status == "satisfied" and c.margin == 1.0
    if abs(m) >= 1e-9:
        assert str(positive_real(z).verdict) == ("potentially_unstable" if m < 0 else "stable")


def test_positive_improper_cases_stay_stable():
    assert str(positive_real(S + 1).verdict) == "stable"
    assert str(positive_real(2.0 * S).verdict) == "stable"
    r = positive_real(mbk_impedance(M_00=2, M_01=1, M_11=2))
    assert str(r.verdict) == "stable"
    assert r.condition("D[ω=∞]").status == "satisfied"
    np.testing.assert_allclose(sorted(r.condition("D[ω=∞]").evidence["eigenvalues"]), [1.0, 3.0])


def test_double_pole_at_infinity_is_a_violation():
    for z in (S**2 + 1, S**3 / (S + 1) + 1, (S**2 + S + 1) * 1e-6):
        c = positive_real(z).condition("D[ω=∞]")
        assert c.status == "violated" and "order 2" in c.detail
    # an improper off-diagonal entry with excess 2 fails a matrix too
    tm = TransferMatrix([[S + 1, S**2], [S**2, S + 1]], "impedance", (2,))
    assert positive_real(tm).condition("D[ω=∞]").status == "violated"


def test_indefinite_mass_matrix_is_potentially_unstable():
    tm = mbk_impedance(M_00=1, M_01=2, M_11=1)
    for crit in ("positive_real", "auto"):
        r = check(tm, crit)
        assert str(r.verdict) == "potentially_unstable" and r.failed_condition == "D[ω=∞]"
        ev = r.condition("D[ω=∞]").evidence
        np.testing.assert_allclose(sorted(ev["eigenvalues"]), [-1.0, 3.0])
        assert ev["negative_minor"] == [1, 2]  # det [[1,2],[2,1]] = -3
    # margins: λ_min/ρ = -1/3 (positive realness), det/perm = -3/5 (Theorem 1's minors)
    assert check(tm, "positive_real").condition("D[ω=∞]").margin == pytest.approx(-1 / 3)
    assert check(tm, "absolute_stability").condition("D[ω=∞]").margin == pytest.approx(-3 / 5)


def test_mass_matrix_flips_exactly_at_singularity():
    # M = [[1, c], [c, 1]] is PSD iff |c| ≤ 1: singular at c = 1 (equality), indefinite beyond
    def status(c):
        return infinity_condition(mbk_impedance(M_00=1, M_01=c, M_11=1)).status

    assert status(1.0) == "equality"
    assert status(float(np.nextafter(1.0, 2.0))) == "violated"
    assert status(float(np.nextafter(1.0, 0.0))) == "satisfied"


def test_asymmetric_residue_violates_positive_realness_exactly():
    tm = TransferMatrix([[S + 1, 0.5 * S], [0.5000000001 * S, S + 1]], "impedance", (2,))
    c = positive_real(tm).condition("D[ω=∞]")
    assert c.status == "violated" and "not symmetric" in c.detail


def test_residue_is_the_exact_ratio_of_leading_coefficients():
    z = Rational.from_desc([0.1, 3.0, 7.0], [0.3, 1.0])  # 0.1/0.3 as binary rationals
    c = infinity_condition(TransferMatrix([[z]]))
    assert c.evidence["residue_inf"][0][0] == float(Fraction(0.1) / Fraction(0.3))


def test_teleoperator_with_negative_apparent_master_mass_fails_llewellyn():
    ok = llewellyn(bilateral_1dof())
    assert str(ok.verdict) == "stable"  # weak: the controllers' residues at s = 0 are singular
    r = llewellyn(bilateral_1dof(m_m=-0.01))
    assert str(r.verdict) == "potentially_unstable"
    assert r.failed_condition == "D[ω=∞]"
    c = r.condition("D[ω=∞]")
    np.testing.assert_allclose(np.asarray(c.evidence["residue_inf"]), [[-0.01, 0.0], [0.0, 0.02]])
    assert "{1}" in c.detail
    # the same two-port under Theorem 1 and under passivity
    assert str(check(bilateral_1dof(m_m=-0.01), "absolute_stability").verdict) == "potentially_unstable"
    assert str(check(bilateral_1dof(m_m=-0.01), "passivity").verdict) == "potentially_unstable"


def test_cli_mbk_negative_mass(capsys):
    assert main(["stability", "--model", "mbk_impedance", "--set", "M_00=-1", "--json"]) == EXIT_UNSTABLE
    d = json.loads(capsys.readouterr().out)
    assert d["verdict"] == "potentially_unstable" and d["failed_condition"] == "D[ω=∞]"
    assert main(["stability", "--model", "mbk_impedance"]) == EXIT_OK


def test_mbk_impedance_one_dof_body() -> None:
    """dof=1: a 1-DOF body Z = (m s² + b s + k)/s, not the 2-DOF defaults; PR iff m, b, k ≥ 0."""
    tm = mbk_impedance(dof=1, M_00=2.0, B_00=3.0, K_00=40.0)
    assert tm.n_ports == 1
    assert positive_real(tm).verdict == "stable"
    assert positive_real(mbk_impedance(dof=1, M_00=-0.5, B_00=3.0, K_00=40.0)).verdict == "potentially_unstable"
    import pytest

    from hil.errors import ModelError

    with pytest.raises(ModelError, match="outside a 1-DOF"):
        mbk_impedance(dof=1, M_01=0.1)
    with pytest.raises(ModelError, match="integer from 1 to 6"):
        mbk_impedance(dof=1.5)
