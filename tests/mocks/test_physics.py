"""Scene assembly (bodies, couplings, terminations, humans, SDEA) against independent derivations.

Closed forms are derived here from the equations of motion; cross-coupled m-DOF bodies are
checked against ``scipy.integrate.solve_ivp`` at tight tolerance and against the undamped modal
solution. Energy of passive terminations is checked to be absorbed (>= 0).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import eigh

from hil.errors import ModelError
from hil.lti import StateSpace, tf
from hil.mocks.physics import Scene, mbk_plant, sdea_plant
from hil.mocks.simulator import simulate
from hil.mocks.terminations import (
    Human,
    Impedance,
    WallSpring,
    absorbed_energy,
    passivity_margin,
    spring_array_wall,
    t2_termination,
)


def msd_step(m: float, b: float, k: float, F: float, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form x, v of m x'' + b x' + k x = F (step, from rest); underdamped/critical/undamped."""
    w = math.sqrt(k / m)
    z = b / (2.0 * math.sqrt(k * m))
    xs = F / k
    if z == 0.0:
        return xs * (1 - np.cos(w * t)), xs * w * np.sin(w * t)
    if abs(z - 1.0) < 1e-12:
        e = np.exp(-w * t)
        return xs * (1 - e * (1 + w * t)), xs * w * w * t * e
    wd = w * math.sqrt(1 - z * z)
    e = np.exp(-z * w * t)
    x = xs * (1 - e * (np.cos(wd * t) + z / math.sqrt(1 - z * z) * np.sin(wd * t)))
    v = xs * e * (w / math.sqrt(1 - z * z)) * np.sin(wd * t)
    return x, v


# Exact ZOH: all comparisons to closed forms are limited by round-off only. Signals are
# compared relative to their natural scale with RTOL = 1e-10 (> 1e4 eps, enough for a few
# thousand steps of accumulation with condition numbers ~ 10).
RTOL = 1e-10


# ---------------------------------------------------------------------------------- validation


@pytest.mark.parametrize(
    ("M", "B", "K"),
    [
        ([[1.0, 0.2], [0.0, 1.0]], None, None),  # M not symmetric
        ([[1.0, 2.0], [2.0, 1.0]], None, None),  # M indefinite
        ([[1.0, 0.0], [0.0, 0.0]], None, None),  # M singular (only PSD)
        (np.eye(2), [[1.0, 0.5], [0.0, 1.0]], None),  # B not symmetric
        (np.eye(2), None, [[1.0, 0.0], [0.0, -1e-3]]),  # K not PSD
        (np.eye(2), np.eye(3), None),  # wrong size
        (np.eye(2), [[np.nan, 0.0], [0.0, 1.0]], None),
        ([[-1.0]], None, None),
    ],
)
def test_invalid_matrices_rejected(M, B, K) -> None:
    with pytest.raises(ModelError):
        mbk_plant(M, B, K)


def test_invalid_scene_elements_rejected() -> None:
    sc = Scene()
    sc.add_body("a", np.eye(2))
    sc.add_body("b", 1.0)
    with pytest.raises(ModelError):
        sc.add_spring("a", "b", 1.0)  # 2-DOF port vs 1-DOF port
    with pytest.raises(ModelError):
        sc.add_spring("a", None, [[1.0, 2.0], [0.0, 1.0]])  # non-symmetric
    with pytest.raises(ModelError):
        sc.add_termination("b", t2_termination())  # 3 ports on 1 DOF
    with pytest.raises(ModelError):
        sc.add_spring("nobody", None, 1.0)
    with pytest.raises(ModelError):
        sc.add_spring(("a", [2]), None, 1.0)
    with pytest.raises(ModelError):
        sc.add_body("a", 1.0)  # duplicate name
    with pytest.raises(ModelError):
        Scene(units="furlongs")  # type: ignore[arg-type]
    with pytest.raises(ModelError):
        Scene().build()


# ------------------------------------------------------------------------------------ SDEA


