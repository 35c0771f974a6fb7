"""Point velocity and acceleration of a coordinate driven by a held force, and its velocity between samples.

A bench holds the force ``u_k`` over ``[kT, (k+1)T)``: the acceleration of a coordinate it drives jumps at
every sample instant by ``Delta a_k = M^-1 G (u_k - u_k-1)`` (the position is C1, its second derivative
piecewise smooth), and a friction joint's acceleration jumps again where its velocity reverses (the
Coulomb force flips: ``Delta a = -M^-1 e_j 2 F_brk s_new``, ``F_brk = F_c (+ F_s)`` the level at rest);
with each, the damping force makes the jerk jump by ``-beta Delta a`` (``beta = (B + B_f) / M`` for an
SDEA motor). A finite-difference stencil assumes a smooth position: each acceleration jump ``Delta a`` at
``tau`` periods from the stencil's centre adds ``T Delta a E_v(tau)`` to the point velocity and
``Delta a E_a(tau)`` to the point acceleration, where, with ``r_n(tau) = sum_i w_i (i - tau)_+^n / n!``
over the stencil's taps ``w_i``,

    E_v(tau) = r_2,v(tau) - (-tau)_+,        E_a(tau) = r_2,a(tau) - H(-tau)

(``H`` the step: the jump is in the point value when it happened before the centre; at ``tau = 0`` the
right limit ``a_k^+`` counts it, the left limit ``a_k^-`` does not, the point value takes half), and each
jerk jump ``Delta j`` adds ``T^2 Delta j F_v`` and ``T Delta j F_a`` with ``F_v = r_3,v - (-tau)_+^2 / 2``,
``F_a = r_3,a - (-tau)_+`` (:func:`jump_kernels`, :func:`jerk_kernels`). The stencils are the 7-point
ones (truncation ``(wT)^6 / 140``; the 5-point velocity's ``(wT)^4 / 30`` is 6.5e-4 at a 119 Hz
resonance sampled at 2 kHz, +0.04 % on a spring damping read from it). At the nodes
(``tau = 0, +-1, +-2``) ``E_v = 3/20, -1/24, 1/120``. The 5-point point velocity of a 2 kHz SDEA record
misses the truth by 1 % rms (the held torque's steps, ``E_v = 1/6, -1/24`` for it), which biased the
spring damping ``B_f`` of the measured spring-torque equation by -0.35 % (1.2 sd) on exact data.
:func:`held_point_kinematics` removes these terms from the stencils' values (given the jumps), and returns
the one-sided accelerations.

Between two samples the velocity is a cubic Hermite in the period (values ``v_k, v_k+1``, slopes the
one-sided accelerations ``a_k^+, a_k+1^-``), with, in a period whose ends differ in sign, the slope jump
of the reversal placed at its zero (found on the interpolant, iterated): :func:`hermite_velocity`. A
velocity LINEAR between samples puts the zeros of a 119 Hz oscillation sampled at 2 kHz (17 samples per
period) systematically late or early with its curvature, which correlates with the acceleration: the
averaged Coulomb column then biases the SDEA's inertia by +0.045 % (1.1 sd) on exact data.

Reversal jumps depend on where the reversals are, which depends on the corrected velocity: the two are
iterated until no reversal moves by more than :data:`TOLERANCE` of a period (at most :data:`ITERATIONS`
rounds; each divides their error by about 50). A stuck joint (velocity zero over some periods) is not
modelled: the held force's steps do not move it, yet are removed as if they did, so its near-zero
velocities may flip sign from round to round (33 stuck samples in 12000 on the SDEA record).
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

logger = logging.getLogger(__name__)

__all__ = ["ITERATIONS", "HeldMotion", "HermiteVelocity", "held_point_kinematics", "hermite_velocity", "jerk_kernels",
           "jump_kernels", "point_stencils"]

#: the point stencils (first and second derivative, 7 taps at -3..3, truncation (wT)^6 / 140 and / 560:
#: the 5-point ones' (wT)^4 / 30 is 6.5e-4 of the velocity at a 119 Hz resonance sampled at 2 kHz, which
#: biases a spring damping read from the point velocity by +0.04 %)
_WV = np.array([-1.0, 9.0, -45.0, 0.0, 45.0, -9.0, 1.0]) / 60.0
_WA = np.array([2.0, -27.0, 270.0, -490.0, 270.0, -27.0, 2.0]) / 180.0
_HALF = (_WV.size - 1) // 2
_TAPS = np.arange(-_HALF, _HALF + 1, dtype=float)
#: at most this many rounds of (reversal times -> corrected velocity -> reversal times); each divides the
#: reversal times' error by about 50 on a 2 kHz SDEA record (a stuck motor, whose held-torque steps do not
#: move it, can keep a few near-zero samples flipping: the rounds then stop here)
ITERATIONS = 6
#: the rounds stop when no reversal time moves by more than this [periods]
TOLERANCE = 1e-9
#: sub-intervals per period on which the zero of the interpolant is bracketed (then linear)
SUBGRID = 16
#: halvings of the bracketing sub-interval (its width 2^-BISECTIONS / SUBGRID of a period)
BISECTIONS = 30


def jump_kernels(tau: NDArray[np.float64], side: str = "mid") -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(E_v, E_a)`` of the module docstring for unit acceleration jumps at ``tau`` [periods from the
    stencil's centre]; ``side``: ``"right"`` (``a_k^+``), ``"left"`` (``a_k^-``) or ``"mid"`` (their mean)
    for a jump at the centre."""
    t = np.asarray(tau, float)
    r2 = np.maximum(_TAPS - t[..., None], 0.0) ** 2 / 2.0
    step = {"right": (t <= 0).astype(float), "left": (t < 0).astype(float),
            "mid": np.where(t == 0, 0.5, (t < 0).astype(float))}[side]
    return r2 @ _WV - np.maximum(-t, 0.0), r2 @ _WA - step


