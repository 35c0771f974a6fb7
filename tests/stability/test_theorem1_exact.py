"""Issue 11: Theorem 1 blocks of size ≥ 3 are decided exactly. Z' (z'_ij = γ_ij √(z_ij z_ji)) is
formed over Q up to a diagonal similarity (√κ_ij need not be rational), conditions A and B and the
sign choice are exact, and identically-zero minors of Re Z' are exactly zero (a float
symmetrization with √2, √3 leaves ~1e-16 residue there, a frequency grid ~1e-9)."""

import math

import numpy as np
import pytest

from hil.stability.criteria import absolute_stability
from hil.stability.rational import Rational, S, TransferMatrix

LAM = np.array([1.0, 1 / math.sqrt(2.0), 1 / math.sqrt(3.0)])  # Z = Λ Z' Λ⁻¹ with Λ = diag(LAM)


def _three_port(r1, r2, r3, r12, r13, r23, s13=1.0):
    """Z = Λ Z' Λ⁻¹ for the symmetric Z' = [[r1, √2 r12, √3 r13], [·, r2, √6 r23], [·, ·, r3]]:
    rational entries z12 = 2 r12, z21 = r12, z13 = 3 r13, z31 = r13, z23 = 3 r23, z32 = 2 r23 (hand
    derivation: z_ij = λ_i/λ_j · z'_ij). ``s13 = -1`` flips the sign of z13 and z31 (cycle
    condition A still holds; γ13 = -1)."""
    return TransferMatrix([[r1, 2 * r12, 3 * s13 * r13], [r12, r2, 3 * r23], [s13 * r13, 2 * r23, r3]],
                          "impedance", (1, 1, 1))


def test_rank_one_three_port_has_exactly_zero_minors():
    # Z = 1/(s+1)·[[1,2,3],[1,2,3],[1,2,3]] = Λ (w wᵀ/(s+1)) Λ⁻¹, w = (1, √2, √3): Re Z' = w wᵀ/(1+ω²)
    # is PSD of rank 1, so every 2×2 and 3×3 principal minor of Re Z' is identically zero
    r = 1 / (S + 1)
    tm = TransferMatrix([[r, 2 * r, 3 * r], [r, 2 * r, 3 * r], [r, 2 * r, 3 * r]], "impedance", (1, 1, 1))
    res = absolute_stability(tm)
    assert str(res.verdict) == "stable" and res.weak, res.summary()
    assert res.condition("A").status == "satisfied" and res.condition("B").status == "satisfied"
    # 1×1: 2 Re z'_ii(jω)·|jω + 1|² = 2 w_i² exactly
    for i, w2 in ((1, 2.0), (2, 4.0), (3, 6.0)):
        c = res.condition(f"E{{{i}}}")
        assert c.status == "satisfied" and c.evidence["polynomial_x_desc"] == [w2]
        assert c.evidence["formed"].startswith("exact")
    for name in ("E{1,2}", "E{1,3}", "E{2,3}", "E{1,2,3}"):
        c = res.condition(name)
        assert c.status == "equality" and c.margin == 0.0
        assert c.evidence["method"] == "identically zero (exact)"


def _grid_min_minor(tm: TransferMatrix) -> float:
    """Independent float reference: the smallest normalized principal minor of Re(Λ⁻¹ Z Λ)(jω)
    (= Re Z', symmetric) on a dense grid."""
    w = np.geomspace(1e-3, 1e3, 4001)
    G = tm.freq(w)
    Zp = (G / LAM[None, :, None]) * LAM[None, None, :]
    R = Zp.real
    assert np.allclose(R, np.swapaxes(R, 1, 2), rtol=1e-12, atol=1e-14)  # Z' symmetric
    worst = np.inf
    for idx in ((0,), (1,), (2,), (0, 1), (0, 2), (1, 2), (0, 1, 2)):
        sub = R[:, idx][:, :, idx]
        worst = min(worst, float(np.min(np.linalg.det(sub) / np.prod(np.abs(np.diagonal(sub, axis1=1, axis2=2)),
                                                                      axis=1))))
    return worst