def test_sdea_locked_output_step_response() -> None:
    """Locked output: M x'' + (B + B_f) x' + K_f x = tau, F = K_f x + B_f x' (rotary units)."""
    M, B, K_f, B_f, tau = 2e-3, 0.01, 40.0, 0.05, 0.3
    plant = sdea_plant(M, B, K_f, B_f, m_out=None)
    dt, N = 1e-3, 1500
    res = simulate(plant, dt, [tau], N)
    x_ref, v_ref = msd_step(M, B + B_f, K_f, tau, res.t)
    F_ref = K_f * x_ref + B_f * v_ref
    assert np.max(np.abs(res.output("sdea.position")[:, 0] - x_ref)) <= RTOL * tau / K_f
    assert np.max(np.abs(res.output("sdea_spring.force")[:, 0] - F_ref)) <= RTOL * tau
    # the motor handle's sensor reads the same spring force
    np.testing.assert_array_equal(res.output("sdea.force"), res.output("sdea_spring.force"))


def test_sdea_free_output_deflection_and_static_value() -> None:
    """Free output, no ground damping (B = 0): the spring deflection d = x_m - x_e obeys
    mu d'' + B_f d' + K_f d = tau mu / M with mu = M m / (M + m); static F = tau m / (M + m)."""
    M, K_f, B_f, m, tau = 1e-2, 100.0, 0.2, 3e-2, 1.5
    plant = sdea_plant(M, 0.0, K_f, B_f, m_out=m, units="linear")
    dt, N = 1e-3, 3000
    res = simulate(plant, dt, [tau, 0.0], N)
    mu = M * m / (M + m)
    d_ref, dd_ref = msd_step(mu, B_f, K_f, tau * mu / M, res.t)
    d = res.output("sdea.position")[:, 0] - res.output("sdea_out.position")[:, 0]
    F_static = tau * m / (M + m)
    assert np.max(np.abs(d - d_ref)) <= RTOL * F_static / K_f * 10  # positions grow ~t^2: 10x scale
    F = res.output("sdea_spring.force")[:, 0]
    np.testing.assert_allclose(F, K_f * d_ref + B_f * dd_ref, rtol=0, atol=1e-8 * F_static)
    # after the relative oscillation decays (rate B_f / (2 mu) = 13 /s over 3 s) the static value
    assert abs(F[-1] - F_static) <= 1e-9 * F_static
    # rigid-body motion: the centre of mass accelerates at tau / (M + m)
    com = (M * res.output("sdea.position")[:, 0] + m * res.output("sdea_out.position")[:, 0]) / (M + m)
    np.testing.assert_allclose(com, tau / (M + m) * res.t**2 / 2, rtol=1e-9, atol=1e-15)


def test_sdea_output_on_wall_static_deflection() -> None:
    """SDEA output on a wall spring k_w: static x_e = tau / k_w, spring deflection tau / K_f."""
    M, B, K_f, B_f, m, k_w, tau = 1e-2, 0.5, 200.0, 0.3, 2e-2, 500.0, 2.0
    sc = Scene()
    sc.add_sdea("act", M, B, K_f, B_f, m_out=m)
    sc.add_termination("act_out", WallSpring(k_w, 1.0))
    plant = sc.build()
    dc = plant.system.dcgain()
    col = plant.inputs["act.effort"].start
    F_sl, xe_sl, xm_sl = (plant.outputs[k] for k in ("act_spring.force", "act_out.position", "act.position"))
    np.testing.assert_allclose(dc[F_sl, col] * tau, tau, rtol=1e-12)
    np.testing.assert_allclose(dc[xe_sl, col] * tau, tau / k_w, rtol=1e-12)
    np.testing.assert_allclose((dc[xm_sl, col] - dc[xe_sl, col]) * tau, tau / K_f, rtol=1e-12)
    res = simulate(plant, 1e-3, [tau, 0.0], 4000)
    assert abs(res.output("act_spring.force")[-1, 0] - tau) <= 1e-6 * tau


