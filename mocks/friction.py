"""Dry friction on the simulated joints: Coulomb + static (Stribeck) friction with exact stick-slip.

The linear part of a scene (masses, viscous damping, springs, terminations; :mod:`hil.mocks.physics`)
is advanced by the exact zero-order-hold solution. Dry friction is not linear: on each friction DOF
``j`` (a generalized coordinate of the plant) it adds the generalized force

* slipping (``v_j != 0``, direction ``s_j = sign(v_j)``):
  ``f_j = -s_j F_j(|v_j|)``, ``F_j(w) = F_c + (F_s - F_c) exp(-(w / v_s)^2)`` (Coulomb level ``F_c``,
  static level ``F_s >= F_c``, Stribeck velocity ``v_s``; ``F_s = F_c`` is plain Coulomb friction);
* sticking (``v_j = 0``): whatever force ``lambda_j`` keeps ``v_j = 0``, as long as
  ``|lambda_j| <= F_s``; beyond it the DOF breaks away in the direction of ``-lambda_j``.

Viscous friction is the body's ``B`` (linear, inside the exact ZOH part).

Scheme (event-located stick-slip on top of the exact ZOH linear part)
---------------------------------------------------------------------
Within a tick the efforts and exogenous inputs are held (ZOH). In every *mode* -- which friction DOFs
stick (set ``S``) and the direction of the others -- the motion is linear with constant inputs:

* a slipping DOF's friction is a constant force ``-s_j F_j`` (``F_j`` taken at the segment start: exact
  for Coulomb friction, first order in the segment length for the Stribeck part);
* sticking DOFs are held by the constraint ``v_S = 0``: with ``W = M^{-1}`` (the inverse assembled mass
  matrix) and the unconstrained acceleration ``a = A_v x + B_v u``, the constraint forces are
  ``lambda_S = -W_SS^{-1} a_S`` and the constrained dynamics ``v' = (I - W_:S W_SS^{-1} E_S) a``, whose
  rows ``S`` are exactly zero: the stuck DOFs' positions and velocities are held exactly (and reset
  to their held values after every segment, so no round-off drift accumulates).

Each mode is therefore solved exactly by the ZOH of its own (constrained) state matrix. A mode ends at
an *event*: a slipping DOF's velocity reaching zero, or a sticking DOF's constraint force reaching
``±F_s``. Events are found on a sub-grid of the segment (at least two points per half period of the
mode's fastest oscillation, at least 4 per tick) and located by bisection on the exact solution
``x(τ) = e^{Aτ} x0 + ∫ e^{As} ds B u``: time within a tick is counted in ``dt / 2**40`` units and each
mode caches the exact ZOH matrices over ``dt / 2**i``, so a bisection step is one matrix-vector
product and an event is located to ``dt / 2**40`` (1e-15 s at 1 kHz). At a velocity zero the
velocity is set to exactly 0 and the DOF sticks when the force needed to hold it is within ``F_s``
(active set over several DOFs, releasing the most violated first), else it reverses; at a breakaway
event the DOF is released in the direction of the net force. Consequences:

* no chattering at zero velocity: a stuck DOF has ``v = 0`` exactly and stays so while
  ``|applied| <= F_s``; no velocity band, no regularized ``tanh``/``atan`` sign;
* stiff cases (contact springs, SDEA springs) are integrated exactly in every mode; the sub-grid
  follows the fastest oscillation so successive reversals inside one tick are found;
* determinism: the same inputs give the same trajectory bit for bit (the full-tick update uses the
  same correctly rounded ``math.fsum`` dot products as :mod:`hil.mocks.simulator`; the root finder is
  deterministic); at most :data:`MAX_SEGMENTS` mode changes per tick (``truncated`` counts ticks where
  the rest of the tick was taken without further events; never reached in the tests).

The energy each friction DOF dissipates is accumulated exactly (``dissipated``, J): in a slipping
segment the friction force is constant, so its work is ``F_j s_j (q_j(end) - q_j(start)) >= 0``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import scipy.linalg as sla

from hil.errors import ModelError

logger = logging.getLogger(__name__)

#: mode changes allowed within one tick before the rest of the tick is taken in the current mode
MAX_SEGMENTS = 64
#: sub-grid points per half period of the fastest oscillation of a mode (event search)
POINTS_PER_HALF_PERIOD = 2
#: bounds of the sub-grid size per segment
MIN_SUBSTEPS, MAX_SUBSTEPS = 4, 256

VelocityEstimate = Literal["estimate", "difference"]


@dataclass(frozen=True)
class Friction:
    """Dry friction on one DOF: Coulomb level ``coulomb`` (N or N.m, ``F_c >= 0``), static level
    ``static`` (``F_s >= F_c``; None: ``F_c``, no Stribeck effect) and Stribeck velocity
    ``stribeck_velocity`` (m/s or rad/s, > 0; required when ``F_s > F_c``). The sliding friction level
    is ``F(w) = F_c + (F_s - F_c) exp(-(w / v_s)^2)`` at speed ``w``."""

    coulomb: float = 0.0
    static: float | None = None
    stribeck_velocity: float | None = None

    def __post_init__(self) -> None:
        c = float(self.coulomb)
        if not (math.isfinite(c) and c >= 0.0):
            raise ModelError(f"friction: coulomb must be a finite number >= 0, got {self.coulomb!r}")
        if self.static is not None:
            s = float(self.static)
            if not (math.isfinite(s) and s >= c):
                raise ModelError(f"friction: static ({self.static!r}) must be finite and >= coulomb ({c:g})")
        if self.stribeck_velocity is not None:
            vs = float(self.stribeck_velocity)
            if not (math.isfinite(vs) and vs > 0.0):
                raise ModelError(f"friction: stribeck_velocity must be a finite number > 0, got "
                                 f"{self.stribeck_velocity!r}")
        if self.F_s > c and self.stribeck_velocity is None:
            raise ModelError("friction: static > coulomb needs a stribeck_velocity (how fast friction falls "
                             "from static to Coulomb)")

    @property
    def F_c(self) -> float:
        """Coulomb (sliding) level, N or N.m."""
        return float(self.coulomb)

    @property
    def F_s(self) -> float:
        """Static (breakaway) level, N or N.m (``F_c`` without a Stribeck effect)."""
        return float(self.coulomb if self.static is None else self.static)

    @property
    def active(self) -> bool:
        """True when the DOF has any dry friction."""
        return self.F_s > 0.0

    def level(self, speed: float) -> float:
        """Sliding friction level ``F(|v|)`` (N or N.m) at ``speed`` = ``|v|`` (``F_s`` at rest)."""
        fc, fs = self.F_c, self.F_s
        if fs == fc or self.stribeck_velocity is None:
            return fc
        return fc + (fs - fc) * math.exp(-((abs(speed) / float(self.stribeck_velocity)) ** 2))


@dataclass(frozen=True)
class Mechanics:
    """A device's mechanics as its simulated twin adds them to the body DOFs it drives: dry
    ``friction``, extra ``viscous`` damping (N.s/m or N.m.s/rad, added to the body's ``B``), the
    encoder's quantization ``encoder_step`` (m or rad; 0: none) and how the device reports velocity
    (``estimate``: the joint velocity, plus the scene's velocity noise; ``difference``: the backward
    difference of the quantized positions over one control period, as a drive that differentiates
    its encoder does). ``source`` says where the values come from (datasheet, identification)."""

    friction: Friction = field(default_factory=Friction)
    viscous: float = 0.0
    encoder_step: float = 0.0
    velocity: VelocityEstimate = "estimate"
    source: str = ""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.viscous) and self.viscous >= 0.0):
            raise ModelError(f"mechanics: viscous must be a finite number >= 0, got {self.viscous!r}")
        if not (math.isfinite(self.encoder_step) and self.encoder_step >= 0.0):
            raise ModelError(f"mechanics: encoder step must be a finite number >= 0, got {self.encoder_step!r}")
        if self.velocity not in ("estimate", "difference"):
            raise ModelError(f"mechanics: velocity must be 'estimate' or 'difference', got {self.velocity!r}")


def quantize(x: np.ndarray, step: float) -> np.ndarray:
    """``x`` on the encoder grid ``step * round(x / step)`` (round half to even); ``x`` when step is 0."""
    if step <= 0.0:
        return x
    return step * np.round(np.asarray(x, dtype=float) / step)


# ----------------------------------------------------------------------------------------------
# the stick-slip stepper

#: the tick is divided into 2**LEVELS time units: event times are located to dt / 2**40 (1e-15 s at 1 kHz)
LEVELS = 40
#: the finest sub-grid used to look for events: 2**MAX_GRID_LEVEL points per tick
MAX_GRID_LEVEL = 12


@dataclass
class _Mode:
    """The constrained dynamics of one stick set ``S`` (cached per set)."""

    S: tuple[int, ...]
    A: np.ndarray  # (n, n) constrained state matrix
    B: np.ndarray  # (n, m) constrained input matrix
    Lx: np.ndarray  # (|S|, n) constraint forces lambda_S = Lx x + Lu u
    Lu: np.ndarray  # (|S|, m)
    grid_level: int  # 2**grid_level sub-grid points per tick
    steps: dict[int, np.ndarray] = field(default_factory=dict)  # level i -> [Phi | Gamma] over dt / 2**i
    full_rows: list[list[float]] | None = None  # level 0 as plain floats (fsum)
    #: event rows over the tick's interior grid points: [velocities of the friction DOFs; lambda_S] at
    #: each point, as one ((k - 1) (|J| + |S|), n + m) matrix applied to [x; u]
    grid_rows: np.ndarray | None = None


def _zoh(A: np.ndarray, B: np.ndarray, tau: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact ZOH ``(e^{A tau}, int_0^tau e^{A s} ds B)`` of the augmented matrix ``[[A, B], [0, 0]] tau``:
    its Taylor series when ``||.||_1 <= 1/2`` (25 terms: truncation below 1e-40), else
    ``scipy.linalg.expm``."""
    n, m = B.shape
    Maug = np.zeros((n + m, n + m))
    Maug[:n, :n] = A * tau
    Maug[:n, n:] = B * tau
    if np.max(np.sum(np.abs(Maug), axis=0)) <= 0.5:
        E = np.eye(n + m)
        term = np.eye(n + m)
        for k in range(1, 26):
            term = term @ Maug / k
            E = E + term
    else:
        E = sla.expm(Maug)
    return E[:n, :n], E[:n, n:]


class StickSlip:
    """Advances ``x' = A x + B u`` plus dry friction on the generalized DOFs ``friction`` (index ->
    :class:`Friction`) by one tick of ``dt`` seconds with ``u`` held (see the module docstring).

    ``A`` (n, n) and ``B`` (n, m) are a :class:`hil.mocks.physics.Plant`'s continuous matrices with
    state ``[q (N), v (N), termination states]`` and the first ``N`` inputs the efforts on the
    generalized coordinates (so ``W = B[N:2N, :N]`` is the inverse mass matrix).

    Time inside a tick is counted in units of ``dt / 2**LEVELS``; every mode keeps the exact ZOH
    matrices over ``dt / 2**i`` (computed once, when first needed), so any segment is a product of
    at most ``LEVELS`` of them and an event is located by bisection with one matrix-vector product
    per halving.

    Attributes: ``dissipated`` (J, per friction DOF in ``dofs`` order), ``segments`` (mode segments
    taken, all ticks), ``events`` (located mode changes), ``truncated`` (ticks that hit
    :data:`MAX_SEGMENTS`).
    """

    def __init__(self, A: np.ndarray, B: np.ndarray, n_dof: int, dt: float, friction: Mapping[int, Friction],
                 *, exact_sum: bool = True) -> None:
        self.A = np.asarray(A, dtype=float)
        self.B = np.asarray(B, dtype=float)
        self.N = int(n_dof)
        self.n, self.m = self.B.shape
        self.dt = float(dt)
        N = self.N
        if self.m < N:
            raise ModelError("stick-slip: the plant has fewer inputs than generalized coordinates")
        bad = [j for j in friction if not 0 <= j < N]
        if bad:
            raise ModelError(f"stick-slip: friction on DOF {bad[0]} outside 0..{N - 1}")
        self.dofs: tuple[int, ...] = tuple(sorted(j for j, f in friction.items() if f.active))
        self.fr = {j: friction[j] for j in self.dofs}
        self.W = self.B[N : 2 * N, :N]
        self.Av = self.A[N : 2 * N]
        self.Bv = self.B[N : 2 * N]
        self._exact = exact_sum
        self._modes: dict[tuple[int, ...], _Mode] = {}
        self.dissipated = np.zeros(len(self.dofs))
        self.segments = 0
        self.events = 0
        self.truncated = 0

    # -- modes ----------------------------------------------------------------------------------

    def _mode(self, S: tuple[int, ...]) -> _Mode:
        mode = self._modes.get(S)
        if mode is not None:
            return mode
        N, n, m = self.N, self.n, self.m
        A, B = self.A.copy(), self.B.copy()
        if S:
            idx = np.array(S)
            Wss = self.W[np.ix_(idx, idx)]
            try:
                Winv = np.linalg.inv(Wss)
            except np.linalg.LinAlgError as exc:  # pragma: no cover - W is SPD
                raise ModelError("stick-slip: singular mass sub-matrix") from exc
            P = np.eye(N) - self.W[:, idx] @ Winv @ np.eye(N)[idx]
            A[N : 2 * N] = P @ self.Av
            B[N : 2 * N] = P @ self.Bv
            # the stuck DOFs' velocity rows and position rows: exactly zero
            A[N + idx] = 0.0
            B[N + idx] = 0.0
            A[idx] = 0.0
            Lx = -Winv @ self.Av[idx]
            Lu = -Winv @ self.Bv[idx]
        else:
            Lx, Lu = np.zeros((0, n)), np.zeros((0, m))
        ev = np.linalg.eigvals(A)
        omega = float(np.max(np.abs(ev.imag))) if ev.size else 0.0
        points = max(MIN_SUBSTEPS, math.ceil(POINTS_PER_HALF_PERIOD * omega * self.dt / math.pi))
        level = min(MAX_GRID_LEVEL, max(2, math.ceil(math.log2(points))))
        mode = _Mode(S, A, B, Lx, Lu, level)
        self._modes[S] = mode
        return mode

    def _step(self, mode: _Mode, level: int) -> np.ndarray:
        """``[Phi | Gamma]`` of the mode over ``dt / 2**level`` (cached)."""
        M = mode.steps.get(level)
        if M is None:
            Phi, Gam = _zoh(mode.A, mode.B, self.dt / 2.0**level)
            M = mode.steps[level] = np.hstack([Phi, Gam])
            if level == 0:
                mode.full_rows = M.tolist()
        return M

    def _go(self, mode: _Mode, x: np.ndarray, ut: np.ndarray, units: int) -> np.ndarray:
        """``x`` advanced by ``units`` time units (0 <= units <= 2**LEVELS) in the mode."""
        if units >= 1 << LEVELS:
            return self._full(mode, x, ut)
        for i in range(1, LEVELS + 1):
            if units & (1 << (LEVELS - i)):
                M = self._step(mode, i)
                x = M[:, : self.n] @ x + M[:, self.n :] @ ut
        return x

    def _full(self, mode: _Mode, x: np.ndarray, ut: np.ndarray) -> np.ndarray:
        """One whole tick in the mode (the correctly rounded sums of :mod:`hil.mocks.simulator`)."""
        M = self._step(mode, 0)
        if self._exact and mode.full_rows is not None:
            z = x.tolist() + ut.tolist()
            fsum = math.fsum
            return np.array([fsum([w * v for w, v in zip(row, z, strict=True)]) for row in mode.full_rows])
        return M[:, : self.n] @ x + M[:, self.n :] @ ut

    def _levels(self, x: np.ndarray, slip: Mapping[int, int]) -> np.ndarray:
        """The friction input (N,) of the slipping DOFs: ``-s_j F_j(|v_j|)``."""
        f = np.zeros(self.N)
        for j, s in slip.items():
            f[j] = -s * self.fr[j].level(float(x[self.N + j]))
        return f

    def _u_total(self, u: np.ndarray, f: np.ndarray) -> np.ndarray:
        ut = np.array(u, dtype=float)
        ut[: self.N] += f
        return ut

    def decide(self, x: np.ndarray, u: np.ndarray, forced: Mapping[int, int] | None = None
               ) -> tuple[tuple[int, ...], dict[int, int], np.ndarray, np.ndarray]:
        """The mode at state ``x`` with inputs ``u``: the stick set, the slipping DOFs' directions,
        the friction input (N,) and the constraint forces of the stick set. ``forced``: DOFs to
        release in a given direction (a located breakaway)."""
        N = self.N
        forced = dict(forced or {})
        slip: dict[int, int] = {}
        cand: list[int] = []
        for j in self.dofs:
            v = float(x[N + j])
            if j in forced:
                slip[j] = forced[j]
            elif v != 0.0:
                slip[j] = 1 if v > 0.0 else -1
            else:
                cand.append(j)
        while True:
            f = self._levels(x, slip)
            S = tuple(cand)
            if not S:
                return S, slip, f, np.zeros(0)
            mode = self._mode(S)
            ut = self._u_total(u, f)
            lam = mode.Lx @ x + mode.Lu @ ut
            excess = np.abs(lam) - np.array([self.fr[j].F_s for j in S])
            w = int(np.argmax(excess))
            if excess[w] <= 0.0:
                return S, slip, f, lam
            j = S[w]
            slip[j] = 1 if -lam[w] > 0.0 else -1
            cand.remove(j)

    def friction_force(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The friction generalized force (N,) at state ``x`` with inputs ``u``: ``-s F(|v|)`` on
        slipping DOFs, the constraint force on sticking ones."""
        S, _slip, f, lam = self.decide(x, u)
        out = f.copy()
        for i, j in enumerate(S):
            out[j] = lam[i]
        return out

    # -- one tick -------------------------------------------------------------------------------

    def step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The state one tick after ``x`` with inputs ``u`` held (ModelError if it diverges)."""
        N = self.N
        T = 1 << LEVELS
        x = np.array(x, dtype=float)
        u = np.asarray(u, dtype=float)
        t = 0
        forced: dict[int, int] = {}
        for seg in range(MAX_SEGMENTS + 1):
            S, slip, f, _lam = self.decide(x, u, forced)
            forced = {}
            mode = self._mode(S)
            ut = self._u_total(u, f)
            held_q = {j: float(x[j]) for j in S}
            last = seg == MAX_SEGMENTS
            hit = None if last else self._first_event(mode, x, ut, t, slip)
            what: list[tuple[str, int, int]] = []
            if hit is None:
                t_end, x1 = T, self._go(mode, x, ut, T - t)
            else:
                t_end, x1, what = hit
            self._account(x, x1, slip, f)
            for j in S:  # exact hold of the stuck DOFs
                x1[j] = held_q[j]
                x1[N + j] = 0.0
            self.segments += 1
            x = x1
            if last:
                self.truncated += 1
                logger.warning("stick-slip: more than %d mode changes in one tick; rest of the tick taken in the "
                               "last mode", MAX_SEGMENTS)
            if not what:
                break
            self.events += 1
            t = t_end
            for kind, j, direction in what:
                if kind == "stop":
                    x[N + j] = 0.0  # the velocity zero, exactly
                else:  # breakaway of a stuck DOF
                    forced[j] = direction
            if t >= T:
                break
        if not np.all(np.isfinite(x)):
            raise ModelError("simulation diverged (non-finite state in the stick-slip step)")
        return x

    def _account(self, x0: np.ndarray, x1: np.ndarray, slip: Mapping[int, int], f: np.ndarray) -> None:
        """Work of the friction forces over a segment (exact: the force is constant in a segment)."""
        for i, j in enumerate(self.dofs):
            if j in slip:
                self.dissipated[i] += max(0.0, -f[j] * (float(x1[j]) - float(x0[j])))

    def _violated(self, mode: _Mode, x: np.ndarray, ut: np.ndarray, slip: Mapping[int, int]) -> list[tuple[str, int]]:
        """The events that have happened at state ``x``: a slipping DOF whose velocity is zero or
        reversed (``("stop", j)``), a stuck DOF whose holding force exceeds ``F_s`` (``("break", j)``)."""
        N = self.N
        out = [("stop", j) for j, s in slip.items() if s * x[N + j] <= 0.0]
        if mode.S:
            lam = mode.Lx @ x + mode.Lu @ ut
            out += [("break", j) for i, j in enumerate(mode.S) if abs(lam[i]) > self.fr[j].F_s]
        return out

    def _grid_scan(self, mode: _Mode, x0: np.ndarray, ut: np.ndarray, slip: Mapping[int, int]) -> int | None:
        """Index of the last interior grid point of a whole tick before the first one where an
        event has happened (0: the tick's start), or None when none has at the interior points."""
        k = 1 << mode.grid_level
        if k < 2:
            return None
        nJ, nS = len(self.dofs), len(mode.S)
        if mode.grid_rows is None:
            n = self.n
            blocks = []
            vrows = [self.N + j for j in self.dofs]
            for i in range(1, k):
                M = self._go_matrix(mode, i * (1 << (LEVELS - mode.grid_level)))
                rows = [M[vrows]]
                if nS:
                    lx = mode.Lx @ M[:, :n]
                    lu = mode.Lx @ M[:, n:] + mode.Lu
                    rows.append(np.hstack([lx, lu]))
                blocks.append(np.vstack(rows))
            mode.grid_rows = np.vstack(blocks)
        vals = (mode.grid_rows @ np.concatenate([x0, ut])).reshape(k - 1, nJ + nS)
        sgn = np.array([slip.get(j, 0) for j in self.dofs], dtype=float)
        bad = ((vals[:, :nJ] * sgn <= 0.0) & (sgn != 0.0)).any(axis=1)
        if nS:
            fs = np.array([self.fr[j].F_s for j in mode.S])
            bad |= (np.abs(vals[:, nJ:]) > fs).any(axis=1)
        hits = np.flatnonzero(bad)
        return None if hits.size == 0 else int(hits[0])

    def _go_matrix(self, mode: _Mode, units: int) -> np.ndarray:
        """``[Phi | Gamma]`` of the mode over ``units`` time units (product of the dyadic steps)."""
        n, m = self.n, self.m
        M = np.hstack([np.eye(n), np.zeros((n, m))])
        for i in range(1, LEVELS + 1):
            if units & (1 << (LEVELS - i)):
                S = self._step(mode, i)
                M = np.hstack([S[:, :n] @ M[:, :n], S[:, :n] @ M[:, n:] + S[:, n:]])
        return M

    def _first_event(self, mode: _Mode, x0: np.ndarray, ut: np.ndarray, t0: int, slip: Mapping[int, int]
                     ) -> tuple[int, np.ndarray, list[tuple[str, int, int]]] | None:
        """The first event after time ``t0`` (units) of the segment from ``x0``: its time, the state
        there and what happens (``("stop", j, 0)``: DOF j's velocity reaches 0; ``("break", j, s)``:
        stuck DOF j breaks away in direction s; nothing: the tick's end, no event), or None when the mode
        has no event to look for. A sub-grid of the mode (``grid_level``) brackets it, bisection on
        the dyadic time units locates it (to one unit)."""
        if not slip and not mode.S:
            return None
        T = 1 << LEVELS
        g = 1 << (LEVELS - mode.grid_level)
        Mg = self._step(mode, mode.grid_level)
        n = self.n
        ta, xa = t0, x0
        if t0 == 0:  # a whole tick: every interior grid point at once, then the tick's end
            first = self._grid_scan(mode, x0, ut, slip)
            if first is None:
                xb = self._full(mode, x0, ut)
                if not self._violated(mode, xb, ut, slip):
                    return T, xb, []
                first = (1 << mode.grid_level) - 1
            ta = first * g
            xa = self._go(mode, x0, ut, ta) if first else x0
        while ta < T:
            tb = min(T, (ta // g + 1) * g)  # the next grid point (grid aligned on the tick)
            xb = (Mg[:, :n] @ xa + Mg[:, n:] @ ut) if (tb - ta == g) else self._go(mode, xa, ut, tb - ta)
            if tb == T and t0 == 0:
                xb = self._full(mode, x0, ut)  # the state the tick ends in without an event
            if self._violated(mode, xb, ut, slip):
                break
            ta, xa = tb, xb
        else:
            return T, np.array(xa, dtype=float), []
        # bisection on [ta, tb]: no event at ta (or ta = t0), an event at tb
        while tb - ta > 1:
            step = 1 << ((tb - ta - 1).bit_length() - 1)  # largest power of two < tb - ta
            tm = ta + step
            xm = self._go(mode, xa, ut, step)
            if self._violated(mode, xm, ut, slip):
                tb, xb = tm, xm
            else:
                ta, xa = tm, xm
        what: list[tuple[str, int, int]] = []
        lam = (mode.Lx @ xb + mode.Lu @ ut) if mode.S else np.zeros(0)
        for kind, j in self._violated(mode, xb, ut, slip):
            if kind == "stop":
                what.append(("stop", j, 0))
            else:
                i = mode.S.index(j)
                what.append(("break", j, 1 if -lam[i] > 0.0 else -1))
        return tb, np.array(xb, dtype=float), what
