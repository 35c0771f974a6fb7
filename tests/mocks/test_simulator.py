"""Lockstep simulator: handles, exact stepping, determinism, actuator nonlinearities, simulate()."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import cont2discrete

from hil.errors import ModelError
from hil.mocks.physics import Scene, mbk_plant, sdea_plant
from hil.mocks.simulator import ActuatorModel, Simulator, simulate
from hil.mocks.terminations import Human, t2_termination


def undamped_or_underdamped_step(m: float, b: float, k: float, F: float, t: np.ndarray) -> np.ndarray:
    """Closed-form position of m x'' + b x' + k x = F from rest (zeta < 1)."""
    w = math.sqrt(k / m)
    z = b / (2 * math.sqrt(k * m))
    wd = w * math.sqrt(1 - z * z)
    return F / k * (1 - np.exp(-z * w * t) * (np.cos(wd * t) + z / math.sqrt(1 - z * z) * np.sin(wd * t)))


def test_handles_tick_and_closed_form() -> None:
    m, b, k, F, dt = 0.5, 1.0, 200.0, 2.0, 1e-3
    sim = Simulator(mbk_plant(m, b, k, name="arm"), dt)
    h = sim.joints("arm")
    assert h.dof == 1
    xs = [h.position()[0]]
    for i in range(1500):
        h.apply_effort([F])
        sim.tick()
        assert sim.step_count == i + 1
        assert sim.time == (i + 1) * dt  # computed as k * dt, never accumulated
        xs.append(h.position()[0])
    t = np.arange(1501) * dt
    ref = undamped_or_underdamped_step(m, b, k, F, t)
    # exact ZOH: round-off only, relative to F/k (see test_lti for the budget)
    assert np.max(np.abs(np.array(xs) - ref)) <= 1e-10 * F / k
    np.testing.assert_array_equal(h.velocity(), sim.state[1:2])


def test_stiff_extreme_case_through_handles_at_1khz() -> None:
    """1e6 N/m on 1e-3 kg, zero damping, 1 kHz: bounded, within 1e-9 F/k of the exact solution
    (per-step transition error ~1e-14 accumulated over 1000 steps plus cos(w t) argument round-off
    ~3.5e-12; 1e-9 leaves a 100x margin)."""
    m, k, F, dt = 1e-3, 1e6, 5.0, 1e-3
    sim = Simulator(mbk_plant(m, 0.0, k), dt)
    h = sim.joints("body")
    h.apply_effort([F])
    xs = np.empty(1001)
    xs[0] = 0.0
    for i in range(1000):
        sim.tick()
        xs[i + 1] = h.position()[0]
    t = np.arange(1001) * dt
    ref = F / k * (1 - np.cos(math.sqrt(k / m) * t))
    assert np.max(np.abs(xs)) <= 2 * F / k * (1 + 1e-9)
    assert np.max(np.abs(xs - ref)) <= 1e-9 * F / k


def test_sampled_pd_loop_against_independent_discretization() -> None:
    """A discrete PD controller (the runner's job) closed around the simulator equals the
    recursion with (Ad, Bd) from scipy.signal.cont2discrete (an independent ZOH implementation)."""
    m, b, k, dt = 0.2, 0.1, 0.0, 1e-3
    Kp, Kd, r = 400.0, 4.0, 0.05
    plant = mbk_plant(m, b, k)

    def pd(_t: float, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        return Kp * (r - q) - Kd * v

    res = simulate(plant, dt, pd, 800)
    A = np.array([[0.0, 1.0], [-k / m, -b / m]])
    B = np.array([[0.0], [1.0 / m]])
    Ad, Bd, *_ = cont2discrete((A, B, np.eye(2), np.zeros((2, 1))), dt, method="zoh")
    x = np.zeros(2)
    ref = [x]
    for _ in range(800):
        u = Kp * (r - x[0]) - Kd * x[1]
        x = Ad @ x + Bd[:, 0] * u
        ref.append(x)
    np.testing.assert_allclose(res.x, np.array(ref), rtol=0, atol=1e-12 * r * max(1.0, Kd / m))
    np.testing.assert_allclose(res.u[:, 0], Kp * (r - res.x[:-1, 0]) - Kd * res.x[:-1, 1], rtol=1e-13,
                               atol=1e-13)


def _teleop_plant():
    """Master (1 DOF, human with active force) coupled to a 3-DOF slave on T2."""
    sc = Scene()
    sc.add_body("master", 0.4, 0.5)
    sc.add_body("slave", np.diag([0.3, 0.3, 0.2]), 0.2 * np.eye(3), None)
    sc.add_spring("master", ("slave", [0]), 500.0, 2.0, name="coupling")
    sc.add_termination("slave", t2_termination())
    sc.add_human("master", Human(1.0, 5.0, 100.0, active=lambda t: [2.0 * math.sin(3.0 * t)]))
    return sc.build()


def test_same_run_twice_is_bit_identical_and_blas_path_agrees() -> None:
    plant = _teleop_plant()
    rng_efforts = np.random.default_rng(5).standard_normal((500, plant.n_dof))
    a = simulate(plant, 1e-3, rng_efforts, 500)
    b = simulate(plant, 1e-3, rng_efforts, 500)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.y, b.y)
    c = simulate(plant, 1e-3, rng_efforts, 500, exact_sum=False)
    np.testing.assert_allclose(c.x, a.x, rtol=0, atol=1e-12 * np.max(np.abs(a.x)))


