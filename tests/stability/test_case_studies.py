"""Every verdict of the papers' case studies, and the documented differences (docs/PAPER_NOTES.md)."""

import numpy as np
import pytest

from hil.models.teleop import (
    bilateral_2dof,
    dual_master_3dof,
    example_Z_000_eq5,
    mcet_trilateral,
    termination_T1,
    termination_T2,
)
from hil.stability.criteria import absolute_stability, llewellyn, positive_real


def test_T1_of_000_is_not_passive_although_its_diagonal_is():
    r = positive_real(termination_T1())
    assert r.verdict == "potentially_unstable"
    assert r.failed_condition == "E{1,2}"
    # each diagonal entry alone is positive real (8/(s+3), 1/(s+3))
    t1 = termination_T1()
    assert positive_real(t1[0, 0]).verdict == "stable"
    assert positive_real(t1[1, 1]).verdict == "stable"
    # independent check: at ω = 0 the Hermitian part [[16/3, -10], [-10, 2/3]] has a negative determinant
    H = np.array([[16 / 3, -10.0], [-10.0, 2 / 3]])
    assert np.linalg.det(H) < 0


def test_T2_of_001_is_passive():
    r = positive_real(termination_T2())
    assert r.verdict == "stable" and not r.weak


def test_000_eq5_subsystem_satisfies_llewellyn():
    assert llewellyn(example_Z_000_eq5()).verdict == "stable"


@pytest.mark.parametrize("alpha", [0.0, 0.25, 0.5, 0.75, 1.0])
def test_000_table1_kvm1_64_stable_80_not(alpha):
    r64 = absolute_stability(mcet_trilateral(k_vm1=64, alpha=alpha))
    r80 = absolute_stability(mcet_trilateral(k_vm1=80, alpha=alpha))
    assert r64.verdict == "stable"
    # condition (36) holds with equality: -(k_vm1 k_pm2 - k_pm1 k_vm2)^2 = 0 exactly for 64
    assert r64.condition("E{1,2}").status == "equality"
    assert r80.verdict == "potentially_unstable"
    assert r80.failed_condition == "E{1,2}"


def test_000_table1_condition_40_boundary_is_exact():
    # (40): k_pm1/k_vm1 = k_pm2/k_vm2. Any other k_vm1 is potentially unstable, however close.
    for kv in (63.9, 64.1, 70.0):
        assert absolute_stability(mcet_trilateral(k_vm1=kv)).verdict == "potentially_unstable"


@pytest.mark.parametrize("gains,expected", [("A1", "stable"), ("A2", "stable"), ("B", "potentially_unstable")])
def test_000_table2(gains, expected):
    r = absolute_stability(bilateral_2dof(gains))
    assert r.verdict == expected


def test_000_table2_B_fails_where_56b_says():
    # (56b): k_pyy k_pzz >= k_pyz^2 fails for B (500*500 < 550^2): the residue matrix at s = 0
    # is not PSD, i.e. condition D decides.
    r = absolute_stability(bilateral_2dof("B"))
    assert r.failed_condition.startswith("D[")


def test_001_table1_as_printed_is_potentially_unstable_exactly():
    # Documented difference: with the printed slave x-z gains (k_psxz = 15, k_vsxz = 20) and the
    # x-channel at its boundary (k_p1xx k_p4xx = k_pmxx k_psxx), Theorem 1 fails exactly.
    r = absolute_stability(dual_master_3dof(k_pmyz=30))
    assert r.verdict == "potentially_unstable"
    d = r.condition("D[ω=0]")
    assert d.status == "violated"
    # independent hand derivation of that residue minor over (x_m, x_s, z_s):
    K = np.array([[400.0, -400.0, 0.0], [-200.0, 200.0, 15.0], [0.0, 15.0, 125.0]])
    assert np.linalg.det(K) == pytest.approx(-90000.0)
    assert "-9e+04" in d.detail


@pytest.mark.parametrize("kpmyz,expected,weak", [(30, "stable", True), (300, "potentially_unstable", False)])
def test_001_table1_with_xz_coupling_removed(kpmyz, expected, weak):
    r = absolute_stability(dual_master_3dof(k_pmyz=kpmyz, k_psxz=0, k_vsxz=0))
    assert r.verdict == expected
    assert r.weak is weak  # 30 is *weakly* stable (non-strict inequalities), as paper 001 says


def test_theorem1_not_applicable_when_symmetrization_fails():
    # master and slave PD gains with different ratios (violating 46c) make Z' impossible
    r = absolute_stability(bilateral_2dof({"k_pmyy": 500, "k_vmyy": 300, "k_pmzz": 500, "k_vmzz": 300,
                                           "k_pmyz": 100, "k_vmyz": 50, "k_psyy": 500, "k_vsyy": 300,
                                           "k_pszz": 500, "k_vszz": 300, "k_psyz": 40, "k_vsyz": 50}))
    assert r.verdict == "not_applicable"
    assert "symmetrization" in r.reason


@pytest.mark.parametrize("make,expected", [
    (lambda: bilateral_2dof("A1"), "stable"),
    (lambda: bilateral_2dof("B"), "potentially_unstable"),
    (lambda: dual_master_3dof(k_pmyz=300, k_psxz=0, k_vsxz=0), "potentially_unstable"),
])
def test_theorem1_numerical_fallback_agrees_with_the_exact_path(make, expected, monkeypatch):
    """Blocks of Z' whose entries √(z_ij z_ji) are irrational are decided by a flagged dense sweep.
    Forcing that path on networks whose Z' is rational must give the exact path's verdict."""
    from hil.stability import criteria

    exact = absolute_stability(make())
    assert exact.verdict == expected
    monkeypatch.setattr(criteria, "_sqrt_of_pair", lambda a, b: None)
    swept = absolute_stability(make())
    assert any(c.evidence.get("method") == "sweep" for c in swept.conditions)
    assert swept.verdict == expected
