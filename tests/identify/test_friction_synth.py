"""The tests' stick-slip simulator (``friction_synth``) against scipy's ``solve_ivp`` with events: the
truth of the friction calibration tests is checked before it judges anything."""

from __future__ import annotations

import numpy as np
from friction_synth import FrictionPlant, Mode, band_limited
from scipy.integrate import solve_ivp

from hil.identify.friction import simulate


def _ivp(p: FrictionPlant, u: np.ndarray, T: float) -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities at k T by RK45 (rtol 1e-11) with terminal events at each moving joint's
    velocity zero and each stuck joint's break-away, the accelerations written here from the plant's
    equations ``M a = G u - F_0 - f - B v - K q`` with the stuck joints' rows replaced by ``a_j = 0``."""
    n = p.n
    x = np.zeros(2 * n)
    mode = p.settle(x, u[0], [True] * n, Mode(tuple([False] * n), tuple([0.0] * n)))
    Q, V = np.empty((u.shape[0], n)), np.empty((u.shape[0], n))
    for k in range(u.shape[0]):
        Q[k], V[k] = x[:n], x[n:]
        if any(mode.stuck):
            mode = p.settle(x, u[k], list(mode.stuck), mode)
        t0 = 0.0
        while t0 < T * (1 - 1e-12):
            st = np.array(mode.stuck)
            s = np.array(mode.sign)

            def rhs(_t: float, y: np.ndarray, st: np.ndarray = st, s: np.ndarray = s, uk: np.ndarray = u[k]
                    ) -> np.ndarray:
                q, v = y[:n], np.where(st, 0.0, y[n:])
                f = (p.Fc + p.Fs * np.exp(-((v / p.vs) ** 2))) * s
                A = p.M.copy()
                r = p.G @ uk - p.F0 - f - p.B @ v - p.K @ q
                A[st] = 0.0
                A[st, st] = 1.0
                r[st] = 0.0
                return np.concatenate([v, np.linalg.solve(A, r)])

            events = []
            for j in range(n):
                if st[j]:
                    def ev(_t: float, y: np.ndarray, j: int = j, m: Mode = mode, uk: np.ndarray = u[k]) -> float:
                        return float(p.brk[j] - abs(p.holding(y, uk, m)[j]))
                elif p.fric[j] and s[j] != 0:
                    def ev(_t: float, y: np.ndarray, j: int = j, sj: float = float(s[j])) -> float:
                        return sj * float(y[n + j])
                else:
                    continue
                ev.terminal, ev.direction = True, -1  # type: ignore[attr-defined]
                ev.joint = j  # type: ignore[attr-defined]
                events.append(ev)
            sol = solve_ivp(rhs, (t0, T), x, events=events or None, rtol=1e-11, atol=1e-14, max_step=T / 4)
            x = sol.y[:, -1].copy()
            x[n:][st] = 0.0
            if sol.status != 1:
                break
            hit = [i for i, te in enumerate(sol.t_events) if te.size]
            j = events[hit[0]].joint  # type: ignore[attr-defined]
            t0 = float(sol.t[-1])
            cand = list(st)
            if st[j]:
                lam = p.holding(x, u[k], mode)
                cand[j] = False
                sign = list(mode.sign)
                sign[j] = float(np.sign(lam[j]))
                mode = p.settle(x, u[k], cand, Mode(mode.stuck, tuple(sign)))
            else:
                x[n + j] = 0.0
                cand[j] = True
                mode = p.settle(x, u[k], cand, mode)
    return Q, V


def test_two_joints_coupled_stick_slip_match_solve_ivp() -> None:
    """Two joints coupled through M, B and K, Coulomb friction and offsets on both: reversals, sticking
    (a stuck joint pulled by the other through the coupling spring until it breaks away)."""
    rng = np.random.default_rng(5)
    T = 1e-3
    M = np.array([[1.0, 0.2], [0.2, 0.6]])
    B = np.array([[8.0, -2.0], [-2.0, 6.0]])
    K = np.array([[600.0, -250.0], [-250.0, 900.0]])
    u = np.repeat(band_limited(rng, 40, 100.0, 10.0, 8.0, columns=2), 10, axis=0)
    p = FrictionPlant(M, B, K, Fc=[3.0, 2.5], F0=[0.5, -0.3])
    Q, V = p.simulate(u, T)
    Qr, Vr = _ivp(p, u, T)
    assert np.all(np.mean(V == 0, axis=0) > 0.05)  # both joints stick for a while ...
    assert np.all(np.ptp(Q, axis=0) > 1e-3)  # ... and move
    assert np.max(np.abs(Q - Qr)) < 1e-8 * np.max(np.ptp(Q, axis=0))
    assert np.max(np.abs(V - Vr)) < 1e-7 * np.max(np.ptp(V, axis=0))


def test_one_joint_agrees_with_the_exact_1dof_simulator_and_stribeck_with_solve_ivp() -> None:
    rng = np.random.default_rng(3)
    T = 1e-3
    u = np.repeat(8.0 * np.sin(np.linspace(0, 6 * np.pi, 60)) + rng.normal(0, 1, 60), 10)
    Q, _ = FrictionPlant([[1.5]], [[4.0]], [[0.0]], Fc=3.0, F0=0.7).simulate(u, T)
    x, _ = simulate(1.5, 4.0, 3.0, 0.7, u, T)  # hil.identify.friction's exact segment kernel
    assert np.max(np.abs(Q[:, 0] - x[0])) < 1e-12 * np.ptp(x)
    p = FrictionPlant([[2.0]], [[8.0]], [[0.0]], Fc=3.0, Fs=2.0, vs=0.05, F0=0.4)
    u = np.repeat(band_limited(rng, 30, 100.0, 5.0, 10.0), 10, axis=0)
    Q, V = p.simulate(u, T)
    Qr, Vr = _ivp(p, u, T)
    assert np.max(np.abs(V - Vr)) < 1e-7 * np.ptp(V)
    assert 0.05 < np.mean(V == 0) < 0.7 and np.ptp(Q) > 1e-3
    assert np.max(np.abs(Q - Qr)) < 1e-7 * np.ptp(Q)
