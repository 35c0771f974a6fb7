"""IDIM-LS: inverse-dynamics least squares from band-pass filtered derivatives of the position.

The robotics community's reference method (Gautier, Khalil; the EMPS benchmark's own estimator:
Janot, Gautier, Brunot, "Data set and reference models of EMPS", Nonlinear System Identification
Benchmarks workshop 2019, sec. 3.4 and its ``Script_IDIM_LS.m``), reproduced step by step:

1. the measured position ``q`` is low-pass filtered forward and backward (zero phase) with a
   Butterworth filter of order 4 at ``f_filter`` (default ``5 * f_dyn``, ``f_dyn`` = 20 Hz: the
   benchmark's 100 Hz at 1 kHz);
2. velocity and acceleration are central differences of the filtered position (the edge samples
   one-sided), and ``n_border`` = 50 samples are dropped at the start;
3. the inverse model ``u = M q'' + B q' + F_c sgn(q') + F_0`` is linear in the parameters: every
   column of the observation matrix and the measured force are decimated by ``r =
   round(0.8 (fs/2) / (2 f_dyn))`` (= 10 at 1 kHz) with an order-8 Chebyshev type-I low-pass
   (ripple 0.05 dB, cut-off ``0.8 / r`` of Nyquist) applied forward and backward, as MATLAB's
   ``decimate`` does (the samples kept are aligned on the last one, as there);
4. ordinary least squares; the standard deviations are the benchmark's
   ``std(e) sqrt(diag((X^T X)^-1))`` (white-residual formula: the residual of the decimated
   equation error is close to white at 100 Hz; it is the number the benchmark publishes).

Stribeck (``F_s exp(-(v/v_s)^2) sgn(v)``) is linear in ``F_s`` for a given ``v_s``: ``v_s`` is found
by a 1-D search of the residual sum of squares (bounded, log scale) with the rest solved linearly.

Closed loop: the regressors are built from the measured motion, not simulated from the force, so a
position controller feeding back the encoder does not bias the equation error the way it biases an
open-loop output-error fit (noise on ``q`` only enters through the heavily filtered derivatives).

Consistent columns (:class:`Motion`, used by the inverse-dynamics ML of every friction model). The
force ``u_k`` of a bench is held over ``[kT, (k+1)T)``. The double central difference of the position,
``D2 q_k = (q_k+2 - 2 q_k + q_k-2) / (4 T^2)``, is EXACTLY the acceleration averaged with the triangle
``Lambda`` of half-width ``2T`` (the convolution of two boxes of width ``2T``), and the same average of
the held force is ``(u_k-2 + 3 u_k-1 + 3 u_k + u_k+1) / 8``. The equation ``M q'' + B q' + K q = u - f``
averaged with ``Lambda`` therefore needs the other columns averaged the same way: in frequency
``Lambda(w) = sinc^2(w T)`` (``sinc x = sin x / x``), which the central difference ``sin(wT)/T`` of the
velocity misses by ``(wT)^2 / 6`` and the position sample by ``(wT)^2 / 3`` -- 5 % of a spring force at
a 120 Hz resonance sampled at 2 kHz. The columns of an equation whose left side is a held force
(``kind="input"``) are the 5-tap FIRs matching ``sinc^2`` (position: ``[1, 16, 26, 16, 1] / 60``, error
``O((wT)^6)``) and ``w sinc^2`` (velocity: ``(q_k+1 - q_k-1) / (3T) + (q_k+2 - q_k-2) / (12 T)``, error
``(wT)^5 / 180``), and the friction columns the triangle's average of the friction law over the motion
(:meth:`Motion.friction`: the sign of a velocity that reverses between two samples is averaged
exactly, not sampled; the velocity's zeros are located on the positions filtered at twice the cut-off,
where the kink of a reversal is not smeared). An equation whose left side is sampled at the instants (a force sensor;
``kind="measured"``, or ``"zero"`` for a body without actuator) takes point values: the position, the
5-point first and second derivatives.

Stick-slip (a spring-free joint with dry friction, :meth:`InverseDynamicsModel.stick_joints
<hil.identify.inverse_models.InverseDynamicsModel.stick_joints>`; today the 1-DOF model with a
Stribeck term). While a joint sticks its friction is the holding force, anywhere within the
break-away level, which no kinetic law expresses: with the kinetic columns the equation error there
is the applied force itself, large, coloured and correlated with the Stribeck column near break-away
(measured on the tests' stick-slip simulator, stuck 12 % of the time: ``F_s`` 0.95 for 2.0 on exact
data, sandwich sd of ``M`` 20x its scatter). But there ``a = v = 0``, so the equation is exactly
``u = f``: the stuck periods (:func:`stuck_periods`: a run of at least :data:`STICK_RUN` periods
without an encoder count) are left out of the equation's held force, friction and offset columns
(the acceleration and velocity columns are zero there), so nothing is lost but equations that say
nothing about the parameters. Three places where the motion is then refined, each measured
against the exactly averaged friction of a 20x finer simulation: the stop before a stuck run is
located within its period from the raw positions (:meth:`Motion._stops`; the period moves up to the
stop and is stuck after it, :attr:`Motion.moving_fraction`); a reversal without stick is refitted as
two quadratics through a common zero (:meth:`Motion._reversals`: the friction flips there, the
acceleration jumps by ``2 (F_c + F_s) / M`` and the velocity filter would smear the kink by up to a
period); a break-away the encoder sees only a few periods later (the joint creeps less than a count)
is moved back to the first period whose force passes the data's break-away level
(:meth:`Motion.breakaways`; taken as stuck, those periods would cost ``M a + B v`` of the creeping
joint). Column error at the truth against the exactly averaged friction (1 um encoder), as the LS
bias of ``F_s`` it causes: -0.0155 N with the stuck periods left out alone, -0.0016 N with the three.

Held force in the point columns (:meth:`Motion.set_held_input`, :mod:`hil.identify.held_kinematics`; the
SDEA models declare it): the held force steps the driven coordinate's acceleration at every sample
instant (and its friction at every reversal), which the 5-point point derivatives read as a smooth
position would not: the point velocity misses ``T (Delta a_k / 6 - (Delta a_k-1 + Delta a_k+1) / 24)``
(1 % rms on a 2 kHz SDEA record; B_f -0.35 % on exact data). With the jumps declared (from the
model's ``M``, ``F_c`` at the least-squares start) the point columns have those terms removed, and the
averaged friction column integrates the velocity as a cubic Hermite between samples (one-sided
accelerations as slopes, the reversal's slope jump placed at its zero) instead of linearly (the linear
zeros of a 119 Hz oscillation sampled at 2 kHz are up to 1 % of a period late: M +0.045 %).

Parallel filtering: the Butterworth filter of the positions attenuates the band it keeps a little
(``1 / (1 + (f / f_filter)^8)``: 6.5e-4 at the top of the decimated band), which an unfiltered force
does not see; the left sides and the friction columns are filtered with the same filter
(:meth:`Motion.lowpass`), so every term of the equation is (a force sensor whose samples are held,
:mod:`hil.identify.inverse_design`, excepted: its held samples are used as recorded).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import optimize, signal

from hil.identify.errors import DataQualityError
from hil.identify.friction import normalize_friction, parameter_names
from hil.identify.held_kinematics import HeldMotion

logger = logging.getLogger(__name__)

__all__ = ["IdimResult", "Motion", "decimate", "diffcent", "filtered_derivatives", "idim_columns", "idim_design",
           "idim_ls"]

#: the benchmark's dynamics bandwidth [Hz]: Butterworth at 5x, decimation to 2x of it
F_DYN = 20.0
#: consecutive sample periods without an encoder count over which a joint is taken as stuck (:func:`stuck_periods`)
STICK_RUN = 5
#: samples before a stuck run whose positions locate the stop (:meth:`Motion._stops`)
STOP_WINDOW = 10
#: periods before and after a reversal whose velocities locate it (:meth:`Motion._reversals`)
REVERSAL_FIT = (3, 7)


def diffcent(y: ArrayLike, dt: float) -> NDArray[np.float64]:
    """Central differences ``(y[k+1] - y[k-1]) / (2 dt)``, one-sided at both ends (MATLAB ``diffcent``)."""
    yy = np.asarray(y, float)
    return np.concatenate([[yy[1] - yy[0]], (yy[2:] - yy[:-2]) / 2.0, [yy[-1] - yy[-2]]]) / dt


def decimate(x: ArrayLike, r: int) -> NDArray[np.float64]:
    """MATLAB's ``decimate(x, r)``: Chebyshev-I order 8, 0.05 dB, cut-off ``0.8/r``, forward-backward,
    keeping samples ``nbeg, nbeg + r, ...`` with ``nbeg = r - (r * ceil(n/r) - n)`` (1-based)."""
    xx = np.asarray(x, float)
    if r <= 1:
        return xx.copy()
    b, a = signal.cheby1(8, 0.05, 0.8 / r)
    y = signal.filtfilt(b, a, xx, padtype="odd", padlen=3 * (max(len(a), len(b)) - 1))
    n = xx.size
    nbeg = r - (r * int(np.ceil(n / r)) - n)
    return np.asarray(y[nbeg - 1 :: r], float)


def filtered_derivatives(q: ArrayLike, fs: float, f_filter: float | None = None
                         ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """``(q_f, v, a)``: the zero-phase Butterworth-filtered position (order 4, ``f_filter`` [Hz],
    default ``min(5 F_DYN, 0.4 fs)``) and its central-difference velocity and acceleration."""
    qq = np.asarray(q, float)
    fc = float(f_filter) if f_filter else min(5 * F_DYN, 0.4 * fs)
    if not 0 < fc < fs / 2:
        raise DataQualityError(f"IDIM filter cut-off {fc:g} Hz outside (0, {fs / 2:g}) Hz")
    b, a = signal.butter(4, fc / (fs / 2))
    qf = signal.filtfilt(b, a, qq, padlen=3 * (max(len(a), len(b)) - 1))
    dt = 1.0 / fs
    v = diffcent(qf, dt)
    return qf, v, diffcent(v, dt)


#: 5-tap stencils (centre at index 2): position averaged as sinc^2 (per sample), velocity as w sinc^2
#: (per T), point first and second derivatives (per T and T^2), the held force's average (per sample)
_AVG_Q = np.array([1.0, 16.0, 26.0, 16.0, 1.0]) / 60.0
_AVG_V = np.array([-1.0, -4.0, 0.0, 4.0, 1.0]) / 12.0
_PT_V = np.array([1.0, -8.0, 0.0, 8.0, -1.0]) / 12.0
_PT_A = np.array([-1.0, 16.0, -30.0, 16.0, -1.0]) / 12.0
_D2 = np.array([1.0, 0.0, -2.0, 0.0, 1.0]) / 4.0
HELD_FORCE = np.array([1.0, 3.0, 3.0, 1.0]) / 8.0  # weights of u_k-2 .. u_k+1


def _stencil(x: NDArray, taps: NDArray) -> NDArray:
    """``sum_i taps[i] x[k + i - 2]`` along axis 0 (edges: the nearest sample repeated)."""
    pad = np.pad(x, [(2, 2)] + [(0, 0)] * (x.ndim - 1), mode="edge")
    return np.asarray(sum(t * pad[i : i + x.shape[0]] for i, t in enumerate(taps) if t != 0.0), float)


def held_force(u: ArrayLike) -> NDArray[np.float64]:
    """The force held over each period as the double central difference of the position sees it:
    ``(u_k-2 + 3 u_k-1 + 3 u_k + u_k+1) / 8`` along axis 0 (edges repeated)."""
    uu = np.asarray(u, float)
    pad = np.pad(uu, [(2, 1)] + [(0, 0)] * (uu.ndim - 1), mode="edge")
    return np.asarray(sum(w * pad[i : i + uu.shape[0]] for i, w in enumerate(HELD_FORCE)), float)


def _unfiltered(x: NDArray) -> NDArray:
    return x


class Motion:
    """The measured coordinates of one record (positions ``Q`` (n, n_c) [m or rad] at ``fs`` [Hz]),
    low-pass filtered forward and backward (Butterworth order 4 at ``f_filter``), and the columns of
    the inverse model built from them (module docstring, "Consistent columns"), full length. ``kind``:
    ``"input"`` (an equation balancing a held force: averaged columns) or ``"measured"``/``"zero"``
    (point columns). ``crop`` drops ``n_border`` samples at both ends (filter transients)."""

    def __init__(self, Q: ArrayLike, fs: float, f_filter: float, n_border: int = 50,
                 stick: Sequence[int] = ()) -> None:
        QQ = np.asarray(Q, float)
        self.Q = QQ[:, None] if QQ.ndim == 1 else QQ
        #: per sample period ``[k, k+1)`` and coordinate: False where the coordinate is taken as stuck
        #: (:func:`stuck_periods`, only for the coordinates ``stick``; True elsewhere)
        self.moving = np.ones(self.Q.shape, bool)
        for c in stick:
            self.moving[:, c] = ~stuck_periods(self.Q[:, c])
        self.fs = float(fs)
        self.f_filter = float(f_filter)
        if not 0 < self.f_filter < self.fs / 2:
            raise DataQualityError(f"IDIM filter cut-off {self.f_filter:g} Hz outside (0, {self.fs / 2:g}) Hz")
        self._ba = signal.butter(4, self.f_filter / (self.fs / 2))
        self.qf = self.lowpass(self.Q)
        self.n = self.Q.shape[0]
        self.n_border = int(n_border)
        if self.n <= 4 * self.n_border:
            raise DataQualityError(f"IDIM: {self.n} samples are too few (need > {4 * self.n_border})")
        T = 1.0 / self.fs
        self._v_pt = _stencil(self.qf, _PT_V) / T
        # the friction law's velocity: filtered less (twice the cut-off), so that a reversal's kink is
        # not smeared across the zero (a 100 Hz filter moves the zeros enough to bias F_c by -0.3 %)
        self.f_velocity = min(2.0 * self.f_filter, 0.4 * self.fs)
        ba = signal.butter(4, self.f_velocity / (self.fs / 2))
        qv = signal.filtfilt(*ba, self.Q, axis=0, padlen=3 * (max(len(ba[0]), len(ba[1])) - 1))
        self._v_fric = _stencil(np.asarray(qv, float), _PT_V) / T
        self.moving_fraction, self._v_stop = self.moving.astype(float), np.zeros(self.Q.shape)
        self._zero = np.full(self.Q.shape, np.nan)  # a reversal's place in its period (kinked velocity)
        #: per coordinate, the point kinematics under a held force (:meth:`set_held_input`): of the
        #: positions filtered at f_filter (point columns) and at f_velocity (the friction law's velocity)
        self._held: dict[int, HeldMotion] = {}
        self._held_v: dict[int, HeldMotion] = {}
        for c in stick:
            self._stops(c)
            self._reversals(c)

    def _stops(self, c: int) -> None:
        """The stop before each stuck run of coordinate ``c`` (:func:`stuck_periods`), within a period.
        The filtered velocity smooths the stop's kink over a few samples; the raw (encoder) positions
        do not: they are fitted, over the ``STOP_WINDOW`` samples before the run's first sample ``j`` and
        3 after it, by ``q = q_s + c_2 x^2 + c_3 x^3`` before the stop and ``q_s`` after it (``x = t - t_0``
        in periods; least squares, linear in ``q_s, c_2, c_3``; ``t_0`` on a 1/50-period grid within
        ``(t_j-2, t_j+2]``, smallest residual). The period holding ``t_0`` moves over ``[t_p, t_0)``
        (velocity linear to 0 from the fit's value at its start), the later ones are stuck, and the
        velocity samples from ``j - 3`` to the stop are the fit's. A fit that does not decelerate towards
        the stop (or a previous run within the window): the filtered velocity and the run as detected."""
        v, mv, q = self._v_fric[:, c], self.moving[:, c], self.Q[:, c]
        th = self.moving_fraction[:, c]
        for j in (int(x) for x in np.flatnonzero(~mv[1:] & mv[:-1]) + 1):
            ks = np.arange(j - STOP_WINDOW, j + 4)
            if ks[0] < 0 or ks[-1] >= self.n or not np.all(mv[ks[0] : j]):
                continue
            sg = np.sign(q[j] - q[ks[0]])
            grid = np.linspace(j - 2.0 + 0.02, j + 2.0, 200)
            t0, cf = _grid_fit(grid, ks.astype(float), q[ks] - q[j], (0, 2, 3), before=True)
            cf = np.array([cf[0] + q[j], cf[1], cf[2]])

            def vel(t: float, t0: float = t0, cf: NDArray = cf) -> float:
                x = min(t - t0, 0.0)
                return float((2 * cf[1] * x + 3 * cf[2] * x * x) * self.fs)

            if sg == 0 or sg * vel(j - 3.0) <= 0:  # not moving towards the stop
                continue
            for pp in range(j - 2, j + 2):
                frac = min(max(t0 - pp, 0.0), 1.0)
                th[pp] = frac
                if 0.0 < frac < 1.0:
                    self._v_stop[pp, c] = vel(pp)
            for kk in range(j - 3, j + 2):
                if kk < t0:
                    v[kk] = vel(kk)

    def breakaways(self, c: int, u: ArrayLike) -> None:
        """Locate the break-away ending each stuck run of coordinate ``c`` from the force ``u`` (n,) held
        over each period that balances its friction. A spring-free joint held against it breaks away at
        the start of the first period whose force passes the break-away level; the encoder shows the
        motion only once it has moved a count, up to a few periods later (the joint creeps), and those
        periods, taken as stuck, would cost the equation the creeping joint's ``M a + B v``. The levels
        (one per direction) are the data's: the largest and the smallest force (5-sample running median,
        against the force noise) over the stuck periods that are not among a run's last ``STICK_RUN``; the
        break-away is the earliest period of the run's last ``STICK_RUN`` from which the force stays
        beyond its direction's level. Those periods are moving, their velocity (tiny) of the motion's
        sign."""
        v, mv, q = self._v_fric[:, c], self.moving[:, c], self.Q[:, c]
        th = self.moving_fraction[:, c]
        if mv.all():
            return
        ub = np.asarray(signal.medfilt(np.asarray(u, float), 5), float)  # robust to the noise, not shifted by a step
        ends = [int(e) for e in np.flatnonzero(~mv[:-1] & mv[1:]) + 1]  # the run's first moving period (encoder)
        sure = ~mv.copy()
        for e in ends:
            sure[max(e - STICK_RUN, 0) : e] = False
        if not sure.any():
            return
        level = {1.0: float(np.max(ub[sure])), -1.0: float(-np.min(ub[sure]))}
        hi = REVERSAL_FIT[-1]
        for e in ends:
            if e + hi >= self.n:
                continue
            sg = float(np.sign(q[e + hi] - q[e]))
            if sg == 0.0:
                continue
            tb = e
            while tb - 1 >= max(e - STICK_RUN, 1) and not mv[tb - 1] and sg * ub[tb - 1] > level[sg]:
                tb -= 1
            if tb == e:
                continue
            th[tb:e] = 1.0
            v[tb] = 0.0
            seg = v[tb + 1 : e + 2]
            seg[sg * seg <= 0] = sg * 1e-12

    def _reversals(self, c: int) -> None:
        """Each reversal of coordinate ``c`` outside its stuck runs (the filtered velocity changes sign
        between samples ``k`` and ``k + 1``): the dry friction flips there, so the acceleration jumps by
        ``2 (F_c + F_s) / M`` and the velocity has a kink, which the velocity filter smooths over a few
        samples (moving the zero and the Stribeck dip by up to a period). The velocity is refitted as
        two lines through a common zero ``t_0`` (least squares on the samples ``REVERSAL_FIT`` periods
        before ``k`` and after ``k + 1``, ``t_0`` on a 1/50-period grid in ``[t_k-1, t_k+2]``); the
        samples in between are set on them and the period holding ``t_0`` is split there
        (:meth:`friction`). A stop or a reversal within the fit's reach: left as filtered."""
        v, th = self._v_fric[:, c], self.moving_fraction[:, c]
        lo, hi = REVERSAL_FIT[0], REVERSAL_FIT[-1]
        ks = np.flatnonzero(v[:-1] * v[1:] < 0)
        for k in (int(x) for x in ks):
            if k - hi - 1 < 0 or k + hi + 2 >= self.n or np.any(th[k - hi - 1 : k + hi + 2] < 1.0):
                continue
            if np.any((ks != k) & (np.abs(ks - k) <= hi + 1)):
                continue
            tb = np.arange(k - hi, k - lo + 1, dtype=float)
            ta = np.arange(k + 1 + lo, k + 1 + hi + 1, dtype=float)
            vb_, va_ = v[tb.astype(int)], v[ta.astype(int)]
            grid = np.linspace(k - 1.0, k + 2.0, 151)
            # each side: v = a x + b x^2, x = t - t_0 (the two sides' residuals add: one t_0 for both)
            sb, cbs = _grid_sse(grid, tb, vb_, (1, 2))
            sa, cas = _grid_sse(grid, ta, va_, (1, 2))
            i0 = int(np.argmin(sb + sa))
            t0, cb, ca = float(grid[i0]), cbs[i0], cas[i0]
            if np.sign(cb[0]) != np.sign(ca[0]):  # not a reversal through zero with a kink: keep the filtered samples
                continue

            def line(t: float, t0: float = t0, cb: NDArray = cb, ca: NDArray = ca) -> float:
                x = t - t0
                cc = cb if x <= 0 else ca
                return float(cc[0] * x + cc[1] * x * x)

            for kk in range(k - lo + 1, k + 1 + lo):
                v[kk] = line(kk)
            p = int(np.floor(t0))
            if 0 <= p < self.n - 1:
                self._zero[p, c] = t0 - p

    def set_held_input(self, node_jumps: ArrayLike, kinks: Sequence[float], damping_rates: Sequence[float]) -> None:
        """Declare the force held over each period (:mod:`hil.identify.held_kinematics`): ``node_jumps``
        (n, n_c) the acceleration jump of each coordinate at each sample instant (``M^-1 G (u_k - u_k-1)``)
        [unit/s^2], ``kinks`` (n_c,) the jump of a coordinate's own acceleration per unit of its new
        velocity sign at a reversal (``-2 F_brk / M``; 0 without friction), ``damping_rates`` (n_c,) [1/s]
        ``beta``: each acceleration jump ``Delta a`` steps the jerk by ``-beta Delta a`` (``(B + B_f) / M``).
        From then on the point columns (``kind`` ``"measured"``/``"zero"``, of the filtered positions) and
        the friction law's velocity (of the UNFILTERED positions: the filter smears the kinks that the held
        kinematics model exactly -- at f_velocity = 800 Hz, fs 2 kHz, the motor inertia comes out +0.009 %
        instead of -0.001 % on exact data) are the 7-point derivatives with the jumps' stencil errors
        removed, and the averaged friction column integrates the velocity as a cubic Hermite between
        samples with the reversal's slope jump at its zero (instead of linear). The coupling of one joint's
        reversal into the other coordinates' accelerations is not modelled."""
        J = np.asarray(node_jumps, float).reshape(self.n, -1)
        for c in range(self.Q.shape[1]):
            kink, beta = float(kinks[c]), float(damping_rates[c])
            self._held[c] = HeldMotion(self.qf[:, c], self.fs, J[:, c], kink, self.lowpass, beta)
            self._held_v[c] = HeldMotion(self.Q[:, c], self.fs, J[:, c], kink, _unfiltered, beta)


    def lowpass(self, x: ArrayLike) -> NDArray:
        """The positions' filter (Butterworth order 4 at ``f_filter``, forward and backward) applied to
        ``x`` along axis 0: what a left side and a friction column get so that the whole equation is
        filtered alike (parallel filtering)."""
        b, a = self._ba
        return np.asarray(signal.filtfilt(b, a, np.asarray(x, float), axis=0, padlen=3 * (max(len(a), len(b)) - 1)),
                          float)

    def crop(self, x: NDArray) -> NDArray:
        return x[self.n_border : self.n - self.n_border]

    def q(self, c: int, kind: str) -> NDArray:
        return _stencil(self.qf[:, c], _AVG_Q) if kind == "input" else self.qf[:, c].copy()

    def v(self, c: int, kind: str) -> NDArray:
        if kind == "input":
            return _stencil(self.qf[:, c], _AVG_V) * self.fs
        return self._held[c].v.copy() if c in self._held else self._v_pt[:, c].copy()

    def a(self, c: int, kind: str) -> NDArray:
        if kind != "input" and c in self._held:
            return self._held[c].a.copy()
        return _stencil(self.qf[:, c], _D2 if kind == "input" else _PT_A) * self.fs**2

    def velocity(self, c: int) -> NDArray:
        """Point velocity [m/s or rad/s] of coordinate ``c`` that the friction law reads: the positions
        filtered at ``f_velocity = min(2 f_filter, 0.4 fs)``, 5-point derivative (under a held force,
        :meth:`set_held_input`, with the jumps' stencil errors removed)."""
        return self._held_v[c].v if c in self._held_v else self._v_fric[:, c]

    def friction(self, c: int, fn: Callable[[NDArray], NDArray], kind: str) -> NDArray:
        """The column of a friction law ``fn(v)`` (e.g. ``sgn v``) of coordinate ``c`` as the equation
        ``kind`` sees it: point values ``fn(v_k)``, or (``"input"``) its average with the triangle
        ``Lambda``, ``sum over the 4 periods around k`` of ``integral Lambda(t - kT) fn(v(t)) dt``, the
        velocity linear between samples: each period split where ``v`` changes sign (``fn`` may jump
        there) and integrated by 4-point Gauss-Legendre on each piece (exact for a piecewise-constant
        ``fn`` such as the sign); then low-pass filtered as the positions (:meth:`lowpass`)."""
        v = self.velocity(c)
        if kind != "input":
            return self.lowpass(fn(v))
        held = self._held_v.get(c)
        if held is not None:  # under a held force: the Hermite velocity with the reversal's slope jump at its zero
            theta = held.between.theta
            x, w = np.polynomial.legendre.leggauss(4)
            x, w = (x + 1) / 2, w / 2  # on (0, 1)
            tau = np.concatenate([theta[:, None] * x, theta[:, None] + (1 - theta)[:, None] * x], axis=1)
            wt = np.concatenate([theta[:, None] * w, (1 - theta)[:, None] * w], axis=1)
            f = np.asarray(fn(held.between(tau)), float)
            i0 = np.sum(wt * f, axis=1)  # integral over the period of fn(v)
            i1 = np.sum(wt * tau * f, axis=1)  # ... times the time since its start (in periods)
            return self.lowpass(self._triangle(i0, i1))
        # per period: the moving part [0, th) (th = 1 moving, 0 stuck, in between: the joint stops in it),
        # the velocity linear over it from va to vb (0 at a stop)
        th, va = self.moving_fraction[:-1, c], v[:-1].copy()
        vb = np.where(th < 1.0, 0.0, v[1:])
        part = (th > 0.0) & (th < 1.0)
        va[part] = self._v_stop[:-1, c][part]
        cross = (va * vb) < 0
        s = np.where(cross, va / np.where(cross, va - vb, 1.0), 1.0)  # the zero's place in the moving part
        z = self._zero[:-1, c]
        kink = cross & np.isfinite(z) & (th == 1.0)
        s = np.where(kink, np.clip(z, 1e-9, 1 - 1e-9), s)
        x, w = np.polynomial.legendre.leggauss(4)
        x, w = (x + 1) / 2, w / 2  # on (0, 1)
        tau = np.concatenate([s[:, None] * x, s[:, None] + (1 - s)[:, None] * x], axis=1)  # in the moving part
        wt = np.concatenate([s[:, None] * w, (1 - s)[:, None] * w], axis=1) * th[:, None]
        # the velocity: linear over the moving part, or (a reversal) linear to 0 at s and from 0 after it
        vel = va[:, None] + (vb - va)[:, None] * tau
        sk = s[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            vk = np.where(tau < sk, va[:, None] * (1 - tau / sk), vb[:, None] * (tau - sk) / (1 - sk))
        f = np.asarray(fn(np.where(kink[:, None], vk, vel)), float)
        i0 = np.sum(wt * f, axis=1)  # integral over the period of fn(v) (a stuck part contributes nothing)
        i1 = np.sum(wt * (th[:, None] * tau) * f, axis=1)  # ... times the time since its start (in periods)
        return self.lowpass(self._triangle(i0, i1))

    def _triangle(self, i0: NDArray, i1: NDArray) -> NDArray:
        """The average with the triangle ``Lambda`` at every sample (n,) of a force known by its integrals
        over each period ``j`` (n - 1,): ``i0_j = integral f``, ``i1_j = integral (t - jT)/T f`` (per T)."""
        # Lambda(t - k) is (t - k + 2)/4 on the period k-2, (t - k + 2)/4 on k-1, (2 - (t - k))/4 on k and k+1:
        i0p, i1p = np.pad(i0, 2, mode="edge"), np.pad(i1, 2, mode="edge")  # period j at index j + 2
        k = np.arange(self.n)
        return np.asarray((i1p[k] + (i0p[k + 1] + i1p[k + 1]) + (2 * i0p[k + 2] - i1p[k + 2])
                           + (i0p[k + 3] - i1p[k + 3])) / 4.0, float)

    def stuck(self, c: int) -> bool:
        """Whether stuck periods were found (and are taken out) on coordinate ``c``."""
        return not bool(np.all(self.moving[:, c]))

    def held_force(self, u: ArrayLike, c: int) -> NDArray[np.float64]:
        """:func:`held_force` of a force ``u`` (n,) balancing the friction of coordinate ``c``, the
        periods (or the part of a period after a stop) where ``c`` is stuck left out (there the friction
        is that force: the equation is ``0 = 0``; :func:`stuck_periods`)."""
        if not self.stuck(c):
            return held_force(u)
        uu, th = np.asarray(u, float)[:-1], self.moving_fraction[:-1, c]
        return self._triangle(uu * th, uu * th**2 / 2.0)

    def offset(self, c: int, kind: str) -> NDArray[np.float64]:
        """The column of a constant force (``F_0``) in an equation balancing the friction of coordinate
        ``c``: ones, or (stuck periods on ``c``, ``kind == "input"``) the triangle average of the moving
        periods' indicator, filtered as the friction columns."""
        if kind != "input" or not self.stuck(c):
            return np.ones(self.n)
        return self.friction(c, np.ones_like, kind)


def _grid_sse(grid: NDArray, t: NDArray, y: NDArray, powers: Sequence[int], *, before: bool = False
              ) -> tuple[NDArray, NDArray]:
    """Least squares of ``y`` (m,) on the monomials ``x^p`` (``p`` in ``powers``) of ``x = t - t0``
    (``before``: ``min(t - t0, 0)``) for every ``t0`` of ``grid`` (G,) at once: residual sums of squares
    (G,) and coefficients (G, len(powers))."""
    x = np.asarray(t, float)[None, :] - grid[:, None]  # (G, m)
    if before:
        x = np.minimum(x, 0.0)
    X = np.stack([x**p for p in powers], axis=-1)  # (G, m, k)
    A = np.einsum("gmi,gmj->gij", X, X) + 1e-30 * np.eye(len(powers))
    cf = np.linalg.solve(A, np.einsum("gmi,m->gi", X, y)[..., None])[..., 0]
    r = y[None, :] - np.einsum("gmi,gi->gm", X, cf)
    return np.sum(r**2, axis=1), cf


def _grid_fit(grid: NDArray, t: NDArray, y: NDArray, powers: Sequence[int], *, before: bool = False
              ) -> tuple[float, NDArray]:
    """The ``t0`` of ``grid`` with the smallest residual of :func:`_grid_sse`, and its coefficients."""
    sse, cf = _grid_sse(grid, t, y, powers, before=before)
    i = int(np.argmin(sse))
    return float(grid[i]), cf[i]


def stuck_periods(q: ArrayLike, run: int | None = None) -> NDArray[np.bool_]:
    """Sample periods ``[k, k+1)`` (n,) (the last one: False) over which a joint is taken as stuck: its
    encoder reading ``q`` (n,) does not change over a run of at least ``run`` (default
    :data:`STICK_RUN`) consecutive periods.

    While a joint sticks, its friction is the holding force (anything within the break-away level), which
    no kinetic friction law expresses: with the held force ``u`` the joint's whole equation there is
    ``u = f`` (``a = v = 0``), so a stuck period is left out of the equation's every term (its held force,
    friction and offset columns; the acceleration and velocity columns are zero there). Why a run: a
    joint reversing (not sticking) with acceleration ``a`` moves ``a t^2 / 2`` from its turning point,
    so its reading stays within one count ``dq`` for at most ``2 sqrt(2 dq / |a|)``; a flat run of
    ``L`` periods ``T`` thus bounds ``|a| < 8 dq / (L T)^2`` and a moving joint taken as stuck
    costs the equation only ``M a + B v`` with ``|v| < dq / T`` (at ``L = 5``, 1 um counts at 1 kHz:
    ``|a| < 0.32 m/s^2``, ``|v| < 1 mm/s``). A position that is not quantized (noise on every sample)
    never repeats: nothing is taken as stuck."""
    qq = np.asarray(q, float).ravel()
    L = STICK_RUN if run is None else int(run)
    flat = np.concatenate([np.diff(qq) == 0.0, [False]])
    d = np.diff(np.concatenate([[0], flat.astype(np.int8), [0]]))
    out = np.zeros(qq.size, bool)
    for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True):
        if b - a >= L:
            out[a:b] = True
    return out


