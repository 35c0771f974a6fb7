"""Dry friction on the simulated joints (hil.mocks.friction) against independent derivations.

Every reference is derived here from the equations of motion, not from the stepper:

* a sliding mass with viscous + Coulomb friction decelerates along the closed form
  ``v(t) = (v0 + F_c/b) e^{-bt/m} - F_c/b`` and stops for good at ``t* = (m/b) ln(1 + b v0/F_c)``;
* an undamped mass on a spring with Coulomb friction reverses every half period ``π/ω`` at
  ``x_n = (-1)^n (x0 - 2 n F_c/k)`` and rests at the first reversal with ``|x_n| <= F_s/k``; the energy
  dissipated is ``k (x0² - x_rest²)/2``; with a time step longer than the half period too (stiff case);
* a held force below static friction moves nothing, exactly; above it, ``v = (F - F_c)/b (1 - e^{-bt/m})``;
* over a steady-state cycle of a sinusoidally forced oscillator the friction dissipates ``4 F_c A``;
* the energy balance ``Σ F_k Δq_k = ΔT + ΔV + D`` (work of the held force over each tick is exact)
  holds to round-off;
* a DOF held by static friction inside a coupled body stays exactly still while the rest moves as
  the reduced linear system, until the holding force reaches ``F_s`` (breakaway time in closed form);
* Stribeck friction: the scheme is first order in dt (samples the level per tick) and converges to
  ``scipy.integrate.solve_ivp`` of the continuous equation.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from hil.errors import ModelError
from hil.mocks.friction import Friction, Mechanics, quantize
from hil.mocks.physics import Scene, mbk_plant
from hil.mocks.simulator import Simulator, simulate

# Exact ZOH + exactly located events: comparisons to closed forms are limited by round-off and by
# the event time resolution dt / 2**40 (a velocity error of |a| dt / 2**40 at the event).
ATOL = 1e-12


def test_sliding_mass_decelerates_and_stops_exactly() -> None:
    m, b, Fc, v0, dt = 2.0, 0.5, 3.0, 1.0, 1e-3
    r = simulate(mbk_plant(m, b), dt, None, 2000, x0=[0.0, v0], friction={"body": Friction(Fc)})
    t = r.t
    t_stop = (m / b) * math.log(1 + b * v0 / Fc)
    tc = np.minimum(t, t_stop)
    v = np.where(t < t_stop, (v0 + Fc / b) * np.exp(-b * t / m) - Fc / b, 0.0)
    x = (m / b) * (v0 + Fc / b) * (1 - np.exp(-b * tc / m)) - Fc * tc / b
    np.testing.assert_allclose(r.x[:, 1], v, rtol=0, atol=ATOL)
    np.testing.assert_allclose(r.x[:, 0], x, rtol=0, atol=ATOL)
    after = t > t_stop
    assert np.all(r.x[after, 1] == 0.0)  # sticks for good: no chattering, exactly zero velocity
    assert np.all(r.x[after, 0] == r.x[-1, 0])


@pytest.mark.parametrize("dt", [1e-4, 1e-3, 3e-3])  # 3 ms > the half period (0.31 ms): stiff
def test_spring_mass_coulomb_reversals_rest_and_dissipated_energy(dt: float) -> None:
    m, k, Fc, x0 = 0.01, 1e4, 2.0, 0.05 + 1.3e-4  # not a multiple of 2 Fc/k: rests off zero
    w = math.sqrt(k / m)
    sim = Simulator(mbk_plant(m, 0.0, k), dt, [x0, 0.0], friction={"body": Friction(Fc)})
    n_rev, xn = 0, x0
    while abs(xn) > Fc / k:
        n_rev += 1
        xn = (-1) ** n_rev * (x0 - 2 * n_rev * Fc / k)
    t_rest = n_rev * math.pi / w
    pos, ts = [], []
    for i in range(math.ceil(1.2 * t_rest / dt)):
        sim.tick()
        pos.append(sim.state[0])
        ts.append((i + 1) * dt)
    ss = sim.stick_slip
    assert ss is not None
    assert sim.state[1] == 0.0 and abs(sim.state[0] - xn) < 1e-12, (sim.state, xn)
    assert ss.events == n_rev  # one located event per reversal, none spurious
    assert ss.truncated == 0
    np.testing.assert_allclose(ss.dissipated[0], 0.5 * k * (x0**2 - xn**2), rtol=1e-10)
    # between reversals the motion is the shifted harmonic one: x = c + (x_n - c) cos(w (t - t_n))
    t = np.array(ts)
    nidx = np.minimum(np.floor(t * w / math.pi).astype(int), n_rev)
    x_start = np.array([(-1) ** n * (x0 - 2 * n * Fc / k) for n in nidx])
    centre = np.where(nidx % 2 == 0, Fc / k, -Fc / k)
    ref = np.where(nidx < n_rev, centre + (x_start - centre) * np.cos(w * (t - nidx * math.pi / w)), xn)
    np.testing.assert_allclose(pos, ref, rtol=0, atol=1e-11)


def test_below_static_friction_nothing_moves_above_it_the_closed_form() -> None:
    m, b, Fc, Fs, vs, dt = 1.5, 2.0, 4.0, 5.0, 0.01, 1e-3
    fr = {"body": Friction(Fc, Fs, vs)}
    still = simulate(mbk_plant(m, b), dt, np.full(500, 0.999 * Fs), 500, friction=fr)
    assert np.all(still.x == 0.0)
    # Coulomb only (F_s = F_c): from rest under F > F_c, v = (F - F_c)/b (1 - e^{-bt/m})
    F = 1.5 * Fc
    r = simulate(mbk_plant(m, b), dt, np.full(800, F), 800, friction={"body": Friction(Fc)})
    v = (F - Fc) / b * (1 - np.exp(-b * r.t / m))
    np.testing.assert_allclose(r.x[:, 1], v, rtol=0, atol=ATOL)


def test_oscillating_force_below_static_friction_never_chatters() -> None:
    m, b, k, Fs = 0.5, 0.3, 200.0, 1.0
    n = 4000
    F = 0.95 * Fs * np.sin(2 * np.pi * 3.0 * np.arange(n) * 1e-3)
    r = simulate(mbk_plant(m, b, k), 1e-3, F[:, None], n, friction={"body": Friction(Fs)})
    assert np.all(r.x == 0.0)
    # above it: stick phases are exactly still; each slip phase ends at one located event
    sim = Simulator(mbk_plant(m, b, k), 1e-3, friction={"body": Friction(Fs)})
    h = sim.joints("body")
    v = []
    for f in 1.3 * F / 0.95:
        h.apply_effort([f])
        sim.tick()
        v.append(sim.state[1])
    v_arr = np.array(v)
    still = v_arr == 0.0
    assert 0.05 < still.mean() < 0.95  # both phases occur
    # a DOF that stuck stays stuck until the force exceeds F_s again: count stick phases = slip stops
    stops = int(np.sum(still[1:] & ~still[:-1]))
    ss = sim.stick_slip
    assert ss is not None and ss.truncated == 0
    assert stops <= ss.events <= 3 * stops + 2  # stop events, breakaways and reversals only


def test_energy_balance_to_round_off_and_4_Fc_A_per_cycle() -> None:
    # b = 0: the work of the held force over each tick, F_k (q_{k+1} - q_k), is exact, so
    # Σ F_k Δq_k = ΔT + ΔV + D_friction to round-off
    m, k, Fc, dt, n = 0.2, 800.0, 1.5, 1e-3, 3000
    t = np.arange(n) * dt
    F = 12.0 * np.sin(2 * np.pi * 4.0 * t) + 3.0 * np.sin(2 * np.pi * 11.0 * t)
    sim = Simulator(mbk_plant(m, 0.0, k), dt, friction={"body": Friction(Fc)})
    h = sim.joints("body")
    q = [0.0]
    for f in F:
        h.apply_effort([f])
        sim.tick()
        q.append(sim.state[0])
    ss = sim.stick_slip
    assert ss is not None
    work = float(np.sum(F * np.diff(q)))
    x, v = sim.state
    stored = 0.5 * m * v**2 + 0.5 * k * x**2
    assert abs(work - stored - ss.dissipated[0]) < 1e-10 * work
    # steady state of a damped oscillator driven above the friction level: over one period the path
    # is 4 A and the friction dissipates 4 F_c A (A = half the peak-to-peak displacement)
    # (b/2m = 10 /s: after 5 periods the transient is e^-25 of the motion)
    m, b, k, Fc, f0, dt = 1.0, 20.0, 400.0, 2.0, 2.0, 2e-4
    period = round(1.0 / f0 / dt)
    sim = Simulator(mbk_plant(m, b, k), dt, friction={"body": Friction(Fc)})
    h = sim.joints("body")
    ss = sim.stick_slip
    assert ss is not None
    xs, d0 = [], 0.0
    for i in range(6 * period):
        if i == 5 * period:
            d0 = float(ss.dissipated[0])
            xs = []
        h.apply_effort([60.0 * math.sin(2 * math.pi * f0 * i * dt)])
        sim.tick()
        xs.append(sim.state[0])
    A = 0.5 * (max(xs) - min(xs))
    # the extremes are sampled every dt: a sample misses a peak by at most |a| dt²/8 (≈ 2e-7 m here,
    # |a| ≈ (2π f0)² A ≈ 25 m/s²), i.e. 1.3e-6 of A
    assert abs((ss.dissipated[0] - d0) - 4 * Fc * A) < 5e-6 * 4 * Fc * A


def test_coupled_body_stuck_dof_holds_exactly_then_breaks_away_on_time() -> None:
    # two bodies joined by a spring, dry friction on body a only: a stays still, b oscillates as a
    # mass on a spring to a fixed point, until the spring force reaches F_s
    ma, mb, k, V, dt = 1.0, 0.25, 100.0, 0.5, 1e-4
    w = math.sqrt(k / mb)
    for Fs, breaks in ((1.01 * k * V / w, False), (0.5 * k * V / w, True)):
        sc = Scene()
        sc.add_body("a", ma)
        sc.add_body("b", mb)
        sc.add_spring("a", "b", k)
        plant = sc.build()
        sim = Simulator(plant, dt, plant.state(v=[0.0, V]), friction={"a": Friction(Fs)})
        n = round(2 * math.pi / w / dt)
        qa, qb, t = [], [], []
        for i in range(n):
            sim.tick()
            qa.append(sim.state[0])
            qb.append(sim.state[1])
            t.append((i + 1) * dt)
        t_arr = np.array(t)
        t_break = math.asin(Fs * w / (k * V)) / w if breaks else math.inf
        held = t_arr < t_break
        assert np.all(np.array(qa)[held] == 0.0)
        np.testing.assert_allclose(np.array(qb)[held], V / w * np.sin(w * t_arr[held]), rtol=0, atol=ATOL)
        if breaks:
            assert np.all(np.array(qa)[t_arr > t_break + dt] != 0.0)


def test_coupled_mass_matrix_constraint_force_is_the_reduced_dynamics() -> None:
    # M = [[1, .2], [.2, .6]]: with q0 held, q1 obeys M11 a1 + B11 v1 + K11 q1 = f1 and the holding
    # force is f0 - (M01 a1 + B01 v1 + K01 q1), i.e. the friction force the simulator reports
    M = np.array([[1.0, 0.2], [0.2, 0.6]])
    B = np.array([[0.5, -0.1], [-0.1, 0.3]])
    K = np.array([[900.0, -150.0], [-150.0, 500.0]])
    dt, f = 1e-3, np.array([0.3, 2.0])
    plant = mbk_plant(M, B, K)
    sim = Simulator(plant, dt, friction={"body": [Friction(50.0), None]})
    h = sim.joints("body")
    h.apply_effort(f)
    w = math.sqrt(K[1, 1] / M[1, 1] - (B[1, 1] / (2 * M[1, 1])) ** 2)
    zeta_w = B[1, 1] / (2 * M[1, 1])
    xs = f[1] / K[1, 1]
    for i in range(1, 400):
        sim.tick()
        tt = i * dt
        q1 = xs * (1 - math.exp(-zeta_w * tt) * (math.cos(w * tt) + zeta_w / w * math.sin(w * tt)))
        v1 = xs * math.exp(-zeta_w * tt) * (w + zeta_w**2 / w) * math.sin(w * tt)
        a1 = (f[1] - B[1, 1] * v1 - K[1, 1] * q1) / M[1, 1]
        assert sim.state[0] == 0.0 and sim.state[2] == 0.0
        assert abs(sim.state[1] - q1) < ATOL and abs(sim.state[3] - v1) < 1e-10
        hold = f[0] - (M[0, 1] * a1 + B[0, 1] * v1 + K[0, 1] * q1)
        fr = sim.friction_force()
        assert fr is not None and abs(fr[0] + hold) < 1e-8  # friction = minus the applied net force


def _stribeck_reference(m: float, b: float, F: float, fr: Friction, t_end: float) -> tuple[np.ndarray, np.ndarray]:
    vs = float(fr.stribeck_velocity or 1.0)

    def rhs(_t: float, y: np.ndarray) -> list[float]:
        v = max(y[1], 0.0)  # slipping forward from rest (F > F_s)
        return [y[1], (F - b * v - (fr.F_c + (fr.F_s - fr.F_c) * math.exp(-((v / vs) ** 2)))) / m]

    sol = solve_ivp(rhs, (0.0, t_end), [0.0, 0.0], method="LSODA", rtol=1e-11, atol=1e-14, dense_output=True)
    tt = np.linspace(0.0, t_end, 201)
    return tt, sol.sol(tt)[1]


def test_stribeck_breakaway_is_first_order_and_converges_to_the_continuous_solution() -> None:
    m, b, fr = 0.4, 1.0, Friction(2.0, 3.0, 0.05)
    F, t_end = 3.2, 0.4
    tt, vref = _stribeck_reference(m, b, F, fr, t_end)
    errs = []
    for dt in (2e-3, 1e-3, 5e-4):
        n = round(t_end / dt)
        r = simulate(mbk_plant(m, b), dt, np.full(n, F), n, friction={"body": fr})
        errs.append(float(np.max(np.abs(np.interp(tt, r.t, r.x[:, 1]) - vref))))
    assert errs[-1] < 0.02 * float(np.max(vref))
    assert 1.6 < errs[0] / errs[1] < 2.5 and 1.6 < errs[1] / errs[2] < 2.5, errs  # first order


def test_deterministic_bit_for_bit() -> None:
    plant = mbk_plant(np.array([[1.0, 0.2], [0.2, 0.6]]), np.diag([0.4, 0.2]), np.diag([300.0, 700.0]))
    rng = np.random.default_rng(3)
    F = rng.normal(0.0, 3.0, (1500, 2))
    fr = {"body": [Friction(1.0, 1.4, 0.02), Friction(0.5)]}
    a = simulate(plant, 1e-3, F, 1500, friction=fr)
    b = simulate(plant, 1e-3, F, 1500, friction=fr)
    assert np.array_equal(a.x, b.x) and np.array_equal(a.y, b.y)
    assert np.any(a.x[:, 2] == 0.0) and np.any(a.x[:, 2] != 0.0)  # it sticks and slips


def test_no_friction_takes_the_linear_path_bit_for_bit() -> None:
    plant = mbk_plant(1.0, 0.5, 20.0)
    F = np.sin(np.arange(300) * 0.05)
    ref = simulate(plant, 1e-3, F, 300)
    zero = simulate(plant, 1e-3, F, 300, friction={"body": Friction(0.0)})
    assert np.array_equal(ref.x, zero.x)


def test_invalid_friction_and_mechanics_are_refused() -> None:
    with pytest.raises(ModelError, match="coulomb"):
        Friction(-1.0)
    with pytest.raises(ModelError, match="static"):
        Friction(2.0, 1.0, 0.1)
    with pytest.raises(ModelError, match="stribeck_velocity"):
        Friction(1.0, 2.0)
    with pytest.raises(ModelError, match="encoder step"):
        Mechanics(encoder_step=-1.0)
    with pytest.raises(ModelError, match="unknown bodies"):
        Simulator(mbk_plant(1.0), 1e-3, friction={"nope": Friction(1.0)})


def test_quantize_puts_values_on_the_grid() -> None:
    x = np.array([0.0, 0.26, -0.26, 1.0e-3, 0.75])
    q = quantize(x, 0.5)
    assert np.array_equal(q, [0.0, 0.5, -0.5, 0.0, 1.0])
    assert np.array_equal(quantize(x, 0.0), x)


def test_agrees_with_the_identification_models_independent_simulator() -> None:
    # hil.identify.friction.simulate is a separate implementation (closed-form runs between reversals,
    # Stribeck excess held per period): the twin's stick-slip step must give the same trajectory
    from hil.identify.friction import simulate as identification_simulate

    rng = np.random.default_rng(5)
    n, dt = 3000, 1e-3
    t = np.arange(n) * dt
    u = 80.0 * np.sin(2 * np.pi * 0.7 * t) + 30.0 * np.sin(2 * np.pi * 2.3 * t + rng.uniform(0, 6))
    for fr_twin, extra in ((Friction(20.0), {}), (Friction(20.0, 26.0, 0.01), {"F_s": 6.0, "v_s": 0.01})):
        r = simulate(mbk_plant(95.0, 200.0), dt, u[:, None], n, friction={"body": fr_twin})
        X, V = identification_simulate(95.0, 200.0, 20.0, 0.0, u, dt, **extra)
        assert np.max(np.abs(X[0] - r.x[:-1, 0])) < 1e-12 and np.max(np.abs(V[0] - r.x[:-1, 1])) < 1e-12


def test_friction_synth_records_carry_their_truth(tmp_path) -> None:
    # tests/axis_friction_synth.py (the calibration datasets): the encoder grid, the difference velocity,
    # the exact friction work (= F_c times the true path length) and a readable run record
    from axis_friction_synth import AxisTruth, axis_record, write_record

    from hil.record.hdf5 import RunRecord

    rec = axis_record(4, AxisTruth(F_c=20.0, F_0=-3.0), duration=4.0, encoder_step=1e-6)
    assert np.allclose(rec.q / 1e-6, np.round(rec.q / 1e-6), rtol=0, atol=1e-6)
    np.testing.assert_array_equal(rec.v[1:], np.diff(rec.q) * 1000.0)
    path_true = np.sum(np.abs(np.diff(np.append(rec.q_true, rec.q_true[-1]))))
    assert rec.dissipated == pytest.approx(20.0 * path_true, rel=1e-3)  # sampled path: reversals between samples
    assert rec.truth.as_dict(("coulomb", "offset")) == {"M": 95.0, "B": 200.0, "F_c": 20.0, "F_0": -3.0}
    r = RunRecord.open(write_record(rec, tmp_path / "axis.h5"))
    np.testing.assert_array_equal(r.channels["axis.position"].reshape(-1), rec.q)
    np.testing.assert_array_equal(r.channels["axis.effort_cmd"].reshape(-1), rec.u)
    assert r.meta["truth"]["F_0"] == -3.0
