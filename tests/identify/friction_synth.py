"""Event-located stick-slip simulation of a linear mechanical system with friction on some joints,
written for the tests independently of ``hil.identify`` (the estimators never simulate; this is the
truth they are judged against).

Plant (``n`` joints, positions ``q`` [m or rad])::

    M q'' + B q' + K q = G u - F_0 - f,      f_j = (F_c,j + F_s,j exp(-(v_j/v_s,j)^2)) sgn(v_j)   (moving)

``u`` (n_in,) held constant over each period ``T`` (zero-order hold), positions and velocities sampled
at ``k T`` before ``u_k`` acts. A joint with ``F_c + F_s > 0`` sticks when its velocity reaches zero
and the force needed to hold it, ``lambda_j``, stays within the break-away level ``F_c + F_s``
(Karnopp); it breaks away in the direction of ``lambda_j`` when ``|lambda_j|`` exceeds it. With the
joints of the stuck set ``S`` held (``v_S = a_S = 0``) the free joints ``F`` obey
``M_FF a_F = r_F``, ``r = G u - F_0 - f - B v - K q``, and ``lambda_S = r_S - M_SF a_F``.

Between events the motion is that of a linear system with a constant force: with Coulomb friction
only it is propagated EXACTLY (modal solution of the linear system with a constant force);
with a Stribeck term (one joint) by classical Runge-Kutta (``RK4_STEPS`` steps per period). Events (a moving
joint's velocity through zero, a stuck joint's holding force at its break-away level) are checked at
``CHECKS`` points per period and located by ``scipy.optimize.brentq`` on the propagated motion. The
tests check this against ``scipy.integrate.solve_ivp`` with events.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import brentq

#: points per period at which events are looked for
CHECKS = 8
#: RK4 steps per period (Stribeck)
RK4_STEPS = 16
#: friction events in one period beyond which the motion is taken for chattering (an error)
MAX_EVENTS = 100


@dataclass
class Mode:
    """Which friction joints are stuck, and the direction of the moving ones (0 for stuck/frictionless)."""

    stuck: tuple[bool, ...]
    sign: tuple[float, ...]


class FrictionPlant:
    """The plant of the module docstring. ``Fc``, ``Fs``, ``vs``, ``F0`` per joint (0 / absent: none)."""

    def __init__(self, M: ArrayLike, B: ArrayLike, K: ArrayLike, *, Fc: ArrayLike, F0: ArrayLike | None = None,
                 Fs: ArrayLike | None = None, vs: ArrayLike | None = None, G: ArrayLike | None = None) -> None:
        self.M = np.atleast_2d(np.asarray(M, float))
        self.n = n = self.M.shape[0]
        self.B = np.atleast_2d(np.asarray(B, float))
        self.K = np.atleast_2d(np.asarray(K, float))
        self.Fc = np.broadcast_to(np.asarray(Fc, float), (n,)).copy()
        self.F0 = np.zeros(n) if F0 is None else np.broadcast_to(np.asarray(F0, float), (n,)).copy()
        self.Fs = np.zeros(n) if Fs is None else np.broadcast_to(np.asarray(Fs, float), (n,)).copy()
        self.vs = np.ones(n) if vs is None else np.broadcast_to(np.asarray(vs, float), (n,)).copy()
        self.G = np.eye(n) if G is None else np.atleast_2d(np.asarray(G, float))
        self.fric = (self.Fc + self.Fs) > 0
        self.brk = self.Fc + self.Fs
        self.stribeck = bool(np.any(self.Fs > 0))
        if self.stribeck and n != 1:
            raise ValueError("the Stribeck term is simulated for one joint only")
        self._cache: dict[tuple, tuple[NDArray, NDArray, NDArray, NDArray, NDArray]] = {}
        self._maps: dict[tuple, tuple[NDArray, NDArray]] = {}

    # ------------------------------------------------------------------ forces
    def friction(self, v: NDArray, mode: Mode) -> NDArray:
        s = np.asarray(mode.sign)
        return (self.Fc + self.Fs * np.exp(-((v / self.vs) ** 2))) * s

    def holding(self, x: NDArray, u: NDArray, mode: Mode) -> NDArray:
        """``lambda`` (n,) of the stuck joints (0 elsewhere) at state ``x = (q, v)``."""
        n = self.n
        q, v = x[:n], x[n:]
        st = np.asarray(mode.stuck)
        r = self.G @ u - self.F0 - self.friction(v, mode) - self.B @ v - self.K @ q
        free = ~st
        aF = np.linalg.solve(self.M[np.ix_(free, free)], r[free]) if free.any() else np.zeros(0)
        lam = np.zeros(n)
        lam[st] = r[st] - self.M[np.ix_(st, free)] @ aF
        return lam

    def settle(self, x: NDArray, u: NDArray, candidates: Sequence[bool], mode: Mode) -> Mode:
        """The mode at an instant where the joints ``candidates`` are at rest (Karnopp): stuck while
        ``|lambda| <= F_c + F_s``; the one exceeding it most breaks away (direction of lambda), repeat."""
        stuck = [bool(c) and bool(f) for c, f in zip(candidates, self.fric, strict=True)]
        sign = [0.0 if stuck[j] else mode.sign[j] for j in range(self.n)]
        while True:
            m = Mode(tuple(stuck), tuple(sign))
            if not any(stuck):
                return m
            lam = self.holding(x, u, m)
            excess = np.where(stuck, np.abs(lam) / np.maximum(self.brk, 1e-300), 0.0)
            j = int(np.argmax(excess))
            if excess[j] <= 1.0:
                return m
            stuck[j] = False
            sign[j] = float(np.sign(lam[j]))

    # ------------------------------------------------------------------ motion
    def _modal(self, mode: Mode) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray]:
        """``(free, lam, V, Vinv, Mi)`` of the free joints' system ``y' = A_F y + [0; M_FF^-1 c]``,
        ``y = (q_F, v_F)``, ``A_F = [[0, I], [-M_FF^-1 K_FF, -M_FF^-1 B_FF]]`` (eigen-decomposition)."""
        hit = self._cache.get(mode.stuck)
        if hit is not None:
            return hit
        free = np.flatnonzero(~np.asarray(mode.stuck))
        m = free.size
        Mi = np.linalg.inv(self.M[np.ix_(free, free)])
        A = np.zeros((2 * m, 2 * m))
        A[:m, m:] = np.eye(m)
        A[m:, :m] = -Mi @ self.K[np.ix_(free, free)]
        A[m:, m:] = -Mi @ self.B[np.ix_(free, free)]
        lam, V = np.linalg.eig(A)
        out = (free, lam, V, np.linalg.inv(V), Mi)
        self._cache[mode.stuck] = out
        return out

    def _linear_maps(self, mode: Mode, ts: NDArray) -> tuple[NDArray, NDArray]:
        """``(Phi, Psi)`` (nt, 2n, 2n), (nt, 2n, n): ``x(t) = Phi x0 + Psi w`` in a Coulomb mode for the
        constant generalized force ``w = G u - F_0 - F_c s`` (the stuck joints held: their spring force
        on the free joints, ``-K_FS q_S``, enters through ``x0``)."""
        n = self.n
        free, lam, V, Vi, Mi = self._modal(mode)
        stk = np.flatnonzero(np.asarray(mode.stuck))
        m = free.size
        nt = ts.size
        Phi = np.zeros((nt, 2 * n, 2 * n))
        Psi = np.zeros((nt, 2 * n, n))
        Phi[:, stk, stk] = 1.0  # stuck positions stay
        if m:
            lt = lam[None, :] * ts[:, None]
            small = np.abs(lam) < 1e-12
            phi = np.where(small[None, :], ts[:, None], np.expm1(lt) / np.where(small, 1.0, lam)[None, :])
            P = np.real(np.einsum("ij,tj,jk->tik", V, np.exp(lt), Vi))  # (nt, 2m, 2m)
            R = np.real(np.einsum("ij,tj,jk->tik", V, phi, Vi))[:, :, m:] @ Mi  # (nt, 2m, m): per unit force c
            rows = np.concatenate([free, n + free])
            Phi[np.ix_(range(nt), rows, rows)] = P
            Phi[np.ix_(range(nt), rows, stk)] = -R @ self.K[np.ix_(free, stk)]
            Psi[np.ix_(range(nt), rows, free)] = R
        return Phi, Psi

    def flow(self, x0: NDArray, u: NDArray, mode: Mode, t: float | NDArray) -> NDArray:
        """State(s) after ``t`` [s] (scalar, or an increasing array: (len(t), 2n)) in ``mode`` (no event
        inside). Coulomb: exact (modal solution of the linear system with the constant force
        ``c = (G u - F_0 - F_c s)_F - K_FS q_S``, the stuck joints held); Stribeck: RK4."""
        ts = np.atleast_1d(np.asarray(t, float))
        n = self.n
        st = np.asarray(mode.stuck)
        if not self.stribeck and ts.size == 1:  # one instant (event location): the modal solution directly
            free, lam, V, Vi, Mi = self._modal(mode)
            x = x0.copy()
            if free.size:
                m = free.size
                q, v = x0[:n], x0[n:]
                w = self.G @ u - self.F0 - self.Fc * np.asarray(mode.sign)
                c = w[free] - self.K[free][:, st] @ q[st]
                lt = lam * ts[0]
                small = np.abs(lam) < 1e-12
                phi = np.where(small, ts[0], np.expm1(lt) / np.where(small, 1.0, lam))
                z = np.exp(lt) * (Vi @ np.concatenate([q[free], v[free]])) + phi * (Vi[:, m:] @ (Mi @ c))
                y = np.real(V @ z)
                x[free], x[n + free] = y[:m], y[m:]
            x[n:][st] = 0.0
            return x[None] if np.ndim(t) else x
        if not self.stribeck:
            key = (mode.stuck, ts.tobytes())
            maps = self._maps.get(key)
            if maps is None:
                maps = self._linear_maps(mode, ts)
                if ts.size == CHECKS and ts[-1] == self._T:  # the full period's check points
                    self._maps[key] = maps
            Phi, Psi = maps
            w = self.G @ u - self.F0 - self.Fc * np.asarray(mode.sign)
            X = Phi @ x0 + Psi @ w
        else:  # one joint (checked in __init__): RK4 in floats
            X = np.empty((ts.size, 2))
            q, v = float(x0[0]), float(x0[1])
            if st[0]:
                X[:] = (q, 0.0)
                return X if np.ndim(t) else X[0]
            M, B, K = float(self.M[0, 0]), float(self.B[0, 0]), float(self.K[0, 0])
            f = float(self.G[0] @ u) - float(self.F0[0])
            sg, Fc, Fs, vs = float(mode.sign[0]), float(self.Fc[0]), float(self.Fs[0]), float(self.vs[0])

            def acc(q: float, v: float) -> float:
                return (f - sg * (Fc + Fs * math.exp(-((v / vs) ** 2))) - B * v - K * q) / M

            t_now = 0.0
            for i, ti in enumerate(ts):
                dt = float(ti) - t_now
                k = max(1, math.ceil(dt / self._h - 1e-9)) if dt > 0 else 0
                h = dt / k if k else 0.0
                for _ in range(k):
                    a1 = acc(q, v)
                    q2, v2 = q + 0.5 * h * v, v + 0.5 * h * a1
                    a2 = acc(q2, v2)
                    q3, v3 = q + 0.5 * h * v2, v + 0.5 * h * a2
                    a3 = acc(q3, v3)
                    q4, v4 = q + h * v3, v + h * a3
                    a4 = acc(q4, v4)
                    q, v = q + h / 6.0 * (v + 2 * v2 + 2 * v3 + v4), v + h / 6.0 * (a1 + 2 * a2 + 2 * a3 + a4)
                X[i] = (q, v)
                t_now = float(ti)
        return X if np.ndim(t) else X[0]

    def _events(self, X: NDArray, u: NDArray, mode: Mode) -> NDArray:
        """Event functions (nt, n) at states ``X`` (nt, 2n): moving friction joint ``s_j v_j``, stuck
        joint ``F_brk - |lambda_j|`` (an event where one reaches 0 from above); +1 for the others."""
        n = self.n
        g = np.ones((X.shape[0], n))
        s = np.asarray(mode.sign)
        st = np.asarray(mode.stuck)
        mv = self.fric & ~st & (s != 0)
        g[:, mv] = s[mv] * X[:, n:][:, mv]
        if st.any():
            free = ~st
            q, v = X[:, :n], X[:, n:]
            r = (self.G @ u - self.F0)[None, :] - self.friction(v, mode) - v @ self.B.T - q @ self.K.T
            lam = r[:, st]
            if free.any():
                aF = np.linalg.solve(self.M[np.ix_(free, free)], r[:, free].T).T
                lam = lam - aF @ self.M[np.ix_(st, free)].T
            g[:, st] = self.brk[st][None, :] - np.abs(lam)
        return g

    def _event(self, x: NDArray, u: NDArray, mode: Mode) -> NDArray:
        return self._events(x[None], u, mode)[0]

    def simulate(self, u: ArrayLike, T: float, *, x0: ArrayLike | None = None
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Positions and velocities (N, n) at ``k T`` for inputs ``u`` (N, n_in) held over each period."""
        uu = np.asarray(u, float)
        uu = uu[:, None] if uu.ndim == 1 else uu
        n = self.n
        self._h = T / RK4_STEPS
        self._T = float(T)
        self._grid = T * np.arange(1, CHECKS + 1) / CHECKS
        x = np.zeros(2 * n) if x0 is None else np.asarray(x0, float).copy()
        mode = Mode(tuple([False] * n), tuple([0.0] * n))
        rest = [bool(self.fric[j] and x[n + j] == 0.0) for j in range(n)]
        mode = self.settle(x, uu[0], rest, Mode(mode.stuck, tuple(np.sign(x[n:]))))
        Q = np.empty((uu.shape[0], n))
        V = np.empty((uu.shape[0], n))
        for k in range(uu.shape[0]):
            Q[k], V[k] = x[:n], x[n:]
            uk = uu[k]
            st = np.asarray(mode.stuck)
            if st.any():  # a new force may break a stuck joint away at the period's start
                mode = self.settle(x, uk, list(st), mode)
            tau = 0.0
            events = 0
            while tau < T * (1 - 1e-12):
                rem = T - tau
                ts = self._grid if tau == 0.0 else rem * np.arange(1, CHECKS + 1) / CHECKS
                X = self.flow(x, uk, mode, ts)
                G = self._events(X, uk, mode) < 0
                rows = np.flatnonzero(G.any(axis=1))
                if rows.size == 0:
                    x = X[-1]
                    break
                i = int(rows[0])
                t0, t1, bad = (float(ts[i - 1]) if i else 0.0), float(ts[i]), np.flatnonzero(G[i])
                te, j = t1, int(bad[0])
                for jj in bad:  # the earliest of the joints with an event in (t0, t1]
                    def fn(t: float, jj: int = int(jj), x: NDArray = x, uk: NDArray = uk, m: Mode = mode) -> float:
                        return float(self._event(self.flow(x, uk, m, t), uk, m)[jj])
                    tj = brentq(fn, t0, t1, xtol=1e-15 * T + 1e-18, rtol=1e-13) if fn(t0) > 0 else t0
                    if tj < te:
                        te, j = tj, int(jj)
                x = self.flow(x, uk, mode, te)
                tau += te
                cand = list(np.asarray(mode.stuck))
                if mode.stuck[j]:  # break-away
                    lam = self.holding(x, uk, mode)
                    cand[j] = False
                    sign = list(mode.sign)
                    sign[j] = float(np.sign(lam[j]))
                    mode = self.settle(x, uk, cand, Mode(mode.stuck, tuple(sign)))
                else:  # velocity through zero: at rest, stuck or reversing
                    x[n + j] = 0.0
                    cand[j] = True
                    mode = self.settle(x, uk, cand, mode)
                events += 1
                if events > MAX_EVENTS:
                    raise RuntimeError(f"more than {MAX_EVENTS} friction events in period {k}")
        return Q, V


def band_limited(rng: np.random.Generator, n: int, fs: float, f_hi: float, rms: float, *, order: int = 2,
                 columns: int = 1) -> NDArray[np.float64]:
    """White Gaussian noise through a Butterworth low-pass at ``f_hi`` [Hz], scaled to ``rms`` (n, columns)."""
    from scipy.signal import butter, lfilter

    b, a = butter(order, f_hi / (fs / 2))
    x = lfilter(b, a, rng.normal(0.0, 1.0, (n + 2000, columns)), axis=0)[2000:]
    return np.asarray(rms * x / np.std(x, axis=0), float)