@dataclass
class IdimResult:
    """IDIM-LS estimate: ``theta`` (names of :func:`hil.identify.friction.parameter_names`), ``std``
    (the benchmark's formula), the decimation factor, the relative error ``100 |e| / |y|`` [%], the
    residual std [N], and ``cov`` (std^2-scaled (X^T X)^-1)."""

    names: tuple[str, ...]
    theta: NDArray[np.float64]
    std: NDArray[np.float64]
    cov: NDArray[np.float64]
    decimation: int
    relative_error_pct: float
    residual_std: float
    n: int
    f_filter: float
    #: residual std per equation [force unit] (models with several equations)
    residual_std_by_equation: dict[str, float] | None = None

    def as_dict(self) -> dict[str, float]:
        return dict(zip(self.names, map(float, self.theta), strict=True))

    def to_dict(self) -> dict[str, Any]:
        return {"estimate": self.as_dict(), "std": dict(zip(self.names, map(float, self.std), strict=True)),
                "decimation": self.decimation, "relative_error_pct": self.relative_error_pct,
                "residual_std": self.residual_std, "n_samples": self.n, "filter_hz": self.f_filter,
                **({"residual_std_by_equation": self.residual_std_by_equation}
                   if self.residual_std_by_equation else {})}


def _columns(v: NDArray, a: NDArray, terms: Sequence[str], v_s: float) -> list[NDArray]:
    cols = [a, v]
    sg = np.sign(v)
    if "coulomb" in terms:
        cols.append(sg)
    if "stribeck" in terms:
        cols.append(np.exp(-((v / v_s) ** 2)) * sg)
    if "offset" in terms:
        cols.append(np.ones_like(v))
    return cols