def jerk_kernels(tau: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(F_v, F_a)``: the stencils' errors for a unit jump of the third derivative at ``tau`` (the
    position's ``(t - tau)_+^3 / 6``): ``F_v = sum w_i (i - tau)_+^3 / 6 - (-tau)_+^2 / 2`` (per T^2) and
    ``F_a = sum w_i (i - tau)_+^3 / 6 - (-tau)_+`` (per T)."""
    t = np.asarray(tau, float)
    r3 = np.maximum(_TAPS - t[..., None], 0.0) ** 3 / 6.0
    return r3 @ _WV - np.maximum(-t, 0.0) ** 2 / 2.0, r3 @ _WA - np.maximum(-t, 0.0)


def _event_sum(times: NDArray, jumps: NDArray, n: int, kernel: Callable[[NDArray], NDArray]) -> NDArray[np.float64]:
    """``sum_j kernel(times_j - k) jumps_j`` per sample ``k`` (n,), over the events within the stencil."""
    out = np.zeros(n)
    if times.size == 0:
        return out
    base = np.floor(times).astype(int)
    for off in range(1 - _HALF, _HALF + 1):
        k = base + off
        tau = times - k
        ok = (k >= 0) & (k < n) & (tau > -_HALF) & (tau < _HALF)
        np.add.at(out, k[ok], kernel(tau[ok]) * jumps[ok])
    return out


_Arrays4 = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]


def point_stencils(q: NDArray, fs: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The 7-point first and second derivatives (:data:`_WV`, :data:`_WA`) of positions ``q`` (n,) at
    ``fs`` [Hz] (edges: the nearest sample repeated)."""
    pad = np.pad(np.asarray(q, float), _HALF, mode="edge")
    n = pad.size - 2 * _HALF
    S = sum(w * pad[i : i + n] for i, w in enumerate(_WV) if w != 0.0) * fs
    A = sum(w * pad[i : i + n] for i, w in enumerate(_WA)) * fs**2
    return np.asarray(S, float), np.asarray(A, float)


def held_point_kinematics(S: NDArray, A: NDArray, fs: float, node_jumps: NDArray, rev_times: NDArray,
                          rev_jumps: NDArray, smooth: Callable[[NDArray], NDArray], damping_rate: float = 0.0
                          ) -> _Arrays4:
    """``(v, a_mid, a_plus, a_minus)`` (n,) of one coordinate from its point stencils ``S`` (velocity)
    and ``A`` (acceleration) (:func:`point_stencils`) of the (filtered) positions: the jumps' terms
    removed (module docstring). ``node_jumps`` (n,) the acceleration jump at each sample instant,
    ``rev_times`` [periods] and ``rev_jumps`` those of the reversals; ``damping_rate`` [1/s] ``beta``: each
    acceleration jump ``Delta a`` comes with a jump ``-beta Delta a`` of its derivative (the damping force
    follows the velocity: ``beta = (B + B_f) / M`` for an SDEA motor); ``smooth`` the positions' filter,
    applied to the correction sequences (the stencils were taken on filtered positions)."""
    n = S.size
    T = 1.0 / fs
    beta = float(damping_rate)
    rt, rj = np.asarray(rev_times, float), np.asarray(rev_jumps, float)

    def total(kernel: Callable[[NDArray], NDArray], J: NDArray, jr: NDArray) -> NDArray:
        # the nodes at integer offsets d from the centre: a fixed FIR, sum_d kernel(d) J_k+d; the reversals
        taps = kernel(_TAPS)  # offsets -_HALF.._HALF
        node = np.convolve(np.pad(J, _HALF), taps[::-1], mode="valid")
        return np.asarray(node + _event_sum(rt, jr, n, kernel), float)

    J = np.asarray(node_jumps, float)
    ev = total(lambda t: jump_kernels(t)[0], J, rj) * T
    ea = total(lambda t: jump_kernels(t)[1], J, rj)  # point values ("mid": half of a jump at the centre)
    if beta:
        ev = ev + total(lambda t: jerk_kernels(t)[0], -beta * J, -beta * rj) * T**2
        ea = ea + total(lambda t: jerk_kernels(t)[1], -beta * J, -beta * rj) * T
    a_mid = A - smooth(ea)
    half = smooth(J / 2.0)  # a_k^+ counts the whole jump at its own instant, a_k^- none of it
    return S - smooth(ev), a_mid, a_mid + half, a_mid - half


def _hermite_basis(t: NDArray) -> NDArray[np.float64]:
    return np.stack([2 * t**3 - 3 * t**2 + 1, t**3 - 2 * t**2 + t, -2 * t**3 + 3 * t**2, t**3 - t**2])


class HermiteVelocity:
    """The velocity between samples of :func:`hermite_velocity`: per period ``k`` (n - 1) the Hermite data
    and the reversal (``theta`` its place in the period, ``kink`` the slope jump there [per period^2, in
    velocity units]); :meth:`__call__` evaluates it at fractions ``tau`` (n - 1, m) of the periods."""

    def __init__(self, v: NDArray, ap: NDArray, am: NDArray, fs: float) -> None:
        T = 1.0 / fs
        self.data = np.stack([v[:-1], T * ap[:-1], v[1:], T * am[1:]], axis=1)  # (n-1, 4)
        self.crossing = v[:-1] * v[1:] < 0
        self.theta = np.ones(v.size - 1)
        self.kink = np.zeros(v.size - 1)

    def __call__(self, tau: NDArray, rows: NDArray | None = None) -> NDArray[np.float64]:
        sel = slice(None) if rows is None else rows
        th, dk = self.theta[sel][:, None], self.kink[sel][:, None]
        d = self.data[sel].copy()
        d[:, 2] -= dk[:, 0] * (1.0 - th[:, 0])  # the kink's share of the right end's value and slope
        d[:, 3] -= dk[:, 0]
        H = _hermite_basis(tau)  # (4, rows, m)
        return np.asarray(np.einsum("kj,jkm->km", d, H) + dk * np.maximum(tau - th, 0.0), float)

    def locate(self, kink_per_sign: float) -> None:
        """Place the reversal of every crossing period at the first zero of the interpolant with the slope
        jump ``kappa = kink_per_sign * sgn(v_k+1)`` at that zero: the root of ``g(theta) = p_theta(theta)``,
        ``p_theta`` the Hermite of the data with the kink's share removed at the right end (a quartic in
        ``theta``, ``g(0) = v_k``, ``g(1) = v_k+1``), bracketed on :data:`SUBGRID` sub-intervals and refined
        by bisection (:data:`BISECTIONS` halvings)."""
        rows = np.flatnonzero(self.crossing)
        if rows.size == 0:
            return
        d = self.data[rows]
        kappa = kink_per_sign * np.sign(d[:, 2])

        def g(th: NDArray) -> NDArray:
            h = _hermite_basis(th)  # (4, rows, m)
            return np.asarray(h[0] * d[:, :1] + h[1] * d[:, 1:2] + h[2] * (d[:, 2:3] - kappa[:, None] * (1 - th))
                              + h[3] * (d[:, 3:4] - kappa[:, None]), float)

        grid = np.broadcast_to(np.linspace(0.0, 1.0, SUBGRID + 1), (rows.size, SUBGRID + 1))
        G = g(grid)
        c = G[:, :-1] * G[:, 1:] <= 0
        j = np.argmax(c, axis=1)
        lo, hi = j / SUBGRID, (j + 1) / SUBGRID
        glo = G[np.arange(rows.size), j]
        for _ in range(BISECTIONS):
            mid = (lo + hi) / 2
            gm = g(mid[:, None])[:, 0]
            left = glo * gm <= 0
            hi = np.where(left, mid, hi)
            lo, glo = np.where(left, lo, mid), np.where(left, glo, gm)
        self.theta[rows] = (lo + hi) / 2
        self.kink[rows] = kappa


def hermite_velocity(v: NDArray, ap: NDArray, am: NDArray, fs: float, kink_per_sign: float) -> HermiteVelocity:
    """The velocity between samples (module docstring) of point velocities ``v`` and one-sided
    accelerations ``ap`` (``a_k^+``), ``am`` (``a_k^-``) at ``fs`` [Hz]; ``kink_per_sign`` [unit/s^2]: the
    acceleration jump of a reversal per unit of the new sign (``-2 F_brk / M``; 0: none)."""
    h = HermiteVelocity(np.asarray(v, float), np.asarray(ap, float), np.asarray(am, float), fs)
    h.locate(float(kink_per_sign) / fs)  # the slope jump in velocity per period
    return h


class HeldMotion:
    """One coordinate's point kinematics and velocity between samples under a held force (module
    docstring), from its positions ``q`` (n,) filtered by ``smooth`` at ``fs`` [Hz], the acceleration jumps
    at the samples ``node_jumps`` (n,) [unit/s^2], per reversal of its own friction ``kink_per_sign``
    [unit/s^2] (0: no friction on it) and the ``damping_rate`` [1/s] (:func:`held_point_kinematics`),
    iterated until the reversals stay put (:data:`TOLERANCE`, :data:`ITERATIONS`). Attributes ``v``,
    ``a`` (point values), ``ap``, ``am`` (one-sided accelerations), ``between``
    (:class:`HermiteVelocity`)."""

    def __init__(self, q: NDArray, fs: float, node_jumps: NDArray, kink_per_sign: float,
                 smooth: Callable[[NDArray], NDArray], damping_rate: float = 0.0) -> None:
        S, A = point_stencils(q, fs)
        rt, rj = np.zeros(0), np.zeros(0)
        self.iterations = 0
        for _ in range(ITERATIONS if kink_per_sign else 1):
            self.v, self.a, self.ap, self.am = held_point_kinematics(S, A, fs, node_jumps, rt, rj, smooth,
                                                                     damping_rate)
            self.between = hermite_velocity(self.v, self.ap, self.am, fs, kink_per_sign)
            self.iterations += 1
            k = np.flatnonzero(self.between.crossing)
            moved = k.size != rt.size or bool(np.any(np.abs(k + self.between.theta[k] - rt) > TOLERANCE))
            rt = k + self.between.theta[k]
            rj = kink_per_sign * np.sign(self.v[k + 1])
            if not moved:
                break
