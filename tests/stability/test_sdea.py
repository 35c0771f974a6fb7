"""SDEA under VSIC (paper 002): eq. (12) re-derived from its blocks, Theorem 5 against the general
criterion, Lemma 5 against the exact Sturm decision, transparency and Z-width limits."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.models.sdea import (
    SDEA_TABLE1,
    lemma5_nonnegative_cubic,
    sdea_vsic,
    theorem5,
    transmitted_impedance,
    z_min,
    z_width,
)
from hil.stability.criteria import llewellyn, two_port_passivity
from hil.stability.exact import decide_nonnegative
from hil.stability.jpoly import XPoly
from hil.stability.rational import Rational, S


def _eq10_h(q):
    """Eq. (10) built from its blocks: P = 1/(Ms+B), C_m, C_f, G11 = 0, G12 = -G21 = 1, with the
    feed-forward turning the '+1' of (C_m C_f + 1) into alpha (independent of eq. 12's coefficients)."""
    P_ = 1 / (q["M"] * S + q["B"])
    Cm = q["P_m"] + q["I_m"] / S
    Cf = q["P_f"] + q["I_f"] / S
    Kb = q["K_f"] + q["B_f"] * S
    den = (Cm * P_ + 1) * S + P_ * Kb * (Cm * Cf + q["alpha"])
    h11 = Kb * (Cm * P_ + 1) / den
    h12 = Cf * Cm * P_ * Kb / den
    return h11, h12


@pytest.mark.parametrize("alpha", [0.0, 0.4, 1.0])
def test_eq12_matches_block_diagram_eq10(alpha):
    q = {**SDEA_TABLE1, "alpha": alpha}
    tm = sdea_vsic(q)
    h11, h12 = _eq10_h(q)
    w = np.geomspace(0.1, 1e5, 25)
    np.testing.assert_allclose(tm[0, 0].freq(w), h11.freq(w), rtol=1e-9)
    np.testing.assert_allclose(tm[0, 1].freq(w), h12.freq(w), rtol=1e-9)


params_st = st.fixed_dictionaries({
    "K_f": st.floats(100, 1000), "B_f": st.floats(0.01, 0.2), "M": st.floats(2e-4, 2e-3),
    "B": st.floats(0.05, 0.5), "P_m": st.floats(0.1, 1.0), "I_m": st.floats(10, 300),
    "P_f": st.floats(5, 80), "I_f": st.floats(5, 150), "k22": st.floats(10, 800),
    "b22": st.floats(0.01, 0.4), "alpha": st.floats(0.0, 1.0),
})


@given(params_st)
@settings(max_examples=40, deadline=None)
def test_theorem5_agrees_with_general_two_port_passivity(q):
    general = two_port_passivity(sdea_vsic(q))
    closed = theorem5(q)
    if general.verdict == "marginal":
        return  # a boundary case: the closed form has no tolerance policy
    assert (closed.verdict == "stable") == (general.verdict == "stable"), (q, general.summary(), closed.summary())


# coefficients in a physical range (the decision flushes coefficients 1e-250 below the largest)
coef = st.one_of(st.just(0.0), st.floats(1e-6, 10), st.floats(-10, -1e-6))
cubic_st = st.tuples(st.floats(1e-3, 10), coef, coef, coef)


@given(cubic_st)
@settings(max_examples=300, deadline=None)
def test_lemma5_against_exact_sturm(c):
    # Lemma 5's proof assumes p3 > 0; see test_lemma5_as_printed_fails_for_p3_zero for p3 = 0
    p3, p2, p1, p0 = c
    d = decide_nonnegative(XPoly(np.array([p0, p1, p2, p3]), np.abs(np.array([p0, p1, p2, p3]))))
    if d.status in ("marginal", "equality"):
        return
    assert lemma5_nonnegative_cubic(p3, p2, p1, p0) == (d.status == "satisfied")


def test_lemma5_as_printed_fails_for_p3_zero():
    # Documented difference: the statement allows p3 >= 0, but for p3 = 0 it can be wrong:
    # x^2 - x + 1 > 0 for all x, yet (a) fails (p1 < 0) and (b)'s last inequality is an equality.
    assert decide_nonnegative(XPoly(np.array([1.0, -1.0, 1.0]), np.ones(3))).status == "satisfied"
    assert lemma5_nonnegative_cubic(0.0, 1.0, -1.0, 1.0) is False


def test_nominal_table1_is_passive_and_absolutely_stable():
    tm = sdea_vsic()
    assert two_port_passivity(tm).verdict == "stable"
    assert llewellyn(tm).verdict == "stable"
    assert theorem5().verdict == "stable"


def test_remark1_no_physical_or_virtual_damping_means_not_passive():
    assert two_port_passivity(sdea_vsic(B_f=0.0)).verdict == "potentially_unstable"
    assert two_port_passivity(sdea_vsic(b22=0.0)).verdict == "potentially_unstable"
    # Lemma 6: without coupler damping not even absolutely stable
    assert llewellyn(sdea_vsic(b22=0.0)).verdict == "potentially_unstable"


def test_transparency_limits_eq20_eq21():
    tm = sdea_vsic()
    lo = tm.freq([1e-6])[0]
    hi = tm.freq([1e9])[0]
    np.testing.assert_allclose(lo, [[0, 1], [-1, 0]], atol=1e-5)
    q = SDEA_TABLE1
    np.testing.assert_allclose(hi, [[q["B_f"], 0], [-1, 1 / q["b22"]]], atol=1e-3)


def test_zmin_zwidth_limits_eq23_eq25():
    tm = sdea_vsic()
    zm, zw = z_min(tm), z_width(tm)
    assert abs(zm.freq(1e-7)) < 1e-6
    assert zm.freq(1e10).real == pytest.approx(SDEA_TABLE1["B_f"], rel=1e-6)
    sz = (S * zw)
    assert sz.freq(1e-7).real == pytest.approx(SDEA_TABLE1["k22"], rel=1e-6)
    assert abs(zw.freq(1e10)) < 1e-3


def test_transmitted_impedance_null_environment_is_h11():
    tm = sdea_vsic()
    zt = transmitted_impedance(tm, Rational.const(0.0))
    w = np.geomspace(1, 1e4, 9)
    np.testing.assert_allclose(zt.freq(w), tm[0, 0].freq(w), rtol=1e-12)