def idim_design(q: ArrayLike, u: ArrayLike, fs: float, *, f_filter: float | None = None, n_border: int = 50,
                decimation: int | None = None, hold: bool = False) -> tuple[NDArray, NDArray, NDArray, int]:
    """``(v, a, y_d, r)``: the full-rate filtered velocity and acceleration after ``n_border`` (steps 1-2 of
    the module docstring), the decimated force ``y_d`` and the decimation factor ``r``.

    ``hold``: the force sample ``u_k`` acts over ``[t_k, t_k+1)`` (a zero-order hold, positions sampled
    before it: the suite's bench convention). The central difference ``q_k+1 - 2 q_k + q_k-1`` of a held
    mass makes the double central difference of :func:`filtered_derivatives` (over ``k-2..k+2``) equal to
    ``(u_k-2 + 3 u_k-1 + 3 u_k + u_k+1) / (8 M)`` exactly, so that FIR of the force is what the acceleration
    is regressed on; the benchmark's script (``hold=False``) uses ``u_k``, half a sample early (measured on a
    simulated axis: M +0.26 %, B -0.6 %, several standard deviations)."""
    qq = np.asarray(q, float)
    uu = np.asarray(u, float)
    if hold and uu.size > 3:  # the force seen by diffcent(diffcent(q)) at k: (u_k-2 + 3 u_k-1 + 3 u_k + u_k+1) / 8
        uu = np.convolve(np.pad(uu, (2, 1), mode="edge"), np.array([1.0, 3.0, 3.0, 1.0]) / 8.0, mode="valid")
    if qq.shape != uu.shape or qq.ndim != 1:
        raise DataQualityError(f"IDIM needs 1-D position and force of one length, got {qq.shape} and {uu.shape}")
    r = int(decimation) if decimation else max(round(0.8 * (fs / 2) / (2 * F_DYN)), 1)
    if qq.size < max(4 * n_border, 40 * r):
        raise DataQualityError(f"IDIM: {qq.size} samples are too few (need >= {max(4 * n_border, 40 * r)})")
    _, v, a = filtered_derivatives(qq, fs, f_filter)
    sl = slice(n_border - 1, None)  # MATLAB's n_border:N (1-based)
    return v[sl], a[sl], decimate(uu[sl], r), r


