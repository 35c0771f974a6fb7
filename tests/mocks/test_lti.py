"""Exact discretization and realizations of hil.lti against closed-form responses.

Every expected value is derived in this file from the textbook solution of the ODE; nothing is
hard-coded. Tolerances are relative to the natural scale of the signal (static deflection
F/k, or unit amplitude) and justified next to each assertion.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg as sla

from hil.errors import ModelError
from hil.lti import (
    StateSpace,
    append,
    expm_accurate,
    feedback,
    gain,
    series,
    tf,
    tf_matrix,
    zoh_matrices,
)


def msd(m: float, b: float, k: float) -> StateSpace:
    """m x'' + b x' + k x = u; states (x, v); outputs (x, v)."""
    return StateSpace([[0.0, 1.0], [-k / m, -b / m]], [[0.0], [1.0 / m]], np.eye(2), np.zeros((2, 1)))


def msd_step(m: float, b: float, k: float, F: float, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form position and velocity of m x'' + b x' + k x = F (step at t = 0, from rest)."""
    w = math.sqrt(k / m)
    z = b / (2.0 * math.sqrt(k * m))
    xs = F / k
    if z == 0.0:
        return xs * (1 - np.cos(w * t)), xs * w * np.sin(w * t)
    if abs(z - 1.0) < 1e-12:
        e = np.exp(-w * t)
        return xs * (1 - e * (1 + w * t)), xs * w * w * t * e
    assert z < 1.0
    wd = w * math.sqrt(1 - z * z)
    e = np.exp(-z * w * t)
    x = xs * (1 - e * (np.cos(wd * t) + z / math.sqrt(1 - z * z) * np.sin(wd * t)))
    v = xs * e * (w / math.sqrt(1 - z * z)) * np.sin(wd * t)
    return x, v


CASES = {
    # (m kg, b N.s/m, k N/m): underdamped (zeta = 0.1), critically damped, undamped
    "underdamped": (2.0, 2 * 0.1 * math.sqrt(2.0 * 50.0), 50.0),
    "critical": (2.0, 2 * math.sqrt(2.0 * 50.0), 50.0),
    "undamped": (2.0, 0.0, 50.0),
}


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("dt", [1e-3, 0.05])
def test_zoh_step_equals_closed_form_at_samples(case: str, dt: float) -> None:
    m, b, k = CASES[case]
    F = 3.0
    N = round(4.0 / dt)
    x, _ = msd(m, b, k).discretize(dt).simulate(np.full((N + 1, 1), F))
    t = np.arange(N + 1) * dt
    x_ref, v_ref = msd_step(m, b, k, F, t)
    # Exact ZOH: the only error is round-off, ~N * eps * (condition ~ 1) relative to F/k.
    # 1e-11 leaves > 100x margin over N * eps for N <= 4000 steps (~1e-12).
    assert np.max(np.abs(x[:, 0] - x_ref)) <= 1e-11 * F / k
    assert np.max(np.abs(x[:, 1] - v_ref)) <= 1e-11 * F / k * math.sqrt(k / m)


def test_stiff_undamped_extreme_at_1khz_bounded_and_exact() -> None:
    """k = 1e6 N/m, m = 1e-3 kg (w = 3.16e4 rad/s, 10x Nyquist of 1 kHz), zero damping."""
    m, k, F, dt = 1e-3, 1e6, 2.0, 1e-3
    N = 1000  # 1 s
    x, _ = msd(m, 0.0, k).discretize(dt).simulate(np.full((N + 1, 1), F))
    t = np.arange(N + 1) * dt
    x_ref, v_ref = msd_step(m, 0.0, k, F, t)
    w = math.sqrt(k / m)
    # Bounded: the exact solution never exceeds 2 F/k; allow nothing beyond round-off.
    assert np.max(np.abs(x[:, 0])) <= 2 * F / k * (1 + 1e-9)
    # Tolerance: per step the transition matrix of a 31.6 rad rotation carries ~1e-14 relative
    # error (measured ~5e-15, see expm test below), accumulating linearly to ~1e-11 over 1000
    # steps; the reference itself has cos(w t) argument round-off ~ w t eps = 3.5e-12. 1e-9 gives
    # a 100x margin and is still 1e6 times below what an explicit integrator achieves here.
    assert np.max(np.abs(x[:, 0] - x_ref)) <= 1e-9 * F / k
    assert np.max(np.abs(x[:, 1] - v_ref)) <= 1e-9 * F / k * w


def test_fast_controller_pole_1e5_at_1khz() -> None:
    """Critically damped double pole at -1e5 rad/s (a fast continuous controller) plus a slow
    mode at -1 rad/s driven by it: stiffness ratio 1e5, A dt has norm ~1e7."""
    a = 1e5
    # x1' = x2, x2' = -a^2 x1 - 2 a x2 + a^2 u  => x1 = 1 - (1 + a t) e^{-a t} for a unit step;
    # x3' = -x3 + x1 (slow filter of x1)
    A = [[0.0, 1.0, 0.0], [-a * a, -2 * a, 0.0], [1.0, 0.0, -1.0]]
    B = [[0.0], [a * a], [0.0]]
    sys = StateSpace(A, B, np.eye(3), np.zeros((3, 1)))
    dt, N = 1e-3, 2000
    x, _ = sys.discretize(dt).simulate(np.ones((N + 1, 1)))
    t = np.arange(N + 1) * dt
    x1 = 1 - (1 + a * t) * np.exp(-a * t)
    # x3 = int_0^t e^{-(t-s)} x1(s) ds, solved in closed form:
    # int e^{-(t-s)} ds = 1 - e^{-t};  int e^{-(t-s)} (1 + a s) e^{-a s} ds
    #   = e^{-t} int (1 + a s) e^{-(a-1) s} ds from 0 to t
    c = a - 1.0
    integral = (1 - np.exp(-c * t)) / c + a * (1 - np.exp(-c * t) * (1 + c * t)) / c**2
    x3 = (1 - np.exp(-t)) - np.exp(-t) * integral
    assert np.all(np.isfinite(x))
    # Exact ZOH: round-off only (signals of scale 1). The fast mode is damped every step, so its
    # error stays at a few eps: 1e-12 is generous. The slow mode integrates its per-step error:
    # its steady state is Bd3 / (1 - Ad33), whose sensitivity to an ulp-level error of
    # Ad33 = e^{-dt} is 1 / (1 - e^{-dt}) ~ tau / dt = 1000; scaling and squaring through ~25
    # squarings (||A dt|| ~ 1e7) leaves Ad33 a few tens of ulps off (measured 44 ulp, against a
    # 40-digit mpmath reference, for scipy's expm and ours alike), hence ~6e-12; allow 3e-11.
    assert np.max(np.abs(x[:, 0] - x1)) <= 1e-12
    assert np.max(np.abs(x[:, 2] - x3)) <= 3e-11


def test_expm_accurate_on_stiff_rotation() -> None:
    """The balanced + extra-squared expm is accurate to ~1e-14 on a 31.6 rad rotation block."""
    m, k, dt = 1e-3, 1e6, 1e-3
    w = math.sqrt(k / m)
    Ad, Bd = zoh_matrices(np.array([[0.0, 1.0], [-k / m, 0.0]]), np.array([[0.0], [1 / m]]), dt)
    c, s = math.cos(w * dt), math.sin(w * dt)
    # reference error from the argument round-off: w dt eps ~ 7e-15; allow 5e-14 relative to the
    # natural scale of each entry (a plain scipy.linalg.expm was measured at ~3e-13 here).
    tol = 5e-14
    assert abs(Ad[0, 0] - c) <= tol and abs(Ad[1, 1] - c) <= tol
    assert abs(Ad[0, 1] - s / w) <= tol / w and abs(Ad[1, 0] + w * s) <= tol * w
    assert abs(Bd[0, 0] - (1 - c) / k) <= tol / k
    assert abs(Bd[1, 0] - s / (m * w)) <= tol / (m * w)
    # agrees with scipy's expm on a benign matrix
    M = np.array([[-1.0, 2.0], [0.5, -3.0]])
    np.testing.assert_allclose(expm_accurate(M), sla.expm(M), rtol=1e-13, atol=1e-14)


@pytest.mark.parametrize("case", list(CASES))
def test_sinusoidal_steady_state_matches_frequency_response(case: str) -> None:
    """Drive the MSD with an exact sine generator (an autonomous LTI exosystem in series), so the
    discretization stays exact, and compare with |G(jW)| and arg G(jW)."""
    m, b, k = CASES[case]
    W = 3.0  # rad/s, away from resonance sqrt(k/m) = 5 rad/s
    gen = StateSpace([[0.0, W], [-W, 0.0]], [[0.0], [0.0]], [[1.0, 0.0]], [[0.0]])  # sin(W t)
    plant = series(gen, msd(m, b, k))
    dt = 1e-2
    N = 3000  # 30 s
    x0 = np.array([0.0, 1.0, 0.0, 0.0])
    x, _ = plant.discretize(dt).simulate(np.zeros((N + 1, 1)), x0)
    t = np.arange(N + 1) * dt
    G = 1.0 / (k - m * W * W + 1j * b * W)
    w0 = math.sqrt(k / m)
    if b == 0.0:
        # zero initial state: x = |G| (sin W t - (W / w0) sin w0 t) -- no decay, full solution
        ref = abs(G) * (np.sin(W * t) - (W / w0) * np.sin(w0 * t))
        sel = slice(None)
    else:
        ref = abs(G) * np.sin(W * t + np.angle(G))
        sel = t > 25.0  # transients decay at least as e^{-zeta w0 t}: e^{-12} here
    decay = b / (2 * m)
    transient_bound = 10 * abs(G) * math.exp(-decay * 25.0) if b else 0.0
    # exact discretization: round-off (~1e-12) plus the bounded leftover transient
    assert np.max(np.abs(x[sel, 2] - ref[sel])) <= 1e-10 * abs(G) + transient_bound


def test_foh_exact_for_ramp_input() -> None:
    """Double integrator driven by u = t: x = t^3 / 6 exactly with FOH; ZOH lags."""
    sys = StateSpace([[0.0, 1.0], [0.0, 0.0]], [[0.0], [1.0]], np.eye(2), np.zeros((2, 1)))
    dt, N = 0.1, 50
    t = np.arange(N + 1) * dt
    x_foh, _ = sys.discretize(dt, "foh").simulate(t.reshape(-1, 1))
    x_zoh, _ = sys.discretize(dt, "zoh").simulate(t.reshape(-1, 1))
    np.testing.assert_allclose(x_foh[:, 0], t**3 / 6, rtol=1e-12, atol=1e-13)
    assert np.max(np.abs(x_zoh[:, 0] - t**3 / 6)) > 1e-3  # the hold matters


def test_discretization_is_cached_and_matrices_readonly() -> None:
    sys = msd(1.0, 0.5, 3.0)
    assert sys.discretize(1e-3) is sys.discretize(1e-3)
    assert sys.discretize(1e-3) is not sys.discretize(2e-3)
    with pytest.raises(ValueError):
        sys.A[0, 0] = 1.0
    with pytest.raises(ModelError):
        sys.discretize(0.0)
    with pytest.raises(ModelError):
        sys.discretize(1e-3, "tustin")  # type: ignore[arg-type]


def test_tf_and_transfer_matrix_realizations() -> None:
    w = np.array([0.0, 0.3, 1.0, 7.0, 100.0])
    s = 1j * w
    g = tf([2.0, 1.0], [3.0, 1.0, 4.0])
    np.testing.assert_allclose(g.freqresp(w)[:, 0, 0], (2 * s + 1) / (3 * s**2 + s + 4), rtol=1e-12)
    biproper = tf([3.0, 1.0, 2.0], [1.0, 2.0, 3.0])
    np.testing.assert_allclose(biproper.freqresp(w)[:, 0, 0], (3 * s**2 + s + 2) / (s**2 + 2 * s + 3),
                               rtol=1e-12)
    entries = [[([1.0], [1.0, 1.0]), None, 2.0], [([1.0, 0.0], [1.0, 3.0]), ([4.0], [2.0, 2.0]), ([1.0], [1.0, 1.0])]]
    G = tf_matrix(entries)
    ref = np.stack([
        np.stack([1 / (s + 1), 0 * s, 2 + 0 * s], axis=-1),
        np.stack([s / (s + 3), 4 / (2 * s + 2), 1 / (s + 1)], axis=-1),
    ], axis=1)
    np.testing.assert_allclose(G.freqresp(w), ref, rtol=1e-12, atol=1e-14)
    # equal denominators (up to scale) in a column are merged: column 1 needs 2 states, column 2
    # one, column 3 one
    assert G.n == 4


@pytest.mark.parametrize("bad", [
    ([1.0, 0.0, 0.0], [1.0, 1.0]),  # improper
    ([1.0], [0.0, 0.0]),  # zero denominator
    ([float("nan")], [1.0, 1.0]),
])
def test_bad_transfer_functions_rejected(bad: tuple[list[float], list[float]]) -> None:
    with pytest.raises(ModelError):
        tf(*bad)


def test_bad_state_space_shapes_rejected() -> None:
    with pytest.raises(ModelError):
        StateSpace(np.eye(2), np.ones((3, 1)), np.ones((1, 2)), np.zeros((1, 1)))
    with pytest.raises(ModelError):
        StateSpace(np.eye(2), np.ones((2, 1)), np.ones((1, 3)), np.zeros((1, 1)))
    with pytest.raises(ModelError):
        StateSpace([[np.inf]], [[1.0]], [[1.0]], [[0.0]])


def test_interconnections_match_transfer_algebra() -> None:
    w = np.array([0.1, 1.0, 10.0])
    s = 1j * w
    g1 = tf([1.0], [1.0, 1.0])
    g2 = tf([2.0, 0.0], [1.0, 5.0])
    np.testing.assert_allclose(series(g1, g2).freqresp(w)[:, 0, 0], 2 * s / ((s + 1) * (s + 5)), rtol=1e-12)
    np.testing.assert_allclose(feedback(g1, 3.0).freqresp(w)[:, 0, 0], 1 / (s + 4), rtol=1e-12)
    # dynamic controller: G/(1 + G C)
    ref = (1 / (s + 1)) / (1 + (1 / (s + 1)) * 2 * s / (s + 5))
    np.testing.assert_allclose(feedback(g1, g2).freqresp(w)[:, 0, 0], ref, rtol=1e-12)
    # positive feedback with a biproper loop: D1 D2 = 1 -> ill-posed
    with pytest.raises(ModelError):
        feedback(gain(1.0), gain(1.0), sign=+1.0)
    both = append(g1, g2)
    F = both.freqresp(w)
    np.testing.assert_allclose(F[:, 0, 0], 1 / (s + 1), rtol=1e-12)
    np.testing.assert_allclose(F[:, 1, 1], 2 * s / (s + 5), rtol=1e-12)
    np.testing.assert_allclose(F[:, 0, 1], 0.0)
    np.testing.assert_allclose(g1.dcgain(), [[1.0]])
    with pytest.raises(ModelError):
        tf([1.0], [1.0, 0.0]).dcgain()
