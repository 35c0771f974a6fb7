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
:class:`ActuatorModel`): command transport delay in ticks and effort saturation. Dry friction
(Coulomb, static/Stribeck) on the joints: ``friction=`` (per body, :class:`hil.mocks.friction.Friction`),
advanced by the event-located stick-slip step of :mod:`hil.mocks.friction` on top of the same exact
ZOH (a plant without friction takes exactly the linear path below, bit for bit).
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hil.errors import ModelError
from hil.lti import ArrayLike
from hil.mocks.friction import Friction, StickSlip
from hil.mocks.physics import JointMap, Plant
from hil.mocks.terminations import profile_value

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class ActuatorModel:
    """Nonlinear actuator effects applied to the commanded effort before the ZOH.

    ``delay_ticks``: the effort applied at tick k is the one commanded at tick ``k - delay``
    (zero before). ``limit``: symmetric saturation ``|effort| <= limit`` (N or N.m).
    ``coulomb``: Coulomb friction level (N or N.m) on every DOF of the body, the same as
    ``Simulator(friction={body: Friction(coulomb)})`` (exact stick-slip, :mod:`hil.mocks.friction`).
    """

    delay_ticks: int = 0
    limit: float | None = None
    coulomb: float = 0.0

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
        elif act.limit is None:
            return self._cmd  # the caller copies it into the input vector
        else:
            e = self._cmd.copy()
        if act.limit is not None:
            e = np.clip(e, -act.limit, act.limit)
        return e

    def position(self) -> np.ndarray:
        """Current positions (m or rad)."""
        return self._sim.output_slice(self._jm.position)

    def velocity(self) -> np.ndarray:
        """Current velocities (m/s or rad/s)."""
        return self._sim.output_slice(self._jm.velocity)

    def previous_position(self) -> np.ndarray:
        """Positions one control period ago (m or rad; the current ones before the first tick)."""
        return self._sim.previous_output_slice(self._jm.position)

    def measured_force(self) -> np.ndarray:
        """Force the body exerts on everything attached to it (N or N.m; e.g. the SDEA spring force
        F = K_f (x_m - x_e) + B_f (v_m - v_e)); see :mod:`hil.mocks.physics`."""
        return self._sim.output_slice(self._jm.force)


FrictionSpec = Friction | Sequence[Friction | None]


class Simulator:
    """Lockstep exact-ZOH simulator of a plant at control period ``dt`` (s).

    ``friction``: dry friction per body, one :class:`~hil.mocks.friction.Friction` for all its DOFs
    or one per DOF (None: none on that DOF); with any, each tick is the stick-slip step of
    :class:`hil.mocks.friction.StickSlip` (its counters and the energy each friction DOF dissipated:
    ``stick_slip``). Outputs with direct feedthrough of the efforts (a hand's force on a held body,
    through the acceleration) include the friction force at the current instant.
    """

    def __init__(self, plant: Plant, dt: float, x0: ArrayLike | None = None, *,
                 actuators: dict[str, ActuatorModel] | None = None, exact_sum: bool = True,
                 friction: Mapping[str, FrictionSpec] | None = None) -> None:
        self.plant = plant
        self.dt = float(dt)
        disc = plant.system.discretize(self.dt, "zoh")
        self.Ad, self.Bd = disc.Ad, disc.Bd
        self._C, self._D = plant.system.C, plant.system.D
        self._rows: dict[tuple[Any, Any, Any], tuple[np.ndarray, np.ndarray]] = {}
        self._no_feed: set[tuple[Any, Any, Any]] = set()  # output slices without effort feedthrough
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
        per_dof = _friction_per_dof(plant, friction or {}, actuators)
        self.stick_slip: StickSlip | None = None
        if any(f.active for f in per_dof.values()):
            self.stick_slip = StickSlip(plant.system.A, plant.system.B, plant.n_dof, self.dt, per_dof,
                                        exact_sum=exact_sum)
        self._f_out: np.ndarray | None = None  # friction generalized force now (outputs' feedthrough)
        self._f_key: tuple[int, int] | None = None  # (step, input version) it was computed for
        self._u_version = 0
        self._extra: dict[str, np.ndarray] = {}
        self.step_count = 0
        self._x = np.zeros(self.n)
        self._x_prev = self._x
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
        self._x_prev = self._x
        self.step_count = 0
        self._extra.clear()
        for h in self.handles.values():
            h.reset()
        self._u = np.zeros(self.m)
        self._fill_exogenous()
        self.last_input = self._u.copy()
        self._u_version += 1

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
        self._u_version += 1

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
        if self.stick_slip is not None and key not in self._no_feed:
            if np.any(rows[1][:, : self.plant.n_dof]):
                return rows[0] @ self._x + rows[1] @ self._u_with_friction()
            self._no_feed.add(key)
        return rows[0] @ self._x + rows[1] @ self._u

    def previous_output_slice(self, sl: slice) -> np.ndarray:
        """Outputs ``sl`` one tick ago, without feedthrough (``C[sl] x_{k-1}``: positions, velocities)."""
        return self._C[sl] @ self._x_prev

    def outputs(self) -> np.ndarray:
        """All outputs at the current instant."""
        if self.stick_slip is not None:
            return self._C @ self._x + self._D @ self._u_with_friction()
        return self._C @ self._x + self._D @ self._u

    def friction_force(self) -> np.ndarray | None:
        """The dry-friction generalized force (N or N.m per DOF) at the current state and held inputs
        (sticking DOFs: the force holding them), or None without friction."""
        if self.stick_slip is None:
            return None
        key = (self.step_count, self._u_version)
        if self._f_key != key or self._f_out is None:
            self._f_out = self.stick_slip.friction_force(self._x, self._u)
            self._f_key = key
        return self._f_out

    def _u_with_friction(self) -> np.ndarray:
        u = self._u.copy()
        f = self.friction_force()
        assert f is not None
        u[: self.plant.n_dof] += f
        return u

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
        self._x_prev = self._x
        if self.stick_slip is not None:
            try:
                x_new = self.stick_slip.step(self._x, u)
            except ModelError as exc:
                raise ModelError(f"simulation diverged at t = {self.time:.6g} s ({exc})") from None
        elif self._exact:
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
        self._u_version += 1


