"""Issue 11, defect 4: imaginary-axis poles are cancelled exactly from the frequency conditions, so a
strictly passive network with a lossless resonance is `stable`, not `marginal`."""

import numpy as np
import pytest

from hil.stability.criteria import check, llewellyn, positive_real
from hil.stability.rational import Rational, S, TransferMatrix


def tank(w0: float, b: float = 1.0, c: float = 1.0, a: float = 1.0) -> Rational:
    """b·(1 + c·w0·(a s)/((a s)² + w0²)): a resistor plus an LC tank at w0/a, residue b·c·w0/(2a)...
    written with coefficients that are exact for b, a powers of two (so the given floats *are*
    this network)."""
    W = float(w0 * w0)
    a2 = a * a
    return Rational.from_desc([b * a2, b * c * w0 * a, b * W], [a2, 0.0, W])


def test_lc_tank_plus_resistor_is_stable_with_exact_residue():
    r = positive_real(1 + S / (S**2 + 1))
    assert str(r.verdict) == "stable" and not r.weak
    d = r.condition("D[ω=1]")
    assert d.status == "satisfied"
    assert complex(d.evidence["residues"][0][0]) == pytest.approx(0.5, abs=1e-15)
    e = r.condition("E{1}")
    assert e.status == "satisfied"
    assert e.evidence["axis_pole_factors_cancelled"] == 1
    assert e.evidence["polynomial_x_desc"] == [2.0]  # Re Z·|d|² / (x - 1)² = 2·Re Z = 2
    # the margin is taken before the axis factor is cancelled (issue 31, item 3): p = 2(1 - x)²
    # vanishes at the pole, where a relative perturbation of u and D makes Re Z change sign (the
    # pole moves off the zero of the numerator's real part), so the margin is 0 there; C agrees
    # (a pole on the axis has damping 0), and the result's margin is 0
    assert (e.margin, e.worst_frequency) == (0.0, 1.0)
    assert (r.condition("C").margin, r.margin) == (0.0, 0.0)


@pytest.mark.parametrize("w0", [*np.geomspace(1e-3, 1e3, 13), 0.37, 1234.5])
@pytest.mark.parametrize("k", [-20, -7, 0, 9, 20])
def test_strictly_passive_tank_is_stable_at_every_frequency_and_scale(w0, k):
    b = 2.0**k  # impedance scale 1e-6 .. 1e6, exactly representable products
    for c in (1.0, 0.5, 3.7):
        r = positive_real(tank(w0, b, c))
        assert str(r.verdict) == "stable" and not r.weak, r.summary()
        d = next(x for x in r.conditions if x.name.startswith("D[ω=") and x.name != "D[ω=∞]")
        assert float(d.name[4:-1]) == pytest.approx(w0, rel=1e-5)


@pytest.mark.parametrize("a", [2.0**-20, 2.0**-5, 1.0, 2.0**7, 2.0**20])
def test_verdict_invariant_under_frequency_scaling(a):
    assert str(positive_real(tank(3.0, 1.0, 1.0, a)).verdict) == "stable"
    # and a violation stays a violation: a resistor smaller than a parallel negative one
    bad = tank(3.0, 1.0, 1.0, a) - 1.5
    r = positive_real(bad)
    assert str(r.verdict) == "potentially_unstable" and r.failed_condition == "E{1}"


def test_negative_residue_is_still_caught_by_the_pole_condition():
    r = positive_real(1 - S / (S**2 + 1))
    assert str(r.verdict) == "potentially_unstable" and r.failed_condition == "D[ω=1]"


def test_real_part_that_really_touches_zero_elsewhere_is_not_cancelled():
    # Z1 = (s² + 4)/(s² + s + 4) is PR with Re Z1(jω) = (4 - ω²)²/((4 - ω²)² + ω²): it touches 0
    # at ω = 2. Adding a tank at ω = 1 cancels the pole factor only; the genuine touching remains.
    z = (S**2 + 4) / (S**2 + S + 4) + S / (S**2 + 1)
    e = positive_real(z).condition("E{1}")
    assert e.evidence["axis_pole_factors_cancelled"] == 1
    assert e.evidence["touching_rad_s"] == [pytest.approx(2.0, rel=1e-9)]