@pytest.mark.parametrize("s13", [1.0, -1.0])
@pytest.mark.parametrize("c", [0.05, 0.2, 0.6, 1.5])
def test_irrational_kappa_three_port_agrees_with_a_float_reference(c, s13):
    r1, r2, r3 = (S + 2) / (S + 1), (2 * S + 1) / (S + 3), (S + 5) / (S + 2)
    tm = _three_port(r1, r2, r3, c / (S + 1), c / (S + 2), c / (S + 3), s13)
    ref = _grid_min_minor(tm)
    assert abs(ref) > 1e-3  # far from the boundary: the grid's sign is reliable (no narrow bands)
    res = absolute_stability(tm)
    assert str(res.verdict) == ("stable" if ref > 0 else "potentially_unstable"), res.summary()
    assert not any(x.evidence.get("method") == "sweep" for x in res.conditions)
    assert res.condition("E{1,2,3}").label.endswith("(Z' exact over Q)")


def test_conditions_a_and_b_are_exact():
    # B: z12 ≠ z21 inside a 2-DOF port block by one ulp is a different network: not applicable
    r = 1 / (S + 1)
    one_ulp = Rational.from_desc([math.nextafter(1.0, 2.0)], [1.0, 1.0])
    tm = TransferMatrix([[r, r], [one_ulp, r]], "impedance", (2,))
    assert str(absolute_stability(tm).verdict) == "not_applicable"
    # A: a cycle product off by one ulp fails exactly
    r12 = 0.5 / (S + 1)
    tm = _three_port(r, r, r, r12, r12, r12)
    assert absolute_stability(tm).condition("A").status == "satisfied"
    bad = TransferMatrix([[tm[i, j] if (i, j) != (0, 1) else tm[0, 1] * math.nextafter(1.0, 2.0)
                           for j in range(3)] for i in range(3)], "impedance", (1, 1, 1))
    res = absolute_stability(bad)
    assert str(res.verdict) == "not_applicable" and res.condition("A").status == "not_applicable"


@pytest.mark.parametrize("c", [0.2, 1.5])
def test_exact_z_prime_has_the_principal_minors_of_z(c):
    """The symmetrized block (up to its diagonal similarity) has exactly Z's principal minors over
    Q(s): checked here independently of the criterion, which relies on cycle balance for it."""
    from flint import fmpq_poly

    from hil.stability.criteria import _exact_sqrt, _exact_symmetrize
    from hil.stability.rational import _RF, _rf_det, _to_rf

    tm = _three_port((S + 2) / (S + 1), (2 * S + 1) / (S + 3), (S + 5) / (S + 2), c / (S + 1), c / (S + 2),
                     c / (S + 3), -1.0)
    RF = _to_rf(tm.entries)
    roots = {(i, j): _exact_sqrt(RF[i][j] * RF[j][i]) for i in range(3) for j in range(i + 1, 3)}
    (nums, dens), why = _exact_symmetrize(RF, [0, 1, 2], roots)
    assert why == ""
    Sm = [[_RF(nums[a][b] if nums[a][b] is not None else fmpq_poly([]), dens[a][b]) for b in range(3)]
          for a in range(3)]
    for idx in ((0, 1), (0, 2), (1, 2), (0, 1, 2)):
        mz = _rf_det([[RF[a][b] for b in idx] for a in idx])
        ms = _rf_det([[Sm[a][b] for b in idx] for a in idx])
        assert mz.n == ms.n and mz.d == ms.d
    for a in range(3):  # the products S_ab S_ba are z_ab z_ba
        for b in range(a + 1, 3):
            p, q = Sm[a][b] * Sm[b][a], RF[a][b] * RF[b][a]
            assert p.n == q.n and p.d == q.d
