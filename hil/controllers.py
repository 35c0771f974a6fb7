"""Discrete-time controllers the runner composes (``docs/RUNNER_SPEC.md``).

Every controller maps the latest measurements to actuator efforts once per control period::

    u = controller.update(t, dt, meas)      # {actuator device name: effort (dof,) in N or N.m}
    controller.reset()                      # back to the initial (rest) state

The effort is applied by the bench over the next period (zero-order hold), so a continuous-time
law ``C(s)`` is realized with an unavoidable half-sample average delay ``e^{-sT/2}`` (T = dt);
the tests compare the closed loop with the papers' continuous network models at frequencies
where ``ωT/2`` is small, and attribute the residual to that delay.

Units and signs
---------------
SI throughout: positions m or rad, velocities m/s or rad/s, efforts N or N.m (``units`` =
``linear`` or ``rotary`` only changes the names in messages). As in ``protocols/base.py`` a
positive effort accelerates a joint in its positive direction. Gains: ``Kp`` in N/m (N.m/rad),
``Kv`` in N.s/m (N.m.s/rad); scalars mean ``k * I``, vectors ``diag(k)``, nested lists matrices.

Position-position controllers (papers 000, 001)
-----------------------------------------------
The papers write a PD position controller as a PI *velocity* controller ``C = (k_p + k_v s)/s``
acting on velocities; with positions measured from the rest configuration (``x = v/s``) this is
``C v = k_p x + k_v v``. All three teleoperation laws are therefore one linear map on the stacked
coordinates ``q`` (positions of all devices) and ``v`` (velocities)::

    u = -(Kp q + Kv v)          (PositionPD)

with block gain matrices chosen so that the closed-loop network matrix is exactly the paper's
``Z_robots(s) + C(s)``, ``C(s) = (Kp + Kv s)/s``. A positive position error of a device w.r.t. its
partner produces a restoring (negative) effort on it.

* ``pd_position_position`` (000 eq. 42-43): ``q = [x_m; x_s]``,
  ``F_m = -Kp_m (x_m - x_s) - Kv_m (v_m - v_s)``, ``F_s = -Kp_s (x_s - x_m) - Kv_s (v_s - v_m)``.
* ``mcet`` (000 eq. 21-25, dual-user four-channel, position-position case ``c1 = c_s``,
  ``c4mi = -c_mi``, ``c2 = c3 = c5 = c6 = 0``). Eq. (22)-(23) give the control forces
  ``f_cm1 = -c_m1 v_h1 - c_4m1 v_h2 = -c_m1 (v_h1 - v_h2)``, ``f_cm2 = -c_m2 (v_h2 - v_h1)``,
  ``f_cs = -c_s v_e + c_1 (α v_h1 + (1-α) v_h2) = -c_s (v_e - α v_h1 - (1-α) v_h2)``; with
  ``c = (k_p + k_v s)/s`` on velocities these are PD laws on positions:
  ``F_m1 = -k_pm1 (x_1 - x_2) - k_vm1 (v_1 - v_2)``, ``F_m2 = -k_pm2 (x_2 - x_1) - k_vm2 (v_2 - v_1)``,
  ``F_s = -k_ps (x_s - α x_1 - (1-α) x_2) - k_vs (v_s - α v_1 - (1-α) v_2)``.
  Substituting into the robots ``Z_i v_i = F_i + f_ci`` reproduces eq. (25) row by row
  (``F_h1 = (c_m1 + Z_m1) v_h1 - c_m1 v_h2`` etc.). Note that in this special case the masters are
  coupled to each other, not to the slave; the slave follows the authority-weighted masters.
* ``dual_master`` (001 eq. 15): ``F_cm = -C_m V_h + C_4 V_e``, ``F_cs = -C_s V_e + C_1 V_h`` with
  ``V_h`` the masters' velocities stacked in the slave's DOF order (master 1 -> x, master 2 ->
  y, z: ``masters: [{device: m1, slave_dofs: [0]}, {device: m2, slave_dofs: [1, 2]}]``) and every
  ``C = (Kp + Kv s)/s`` a matrix; i.e. ``Kp = [[C_m.kp, -C_4.kp], [-C_1.kp, C_s.kp]]``.

Configuration
-------------
Each controller type has one pydantic schema here (:class:`NoController`, :class:`PdPositionPosition`,
:class:`Mcet`, :class:`DualMaster`, :class:`Vsic`; their docstrings list every field) and one builder,
registered in :data:`CONTROLLER_TYPES` (``register_controller``); :mod:`hil.scene.spec` composes the
scene's ``controller`` block from that registry. :func:`make_controller` takes the validated model
(or validates a mapping once against the same schema).

SDEA velocity-sourced impedance control (paper 002)
---------------------------------------------------
See :class:`VSIC` for the block diagram and its equivalence with eq. (12).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Annotated, Any, ClassVar, Literal, Protocol, TypeAlias, runtime_checkable

import numpy as np
from pydantic import BeforeValidator, Field, model_validator
from pydantic_core import PydanticCustomError

from hil.errors import SceneError
from hil.plugins import load_group
from hil.protocols.base import JointSample, WrenchSample
from hil.schema import (
    DampMat,
    DampNonneg,
    DofList,
    FieldError,
    Fraction,
    MatrixValue,
    Name,
    SceneView,
    StiffMat,
    StiffNonneg,
    StrictModel,
    WrenchAxes,
    as_matrix,
    matrix_shape,
    number,
    parse_matrix,
    register_tagged,
    validate,
)

logger = logging.getLogger(__name__)

__all__ = [
    "CONTROLLER_TYPES",
    "VSIC",
    "Controller",
    "ControllerConfig",
    "ControllerType",
    "DualMaster",
    "Mcet",
    "Measurements",
    "NoController",
    "NullController",
    "PdPositionPosition",
    "PositionPD",
    "Vsic",
    "VsicEnvironment",
    "controller_schemas",
    "dual_master_controller",
    "gain_matrix",
    "make_controller",
    "mcet_controller",
    "pd_position_position",
    "register_controller",
    "vsic_controller",
]

DeviceSample: TypeAlias = JointSample | WrenchSample
Measurements: TypeAlias = Mapping[str, DeviceSample]


@runtime_checkable
class Controller(Protocol):
    """What the runner calls once per control period."""

    def reset(self) -> None:
        """Back to the initial state (integrators, virtual environment at rest)."""

    def update(self, t: float, dt: float, meas: Measurements) -> dict[str, np.ndarray]:
        """Efforts (N or N.m) per actuator device for the period starting at ``t`` (s)."""


# ---------------------------------------------------------------------------------------------
# helpers


def _field(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key


def gain_matrix(value: Any, dof: int | None, field: str) -> np.ndarray:
    """A ``dof x dof`` gain matrix from a scalar (``k I``), a vector (``diag``) or a matrix (as a
    scene writes it, or a parsed matrix field: :func:`hil.schema.parse_matrix`, the one parser).

    Raises :class:`SceneError` naming ``field`` for wrong shapes or non-finite entries. With
    ``dof=None`` a scalar gives a 1x1 matrix.
    """
    try:
        parsed = parse_matrix(value)
    except PydanticCustomError as exc:
        raise SceneError(f"{field}: {exc.message()}") from None
    shape = matrix_shape(parsed)
    if shape is not None and shape[0] != shape[1]:
        raise SceneError(f"{field}: must be a scalar, a vector or a square matrix, got shape {shape}")
    n = (shape[0] if shape is not None else 1) if dof is None else dof
    if shape is not None and shape[0] != n:
        raise SceneError(f"{field}: is {shape[0]}x{shape[1]}, expected {n}x{n}")
    return as_matrix(parsed, n)


def _gain_dof(dof: int | None, gains: Sequence[MatrixValue]) -> int:
    """``dof`` when given, else the size of the first gain that is a matrix (default 1)."""
    if dof is not None:
        return dof
    for g in gains:
        shape = matrix_shape(g)
        if shape is not None:
            return shape[0]
    return 1


def _square_gain(path: str, value: MatrixValue, n: int, what: str) -> None:
    """A pure check: ``value`` is a number (``k I``) or an ``n x n`` matrix."""
    shape = matrix_shape(value)
    if shape is not None and shape != (n, n):
        raise FieldError(path, f"expected a {n}x{n} matrix ({what}), got {shape[0]}x{shape[1]}")


def _full(value: MatrixValue, n: int) -> MatrixValue:
    """A gain as the full ``n x n`` matrix it stands for (scalars expanded: the final values that
    the scene's dumps, the network models and the records see)."""
    return as_matrix(value, n).tolist() if matrix_shape(value) is None else value


def _joint(meas: Measurements, name: str, field: str) -> JointSample:
    try:
        s = meas[name]
    except KeyError as exc:
        raise SceneError(f"{field}: no measurement from device {name!r} (have {sorted(meas)})") from exc
    if not isinstance(s, JointSample):
        raise SceneError(f"{field}: device {name!r} is not an actuator (got {type(s).__name__})")
    return s


# ---------------------------------------------------------------------------------------------
# none


class NullController:
    """``type: none``: zero effort on every actuator present in the measurements."""

    name = "none"

    def reset(self) -> None:
        """Nothing to reset."""

    def update(self, t: float, dt: float, meas: Measurements) -> dict[str, np.ndarray]:
        return {k: np.zeros(np.asarray(s.position).size) for k, s in meas.items() if isinstance(s, JointSample)}


# ---------------------------------------------------------------------------------------------
# position-position PD family


class PositionPD:
    """``u = -(Kp q + Kv v)`` on coordinates stacked from several devices.

    ``layout``: ``[(device, stack indices), ...]``: device ``i``'s DOF ``j`` sits at
    ``q[idx_i[j]]`` and receives ``u[idx_i[j]]``. ``Kp`` (N/m or N.m/rad) and ``Kv`` (N.s/m or
    N.m.s/rad) are ``n x n``. Stateless (a static map of the sampled positions/velocities); the
    continuous equivalent is ``C(s) = (Kp + Kv s)/s`` acting on velocities (module doc).
    """

    def __init__(self, name: str, layout: Sequence[tuple[str, Sequence[int]]], Kp: np.ndarray, Kv: np.ndarray,
                 where: str = "controller") -> None:
        self.name = name
        self.layout = [(dev, np.asarray(idx, dtype=int)) for dev, idx in layout]
        self.n = int(sum(idx.size for _, idx in self.layout))
        covered = np.sort(np.concatenate([idx for _, idx in self.layout])) if self.layout else np.zeros(0)
        if not np.array_equal(covered, np.arange(self.n)):
            raise SceneError(f"{where}: device DOF maps must cover stack indices 0..{self.n - 1} exactly once "
                             f"(got {[idx.tolist() for _, idx in self.layout]})")
        self.Kp = gain_matrix(Kp, self.n, f"{where}: Kp (stacked)")
        self.Kv = gain_matrix(Kv, self.n, f"{where}: Kv (stacked)")
        self.where = where

    def reset(self) -> None:
        """Stateless: nothing to reset."""

    def stack(self, meas: Measurements) -> tuple[np.ndarray, np.ndarray]:
        """Stacked positions and velocities from the devices' :class:`JointSample`s."""
        q = np.zeros(self.n)
        v = np.zeros(self.n)
        for dev, idx in self.layout:
            s = _joint(meas, dev, self.where)
            pos = np.asarray(s.position, dtype=float).reshape(-1)
            vel = np.asarray(s.velocity, dtype=float).reshape(-1)
            if pos.size != idx.size or vel.size != idx.size:
                raise SceneError(f"{self.where}: device {dev!r} reports {pos.size} DOF, the controller "
                                 f"expects {idx.size}")
            q[idx] = pos
            v[idx] = vel
        return q, v

    def update(self, t: float, dt: float, meas: Measurements) -> dict[str, np.ndarray]:
        q, v = self.stack(meas)
        u = -(self.Kp @ q + self.Kv @ v)
        return {dev: u[idx].copy() for dev, idx in self.layout}


# ---------------------------------------------------------------------------------------------
# schemas: one pydantic model per controller type, validated once (by hil.scene.spec or make_controller)


class ControllerConfig(StrictModel):
    """A scene's ``controller`` block; ``type`` selects the schema (:data:`CONTROLLER_TYPES`).

    Subclasses may add two scene-level steps, both called by :mod:`hil.scene.spec` after validation:
    :meth:`normalized` (the final values: gains expanded to the devices' sizes) and
    :meth:`check_scene` (pure: cross-references and shapes; raises :class:`hil.schema.FieldError`)."""

    type: str

    def normalized(self, scene: SceneView) -> ControllerConfig:
        """This configuration with its final values for ``scene`` (a copy; unknown devices are left
        for :meth:`check_scene` to report)."""
        return self

    def check_scene(self, scene: SceneView) -> None:
        """Refuse broken references to ``scene``'s devices (pure: changes nothing)."""


def _dof_of(scene: SceneView, name: str) -> int | None:
    try:
        return scene.device(name).dof
    except KeyError:
        return None


class NoController(ControllerConfig):
    """No controller: the experiment's excitation is the only effort."""

    type: Literal["none"]


class PdPositionPosition(ControllerConfig):
    """Bilateral position-position PD (paper 000 eq. 42-43): master effort
    ``-Kp_m (q_m - q_s) - Kv_m (v_m - v_s)``, slave effort ``-Kp_s (q_s - q_m) - Kv_s (v_s - v_m)``.
    Gains are dof x dof (N/m, N.s/m or N.m/rad, N.m.s/rad); a number means ``k * I``, a flat list
    a diagonal. ``dof`` (optional) must equal the devices' DOF count."""

    type: Literal["pd_position_position"]
    master: Name
    slave: Name
    Kp_m: StiffMat
    Kv_m: DampMat
    Kp_s: StiffMat
    Kv_s: DampMat
    dof: int | None = Field(default=None, ge=1, le=6)

    def normalized(self, scene: SceneView) -> PdPositionPosition:
        n = _dof_of(scene, self.master)
        if n is None:
            return self
        return self.model_copy(update={k: _full(getattr(self, k), n) for k in ("Kp_m", "Kv_m", "Kp_s", "Kv_s")})

    def check_scene(self, scene: SceneView) -> None:
        m = scene.require("controller.master", self.master, "actuator")
        s = scene.require("controller.slave", self.slave, "actuator")
        if m.dof != s.dof:
            raise FieldError("controller.slave", f"master {m.name!r} has {m.dof} DOF, slave {s.name!r} has {s.dof}")
        if self.dof is not None and self.dof != m.dof:
            raise FieldError("controller.dof", f"is {self.dof}, the devices have {m.dof} DOF")
        for key in ("Kp_m", "Kv_m", "Kp_s", "Kv_s"):
            _square_gain(f"controller.{key}", getattr(self, key), m.dof, f"dof x dof of {m.name!r}/{s.name!r}")


class McetForceSensors(StrictModel):
    """Force sensors of the MCET force channels (device names): ``master1`` and ``master2`` read
    the users' forces on the masters, ``slave`` the force between slave and environment."""

    master1: Name | None = None
    master2: Name | None = None
    slave: Name | None = None


class McetForceAxes(StrictModel):
    """Wrench components (indices into Fx..Tz) each MCET force sensor contributes, per DOF."""

    master1: WrenchAxes | None = None
    master2: WrenchAxes | None = None
    slave: WrenchAxes | None = None


class Mcet(ControllerConfig):
    """Dual-user MCET four-channel controller (paper 000 eq. 21-25): ``masters: [m1, m2]``,
    ``slave``, ``alpha`` in [0, 1] (user 1's authority), local PD gains ``k_pm1, k_vm1, k_pm2,
    k_vm2, k_ps, k_vs``; optional coordinating channels ``k_p4m1, k_v4m1, k_p4m2, k_v4m2``
    (default -k_pm1, ...: position-position) and ``k_p1, k_v1`` (default k_ps, k_vs); force gains
    ``c2m1, c2m2, c3, c5, c6m1, c6m2`` (default 0: position-position, eq. 25) with
    ``force_sensors: {master1, master2, slave}`` (required for the channels those gains use),
    ``force_axes`` (same keys: the wrench components of each sensor), ``slave_force_sign``
    (default -1: the slave sensor reports the force the slave exerts on the environment), ``dof``
    (optional; the three devices' common DOF count). Gains are numbers (``k I``) or dof x dof."""

    type: Literal["mcet"]
    masters: Annotated[list[Name], Field(min_length=2, max_length=2)]
    slave: Name
    alpha: Fraction
    k_pm1: StiffMat
    k_vm1: DampMat
    k_pm2: StiffMat
    k_vm2: DampMat
    k_ps: StiffMat
    k_vs: DampMat
    k_p4m1: StiffMat | None = None
    k_v4m1: DampMat | None = None
    k_p4m2: StiffMat | None = None
    k_v4m2: DampMat | None = None
    k_p1: StiffMat | None = None
    k_v1: DampMat | None = None
    c2m1: Annotated[float, BeforeValidator(number)] = 0.0
    c2m2: Annotated[float, BeforeValidator(number)] = 0.0
    c3: Annotated[float, BeforeValidator(number)] = 0.0
    c5: Annotated[float, BeforeValidator(number)] = 0.0
    c6m1: Annotated[float, BeforeValidator(number)] = 0.0
    c6m2: Annotated[float, BeforeValidator(number)] = 0.0
    force_sensors: McetForceSensors = Field(default_factory=McetForceSensors)
    force_axes: McetForceAxes = Field(default_factory=McetForceAxes)
    slave_force_sign: Literal[1, -1] = -1
    dof: int | None = Field(default=None, ge=1, le=6)

    GAINS: ClassVar[tuple[str, ...]] = ("k_pm1", "k_vm1", "k_pm2", "k_vm2", "k_ps", "k_vs")
    CHANNELS: ClassVar[tuple[str, ...]] = ("k_p4m1", "k_v4m1", "k_p4m2", "k_v4m2", "k_p1", "k_v1")

    def check_scene(self, scene: SceneView) -> None:
        devs = [scene.require(f"controller.masters[{k}]", m, "actuator") for k, m in enumerate(self.masters)]
        devs.append(scene.require("controller.slave", self.slave, "actuator"))
        d = self.dof if self.dof is not None else devs[0].dof
        for path, dev in zip(("controller.masters[0]", "controller.masters[1]", "controller.slave"), devs,
                             strict=True):
            if dev.dof != d:
                raise FieldError(path, f"mcet needs robots of equal DOF ({d}); {dev.name!r} has {dev.dof} DOF")
        for key in (*self.GAINS, *self.CHANNELS):
            g = getattr(self, key)
            if g is not None:
                _square_gain(f"controller.{key}", g, d, "dof x dof of the robots")
        for role in ("master1", "master2", "slave"):
            sensor = getattr(self.force_sensors, role)
            if sensor is not None:
                sdev = scene.require(f"controller.force_sensors.{role}", sensor, "force_sensor")
                axes = getattr(self.force_axes, role)
                if axes is not None and len(axes) != d:
                    raise FieldError(f"controller.force_axes.{role}", f"lists {len(axes)} wrench components for "
                                                                      f"{d} DOF")
                if axes is None and sdev.dof < d:
                    raise FieldError(f"controller.force_sensors.{role}", f"sensor {sensor!r} measures {sdev.dof} "
                                                                         f"DOF, the robots have {d}")


class PdGain(StrictModel):
    """A PD gain matrix pair, i.e. the PI velocity controller ``(kp + kv s)/s`` of the papers."""

    kp: StiffMat
    kv: DampMat


class MasterMap(StrictModel):
    """A master device and the slave DOFs it commands (paper 001: master 1 -> x, master 2 -> y, z)."""

    device: Name
    slave_dofs: DofList


class DualMaster(ControllerConfig):
    """Dual-master / single-slave cooperative teleoperation (paper 001 eq. 15-17). ``masters:
    [{device: m1, slave_dofs: [0]}, {device: m2, slave_dofs: [1, 2]}]``: the slave DOFs each
    master's DOFs map to (together, each of the slave's DOFs exactly once). ``C_m`` (master local),
    ``C_4`` (slave -> masters), ``C_s`` (slave local), ``C_1`` (masters -> slave) are ``{kp, kv}``
    pairs of n x n matrices, n the slave DOF count (a number: ``k I``): master effort
    ``C_4 x_s - C_m x_m``, slave effort ``C_1 x_m - C_s x_s`` (x in the slave DOF order)."""

    type: Literal["dual_master"]
    masters: Annotated[list[MasterMap], Field(min_length=1)]
    slave: Name
    C_m: PdGain
    C_4: PdGain
    C_s: PdGain
    C_1: PdGain

    @property
    def n(self) -> int:
        """The slave's DOF count as the masters' maps give it."""
        return sum(len(m.slave_dofs) for m in self.masters)

    def normalized(self, scene: SceneView) -> DualMaster:
        n = _dof_of(scene, self.slave)
        if n is None:
            return self
        gains = {key: getattr(self, key) for key in ("C_m", "C_4", "C_s", "C_1")}
        return self.model_copy(update={key: PdGain(kp=_full(g.kp, n), kv=_full(g.kv, n)) for key, g in gains.items()})

    def check_scene(self, scene: SceneView) -> None:
        s = scene.require("controller.slave", self.slave, "actuator")
        covered: list[int] = []
        for k, mm in enumerate(self.masters):
            d = scene.require(f"controller.masters[{k}].device", mm.device, "actuator")
            if len(mm.slave_dofs) != d.dof:
                raise FieldError(f"controller.masters[{k}].slave_dofs",
                                 f"master {d.name!r} has {d.dof} DOF but maps {len(mm.slave_dofs)} slave DOF")
            bad = [j for j in mm.slave_dofs if j >= s.dof]
            if bad:
                raise FieldError(f"controller.masters[{k}].slave_dofs",
                                 f"slave {s.name!r} has {s.dof} DOF; index {bad[0]} is out of range")
            covered += mm.slave_dofs
        if sorted(covered) != list(range(s.dof)):
            raise FieldError("controller.masters", f"the masters' slave_dofs must cover each of the slave's {s.dof} "
                                                   f"DOF exactly once, got {covered}")
        for key in ("C_m", "C_4", "C_s", "C_1"):
            g = getattr(self, key)
            _square_gain(f"controller.{key}.kp", g.kp, s.dof, "n x n, n = slave DOF")
            _square_gain(f"controller.{key}.kv", g.kv, s.dof, "n x n, n = slave DOF")


_ENV_FIELDS = {"none": (), "spring": ("k", "b"), "spring_damper": ("k", "b"), "mass_spring_damper": ("m", "k", "b")}


class VsicEnvironment(StrictModel):
    """Virtual environment rendered by the VSIC behind the coupler, by ``type`` (default
    ``spring``; no ``environment`` at all: ``none``): ``none`` (no environment:
    ``F_ref = 0``), ``spring`` / ``spring_damper`` (spring ``k`` N.m/rad to its rest at 0,
    damper ``b`` N.m.s/rad), ``mass_spring_damper`` (plus the mass ``m`` kg.m^2)."""

    type: Literal["none", "spring", "spring_damper", "mass_spring_damper"] = "spring"
    k: StiffNonneg = 0.0
    b: DampNonneg = 0.0
    m: Annotated[float, BeforeValidator(lambda v: number(v, "kg or kg.m^2")), Field(ge=0)] = 0.0

    @model_validator(mode="after")
    def _fields_of_type(self) -> VsicEnvironment:
        # a parameter of another type is refused unless it is 0 (a dump lists every field)
        extra = sorted(k for k in set(self.model_fields_set) - {"type", *_ENV_FIELDS[self.type]} if getattr(self, k))
        if extra:
            raise PydanticCustomError("environment", "{key} does not apply to a {t} environment (it takes: {ok})",
                                      {"key": extra[0], "t": self.type,
                                       "ok": ", ".join(_ENV_FIELDS[self.type]) or "nothing"})
        return self

    def parameters(self) -> dict[str, float]:
        """The parameters given for this type (``k``, ``b``, ``m``)."""
        return {k: float(getattr(self, k)) for k in ("k", "b", "m") if k in self.model_fields_set}


class Vsic(ControllerConfig):
    """Velocity-sourced impedance control of an SDEA (paper 002; :class:`VSIC`): inner motor
    velocity PI (``P_m``, ``I_m``), force PI (``P_f``, ``I_f``) on the spring-force error,
    feed-forward ``1 - alpha`` and a virtual coupler (``k22``, ``b22``) to the ``environment``.
    ``force_sensor``: the spring-force sensor (absent: the actuator's effort channel);
    ``force_axis``: its wrench component (default: the sensor's ``axes[0]``, else 0);
    ``force_sign``: +1 or -1 applied to that reading; ``output``: an end-effector encoder device
    (absent: a locked output, ``x_o = v_o = 0``)."""

    type: Literal["vsic"]
    actuator: Name
    force_sensor: Name | None = None
    force_axis: Annotated[int, Field(ge=0, le=5)] | None = None
    force_sign: Literal[1, -1] = 1
    output: Name | None = None
    P_m: Annotated[float, BeforeValidator(lambda v: number(v, "N.m.s/rad")), Field(gt=0)]
    I_m: Annotated[float, BeforeValidator(lambda v: number(v, "N.m/rad")), Field(ge=0)]
    P_f: Annotated[float, BeforeValidator(lambda v: number(v, "rad/(N.m.s)")), Field(gt=0)]
    I_f: Annotated[float, BeforeValidator(lambda v: number(v, "rad/(N.m.s^2)")), Field(ge=0)]
    alpha: Fraction = 1.0
    k22: Annotated[float, BeforeValidator(lambda v: number(v, "N.m/rad")), Field(ge=0)]
    b22: Annotated[float, BeforeValidator(lambda v: number(v, "N.m.s/rad")), Field(ge=0)]
    environment: VsicEnvironment = Field(default_factory=lambda: VsicEnvironment(type="none"))

    @model_validator(mode="after")
    def _coupler(self) -> Vsic:
        if self.k22 == 0 and self.b22 == 0:
            raise PydanticCustomError("coupler", "the virtual coupler needs k22 > 0 or b22 > 0", {"key": "k22"})
        return self

    def check_scene(self, scene: SceneView) -> None:
        a = scene.require("controller.actuator", self.actuator, "actuator")
        if a.dof != 1:
            raise FieldError("controller.actuator", "vsic controls a 1-DOF SDEA (actuator and sensor with dof 1)")
        if self.force_sensor is not None:
            f = scene.require("controller.force_sensor", self.force_sensor, "force_sensor")
            if f.dof != 1:
                raise FieldError("controller.actuator", "vsic controls a 1-DOF SDEA (actuator and sensor with dof 1)")
        if self.output is not None:
            scene.require("controller.output", self.output, "actuator")


# ---------------------------------------------------------------------------------------------
# builders: validated configuration -> controller


def pd_position_position(cfg: PdPositionPosition | Mapping[str, Any], where: str = "controller") -> PositionPD:
    """Paper 000 eq. (42)-(43): ``Kp = [[Kp_m, -Kp_m], [-Kp_s, Kp_s]]`` (same for ``Kv``)."""
    c = validate(PdPositionPosition, cfg, where)
    master, slave = c.master, c.slave
    keys = ("Kp_m", "Kv_m", "Kp_s", "Kv_s")
    d = _gain_dof(c.dof, [getattr(c, k) for k in keys])
    Kp_m, Kv_m, Kp_s, Kv_s = (gain_matrix(getattr(c, k), d, _field(where, k)) for k in keys)
    Kp = np.block([[Kp_m, -Kp_m], [-Kp_s, Kp_s]])
    Kv = np.block([[Kv_m, -Kv_m], [-Kv_s, Kv_s]])
    return PositionPD("pd_position_position", [(master, range(d)), (slave, range(d, 2 * d))], Kp, Kv, where)


class FourChannelMCET:
    """Dual-user MCET four-channel law of paper 000, eq. (22)-(23), in the time domain.

    With the position controllers ``c = (k_p + k_v s)/s`` acting on velocities (PD on positions,
    written ``c[q]`` = k_p q + k_v v) and static force gains::

        f_cm1 = -c_m1[q_1] - c_4m1[q_2] + c_6m1 f_h1 - c_2m1 f_e / 2
        f_cm2 = -c_m2[q_2] - c_4m2[q_1] + c_6m2 f_h2 - c_2m2 f_e / 2
        f_cs  = -c_s[q_e] + c_1[α q_1 + (1-α) q_2] - c_5 f_e + c_3 (α f_h1 + (1-α) f_h2)

    (v_h1d = v_h2, v_h2d = v_h1, v_ed = α v_h1 + (1-α) v_h2, f_hid = f_e/2, f_ed = α f_h1 + (1-α) f_h2).
    ``f_hi``: force of user i on master i (positive along its velocity); ``f_e``: force of the
    environment on the slave. The position part is a :class:`PositionPD` on the stacked
    coordinates; the force part needs force sensors (``force_sensors``) when any force gain is
    non-zero. Position-position control is the special case c_4mi = -c_mi, c_1 = c_s, force gains 0
    (eq. 25).
    """

    def __init__(self, pd: PositionPD, force_gain: np.ndarray, sensors: Sequence[str | None],
                 signs: Sequence[float], axes: Sequence[Sequence[int] | None], d: int) -> None:
        self.name = "mcet"
        self.pd = pd
        self.G = force_gain  # (3d, 3d): u_force = G @ [f_h1; f_h2; f_e]
        self.sensors, self.signs, self.axes, self.d = list(sensors), list(signs), list(axes), d
        self.uses_force = bool(np.any(self.G))

    def reset(self) -> None:
        self.pd.reset()

    def update(self, t: float, dt: float, meas: Measurements) -> dict[str, np.ndarray]:
        out = self.pd.update(t, dt, meas)
        if not self.uses_force:
            return out
        f = np.zeros(3 * self.d)
        for k, (sensor, sign, axes) in enumerate(zip(self.sensors, self.signs, self.axes, strict=True)):
            if sensor is None:
                continue
            sample = meas[sensor]
            if not isinstance(sample, WrenchSample):
                raise SceneError(f"MCET: no wrench from force sensor {sensor!r}")
            w = np.asarray(sample.wrench, dtype=float).reshape(-1)
            w = w[list(axes)] if axes is not None else w[: self.d]
            f[k * self.d:(k + 1) * self.d] = sign * w
        uf = self.G @ f
        for dev, idx in self.pd.layout:
            out[dev] = out[dev] + uf[idx]
        return out


def mcet_controller(cfg: Mcet | Mapping[str, Any], where: str = "controller") -> FourChannelMCET:
    """Paper 000 eq. (21)-(25): the dual-user MCET four-channel controller (:class:`FourChannelMCET`)
    from a :class:`Mcet` configuration (fields there)."""
    c = validate(Mcet, cfg, where)
    m1, m2 = c.masters
    slave = c.slave
    a = c.alpha
    d = _gain_dof(c.dof, [getattr(c, k) for k in Mcet.GAINS])
    kp1, kv1, kp2, kv2, kps, kvs = (gain_matrix(getattr(c, k), d, _field(where, k)) for k in Mcet.GAINS)

    def opt_gain(key: str, default: np.ndarray) -> np.ndarray:
        v = getattr(c, key)
        return default if v is None else gain_matrix(v, d, _field(where, key))

    kp4m1, kv4m1 = opt_gain("k_p4m1", -kp1), opt_gain("k_v4m1", -kv1)
    kp4m2, kv4m2 = opt_gain("k_p4m2", -kp2), opt_gain("k_v4m2", -kv2)
    kpc1, kvc1 = opt_gain("k_p1", kps), opt_gain("k_v1", kvs)
    Z = np.zeros((d, d))

    def block(cm1: np.ndarray, c4m1: np.ndarray, cm2: np.ndarray, c4m2: np.ndarray, c1: np.ndarray,
              cs: np.ndarray) -> np.ndarray:
        # u = -(K q): row i of K holds the channels acting on master i / the slave
        return np.block([[cm1, c4m1, Z], [c4m2, cm2, Z], [-a * c1, -(1 - a) * c1, cs]])

    layout = [(m1, range(d)), (m2, range(d, 2 * d)), (slave, range(2 * d, 3 * d))]
    pd = PositionPD("mcet", layout, block(kp1, kp4m1, kp2, kp4m2, kpc1, kps),
                    block(kv1, kv4m1, kv2, kv4m2, kvc1, kvs), where)
    g = {k: float(getattr(c, k)) for k in ("c2m1", "c2m2", "c3", "c5", "c6m1", "c6m2")}
    I_ = np.eye(d)
    G = np.block([[g["c6m1"] * I_, Z, -0.5 * g["c2m1"] * I_],
                  [Z, g["c6m2"] * I_, -0.5 * g["c2m2"] * I_],
                  [a * g["c3"] * I_, (1 - a) * g["c3"] * I_, -g["c5"] * I_]])
    fs, fa = c.force_sensors, c.force_axes
    sensors = [fs.master1, fs.master2, fs.slave]
    needs = [bool(g["c6m1"] or g["c3"]), bool(g["c6m2"] or g["c3"]), bool(g["c2m1"] or g["c2m2"] or g["c5"])]
    for name, s_, need in zip(("master1", "master2", "slave"), sensors, needs, strict=True):
        if need and not s_:
            raise SceneError(f"{_field(where, 'force_sensors')}: the force gains need a {name!r} force sensor")
    signs = [1.0, 1.0, float(c.slave_force_sign)]
    axes: list[Sequence[int] | None] = [fa.master1, fa.master2, fa.slave]
    return FourChannelMCET(pd, G, sensors, signs, axes, d)


def dual_master_controller(cfg: DualMaster | Mapping[str, Any], where: str = "controller") -> PositionPD:
    """Paper 001 eq. (15) with matrix PD gains (module doc) from a :class:`DualMaster` configuration:
    the stack is the masters' DOFs at their slave DOF indices, then the slave's."""
    c = validate(DualMaster, cfg, where)
    n = c.n
    names = [m.device for m in c.masters]
    maps = [list(m.slave_dofs) for m in c.masters]
    slave = c.slave

    def pair(tag: str) -> tuple[np.ndarray, np.ndarray]:
        g = getattr(c, f"C_{tag}")
        f = _field(where, f"C_{tag}")
        return gain_matrix(g.kp, n, f"{f}.kp"), gain_matrix(g.kv, n, f"{f}.kv")

    Kp_m, Kv_m = pair("m")
    Kp_4, Kv_4 = pair("4")
    Kp_s, Kv_s = pair("s")
    Kp_1, Kv_1 = pair("1")
    Kp = np.block([[Kp_m, -Kp_4], [-Kp_1, Kp_s]])
    Kv = np.block([[Kv_m, -Kv_4], [-Kv_1, Kv_s]])
    layout: list[tuple[str, Sequence[int]]] = [(nm, mp) for nm, mp in zip(names, maps, strict=True)]
    layout.append((slave, range(n, 2 * n)))
    return PositionPD("dual_master", layout, Kp, Kv, where)


# ---------------------------------------------------------------------------------------------
# SDEA: velocity-sourced impedance control with a virtual coupler


class _Trapezoid:
    """Linear ODE ``x' = A x + B u``, ``y = C x + D u`` integrated with the trapezoidal rule
    (Tustin: A-stable, maps a passive continuous impedance to a passive discrete one)."""

    def __init__(self, A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray) -> None:
        self.A, self.B, self.C, self.D = (np.atleast_2d(np.asarray(m, dtype=float)) for m in (A, B, C, D))
        self.n = self.A.shape[0] if self.A.size else 0
        self.x = np.zeros(self.n)
        self.u_prev: np.ndarray | None = None
        self._dt = -1.0

    def reset(self) -> None:
        self.x = np.zeros(self.n)
        self.u_prev = None

    def step(self, u: np.ndarray, dt: float) -> np.ndarray:
        if self.n == 0:
            return self.D @ u
        if self.u_prev is None:
            # start at the equilibrium for the first input (no kick from the initial offset)
            try:
                self.x = -np.linalg.solve(self.A, self.B @ u)
            except np.linalg.LinAlgError:
                self.x = np.zeros(self.n)
            self.u_prev = u.copy()
        if dt != self._dt:
            eye = np.eye(self.n)
            self._lhs = np.linalg.inv(eye - 0.5 * dt * self.A)
            self._rhs = eye + 0.5 * dt * self.A
            self._dt = dt
        self.x = self._lhs @ (self._rhs @ self.x + 0.5 * dt * (self.B @ (u + self.u_prev)))
        self.u_prev = u.copy()
        return self.C @ self.x + self.D @ u


class _TrapezoidPI:
    """``y = P e + I ∫ e dt`` with the integral by the trapezoidal rule (Tustin ``T/2 (z+1)/(z-1)``)."""

    def __init__(self, P: float, I: float) -> None:
        self.P, self.I = float(P), float(I)
        self.reset()

    def reset(self) -> None:
        self.z = 0.0
        self.e_prev: float | None = None

    def step(self, e: float, dt: float) -> float:
        prev = e if self.e_prev is None else self.e_prev
        # first sample: (e + e)/2 * dt would integrate an error from before the start; use 0
        self.z += 0.0 if self.e_prev is None else 0.5 * dt * (e + prev)
        self.e_prev = e
        return self.P * e + self.I * self.z


def virtual_environment(k22: float, b22: float, k: float = 0.0, b: float = 0.0,
                        m: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """State space of virtual coupler (``k22``, ``b22``) + virtual environment (mass ``m``, damper
    ``b``, spring ``k`` to its rest at 0) driven by the output position/velocity ``u = [x_o, v_o]``;
    output the coupler force on the output ``F_ref = k22 (x_ve - x_o) + b22 (v_ve - v_o)``.

    ``m > 0``: states ``[x_ve, v_ve]``, ``m a_ve = -F_ref - k x_ve - b v_ve``. ``m = 0`` and
    ``b + b22 > 0``: state ``x_ve``, ``(b + b22) v_ve = k22 x_o + b22 v_o - (k + k22) x_ve``.
    Otherwise static: ``F_ref = -k k22/(k + k22) x_o`` (zero when both are zero).
    """
    if m > 0:
        A = np.array([[0.0, 1.0], [-(k + k22) / m, -(b + b22) / m]])
        B = np.array([[0.0, 0.0], [k22 / m, b22 / m]])
        C = np.array([[k22, b22]])
        D = np.array([[-k22, -b22]])
        return A, B, C, D
    bt = b + b22
    if bt > 0:
        # v_ve = (k22 x_o + b22 v_o - (k + k22) x_ve)/bt
        A = np.array([[-(k + k22) / bt]])
        B = np.array([[k22 / bt, b22 / bt]])
        C = np.array([[k22 + b22 * A[0, 0]]])
        D = np.array([[-k22 + b22 * B[0, 0], -b22 + b22 * B[0, 1]]])
        return A, B, C, D
    kt = k + k22
    keq = k * k22 / kt if kt > 0 else 0.0
    return np.zeros((0, 0)), np.zeros((0, 2)), np.zeros((1, 0)), np.array([[-keq, 0.0]])


class VSIC:
    """Velocity-sourced impedance control of a series damped elastic actuator (paper 002).

    Block diagram implemented (one DOF; rotary units N.m, rad, rad/s by default)::

        x_o, v_o (output) ─► [virtual coupler k22, b22 + virtual environment] ─► F_ref (+ F_d(t))
        F_ref - F ─► C_f = P_f + I_f/s ─► v_ref
        v_ref - v_m ─► C_m = P_m + I_m/s ─► τ_fb
        τ = τ_fb + (1 - α) F                          (feed-forward of the interaction force)

    with ``F`` the measured series-spring force ``F = K_f (x_m - x_o) + B_f (v_m - v_o)`` (force
    sensor, or the actuator's effort channel), ``v_m`` the motor velocity. The motor obeys
    ``M s v_m = τ - B v_m - F``, so ``(M s + B + C_m) v_m = C_m C_f F_ref - (C_m C_f + α) F``: the
    feed-forward turns the "+1" (spring reaction) of ``(C_m C_f + 1)`` into ``α``. Eliminating
    ``v_m`` with ``F = (K_f + B_f s)/s (v_m - v_o)`` and multiplying by ``s³`` gives eq. (12a)::

        F = h11 (-v_o) + h12 F_ref,   a(s) = s²(Ms² + (B+P_m)s + I_m) + (K_f + B_f s)((P_m s + I_m)(P_f s + I_f) + α s²)
        h11 = s (K_f + B_f s)(M s² + (B + P_m) s + I_m)/a(s),   h12 = (K_f + B_f s)(P_m s + I_m)(P_f s + I_f)/a(s)

    and the virtual coupler ``F_ref = (k22/s + b22)(v_ve - v_o)`` is eq. (12b) (``v_ve = v_o + h22
    F_ref``, ``h22 = s/(b22 s + k22)``) with the virtual environment terminating port 2
    (``F_ref = -Z_env v_ve``). A disturbance torque ``d`` added to ``τ`` (e.g. an effort
    excitation) reaches the locked-output force as ``F/d = s² (K_f + B_f s)/a(s)``.

    Discretization at the control period T: both PI integrals and the coupler/environment ODE use
    the trapezoidal rule (Tustin; A-stable, passivity-preserving for the virtual environment);
    ``τ`` is computed from the samples at ``t_k`` and held over ``[t_k, t_k + T)``.
    """

    name = "vsic"

    def __init__(self, actuator: str, *, P_m: float, I_m: float, P_f: float, I_f: float, alpha: float = 1.0,
                 k22: float, b22: float, environment: VsicEnvironment | Mapping[str, Any] | None = None,
                 force_sensor: str | None = None, force_axis: int = 0, force_sign: float = 1.0,
                 output: str | None = None, force_reference: Callable[[float], float] | None = None,
                 where: str = "controller") -> None:
        self.actuator = actuator
        self.force_sensor = force_sensor
        self.force_axis = int(force_axis)
        self.force_sign = float(force_sign)
        self.output = output
        self.alpha = float(alpha)
        self.where = where
        for key, val in {"P_m": P_m, "I_m": I_m, "P_f": P_f, "I_f": I_f, "k22": k22, "b22": b22}.items():
            if not math.isfinite(float(val)) or float(val) < 0:
                raise SceneError(f"{_field(where, key)}: must be finite and non-negative, got {val!r}")
        if not 0.0 <= self.alpha <= 1.0:
            raise SceneError(f"{_field(where, 'alpha')}: must lie in [0, 1], got {alpha}")
        if k22 == 0 and b22 == 0:
            raise SceneError(f"{_field(where, 'k22')}: the virtual coupler needs k22 > 0 or b22 > 0")
        env = validate(VsicEnvironment, environment if environment is not None else {"type": "none"},
                       _field(where, "environment"))
        ev = env.parameters()
        self.environment: dict[str, Any] = {"type": env.type, **ev}
        self.k22, self.b22 = float(k22), float(b22)
        self._env_free = env.type == "none"
        self._env = _Trapezoid(*virtual_environment(self.k22, self.b22, ev.get("k", 0.0), ev.get("b", 0.0),
                                                    ev.get("m", 0.0)))
        self._pf = _TrapezoidPI(P_f, I_f)
        self._pm = _TrapezoidPI(P_m, I_m)
        self.params = {"P_m": float(P_m), "I_m": float(I_m), "P_f": float(P_f), "I_f": float(I_f),
                       "alpha": self.alpha, "k22": self.k22, "b22": self.b22}
        self.force_reference = force_reference
        self.last: dict[str, float] = {}

    def reset(self) -> None:
        """Integrators and the virtual environment back to rest."""
        self._env.reset()
        self._pf.reset()
        self._pm.reset()
        self.last = {}

    def spring_force(self, meas: Measurements) -> float:
        """Measured series-spring force F (N or N.m): ``force_sign * wrench[force_axis]`` of the
        force sensor, or the actuator's effort channel when no sensor is configured."""
        if self.force_sensor is not None:
            s = meas.get(self.force_sensor)
            if not isinstance(s, WrenchSample):
                raise SceneError(f"{_field(self.where, 'force_sensor')}: no wrench from {self.force_sensor!r}")
            w = np.asarray(s.wrench, dtype=float).reshape(-1)
            if w.size <= self.force_axis and w.size != 1:
                raise SceneError(f"{_field(self.where, 'force_axis')}: {self.force_axis} out of range for the "
                                 f"{w.size}-component wrench of {self.force_sensor!r}")
            return self.force_sign * float(w[self.force_axis if w.size > self.force_axis else 0])
        j = _joint(meas, self.actuator, _field(self.where, "actuator"))
        if j.effort is None:
            raise SceneError(f"{_field(self.where, 'force_sensor')}: required: actuator {self.actuator!r} "
                             "reports no effort channel")
        return self.force_sign * float(np.asarray(j.effort, dtype=float).reshape(-1)[0])

    def update(self, t: float, dt: float, meas: Measurements) -> dict[str, np.ndarray]:
        jm = _joint(meas, self.actuator, _field(self.where, "actuator"))
        v_m = float(np.asarray(jm.velocity, dtype=float).reshape(-1)[0])
        F = self.spring_force(meas)
        if self.output is not None:
            jo = _joint(meas, self.output, _field(self.where, "output"))
            x_o = float(np.asarray(jo.position, dtype=float).reshape(-1)[0])
            v_o = float(np.asarray(jo.velocity, dtype=float).reshape(-1)[0])
        else:
            x_o = v_o = 0.0  # locked output (or no output encoder): v_h = 0
        F_ref = 0.0 if self._env_free else float(self._env.step(np.array([x_o, v_o]), dt)[0])
        if self.force_reference is not None:
            F_ref += float(self.force_reference(t))
        v_ref = self._pf.step(F_ref - F, dt)
        tau = self._pm.step(v_ref - v_m, dt) + (1.0 - self.alpha) * F
        self.last = {"F": F, "F_ref": F_ref, "v_ref": v_ref, "tau": tau}
        return {self.actuator: np.array([tau])}


def vsic_controller(cfg: Vsic | Mapping[str, Any], where: str = "controller", scene: Any = None) -> VSIC:
    """:class:`VSIC` from a :class:`Vsic` configuration. Without ``force_axis`` the force sensor's
    wrench component is the first of its ``axes`` in ``scene`` (a :class:`hil.scene.spec.Scene`), else 0."""
    c = validate(Vsic, cfg, where)
    axis = c.force_axis
    if axis is None and c.force_sensor is not None and scene is not None:
        try:
            axes = scene.device(c.force_sensor).axes
        except (KeyError, AttributeError):
            axes = None
        axis = int(axes[0]) if axes else None
    return VSIC(c.actuator, P_m=c.P_m, I_m=c.I_m, P_f=c.P_f, I_f=c.I_f, alpha=c.alpha, k22=c.k22, b22=c.b22,
                environment=c.environment, force_sensor=c.force_sensor, force_axis=0 if axis is None else axis,
                force_sign=float(c.force_sign), output=c.output, where=where)


# ---------------------------------------------------------------------------------------------
# registry and factory


@dataclass(frozen=True)
class ControllerType:
    """One controller type: its scene ``type`` name, its schema and its builder
    ``build(validated_config, where, scene)``."""

    name: str
    schema: type[ControllerConfig]
    build: Callable[[Any, str, Any], Controller]


#: controller type name -> (schema, builder); :mod:`hil.scene.spec` builds its ``controller`` union
#: from it (register before importing :mod:`hil.scene.spec`)
CONTROLLER_TYPES: dict[str, ControllerType] = {}


def register_controller(name: str, schema: type[ControllerConfig],
                        build: Callable[[Any, str, Any], Controller]) -> None:
    """Add a controller type: ``schema`` is a :class:`ControllerConfig` whose ``type`` field is
    ``Literal[name]``; ``build(cfg, where, scene)`` makes the :class:`Controller` from a validated
    ``cfg`` (``where``: the field path for messages, ``scene``: the scene or None)."""
    register_tagged(CONTROLLER_TYPES, name, schema, ControllerType(name, schema, build), "controller type")


def controller_schemas() -> tuple[type[ControllerConfig], ...]:
    """The schemas of every registered controller type (registration order), after those of the
    ``hil_certify.controllers`` entry points (:mod:`hil.plugins`, read once)."""
    load_group("controllers", ControllerType, lambda t: register_controller(t.name, t.schema, t.build))
    return tuple(t.schema for t in CONTROLLER_TYPES.values())


register_controller("none", NoController, lambda c, where, scene: NullController())
register_controller("pd_position_position", PdPositionPosition, lambda c, where, scene: pd_position_position(c, where))
register_controller("mcet", Mcet, lambda c, where, scene: mcet_controller(c, where))
register_controller("dual_master", DualMaster, lambda c, where, scene: dual_master_controller(c, where))
register_controller("vsic", Vsic, vsic_controller)

#: what a scene's ``units`` may be: names in messages and records (the laws are unit-agnostic)
Units: TypeAlias = Literal["linear", "rotary"]
#: the units a scene (and everything that reads one: runner, records) assumes when it names none
DEFAULT_UNITS: Units = "linear"


def make_controller(cfg: ControllerConfig | Mapping[str, Any] | None, *, units: str = DEFAULT_UNITS,
                    scene: Any = None) -> Controller:
    """Build the scene's controller from its validated configuration (``scene.controller``), or
    from a mapping, which is validated here against the schema of its ``type`` (none |
    pd_position_position | mcet | dual_master | vsic; None: no controller). ``units`` (``linear``
    | ``rotary``) is validated and logged; the laws are unit-agnostic. Raises :class:`SceneError`
    naming the offending field.

    ``scene`` (optional, a :class:`hil.scene.spec.Scene`): used to resolve the VSIC force sensor's
    wrench component (``devices[].axes``) when ``force_axis`` is not given. Without it the VSIC
    reads wrench component 0 (or the only component)."""
    if units not in ("linear", "rotary"):
        raise SceneError(f"units: must be 'linear' or 'rotary', got {units!r}")
    if cfg is None:
        return NullController()
    if isinstance(cfg, ControllerConfig):
        ctype = cfg.type
        model: ControllerConfig = cfg
    else:
        raw = {k: v for k, v in dict(cfg).items() if v is not None or k == "type"}
        ctype = str(raw.get("type", "none"))
        raw["type"] = ctype
        if ctype not in CONTROLLER_TYPES:
            raise SceneError(f"controller.type: unknown controller {ctype!r}; one of {list(CONTROLLER_TYPES)}")
        model = validate(CONTROLLER_TYPES[ctype].schema, raw, "controller")
    if ctype not in CONTROLLER_TYPES:
        raise SceneError(f"controller.type: unknown controller {ctype!r}; one of {list(CONTROLLER_TYPES)}")
    ctrl = CONTROLLER_TYPES[ctype].build(model, "controller", scene)
    logger.info("controller %s (%s units)", ctype, units)
    return ctrl