def test_matrix_with_a_hermitian_psd_residue_at_a_resonance_is_stable():
    k = 0.5
    t = S / (S**2 + 1)
    tm = TransferMatrix([[1 + t, k * t], [k * t, 1 + t]], "impedance", (2,))
    r = positive_real(tm)
    assert str(r.verdict) == "stable" and not r.weak, r.summary()
    assert r.condition("E{1,2}").evidence["axis_pole_factors_cancelled"] >= 1
    # an indefinite residue matrix (|k| > 1) is caught by D, the frequency part stays clean
    tm2 = TransferMatrix([[1 + t, 2 * t], [2 * t, 1 + t]], "impedance", (2,))
    r2 = positive_real(tm2)
    assert str(r2.verdict) == "potentially_unstable" and r2.failed_condition.startswith("D[ω=1")


def test_auto_criterion_on_one_port_tank():
    assert str(check(1 + S / (S**2 + 1)).verdict) == "stable"


def test_llewellyn_eta_with_a_resonance_is_decided_after_cancellation():
    t = S / (S**2 + 1)
    zero = 0.0 * S
    # a resonance shared by all four entries, symmetric PSD residue [[.5, .25], [.25, .5]]
    r = llewellyn(TransferMatrix([[1 + t, 0.5 * t], [0.5 * t, 1 + t]], "impedance", (1, 1)))
    assert str(r.verdict) == "stable" and not r.weak, r.summary()
    assert r.condition("E{1,2}").status == "satisfied" and r.condition("E{1,2}").margin == 0.0  # at the pole
    # resonance on one port, resistive coupling: η = 2 - 0.02 > 0
    r = llewellyn(TransferMatrix([[1 + t, 0.1 + zero], [0.1 + zero, 1 + zero]], "impedance", (1, 1)))
    assert str(r.verdict) == "stable" and not r.weak, r.summary()
    # too strong a resistive coupling: η = 2·1·1 - 2·1.5² < 0 everywhere; after cancelling the axis
    # factor the condition polynomial is a negative constant (the status); the margin, taken on
    # the uncancelled polynomial, is negative and 0 only at the pole
    r = llewellyn(TransferMatrix([[1 + t, 1.5 + zero], [1.5 + zero, 1 + t]], "impedance", (1, 1)))
    assert str(r.verdict) == "potentially_unstable" and r.failed_condition == "E{1,2}"
    assert -1.0 < r.condition("E{1,2}").margin < 0


@pytest.mark.parametrize("w0", np.geomspace(1e-3, 1e3, 25))
def test_formula_built_tank_is_stable_at_every_omega0(w0):
    # Z = 1 + ω0·s/(s² + ω0²) built with the Rational algebra (Re Z = 1, residue ω0/2 at jω0)
    r = check(1 + w0 * S / (S**2 + w0**2))
    assert str(r.verdict) == "stable" and not r.weak, r.summary()
    d = next(x for x in r.conditions if x.name.startswith("D[ω=") and x.name != "D[ω=∞]")
    assert complex(d.evidence["residues"][0][0]).real == pytest.approx(w0 / 2, rel=1e-9)


@pytest.mark.parametrize("b", np.geomspace(1e-6, 1e6, 7))
def test_rounded_impedance_scaling_is_decided_exactly_and_marginal_under_rtol(b):
    # b·(1 + tank) with a decimal b: the float products b·ω0² are rounded, so the given coefficients
    # describe (exactly) a network whose residue at jω0 is complex by ~1e-16 relative: the exact
    # verdict for those coefficients is whatever it is (stable or potentially_unstable), and with a
    # tolerance on the inputs of 1e-12 (far above the rounding) it is never potentially_unstable
    from hil.stability.criteria import Tolerances

    for w0 in (1e-3, 0.37, 10.0, 1e3):
        z = b * (1 + w0 * S / (S**2 + w0**2))
        assert str(check(z).verdict) in ("stable", "potentially_unstable")
        r = check(z, tol=Tolerances(rtol=1e-12))
        assert str(r.verdict) in ("stable", "marginal"), r.summary()