# ---------------------------------------------------------------------------- m-DOF bodies


def _random_mbk(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((n, n))
    M = X @ X.T + n * np.eye(n)
    Y = rng.standard_normal((n, n))
    K = 200.0 * (Y @ Y.T + 0.5 * np.eye(n))
    Z = rng.standard_normal((n, n))
    B = 0.5 * (Z @ Z.T)
    return M, B, K


def test_cross_coupled_mdof_body_against_solve_ivp() -> None:
    M, B, K = _random_mbk(3, 7)
    f = np.array([1.0, -2.0, 0.5])
    plant = mbk_plant(M, B, K)
    dt, N = 2e-3, 1000
    q0 = np.array([0.01, 0.0, -0.02])
    v0 = np.array([0.0, 0.1, 0.0])
    res = simulate(plant, dt, f, N, x0=plant.state(q0, v0))
    Minv = np.linalg.inv(M)

    def rhs(_t: float, y: np.ndarray) -> np.ndarray:
        q, v = y[:3], y[3:]
        return np.concatenate([v, Minv @ (f - B @ v - K @ q)])

    sol = solve_ivp(rhs, (0.0, N * dt), np.concatenate([q0, v0]), method="DOP853", t_eval=res.t,
                    rtol=1e-12, atol=1e-14)
    scale = np.max(np.abs(sol.y[:3]))
    # DOP853 at rtol 1e-12 is accurate to ~1e-11 relative; exact ZOH to round-off.
    assert np.max(np.abs(res.x[:, :3] - sol.y[:3].T)) <= 1e-9 * scale


def test_undamped_mdof_body_modal_closed_form() -> None:
    """B = 0: q(t) = sum_i phi_i phi_i^T f (1 - cos w_i t) / w_i^2 with M-orthonormal modes."""
    M, _, K = _random_mbk(4, 3)
    f = np.array([0.5, 0.0, -1.0, 2.0])
    w2, Phi = eigh(K, M)  # Phi^T M Phi = I
    plant = mbk_plant(M, None, K)
    dt, N = 1e-3, 2000
    res = simulate(plant, dt, f, N)
    t = res.t
    modal = (Phi.T @ f)[None, :] * (1 - np.cos(np.sqrt(w2)[None, :] * t[:, None])) / w2[None, :]
    q_ref = modal @ Phi.T
    scale = np.max(np.abs(q_ref))
    assert np.max(np.abs(res.x[:, :4] - q_ref)) <= RTOL * scale


def test_two_bodies_coupled_by_spring_closed_form() -> None:
    """Equal masses m, spring k, force F on body a: d = x_a - x_b = F/(2k) (1 - cos(sqrt(2k/m) t)),
    centre c = F t^2 / (4 m)."""
    m, k, F = 0.5, 800.0, 3.0
    sc = Scene()
    sc.add_body("a", m)
    sc.add_body("b", m)
    sc.add_spring("a", "b", k, name="link")
    plant = sc.build()
    res = simulate(plant, 1e-3, [F, 0.0], 1000)
    t = res.t
    d_ref = F / (2 * k) * (1 - np.cos(math.sqrt(2 * k / m) * t))
    c_ref = F * t**2 / (4 * m)
    xa, xb = res.output("a.position")[:, 0], res.output("b.position")[:, 0]
    assert np.max(np.abs(xa - xb - d_ref)) <= RTOL * F / k
    assert np.max(np.abs((xa + xb) / 2 - c_ref)) <= RTOL * max(1.0, c_ref[-1])
    # link force (a on spring) and the sensors of both bodies
    # (xa - xb) cancels: round-off scales with k |xa|, not with the force itself
    atol = 1e-12 * k * np.max(np.abs(xa))
    np.testing.assert_allclose(res.output("link.force")[:, 0], k * (xa - xb), rtol=0, atol=atol)
    np.testing.assert_allclose(res.output("a.force")[:, 0], k * (xa - xb), rtol=0, atol=atol)
    np.testing.assert_allclose(res.output("b.force")[:, 0], -k * (xa - xb), rtol=0, atol=atol)


# ---------------------------------------------------------------------------- terminations


def test_static_damper_termination_has_feedthrough_without_algebraic_loop() -> None:
    """Z(s) = b (pure feedthrough) on a mass with a spring to ground equals the MSD (m, b, k)."""
    m, b, k, F = 1.0, 2 * 0.3 * math.sqrt(50.0), 50.0, 1.0
    sc = Scene()
    sc.add_body("x", m, None, k)
    sc.add_termination("x", StateSpace(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), [[b]]))
    res = simulate(sc.build(), 1e-3, [F], 2000)
    x_ref, v_ref = msd_step(m, b, k, F, res.t)
    assert np.max(np.abs(res.x[:, 0] - x_ref)) <= RTOL * F / k
    # the termination's force is b v (device on termination) and the body's sensor reads it
    np.testing.assert_allclose(res.output("impedance.force")[:, 0], b * v_ref, rtol=0, atol=1e-9 * F)