def _friction_per_dof(plant: Plant, friction: Mapping[str, FrictionSpec],
                      actuators: Mapping[str, ActuatorModel]) -> dict[int, Friction]:
    """Friction per generalized DOF index from per-body specs (and ``ActuatorModel.coulomb``)."""
    out: dict[int, Friction] = {}
    unknown = sorted(set(friction) - set(plant.joints))
    if unknown:
        raise ModelError(f"friction for unknown bodies {unknown}; have {sorted(plant.joints)}")
    for body, act in actuators.items():
        if act.coulomb > 0.0:
            if body in friction:
                raise ModelError(f"{body}: friction given twice (ActuatorModel.coulomb and friction=)")
            friction = {**friction, body: Friction(act.coulomb)}
    for body, spec in friction.items():
        jm = plant.joints[body]
        dofs = range(jm.q.start, jm.q.stop)
        per = [spec] * jm.dof if isinstance(spec, Friction) else list(spec)
        if len(per) != jm.dof:
            raise ModelError(f"{body}: {len(per)} friction entries for {jm.dof} DOF")
        for j, f in zip(dofs, per, strict=True):
            if f is not None:
                out[j] = f
    return out


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
             exact_sum: bool = True, friction: Mapping[str, FrictionSpec] | None = None) -> SimResult:
    """Run ``n_steps`` lockstep ticks.

    ``efforts``: all body efforts concatenated in body order (``plant.n_dof`` values), either an
    array of shape ``(n_steps, n_dof)`` (or ``(n_dof,)`` held constant), or a callable
    ``f(t, q, v) -> efforts`` evaluated at each tick start from the sampled generalized positions
    and velocities (a discrete controller), or ``None`` (zero). Exogenous inputs follow their
    profiles. ``friction``: see :class:`Simulator` (outputs then include the friction force's
    feedthrough at each sample).
    """
    sim = Simulator(plant, dt, x0, actuators=actuators, exact_sum=exact_sum, friction=friction)
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
    if sim.stick_slip is not None:  # the friction force at each sample (feedthrough of force outputs)
        ss = sim.stick_slip
        fs = np.array([ss.friction_force(xs[k], u_y[k]) for k in range(n_steps + 1)])
        u_y = u_y.copy()
        u_y[:, :N] += fs
    ys = xs @ plant.system.C.T + u_y @ plant.system.D.T
    t = np.arange(n_steps + 1) * sim.dt
    return SimResult(t, xs, us[:n_steps], ys, plant)
