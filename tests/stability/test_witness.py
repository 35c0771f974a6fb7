"""Instability witnesses agree with the criteria: potentially unstable networks have passive
terminations making the operator-port impedance non-positive-real; absolutely stable ones do not
(Llewellyn's criterion is exactly 'Re Z_in ≥ 0 for every passive load', so no witness may exist)."""

import numpy as np
import pytest

from hil.models.teleop import bilateral_2dof, mcet_trilateral
from hil.stability.criteria import positive_real
from hil.stability.witness import Termination, find_witness, input_impedance, termination_family

LAG = Termination("lag", {"g": 1.0, "a": 1.0})  # paper 000's terminations 1/(s+1)


def test_mcet_with_the_papers_terminations():
    z80 = input_impedance(mcet_trilateral(k_vm1=80), 0, [None, LAG.matrix(1), LAG.matrix(1)])
    z64 = input_impedance(mcet_trilateral(k_vm1=64), 0, [None, LAG.matrix(1), LAG.matrix(1)])
    assert positive_real(z80).verdict == "potentially_unstable"
    assert positive_real(z64).verdict == "stable"


def test_input_impedance_matches_direct_frequency_response():
    # independent check at a few frequencies: Z_in = Z11 - Z1r (Zrr + T)^-1 Zr1 numerically
    Z = mcet_trilateral(k_vm1=80, alpha=0.3)
    zin = input_impedance(Z, 0, [None, LAG.matrix(1), LAG.matrix(1)])
    w = np.array([0.3, 2.0, 9.0])
    G = Z.freq(w)
    T = np.array([1 / (1j * wi + 1) for wi in w])
    for i in range(w.size):
        Zrr = G[i, 1:, 1:] + np.diag([T[i], T[i]])
        direct = G[i, 0, 0] - G[i, 0, 1:] @ np.linalg.solve(Zrr, G[i, 1:, 0])
        assert zin[0, 0].freq(w[i]) == pytest.approx(direct, rel=1e-9)


@pytest.mark.parametrize("model,expect_witness", [
    (lambda: mcet_trilateral(k_vm1=80), True),
    (lambda: mcet_trilateral(k_vm1=64), False),
    (lambda: bilateral_2dof("B"), True),
    (lambda: bilateral_2dof("A1"), False),
])
def test_witness_exists_iff_potentially_unstable(model, expect_witness):
    Z = model()
    cands = termination_family(max(Z.port_dofs))[::4]  # a spread subset keeps the test quick
    w = find_witness(Z, 0, cands)
    assert (w is not None) == expect_witness
    if w is not None:
        assert w.result.verdict == "potentially_unstable"
        assert w.drive_frequency > 0