def test_integrating_impedance_is_a_spring() -> None:
    """Z(s) = k / s (velocity -> force) realized from a transfer function acts as a spring."""
    m, k, F = 0.2, 300.0, 2.0
    sc = Scene()
    sc.add_body("x", m)
    sc.add_termination("x", Impedance(tf([k], [1.0, 0.0]), "spring_tf"))
    res = simulate(sc.build(), 1e-3, [F], 1000)
    x_ref, _ = msd_step(m, 0.0, k, F, res.t)
    assert np.max(np.abs(res.x[:, 0] - x_ref)) <= RTOL * F / k
    np.testing.assert_allclose(res.output("spring_tf.force")[:, 0], k * x_ref, rtol=0, atol=1e-9 * F)


def test_maxwell_termination_with_fast_pole_against_solve_ivp() -> None:
    """Z(s) = k a / (s + a) (spring in series with a damper, corner a = 1e5 rad/s) on a mass at
    1 kHz. Reference: m x'' = F - f, f' = -a f + k a v, integrated by Radau (stiff) tightly."""
    m, k, a, F = 0.1, 1e3, 1e5, 1.0
    sc = Scene()
    sc.add_body("x", m)
    sc.add_termination("x", Impedance(tf([k * a], [1.0, a]), "maxwell"))
    res = simulate(sc.build(), 1e-3, [F], 200)

    def rhs(_t: float, y: np.ndarray) -> np.ndarray:
        _x, v, f = y
        return np.array([v, (F - f) / m, -a * f + k * a * v])

    sol = solve_ivp(rhs, (0, res.t[-1]), [0.0, 0.0, 0.0], method="Radau", t_eval=res.t, rtol=1e-11,
                    atol=1e-14)
    fz = res.output("maxwell.force")[:, 0]
    scale = np.max(np.abs(sol.y[0]))
    assert np.all(np.isfinite(res.x))
    # Radau at rtol 1e-11 is the limiting accuracy (~1e-10 relative); allow 1e-8.
    assert np.max(np.abs(res.x[:, 0] - sol.y[0])) <= 1e-8 * scale
    assert np.max(np.abs(fz - sol.y[2])) <= 1e-8 * max(F, np.max(np.abs(sol.y[2])))


def test_t2_realization_matches_paper_matrix() -> None:
    T2 = t2_termination()
    w = np.array([0.0, 0.5, 1.0, 3.0, 20.0])
    s = 1j * w
    ref = np.empty((w.size, 3, 3), dtype=complex)
    ref[:, 0] = np.stack([9 / (s + 1), -2 / (s + 2), -1 / (s + 3)], axis=-1)
    ref[:, 1] = np.stack([-2 / (s + 2), 5 / (s + 1), 2 / (s + 1)], axis=-1)
    ref[:, 2] = np.stack([-1 / (s + 3), 2 / (s + 1), 4 / (s + 1)], axis=-1)
    np.testing.assert_allclose(T2.system.freqresp(w), ref, rtol=1e-12, atol=1e-14)
    assert T2.system.n <= 9
    assert np.all(T2.system.poles().real < 0)


