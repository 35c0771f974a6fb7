"""Issue 31, item 2: the weak flag ("holds with equality somewhere") does not depend on the criterion.

A principal minor of a residue matrix that is zero by the pattern alone (every term of its
determinant contains an entry without a pole there) is not an equality: residues.py skipped such
minors for Llewellyn and Theorem 1, but positive realness (det K = 0) and the pole at s = ∞
(R_ii = 0) counted them, so diag(1 + 1/s, 1) was weak for passivity only."""

from __future__ import annotations

import itertools

import pytest

from hil.errors import ConversionError
from hil.stability.criteria import check
from hil.stability.rational import Rational, S, TransferMatrix

CRITERIA = ("positive_real", "passivity", "llewellyn", "absolute_stability")


def _flags(tm: TransferMatrix) -> set[tuple[str, bool]]:
    out = set()
    for crit in CRITERIA:
        for margins in (True, False):
            r = check(tm, crit, margins=margins)
            out.add((str(r.verdict), r.weak))
    return out


@pytest.mark.parametrize("block", [1 + 1 / S, S + 1, 1 + S / (S**2 + 1), 2 + 1 / S + S])
def test_a_pole_in_one_diagonal_entry_is_not_an_equality(block):
    # each block alone is strictly admissible (residue > 0, Re > 0): the block-diagonal network
    # is stable and not weak under every criterion; the old code said weak for passivity only
    assert check(block, "positive_real").weak is False
    assert _flags(TransferMatrix([[block, 0], [0, 1]])) == {("stable", False)}
    assert _flags(TransferMatrix([[1, 0], [0, block]])) == {("stable", False)}


def test_a_weak_block_makes_every_criterion_weak():
    # 1/s is lossless (Re ≡ 0: equality at every ω); the 2x2 network inherits it everywhere
    assert _flags(TransferMatrix([[1 / S, 0], [0, 1]])) == {("stable", True)}
    # a residue matrix singular by its values, not by its pattern: [[1, 1], [1, 1]] at s = 0
    tm = TransferMatrix([[1 + 1 / S, 1 / S], [1 / S, 1 + 1 / S]])
    assert _flags(tm) == {("stable", True)}
    assert check(tm, "passivity").condition("D[ω=0]").status == "equality"


R_ = Rational.const
ELEMENTS = {"R": R_(1.0), "L": S, "C": 1 / (4 * S), "RL": 1 + S / 2, "RC": 2 + 1 / (S / 2),
            "LC": S + 1 / S, "L||C": S / (S**2 + 1), "R||L": S / (S + 1)}


@pytest.mark.parametrize("kind", ["impedance", "admittance", "hybrid", "inverse_hybrid"])
def test_rlc_t_ladders_get_one_verdict_and_one_weak_flag_from_every_criterion(kind):
    """T ladders (series a, shunt b, series c) of R, L, C elements in every immittance form that
    exists: passivity, Llewellyn and Theorem 1 agree on the verdict and on the weak flag. Before the
    fix 322 of the 2916 combinations of these elements and forms differed (e.g. R, R, C: the pole
    at s = 0 sits in z22 only)."""
    seen = 0
    for (_na, a), (_nb, b), (_nc, c) in itertools.islice(itertools.product(ELEMENTS.items(), repeat=3), 0, None, 7):
        z = TransferMatrix([[a + b, b], [b, c + b]])
        try:
            tm = z.to(kind)
        except ConversionError:  # this form does not exist for this ladder
            continue
        flags = {(str(r.verdict), r.weak) for r in (check(tm, crit) for crit in CRITERIA[1:])}
        assert len(flags) == 1, (kind, tm.to_dict(), flags)
        seen += 1
    assert seen >= 40


def test_the_reported_rlc_case():
    # series R, shunt R, series C (z22 = 1 + 1/(0.25 s)·..): the pole at s = 0 is in z22 only
    z = TransferMatrix([[R_(2.0), R_(1.0)], [R_(1.0), 1 + 1 / (S / 4)]])
    for kind in ("impedance", "inverse_hybrid"):
        assert {(str(check(z.to(kind), c).verdict), check(z.to(kind), c).weak) for c in CRITERIA[1:]} == {
            ("stable", False)}
