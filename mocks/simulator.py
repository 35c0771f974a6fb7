"""Lockstep simulator: advances a :class:`~hil.mocks.physics.Plant` by exactly one control period.

* ``Simulator(plant, dt)`` precomputes the exact ZOH matrices ``(Ad, Bd)`` once; ``tick()`` does
  ``x <- Ad x + Bd u`` with the input ``u`` held over the period.
* ``u`` = actuator efforts (set through the :class:`Joints` handles, held until changed) plus
  exogenous inputs (human active forces), sampled from their profiles at the START of each tick
  (``t_k = k dt``) and held over it.
* Time is ``k * dt`` (computed, not accumulated); no wall clock anywhere.
* Determinism: the state update uses exactly rounded products summed with ``math.fsum``
  (correctly rounded), so for given ``(Ad, Bd)`` the trajectory does not depend on the BLAS
  build, thread count or SIMD width. ``(Ad, Bd)`` themselves come from LAPACK once per
  ``(plant, dt)``; bit-identity across machines therefore also assumes identical
  ``scipy.linalg.expm`` results (true for the same wheels; ULP differences are possible between
  different LAPACK builds). Pass ``exact_sum=False`` for a faster BLAS matvec.

Actuator-side nonlinearities (applied around the linear core, per handle, see
:class:`ActuatorModel`): command transport delay in ticks, effort saturation and Coulomb friction
(sampled at the tick start and held, like every input).
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from hil.errors import ModelError
from hil.lti import ArrayLike
from hil.mocks.physics import JointMap, Plant
from hil.mocks.terminations import profile_value

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class ActuatorModel:
    """Nonlinear actuator effects applied to the commanded effort before the ZOH.

    ``delay_ticks``: the effort applied at tick k is the one commanded at tick ``k - delay``
    (zero before). ``limit``: symmetric saturation ``|effort| <= limit`` (N or N.m).
    ``coulomb``: Coulomb friction level (N or N.m) opposing the joint velocity sampled at the
    tick start; when ``|v| <= stick_velocity`` it cancels up to ``coulomb`` of the (saturated)
    command (static friction approximation on the command only).
    """

    delay_ticks: int = 0
    limit: float | None = None
    coulomb: float = 0.0
    stick_velocity: float = 1e-6

    def __post_init__(self) -> None:
        if self.delay_ticks < 0 or (self.limit is not None and self.limit < 0) or self.coulomb < 0:
            raise ModelError("ActuatorModel: delay_ticks, limit and coulomb must be non-negative")


class Joints:
    """A :class:`hil.mocks.interfaces.SimulatedJoints` handle on one body of a simulated plant."""

    def __init__(self, sim: Simulator, jm: JointMap, actuator: ActuatorModel | None = None) -> None:
        self._sim = sim
        self._jm = jm
        self.name = jm.body
        self.dof = jm.dof
        self.units = sim.plant.units
        self.actuator = actuator or ActuatorModel()
        self._cmd = np.zeros(self.dof)
        self._queue: deque[np.ndarray] = deque()
        self.reset()

    def reset(self) -> None:
        """Zero the command and empty the delay line (``resets`` counts the calls)."""
        self.resets = getattr(self, "resets", -1) + 1
        self._cmd = np.zeros(self.dof)
        self._queue = deque(np.zeros(self.dof) for _ in range(self.actuator.delay_ticks))

    @property
    def sample_index(self) -> int:
        """Tick counter of the owning simulator (changes once per control period)."""
        return self._sim.step_count

    def apply_effort(self, effort: ArrayLike) -> None:
        """Command the effort (N or N.m, one per DOF) held from the next tick on (ZOH)."""
        e = np.array(effort, dtype=float).reshape(-1)  # a copy: later changes of `effort` do not leak in
        if e.size != self.dof:
            raise ModelError(f"{self.name}: effort has {e.size} values, the body has {self.dof} DOF")
        if not all(map(math.isfinite, e.tolist())):
            raise ModelError(f"{self.name}: non-finite effort {e}")
        self._cmd = e

    def _effective_effort(self) -> np.ndarray:
        act = self.actuator
        if act.delay_ticks:
            self._queue.append(self._cmd.copy())
            e = self._queue.popleft()
        elif act.limit is None and not act.coulomb > 0.0:
            return self._cmd  # the caller copies it into the input vector
        else:
            e = self._cmd.copy()
        if act.limit is not None:
            e = np.clip(e, -act.limit, act.limit)
        if act.coulomb > 0.0:
            v = self.velocity()
            moving = np.abs(v) > act.stick_velocity
            e = np.where(moving, e - act.coulomb * np.sign(v), e - np.clip(e, -act.coulomb, act.coulomb))
        return e

    def position(self) -> np.ndarray:
        """Current positions (m or rad)."""
        return self._sim.output_slice(self._jm.position)

    def velocity(self) -> np.ndarray:
        """Current velocities (m/s or rad/s)."""
        return self._sim.output_slice(self._jm.velocity)

    def measured_force(self) -> np.ndarray:
        """Force the body exerts on everything attached to it (N or N.m; e.g. the SDEA spring force
        F = K_f (x_m - x_e) + B_f (v_m - v_e)); see :mod:`hil.mocks.physics`."""
        return self._sim.output_slice(self._jm.force)


class Simulator:
    """Lockstep exact-ZOH simulator of a plant at control period ``dt`` (s)."""

    def __init__(self, plant: Plant, dt: float, x0: ArrayLike | None = None, *,
                 actuators: dict[str, ActuatorModel] | None = None, exact_sum: bool = True) -> None:
        self.plant = plant
        self.dt = float(dt)
        disc = plant.system.discretize(self.dt, "zoh")
        self.Ad, self.Bd = disc.Ad, disc.Bd
        self._C, self._D = plant.system.C, plant.system.D
        self._rows: dict[tuple[Any, Any, Any], tuple[np.ndarray, np.ndarray]] = {}
        self._W = np.hstack([self.Ad, self.Bd])
        self._W_rows: list[list[float]] = self._W.tolist()  # the exact sum's rows as plain floats
        self._exact = exact_sum
        self.n, self.m = self.Bd.shape
        actuators = actuators or {}
        unknown = set(actuators) - set(plant.joints)
        if unknown:
            raise ModelError(f"actuator models for unknown bodies {sorted(unknown)}")
        self.handles: dict[str, Joints] = {
            name: Joints(self, jm, actuators.get(name)) for name, jm in plant.joints.items()
        }
        self._extra: dict[str, np.ndarray] = {}
        self.step_count = 0
        self._x = np.zeros(self.n)
        self._u = np.zeros(self.m)
        self.last_input = np.zeros(self.m)  # input actually applied during the last tick
        self.reset(x0)

    # -- state -----------------------------------------------------------------------------

    @property
    def time(self) -> float:
        """Simulated time ``step_count * dt`` (s)."""
        return self.step_count * self.dt

    @property
    def state(self) -> np.ndarray:
        """Copy of the state vector (layout: see :mod:`hil.mocks.physics`)."""
        return self._x.copy()

    @property
    def input(self) -> np.ndarray:
        """Copy of the input vector applied during the last tick (or to be applied, before any)."""
        return self._u.copy()

    def reset(self, x0: ArrayLike | None = None) -> None:
        """Back to ``t = 0`` with state ``x0`` (zeros by default); commands and delay lines cleared."""
        x = np.zeros(self.n) if x0 is None else np.asarray(x0, dtype=float).reshape(-1)
        if x.size != self.n:
            raise ModelError(f"x0 has {x.size} entries, the plant has {self.n} states")
        self._x = x.copy()
        self.step_count = 0
        self._extra.clear()
        for h in self.handles.values():
            h.reset()
        self._u = np.zeros(self.m)
        self._fill_exogenous()
        self.last_input = self._u.copy()

    def joints(self, body: str) -> Joints:
        """The :class:`Joints` handle of ``body``."""
        try:
            return self.handles[body]
        except KeyError as exc:
            raise ModelError(f"no body {body!r}; have {sorted(self.handles)}") from exc

    def set_input(self, name: str, value: ArrayLike) -> None:
        """Hold an input group (e.g. ``"human.active"``) at ``value``, overriding its profile."""
        sl = self.plant.inputs.get(name)
        if sl is None:
            raise ModelError(f"no input {name!r}; have {sorted(self.plant.inputs)}")
        val = np.asarray(value, dtype=float).reshape(-1)
        if val.size != sl.stop - sl.start:
            raise ModelError(f"input {name!r} takes {sl.stop - sl.start} values")
        self._extra[name] = val.copy()
        self._u[sl] = val

    def output(self, name: str) -> np.ndarray:
        """Output group ``name`` at the current instant: ``C x + D u``."""
        sl = self.plant.outputs.get(name)
        if sl is None:
            raise ModelError(f"no output {name!r}; have {sorted(self.plant.outputs)}")
        return self.output_slice(sl)

    def output_slice(self, sl: slice) -> np.ndarray:
        """Outputs ``sl`` at the current instant: ``C[sl] x + D[sl] u`` (row views cached per slice)."""
        key = (sl.start, sl.stop, sl.step)
        rows = self._rows.get(key)
        if rows is None:
            rows = self._rows[key] = (self._C[sl], self._D[sl])
        return rows[0] @ self._x + rows[1] @ self._u

    def outputs(self) -> np.ndarray:
        """All outputs at the current instant."""
        return self._C @ self._x + self._D @ self._u

    # -- stepping --------------------------------------------------------------------------

    def _fill_exogenous(self) -> None:
        k, t = self.step_count, self.time
        for name, profile in self.plant.profiles.items():
            if name in self._extra:
                continue
            sl = self.plant.inputs[name]
            self._u[sl] = profile_value(profile, t, k, sl.stop - sl.start)

    def tick(self) -> None:
        """Advance exactly one control period with the current commands held (ZOH)."""
        u = self._u
        for h in self.handles.values():
            u[h._jm.effort] = h._effective_effort()
        if self._exact:
            # plain floats: each product is the same IEEE double product numpy forms elementwise and
            # math.fsum rounds their sum correctly, so this equals the array expression
            # fsum(W[i] * concat(x, u)) bit for bit, without the array temporaries (n <= ~30)
            z = self._x.tolist()
            z += u.tolist()
            fsum = math.fsum
            new = [fsum([w * v for w, v in zip(row, z, strict=True)]) for row in self._W_rows]
            if not all(map(math.isfinite, new)):
                raise ModelError(f"simulation diverged at t = {self.time:.6g} s (non-finite state)")
            x_new = np.array(new)
        else:
            x_new = self.Ad @ self._x + self.Bd @ u
            if not np.isfinite(x_new).all():
                raise ModelError(f"simulation diverged at t = {self.time:.6g} s (non-finite state)")
        self._x = x_new
        self.last_input = u.copy()
        self.step_count += 1
        if self.plant.profiles:
            self._fill_exogenous()


@dataclass(frozen=True)
class SimResult:
    """Arrays of a :func:`simulate` run: ``t`` (N+1,), ``x`` (N+1, n), ``u`` (N, m) held over
    ``[t_k, t_k+1)``, ``y`` (N+1, p) with ``y[k] = C x[k] + D u[k]`` (``u[N] = u[N-1]``)."""

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    y: np.ndarray
    plant: Plant

    def output(self, name: str) -> np.ndarray:
        """Samples of output group ``name``, shape (N+1, size)."""
        sl = self.plant.outputs.get(name)
        if sl is None:
            raise ModelError(f"no output {name!r}; have {sorted(self.plant.outputs)}")
        return self.y[:, sl]


EffortFn = Callable[[float, np.ndarray, np.ndarray], ArrayLike]


def simulate(plant: Plant, dt: float, efforts: EffortFn | ArrayLike | None, n_steps: int,
             x0: ArrayLike | None = None, *, actuators: dict[str, ActuatorModel] | None = None,
             exact_sum: bool = True) -> SimResult:
    """Run ``n_steps`` lockstep ticks.

    ``efforts``: all body efforts concatenated in body order (``plant.n_dof`` values), either an
    array of shape ``(n_steps, n_dof)`` (or ``(n_dof,)`` held constant), or a callable
    ``f(t, q, v) -> efforts`` evaluated at each tick start from the sampled generalized positions
    and velocities (a discrete controller), or ``None`` (zero). Exogenous inputs follow their
    profiles.
    """
    sim = Simulator(plant, dt, x0, actuators=actuators, exact_sum=exact_sum)
    N = plant.n_dof
    arr = None
    if efforts is not None and not callable(efforts):
        arr = np.asarray(efforts, dtype=float)
        arr = np.broadcast_to(arr.reshape(1, N), (n_steps, N)) if arr.size == N else arr.reshape(n_steps, N)
    handles = list(sim.handles.values())
    xs = np.empty((n_steps + 1, sim.n))
    us = np.empty((max(n_steps, 1), sim.m))
    for k in range(n_steps):
        xs[k] = sim._x
        if efforts is None:
            e = np.zeros(N)
        elif arr is not None:
            e = arr[k]
        else:
            assert callable(efforts)
            x = sim._x
            e = np.asarray(efforts(sim.time, x[:N].copy(), x[N : 2 * N].copy()), dtype=float).reshape(N)
        for h in handles:
            h.apply_effort(e[h._jm.effort])
        sim.tick()
        us[k] = sim.last_input
    xs[n_steps] = sim._x
    if n_steps == 0:
        us[0] = sim._u
    u_y = np.vstack([us[:n_steps], us[n_steps - 1 : n_steps] if n_steps else us[:1]])
    ys = xs @ plant.system.C.T + u_y @ plant.system.D.T
    t = np.arange(n_steps + 1) * sim.dt
    return SimResult(t, xs, us[:n_steps], ys, plant)