def test_t2_is_passive_and_absorbs_energy() -> None:
    T2 = t2_termination().system
    w = np.concatenate([[0.0], np.logspace(-3, 4, 400)])
    assert passivity_margin(T2, w) >= 0.0
    # random port velocities (seeded): absorbed energy from rest stays >= 0 at all times.
    rng = np.random.default_rng(42)
    dt = 1e-3
    v = np.cumsum(rng.standard_normal((4000, 3)), axis=0) * 0.01
    E = absorbed_energy(T2, v, dt)
    # trapezoidal error on a ~0.1 J scale is < 1e-9 J; allow that much below zero
    assert np.min(E) >= -1e-9
    assert E[-1] > 0.0


def test_device_energy_never_exceeds_initial_with_passive_termination() -> None:
    """A 3-DOF body on T2 (plus a matrix spring array), released with velocity and no actuation:
    its kinetic + potential energy can only decrease (the termination absorbs >= 0)."""
    M, _, K = _random_mbk(3, 11)
    sc = Scene()
    sc.add_body("slave", M, None, K)
    sc.add_termination("slave", t2_termination())
    plant = sc.build()
    v0 = np.array([0.3, -0.2, 0.5])
    res = simulate(plant, 1e-3, None, 3000, x0=plant.state(None, v0))
    q, v = res.x[:, :3], res.x[:, 3:6]
    E = 0.5 * np.einsum("ti,ij,tj->t", v, M, v) + 0.5 * np.einsum("ti,ij,tj->t", q, K, q)
    assert np.max(E - E[0]) <= 1e-12 * E[0]
    assert E[-1] < 0.99 * E[0]  # and it does absorb


def test_spring_array_wall_static_deflection() -> None:
    """2-DOF body on a coupled 2x2 spring array to a wall: static q = K^-1 f."""
    wall = spring_array_wall((1e5, 2e5), (50.0, 80.0), coupling=3e4)
    sc = Scene()
    sc.add_body("tool", np.diag([0.2, 0.3]))
    sc.add_termination("tool", wall)
    plant = sc.build()
    f = np.array([10.0, -5.0])
    K, _ = wall.matrices(2)
    dc = plant.system.dcgain()
    pos = plant.outputs["tool.position"]
    np.testing.assert_allclose(dc[pos, :2] @ f, np.linalg.solve(K, f), rtol=1e-12)
    # the tool's force sensor reads the applied force at rest (it pushes the wall with f)
    np.testing.assert_allclose(dc[plant.outputs["tool.force"], :2] @ f, f, rtol=1e-12)
    with pytest.raises(ModelError):
        spring_array_wall((1.0, 1.0), coupling=-5.0).matrices(2)


def test_human_arm_adds_mass_damping_stiffness_and_active_force() -> None:
    """Device mass M with a human (m_h, b_h, k_h) and an active step f: (M + m_h) x'' + b_h x'
    + k_h x = f. The handle's sensor (force the device exerts on the hand) reads -M a."""
    M, m_h, b_h, k_h, f = 0.3, 1.2, 6.0, 300.0, 4.0
    sc = Scene()
    sc.add_body("master", M)
    sc.add_human("master", Human(m_h, b_h, k_h, active=lambda t: [f]))
    plant = sc.build()
    res = simulate(plant, 1e-3, None, 2000)
    x_ref, v_ref = msd_step(M + m_h, b_h, k_h, f, res.t)
    assert np.max(np.abs(res.x[:, 0] - x_ref)) <= RTOL * f / k_h
    a_ref = (f - b_h * v_ref - k_h * x_ref) / (M + m_h)
    np.testing.assert_allclose(res.output("master.force")[:, 0], -M * a_ref, rtol=0, atol=1e-9 * f)