def idim_columns(v: NDArray, a: NDArray, terms: Sequence[str], r: int, v_s: float = 1.0) -> NDArray:
    """Decimated observation matrix (n_d, p-without-v_s) of the inverse model (module docstring)."""
    return np.column_stack([decimate(c, r) for c in _columns(v, a, terms, v_s)])


def idim_ls(
    q: ArrayLike, u: ArrayLike, fs: float, friction: Sequence[str] | str = ("coulomb", "offset"), *,
    f_filter: float | None = None, n_border: int = 50, decimation: int | None = None,
) -> IdimResult:
    """IDIM-LS of ``u = M q'' + B q' [+ F_c sgn q'] [+ F_s e^{-(q'/v_s)^2} sgn q'] [+ F_0]`` from the
    position ``q`` [m or rad] and the force ``u`` [N or N.m] sampled at ``fs`` [Hz] (module docstring)."""
    terms = normalize_friction(friction)
    v, a, yd, r = idim_design(q, u, fs, f_filter=f_filter, n_border=n_border, decimation=decimation)

    def solve(v_s: float) -> tuple[NDArray, NDArray, NDArray]:
        X = idim_columns(v, a, terms, r, v_s)
        beta, *_ = np.linalg.lstsq(X, yd, rcond=None)
        return beta, X, yd - X @ beta

    names = parameter_names(terms)
    v_s = 1.0
    if "stribeck" in terms:
        vmax = float(np.max(np.abs(v)))
        res = optimize.minimize_scalar(lambda lv: float(np.sum(solve(float(np.exp(lv)))[2] ** 2)),
                                       bounds=(np.log(vmax * 1e-3), np.log(vmax)), method="bounded",
                                       options={"xatol": 1e-3})
        v_s = float(np.exp(res.x))
    beta, X, e = solve(v_s)
    s_e = float(np.std(e, ddof=1))
    cov_b = s_e**2 * np.linalg.inv(X.T @ X)
    theta = list(beta)
    std = list(np.sqrt(np.diag(cov_b)))
    if "stribeck" in terms:  # insert v_s after F_s (std not from the linear fit: reported as NaN)
        i = names.index("v_s")
        theta.insert(i, v_s)
        std.insert(i, float("nan"))
        cov = np.full((len(names), len(names)), np.nan)
        keep = [j for j in range(len(names)) if j != i]
        cov[np.ix_(keep, keep)] = cov_b
    else:
        cov = cov_b
    rel = float(100 * np.linalg.norm(e) / np.linalg.norm(yd))
    logger.info("IDIM-LS %s: %s (relative error %.2f %%)", names, np.round(theta, 4), rel)
    return IdimResult(names, np.asarray(theta, float), np.asarray(std, float), cov, r, rel, s_e, int(yd.size),
                      float(f_filter or min(5 * F_DYN, 0.4 * fs)))