def test_reset_restores_initial_conditions() -> None:
    plant = _teleop_plant()
    sim = Simulator(plant, 1e-3)
    x0 = plant.state(q=[0.01, 0.0, 0.0, 0.0])
    sim.reset(x0)
    h = sim.joints("master")
    for _ in range(50):
        h.apply_effort([1.0])
        sim.tick()
    first = sim.state
    sim.reset(x0)
    assert sim.time == 0.0
    np.testing.assert_array_equal(sim.state, x0)
    for _ in range(50):
        h.apply_effort([1.0])
        sim.tick()
    np.testing.assert_array_equal(sim.state, first)
    with pytest.raises(ModelError):
        sim.reset(np.zeros(3))


def test_handles_are_simulated_joints_and_validate() -> None:
    sim = Simulator(_teleop_plant(), 1e-3)
    slave = sim.joints("slave")
    assert slave.dof == 3
    for attr in ("apply_effort", "position", "velocity", "measured_force"):
        assert callable(getattr(slave, attr))
    assert slave.position().shape == (3,)
    assert slave.measured_force().shape == (3,)
    with pytest.raises(ModelError):
        slave.apply_effort([1.0, 2.0])
    with pytest.raises(ModelError):
        slave.apply_effort([np.nan, 0.0, 0.0])
    with pytest.raises(ModelError):
        sim.joints("nobody")
    with pytest.raises(ModelError):
        sim.output("nothing")


def test_sdea_handle_measures_spring_force() -> None:
    K_f, B_f = 50.0, 0.1
    sim = Simulator(sdea_plant(1e-3, 0.01, K_f, B_f, m_out=5e-3), 1e-3)
    h = sim.joints("sdea")
    h.apply_effort([0.2])
    for _ in range(100):
        sim.tick()
    xm, xe = sim.output("sdea.position")[0], sim.output("sdea_out.position")[0]
    vm, ve = sim.output("sdea.velocity")[0], sim.output("sdea_out.velocity")[0]
    assert h.measured_force()[0] == pytest.approx(K_f * (xm - xe) + B_f * (vm - ve), rel=1e-12)


def test_human_profile_array_equals_callable_and_ends_at_zero() -> None:
    dt, N = 1e-3, 300
    t = np.arange(N) * dt
    prof = np.sin(7.0 * t)

    def build(active):
        sc = Scene()
        sc.add_body("h", 0.5, 1.0, 50.0)
        sc.add_human("h", Human(0.5, 1.0, 10.0, active=active))
        return sc.build()

    a = simulate(build(lambda tt: [math.sin(7.0 * tt)]), dt, None, N)
    b = simulate(build(prof), dt, None, N)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(b.u[:, 1], prof)
    c = simulate(build(prof[:100]), dt, None, N)
    np.testing.assert_array_equal(c.u[100:, 1], 0.0)
    # explicit override of the exogenous input
    sim = Simulator(build(prof), dt)
    sim.set_input("human.active", [3.0])
    sim.tick()
    assert sim.last_input[1] == 3.0


def test_actuator_saturation_and_delay() -> None:
    plant = mbk_plant(1.0, 0.5, 20.0)
    dt, N = 1e-3, 400
    sat = simulate(plant, dt, np.full(N, 10.0), N, actuators={"body": ActuatorModel(limit=2.0)})
    ref = simulate(plant, dt, np.full(N, 2.0), N)
    np.testing.assert_array_equal(sat.x, ref.x)
    delayed = simulate(plant, dt, np.full(N, 2.0), N, actuators={"body": ActuatorModel(delay_ticks=7)})
    np.testing.assert_array_equal(delayed.x[7:], ref.x[: N + 1 - 7])
    np.testing.assert_array_equal(delayed.x[:8], 0.0)


def test_coulomb_friction_sticks_and_decelerates() -> None:
    m, Fc, dt = 2.0, 3.0, 1e-3
    plant = mbk_plant(m)
    act = {"body": ActuatorModel(coulomb=Fc)}
    stuck = simulate(plant, dt, np.full(100, 0.9 * Fc), 100, actuators=act)
    np.testing.assert_array_equal(stuck.x, 0.0)
    # sliding from v0 with no command: v decreases by Fc/m per second (held sign, exact ZOH)
    v0 = 1.0
    slide = simulate(plant, dt, None, 200, x0=[0.0, v0], actuators=act)
    t = slide.t
    np.testing.assert_allclose(slide.x[:, 1], v0 - Fc / m * t, rtol=0, atol=1e-12)
    with pytest.raises(ModelError):
        ActuatorModel(coulomb=-1.0)
