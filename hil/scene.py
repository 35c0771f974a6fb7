"""Scene files: what a run talks to (devices), what it simulates, how it is controlled and excited.

A scene is pure data (YAML), never code. See docs/RUNNER_SPEC.md for the format; this module is
its single source of truth (pydantic models, ``extra="forbid"`` everywhere).

* :func:`load_scene` takes a YAML path or the name of a built-in scene (``hil/scenes/<name>.yaml``,
  shipped as package data) and returns a validated :class:`Scene` with ``source_text`` (the exact
  YAML text) and ``sha256`` (of that text, UTF-8) set.
* :func:`builtin_scenes` lists ``(name, description)`` of the built-in scenes.
* Every mistake raises :class:`hil.errors.SceneError` with ONE line ``file: field.path: message``
  (e.g. ``sdea.yaml: devices[0].driver: unknown driver 'odrive_cna' (did you mean 'odrive_can'?)``).
* The whole scene is checked at load time, before any device moves: YAML without duplicate keys
  (:func:`parse_yaml`, any depth, with line numbers), unknown keys (``unknown key 'drivr', did you
  mean 'driver'?``), cross-references, seeds in [0, 2**32-1], every experiment and the controller
  built as the runner builds them, and the ``certification`` section (network model and its
  parameters, criterion for that network, identify entries and both sides of their ``map``,
  uncertain parameters, design range, policy) -- see :func:`_check_certification`.
* :func:`check_seed` validates a seed given outside a file (``--seed``).

Units are SI and never written in numeric fields: ``max_effort: 5.0`` (N or N.m, per
``units``), not ``"5 Nm"``. Matrices are lists of rows; where a gain or parameter matrix is
expected, a plain number means that number times the identity, and a flat list a diagonal.

Sign conventions: those of :mod:`hil.protocols.base` (positive effort accelerates the joint in its
positive direction) and :mod:`hil.mocks.physics` (a termination exerts ``-Z(s) v`` on the device;
velocities into the ports).

Controller and experiment blocks are validated here but executed elsewhere:
``hil.controllers.make_controller(scene.controller.model_dump(), units=scene.units)`` and
``hil.experiments.make_experiment(exp.model_dump(), rate_hz=scene.rate_hz)`` consume plain dicts.

Additions to the spec (documented in each model): ``devices[].axes`` (wrench components of a
force sensor that correspond to the body DOFs), ``devices[].sim`` options, ``experiments[].controller``
(``none`` runs that experiment open loop, e.g. identification chirps), ``variant`` on static holds
and multisines, ``human`` may be a list (one per port).
"""

from __future__ import annotations

import difflib
import hashlib
import logging
import math
import re
from collections.abc import Sequence
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    PrivateAttr,
    ValidationError,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError

from hil.errors import SceneError
from hil.inputs import SEED_MAX, DuplicateKeyError, field_path, unique_key_loader
from hil.inputs import parse_yaml as _parse_yaml

__all__ = [
    "ChirpExperiment",
    "Device",
    "DuplicateKeyError",
    "EnergyInjectionExperiment",
    "MultisineExperiment",
    "Scene",
    "Simulation",
    "StaticHoldExperiment",
    "builtin_scenes",
    "check_seed",
    "load_scene",
    "parse_yaml",
    "scene_from_dict",
    "unique_key_loader",
    "unknown_key_message",
]

logger = logging.getLogger(__name__)

_BUILTIN_PACKAGE = "hil"
_BUILTIN_DIR = "scenes"

# ---------------------------------------------------------------------------------------------
# numbers and matrices
# ---------------------------------------------------------------------------------------------

_LEADING_NUMBER = re.compile(r"\s*([-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?)")


def _number(value: Any, unit: str) -> float:
    """A finite real number. Strings holding only a number are accepted (YAML 1.1 reads ``1e-3``
    as a string); strings with units are rejected with a hint."""
    what = f"a number{(' in ' + unit) if unit else ''}"
    if isinstance(value, bool) or value is None:
        raise PydanticCustomError("number", "expected {what}, got {got}", {"what": what, "got": repr(value)})
    if isinstance(value, int | float):
        x = float(value)
    elif isinstance(value, str):
        try:
            x = float(value)
        except ValueError:
            m = _LEADING_NUMBER.match(value)
            hint = f" (numbers are SI: write {float(m.group(1))!r})" if m else ""
            raise PydanticCustomError(
                "number", "expected {what}, got {got}{hint}", {"what": what, "got": repr(value), "hint": hint}
            ) from None
    else:
        raise PydanticCustomError("number", "expected {what}, got {got}",
                                  {"what": what, "got": type(value).__name__})
    if not math.isfinite(x):
        raise PydanticCustomError("number", "expected {what}, got {got}", {"what": what, "got": repr(value)})
    return x


def _num_type(unit: str = "", **constraints: Any) -> Any:
    """A float field type that rejects unit strings; ``unit`` appears in the error message;
    ``constraints`` go to :func:`pydantic.Field` (gt, ge, le, ...)."""
    if constraints:
        return Annotated[float, BeforeValidator(lambda v: _number(v, unit)), Field(**constraints)]
    return Annotated[float, BeforeValidator(lambda v: _number(v, unit))]


def _matrix(value: Any, unit: str) -> list[list[float]]:
    """A matrix as a list of rows; a number is a 1x1 matrix or (later) ``x * I``; a flat list a
    diagonal. Shapes are checked against the referenced devices by the scene."""
    if isinstance(value, int | float | str) and not isinstance(value, bool):
        return [[_number(value, unit)]]
    if isinstance(value, Sequence) and not isinstance(value, str):
        if all(not isinstance(r, Sequence) or isinstance(r, str) for r in value):
            diag = [_number(v, unit) for v in value]
            n = len(diag)
            if n == 0:
                raise PydanticCustomError("matrix", "expected a matrix (list of rows), got an empty list")
            return [[diag[i] if i == j else 0.0 for j in range(n)] for i in range(n)]
        rows = []
        for r in value:
            if not isinstance(r, Sequence) or isinstance(r, str):
                raise PydanticCustomError("matrix", "expected a matrix (list of rows of numbers), got a mix")
            rows.append([_number(v, unit) for v in r])
        if not rows or any(len(r) != len(rows[0]) for r in rows) or not rows[0]:
            raise PydanticCustomError("matrix", "expected a rectangular matrix (rows of equal length)")
        return rows
    raise PydanticCustomError("matrix", "expected a number or a matrix (list of rows), got {got}",
                              {"got": type(value).__name__})


def _matrix_or_scalar(value: Any, unit: str) -> Any:
    if isinstance(value, int | float | str) and not isinstance(value, bool):
        return _number(value, unit)
    return _matrix(value, unit)


def _mat_type(unit: str = "") -> Any:
    """A matrix field type (list of rows); a number is kept as a scalar meaning ``x * I``."""
    return Annotated[float | list[list[float]], BeforeValidator(lambda v: _matrix_or_scalar(v, unit))]


Number = _num_type()
MassMat = _mat_type("kg or kg.m^2")
DampMat = _mat_type("N.s/m or N.m.s/rad")
StiffMat = _mat_type("N/m or N.m/rad")
PGain = _num_type("N/m or N.m/rad")
VGain = _num_type("N.s/m or N.m.s/rad")
MassPos = _num_type("kg or kg.m^2", gt=0)
DampNonneg = _num_type("N.s/m or N.m.s/rad", ge=0)
StiffPos = _num_type("N/m or N.m/rad", gt=0)
StiffNonneg = _num_type("N/m or N.m/rad", ge=0)
Fraction = _num_type("[0, 1]", ge=0, le=1)
Hz = _num_type("Hz", gt=0)
Seconds = _num_type("s", gt=0)
SecondsOrZero = _num_type("s", ge=0)
Effort = _num_type("N or N.m")
Position = _num_type("m or rad")


def as_matrix(value: float | list[list[float]], n: int) -> np.ndarray:
    """A matrix field as an ``n x n`` array (scalars become ``x * I``)."""
    if isinstance(value, int | float):
        return float(value) * np.eye(n)
    return np.asarray(value, dtype=float)


def _shape(value: float | list[list[float]]) -> tuple[int, int] | None:
    if isinstance(value, int | float):
        return None
    return (len(value), len(value[0]) if value else 0)


# ---------------------------------------------------------------------------------------------
# base model: unknown keys with did-you-mean
# ---------------------------------------------------------------------------------------------


class _Strict(BaseModel):
    """``extra="forbid"`` with a did-you-mean message naming the offending key."""

    model_config = ConfigDict(extra="forbid", frozen=False, populate_by_name=True)

    @model_validator(mode="before")
    @classmethod
    def _unknown_keys(cls, data: Any) -> Any:
        if isinstance(data, dict):
            known = set(cls.model_fields) | {f.alias for f in cls.model_fields.values() if f.alias}
            for key in data:
                if key not in known:
                    raise PydanticCustomError("unknown_key", "{msg}",
                                              {"key": str(key), "msg": unknown_key_message(key, known)})
        return data


def unknown_key_message(key: Any, known: Any) -> str:
    """``unknown key 'matrx', did you mean 'matrix'?`` (or the list of known keys when none is
    close): the one message for a mistyped key, shared by every strict mapping."""
    names = sorted(str(k) for k in known)
    close = difflib.get_close_matches(str(key), names, n=1, cutoff=0.6)
    if close:
        return f"unknown key {str(key)!r}, did you mean {close[0]!r}?"
    return f"unknown key {str(key)!r}; expected one of: {', '.join(names)}"


def _seed(value: Any) -> Any:
    if isinstance(value, bool):
        raise PydanticCustomError("seed", "expected an integer seed in [0, 2**32-1], got {got}", {"got": repr(value)})
    if isinstance(value, int) and not 0 <= value <= SEED_MAX:
        raise PydanticCustomError("seed", "expected an integer seed in [0, 2**32-1], got {got}", {"got": value})
    return value


#: a random seed: an integer in [0, 2**32 - 1] (what numpy's generators and the mocks accept)
Seed = Annotated[int, BeforeValidator(_seed), Field(ge=0, le=SEED_MAX)]


def check_seed(value: Any, what: str = "--seed") -> int:
    """``value`` as a seed, or :class:`SceneError` ``what: expected an integer seed in [0, 2**32-1]``
    (for seeds given outside a scene file, e.g. ``hil run --seed``)."""
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= SEED_MAX:
        raise SceneError(f"{what}: expected an integer seed in [0, 2**32-1], got {value!r}")
    return int(value)


Name = Annotated[str, Field(pattern=r"^[A-Za-z_][A-Za-z0-9_]*$", max_length=64)]
DofList = Annotated[list[Annotated[int, Field(ge=0)]], Field(min_length=1)]

# ---------------------------------------------------------------------------------------------
# devices
# ---------------------------------------------------------------------------------------------


class DeviceSim(_Strict):
    """Options of a device's simulated counterpart (ignored on real hardware).

    ``seed``: seed of its fault injector and noise (default: derived from the bench seed and the
    device index). ``faults``: a :class:`hil.mocks.faults.FaultPlan` mapping. ``noise_std``:
    Gaussian noise on the device's measurement (force in N/N.m for sensors, position in m/rad for
    actuators), on top of ``simulation.sensor_noise``. ``measure`` (force sensors): ``body`` = the
    force the body exerts on everything attached (SDEA: the spring force), ``human`` = the force
    the operator's hand exerts on the device (F_h, positive along the port velocity), ``auto`` =
    ``human`` when a human holds that body, else ``body``. ``framing`` (FT-300): Modbus/TCP or RTU
    over TCP.
    """

    seed: Seed | None = None
    faults: dict[str, Any] | None = None
    noise_std: Annotated[float, BeforeValidator(lambda v: _number(v, "N, N.m, m or rad")), Field(ge=0)] = 0.0
    measure: Literal["auto", "body", "human"] = "auto"
    framing: Literal["tcp", "rtu"] = "tcp"

    @field_validator("faults")
    @classmethod
    def _faults(cls, v: dict[str, Any] | None) -> dict[str, Any] | None:
        if v is None:
            return v
        from hil.mocks.faults import FaultPlan  # stdlib + numpy only

        try:
            FaultPlan.from_dict(v)
        except (TypeError, ValueError) as exc:
            raise PydanticCustomError("faults", "{msg}", {"msg": str(exc)}) from None
        return v


class Device(_Strict):
    """One device the runner talks to, opened with ``open_device(driver, **params)``.

    ``body``/``dofs``: the simulated body (and its DOF indices, default all) the device acts on or
    measures; required when the scene is simulated. ``axes`` (force sensors): indices into the
    wrench ``(Fx, Fy, Fz, Tx, Ty, Tz)`` that correspond, in order, to the ``dof`` measured DOFs
    (default ``[0, 1, ..., dof-1]``).
    """

    name: Name
    role: Literal["actuator", "force_sensor"]
    driver: str
    params: dict[str, Any] = Field(default_factory=dict)
    dof: int = Field(default=1, ge=1, le=6)
    body: Name | None = None
    dofs: DofList | None = None
    axes: Annotated[list[Annotated[int, Field(ge=0, le=5)]], Field(min_length=1)] | None = None
    sim: DeviceSim = Field(default_factory=DeviceSim)

    @field_validator("driver")
    @classmethod
    def _driver(cls, v: str) -> str:
        from hil.protocols.registry import available_drivers  # registry only: imports no driver

        known = available_drivers()
        if v not in known:
            close = difflib.get_close_matches(v, known, n=1, cutoff=0.5)
            hint = f" (did you mean {close[0]!r}?)" if close else f"; known drivers: {', '.join(known)}"
            raise PydanticCustomError("driver", "unknown driver {name}{hint}", {"name": repr(v), "hint": hint})
        return v

    @model_validator(mode="after")
    def _sizes(self) -> Device:
        if self.dofs is not None and len(self.dofs) != self.dof:
            raise PydanticCustomError("dofs", "dofs lists {n} indices but dof is {dof}",
                                      {"n": len(self.dofs), "dof": self.dof, "key": "dofs"})
        if self.axes is not None:
            if self.role != "force_sensor":
                raise PydanticCustomError("axes", "axes applies to force sensors only", {"key": "axes"})
            if len(self.axes) != self.dof:
                raise PydanticCustomError("axes", "axes lists {n} wrench components but dof is {dof}",
                                          {"n": len(self.axes), "dof": self.dof, "key": "axes"})
        return self

    @property
    def wrench_axes(self) -> list[int]:
        """Wrench components measuring the device's DOFs (force sensors)."""
        return list(self.axes) if self.axes is not None else list(range(self.dof))


# ---------------------------------------------------------------------------------------------
# simulation
# ---------------------------------------------------------------------------------------------


class BodyCfg(_Strict):
    """An m-DOF body ``M a + B v + K q = f`` (kg or kg.m^2, N.s/m or N.m.s/rad, N/m or N.m/rad).
    A number means a 1-DOF body (or ``x * I`` for B/K of a larger body), a flat list a diagonal."""

    name: Name
    M: MassMat
    B: DampMat = 0.0
    K: StiffMat = 0.0

    @property
    def dof(self) -> int:
        s = _shape(self.M)
        return 1 if s is None else s[0]


class SdeaCfg(_Strict):
    """A series damped elastic actuator (paper 002): motor body ``name`` (inertia ``M``, damping
    ``B``), series spring ``K_f`` with parallel damper ``B_f`` to the output body ``<name>_out``
    (``m_out``, ``b_out``), or to ground when ``m_out`` is null (locked output). Rotary units:
    kg.m^2, N.m.s/rad, N.m/rad."""

    name: Name = "motor"
    M: MassPos
    B: DampNonneg
    K_f: StiffPos
    B_f: DampNonneg = 0.0
    m_out: MassPos | None = None
    b_out: DampNonneg = 0.0


class SpringCfg(_Strict):
    """Spring + parallel damper between body ``a`` (DOFs ``a_dofs``) and body ``b`` (``b_dofs``) or
    ground (``b`` null). Force ``K (x_a - x_b) + B (v_a - v_b)``."""

    name: Name | None = None
    a: Name
    a_dofs: DofList | None = None
    b: Name | None = None
    b_dofs: DofList | None = None
    stiffness: StiffMat = 0.0
    damping: DampMat = 0.0


class TfEntry(_Strict):
    """One transfer function ``num(s)/den(s)``, coefficients in descending powers of s."""

    num: Annotated[list[Number], Field(min_length=1)]
    den: Annotated[list[Number], Field(min_length=1)] = Field(default_factory=lambda: [1.0])

    @field_validator("den")
    @classmethod
    def _den(cls, v: list[float]) -> list[float]:
        if not any(v):
            raise PydanticCustomError("den", "denominator must not be identically zero")
        return v


class _TermBase(_Strict):
    port: Name
    dofs: DofList | None = None
    name: Name | None = None


class ImpedanceTermination(_TermBase):
    """LTI impedance ``Z(s)`` (velocity -> force on the termination), a square transfer matrix."""

    type: Literal["impedance"]
    tf: Annotated[list[Annotated[list[TfEntry], Field(min_length=1)]], Field(min_length=1)]

    @field_validator("tf")
    @classmethod
    def _square(cls, m: list[list[TfEntry]]) -> list[list[TfEntry]]:
        for i, row in enumerate(m):
            if len(row) != len(m):
                raise PydanticCustomError("tf", "row {i} has {k} entries; the transfer matrix must be square "
                                          "({n}x{n})", {"i": i, "k": len(row), "n": len(m)})
        return m


class WallTermination(_TermBase):
    """Springs/dampers to a fixed wall at port displacement 0 (``Z = K/s + B``)."""

    type: Literal["wall"]
    stiffness: StiffMat
    damping: DampMat = 0.0


class NamedTermination(_TermBase):
    """A built-in termination: ``T2`` (3x3, paper 001 sec. VI-A), ``T1`` (2x2, paper 000 eq. 1,
    not passive)."""

    type: Literal["named"]
    name: Literal["T1", "T2"]  # type: ignore[assignment]


Termination = Annotated[ImpedanceTermination | WallTermination | NamedTermination, Field(discriminator="type")]
NAMED_TERMINATION_DOF = {"T1": 2, "T2": 3}


class HumanCfg(_Strict):
    """Human arm at a body port: passive mass/damping/stiffness (numbers or matrices) plus an active
    force set by the experiment through ``Bench.set_human_force``."""

    port: Name
    dofs: DofList | None = None
    name: Name | None = None
    mass: MassMat = 0.0
    damping: DampMat = 0.0
    stiffness: StiffMat = 0.0


class SensorNoise(_Strict):
    """Gaussian noise added to every simulated measurement (seeded from the bench seed)."""

    force_std: Annotated[float, BeforeValidator(lambda v: _number(v, "N or N.m")), Field(ge=0)] = 0.0
    velocity_std: Annotated[float, BeforeValidator(lambda v: _number(v, "m/s or rad/s")), Field(ge=0)] = 0.0
    position_std: Annotated[float, BeforeValidator(lambda v: _number(v, "m or rad")), Field(ge=0)] = 0.0


class Simulation(_Strict):
    """The simulated plant (present => mocked bench). See :mod:`hil.mocks.physics`."""

    bodies: list[BodyCfg] = Field(default_factory=list)
    sdea: SdeaCfg | None = None
    springs: list[SpringCfg] = Field(default_factory=list)
    terminations: list[Termination] = Field(default_factory=list)
    human: HumanCfg | list[HumanCfg] | None = None
    sensor_noise: SensorNoise = Field(default_factory=SensorNoise)

    @property
    def humans(self) -> list[HumanCfg]:
        """The humans as a list (``human`` may be one mapping or a list)."""
        if self.human is None:
            return []
        return [self.human] if isinstance(self.human, HumanCfg) else list(self.human)

    def body_dofs(self, variant: str | None = None) -> dict[str, int]:
        """Body name -> DOF count, including the SDEA motor and (free variant) output bodies."""
        out = {b.name: b.dof for b in self.bodies}
        if self.sdea is not None:
            out[self.sdea.name] = 1
            if self.sdea.m_out is not None and variant != "locked":
                out[f"{self.sdea.name}_out"] = 1
        return out


# ---------------------------------------------------------------------------------------------
# network, controller, safety
# ---------------------------------------------------------------------------------------------


class PortCfg(_Strict):
    """A port of the network: the actuator driving it, the force sensor measuring the
    interaction force (optional), and its DOF count. The port force is ``force_sign`` times the
    sensor's port axes and must be the force applied *to* the device, positive along the port
    velocity, so that F·V is the power flowing into the device (simulated sensors with
    ``sim.measure: human``/``auto`` report exactly that)."""

    name: Name
    actuator: Name
    force_sensor: Name | None = None
    dofs: int = Field(default=1, ge=1, le=6)
    force_sign: Literal[1, -1] = 1  # -1 for a sensor that reports the force the device exerts


class NetworkCfg(_Strict):
    ports: list[PortCfg] = Field(default_factory=list)


class GroupCfg(_Strict):
    """Several actuators driven as one multi-DOF actuator (e.g. a 2-DOF master made of two 1-DOF
    drives on the y and z axes of one coupled body). Controllers, ports and experiments may name
    the group; its DOFs are the members' DOFs in order."""

    name: Name
    devices: Annotated[list[Name], Field(min_length=2)]


class NoController(_Strict):
    """No controller: the experiment's excitation is the only effort."""

    type: Literal["none"]


class PdPositionPosition(_Strict):
    """Bilateral position-position PD (paper 000 eq. 43/44): master effort
    ``Kp_m (q_s - q_m) + Kv_m (v_s - v_m)``, slave effort ``Kp_s (q_m - q_s) + Kv_s (v_m - v_s)``.
    Gains are dof x dof (N/m, N.s/m or N.m/rad, N.m.s/rad); a number means ``k * I``."""

    type: Literal["pd_position_position"]
    master: Name
    slave: Name
    Kp_m: StiffMat
    Kv_m: DampMat
    Kp_s: StiffMat
    Kv_s: DampMat


class Mcet(_Strict):
    """Dual-user MCET four-channel controller (paper 000 eq. 22-23), 1-DOF robots. Local PD gains
    (k_pmi, k_vmi), (k_ps, k_vs); optional coordinating channels c_4mi (default -c_mi) and c_1
    (default c_s) and force gains c2m1, c2m2, c3, c5, c6m1, c6m2 (default 0: position-position,
    eq. 25); ``force_sensors`` {master1, master2, slave} when force gains are used."""

    type: Literal["mcet"]
    masters: Annotated[list[Name], Field(min_length=2, max_length=2)]
    slave: Name
    alpha: Fraction
    k_pm1: PGain
    k_vm1: VGain
    k_pm2: PGain
    k_vm2: VGain
    k_ps: PGain
    k_vs: VGain
    k_p4m1: float | None = None
    k_v4m1: float | None = None
    k_p4m2: float | None = None
    k_v4m2: float | None = None
    k_p1: float | None = None
    k_v1: float | None = None
    c2m1: float = 0.0
    c2m2: float = 0.0
    c3: float = 0.0
    c5: float = 0.0
    c6m1: float = 0.0
    c6m2: float = 0.0
    force_sensors: dict[str, Name] | None = None
    slave_force_sign: Literal[1, -1] = -1


class PdGain(_Strict):
    """A PD gain matrix pair, i.e. the PI velocity controller ``(kp + kv s)/s`` of the papers."""

    kp: StiffMat
    kv: DampMat


class MasterMap(_Strict):
    """A master device and the slave DOFs it commands (paper 001: master 1 -> x, master 2 -> y, z)."""

    device: Name
    slave_dofs: DofList


class DualMaster(_Strict):
    """Dual-master / single-slave cooperative teleoperation (paper 001 eq. 17). The masters' DOFs,
    concatenated in order, map onto ``slave_dofs``; ``C_m`` (master local), ``C_4`` (slave ->
    masters), ``C_s`` (slave local), ``C_1`` (masters -> slave) are n x n PD gain pairs with n the
    slave DOF count: master effort ``C_4 x_s - C_m x_m``, slave effort ``C_1 x_m - C_s x_s``
    (x in the slave DOF order)."""

    type: Literal["dual_master"]
    masters: Annotated[list[MasterMap], Field(min_length=1)]
    slave: Name
    C_m: PdGain
    C_4: PdGain
    C_s: PdGain
    C_1: PdGain


class VsicEnvironment(_Strict):
    """Virtual environment rendered by the VSIC: a spring ``k`` (N.m/rad) with damping ``b``."""

    type: Literal["spring"] = "spring"
    k: StiffNonneg = 0.0
    b: DampNonneg = 0.0


class Vsic(_Strict):
    """Velocity-sourced impedance control of an SDEA (paper 002): inner motor velocity PI
    (P_m, I_m), force PI (P_f, I_f) on the spring-force error, feed-forward ``1 - alpha`` and a
    virtual coupler (k22, b22) to the environment."""

    type: Literal["vsic"]
    actuator: Name
    force_sensor: Name
    P_m: Annotated[float, BeforeValidator(lambda v: _number(v, "N.m.s/rad")), Field(gt=0)]
    I_m: Annotated[float, BeforeValidator(lambda v: _number(v, "N.m/rad")), Field(ge=0)]
    P_f: Annotated[float, BeforeValidator(lambda v: _number(v, "rad/(N.m.s)")), Field(gt=0)]
    I_f: Annotated[float, BeforeValidator(lambda v: _number(v, "rad/(N.m.s^2)")), Field(ge=0)]
    alpha: Fraction = 1.0
    k22: Annotated[float, BeforeValidator(lambda v: _number(v, "N.m/rad")), Field(ge=0)]
    b22: Annotated[float, BeforeValidator(lambda v: _number(v, "N.m.s/rad")), Field(ge=0)]
    environment: VsicEnvironment = Field(default_factory=VsicEnvironment)


Controller = Annotated[NoController | PdPositionPosition | Mcet | DualMaster | Vsic, Field(discriminator="type")]


class Safety(_Strict):
    """Limits checked every tick (per DOF, SI): effort N or N.m, velocity m/s or rad/s, position
    m or rad, energy J (|E_s| at any port), watchdog ms; realtime loop: ``max_lateness_ms`` (default
    ``watchdog_ms``) and ``max_overrun_fraction`` (see :mod:`hil.realtime`)."""

    max_effort: Annotated[float, BeforeValidator(lambda v: _number(v, "N or N.m")), Field(gt=0)] = 5.0
    max_velocity: Annotated[float, BeforeValidator(lambda v: _number(v, "m/s or rad/s")), Field(gt=0)] = 20.0
    position_limits: tuple[Position, Position] | None = None
    max_energy: Annotated[float, BeforeValidator(lambda v: _number(v, "J")), Field(gt=0)] = 50.0
    watchdog_ms: Annotated[float, BeforeValidator(lambda v: _number(v, "ms")), Field(gt=0)] = 50.0
    #: realtime loop: a tick starting later than this after its deadline is a safe stop (None: watchdog_ms)
    max_lateness_ms: Annotated[float, BeforeValidator(lambda v: _number(v, "ms")), Field(gt=0)] | None = None
    #: realtime loop: more overruns (ticks later than one period) than this fraction of any 1 s window: a safe stop
    max_overrun_fraction: Annotated[float, BeforeValidator(lambda v: _number(v, "fraction")),
                                    Field(ge=0, le=1)] = 0.01

    @field_validator("position_limits")
    @classmethod
    def _ordered(cls, v: tuple[float, float] | None) -> tuple[float, float] | None:
        if v is not None and not v[0] < v[1]:
            raise PydanticCustomError("limits", "expected [low, high] with low < high, got {v}", {"v": list(v)})
        return v


# ---------------------------------------------------------------------------------------------
# experiments
# ---------------------------------------------------------------------------------------------


class _ExpBase(_Strict):
    """Common experiment fields. ``controller``: ``scene`` runs the scene's controller during the
    experiment, ``none`` runs it open loop (identification). ``name`` defaults to the type."""

    name: Name | None = None
    controller: Literal["scene", "none"] = "scene"




class ChirpExperiment(_ExpBase):
    """Swept sine from ``f0`` to ``f1`` (Hz) of ``amplitude`` (N or N.m) on ``target``'s ``dofs``,
    ``sweep`` log or linear, cosine fade in/out of ``fade`` s. ``periodic``: ``periods`` identical
    sweeps of ``duration / periods`` s each (one period per Welch segment). ``variant``: plant
    configuration of a simulated SDEA (``locked`` output or ``free`` output)."""

    type: Literal["chirp"]
    f0: Hz
    f1: Hz
    duration: Seconds
    amplitude: Effort
    sweep: Literal["log", "linear"] = "log"
    fade: SecondsOrZero = 0.0
    target: Name
    dofs: DofList | None = None
    excite: Literal["effort"] = "effort"
    periodic: bool = False
    periods: int = Field(default=1, ge=1)
    variant: Literal["locked", "free"] | None = None

    @model_validator(mode="after")
    def _band(self) -> ChirpExperiment:
        if not self.f0 < self.f1:
            raise PydanticCustomError("band", "f1 ({f1} Hz) must exceed f0 ({f0} Hz)",
                                      {"f0": self.f0, "f1": self.f1, "key": "f1"})
        return self


class MultisineExperiment(_ExpBase):
    """Sum of ``n_lines`` sines between ``f0`` and ``f1`` (Hz), total ``amplitude`` (N or N.m) on
    ``target``'s ``dofs``; ``simultaneous``: all DOFs at once with orthogonal phases, else one DOF
    after the other."""

    type: Literal["multisine"]
    f0: Hz
    f1: Hz
    n_lines: int = Field(default=64, ge=1)
    duration: Seconds
    amplitude: Effort
    target: Name
    dofs: DofList | None = None
    simultaneous: bool = True
    periods: int = Field(default=1, ge=1)
    seed: Seed | None = None
    variant: Literal["locked", "free"] | None = None

    @model_validator(mode="after")
    def _band(self) -> MultisineExperiment:
        if not self.f0 < self.f1:
            raise PydanticCustomError("band", "f1 ({f1} Hz) must exceed f0 ({f0} Hz)",
                                      {"f0": self.f0, "f1": self.f1, "key": "f1"})
        return self


class ForceProfileCfg(_Strict):
    """Active operator force: ``sine`` (amplitude N, freq Hz), ``square``, ``step`` (amplitude from
    t = 0), ``noise`` (band-limited Gaussian, std = amplitude, seeded). ``direction``: unit weights
    per port DOF (default all ones)."""

    kind: Literal["sine", "square", "step", "noise"] = "sine"
    amplitude: Annotated[float, BeforeValidator(lambda v: _number(v, "N or N.m"))]
    freq: Annotated[float, BeforeValidator(lambda v: _number(v, "Hz")), Field(ge=0)] = 1.0
    phase: Annotated[float, BeforeValidator(lambda v: _number(v, "rad"))] = 0.0
    direction: list[Number] | None = None
    seed: Seed | None = None


def _auto_or_joules(value: Any) -> Any:
    if value == "auto":
        return value
    x = _number(value, "J (or 'auto')")
    if x < 0:
        raise PydanticCustomError("number", "expected 'auto' or a number >= 0 in J, got {got}", {"got": x})
    return x


class EnergyInjectionExperiment(_ExpBase):
    """Active force at a network ``port`` (simulated human) for ``duration`` s while the energy
    ``E_s = int F^T V dt`` at the port is tracked; ``noise_bound``: ``auto`` (from the sensor noise)
    or a number in J."""

    type: Literal["energy_injection"]
    port: Name
    duration: Seconds
    profile: ForceProfileCfg
    noise_bound: Annotated[Literal["auto"] | float, BeforeValidator(_auto_or_joules)] = "auto"


class StaticHoldExperiment(_ExpBase):
    """Constant ``effort`` (N or N.m) on ``target``'s ``dofs`` for ``duration`` s; the statistics
    are taken after ``settle`` s."""

    type: Literal["static_hold"]
    target: Name
    dofs: DofList | None = None
    effort: Effort
    duration: Seconds
    settle: SecondsOrZero = 0.0
    variant: Literal["locked", "free"] | None = None

    @model_validator(mode="after")
    def _settle(self) -> StaticHoldExperiment:
        if self.settle >= self.duration:
            raise PydanticCustomError("settle", "settle ({s} s) must be shorter than duration ({d} s)",
                                      {"s": self.settle, "d": self.duration, "key": "settle"})
        return self


Experiment = Annotated[
    ChirpExperiment | MultisineExperiment | EnergyInjectionExperiment | StaticHoldExperiment,
    Field(discriminator="type"),
]

# ---------------------------------------------------------------------------------------------
# certification
# ---------------------------------------------------------------------------------------------


#: identification models of :mod:`hil.identify.models` (``sdea`` is an alias of ``sdea_locked``)
IDENTIFICATION_MODELS = ("sdea_locked", "sdea_free", "mbk")


class IdentifyCfg(_Strict):
    """Identify plant parameters from an experiment's record: ``experiment`` names a chirp or
    multisine of ``experiments``; ``model`` one of :data:`IDENTIFICATION_MODELS` (default: inferred
    as ``hil identify`` does); ``map`` renames identified parameters to the network model's (e.g.
    ``{M: M, B: B, K_f: K_f, B_f: B_f}``; empty: every identified parameter under its own name).
    Checked at load time against both models (see :func:`_check_certification`)."""

    experiment: Name
    model: str | None = None
    map: dict[str, str] = Field(default_factory=dict)


class UncertainCfg(_Strict):
    """A parameter known only to a relative standard deviation (log-normal around ``value`` > 0)."""

    value: Annotated[float, BeforeValidator(lambda v: _number(v, "")), Field(gt=0)]
    rel_std: Annotated[float, BeforeValidator(lambda v: _number(v, "")), Field(ge=0, le=1)] = 0.05


class DesignCfg(_Strict):
    """A free design parameter of the model and the range ``[low, high]`` to search (largest value
    that keeps the required probability of stability), finite with low < high."""

    parameter: str
    range: tuple[Number, Number]

    @field_validator("range")
    @classmethod
    def _ordered(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not v[0] < v[1]:
            raise PydanticCustomError("range", "expected [low, high] with low < high, got {v}", {"v": list(v)})
        return v


Probability = _num_type("(0, 1)", gt=0, lt=1)


class PolicyCfg(_Strict):
    """The verdict policy (:class:`hil.certify.Policy`): probabilities strictly inside (0, 1)."""

    required_probability: Probability = 0.95
    confidence: Probability = 0.95
    credible: Probability = 0.90


class CertificationCfg(_Strict):
    """What ``hil certify`` checks: the network model (a built-in model of ``hil.models``), its
    fixed parameters (controller gains, ...), the parameters identified from experiments or known
    only with an uncertainty, the criterion, a design parameter and the verdict policy."""

    model: str
    criterion: Literal["auto", "passivity", "absolute_stability", "llewellyn", "positive_real"] = "auto"
    parameters: dict[str, Any] = Field(default_factory=dict)
    identify: list[IdentifyCfg] = Field(default_factory=list)
    uncertain: dict[str, UncertainCfg] = Field(default_factory=dict)
    design: DesignCfg | None = None
    policy: PolicyCfg = Field(default_factory=PolicyCfg)
    draws: Annotated[int, Field(ge=20, le=100_000)] = 2000
    witness: bool = True


# ---------------------------------------------------------------------------------------------
# the scene
# ---------------------------------------------------------------------------------------------


class Scene(_Strict):
    """A validated scene. ``source_text`` / ``sha256`` / ``path`` are set by :func:`load_scene`."""

    name: Name
    description: str = ""
    seed: Seed = 0
    rate_hz: Annotated[float, BeforeValidator(lambda v: _number(v, "Hz")), Field(gt=0, le=100_000)] = 1000.0
    mode: Literal["lockstep", "realtime"] | None = None
    units: Literal["rotary", "linear"] = "linear"
    devices: Annotated[list[Device], Field(min_length=1)]
    groups: list[GroupCfg] = Field(default_factory=list)
    simulation: Simulation | None = None
    network: NetworkCfg = Field(default_factory=NetworkCfg)
    controller: Controller = Field(default_factory=lambda: NoController(type="none"))
    safety: Safety = Field(default_factory=Safety)
    experiments: list[Experiment] = Field(default_factory=list)
    certification: CertificationCfg | None = None

    _source_text: str = PrivateAttr(default="")
    _sha256: str = PrivateAttr(default="")
    _path: str = PrivateAttr(default="")

    @property
    def source_text(self) -> str:
        """The exact YAML text the scene was loaded from ('' when built from a dict)."""
        return self._source_text

    @property
    def sha256(self) -> str:
        """Hex SHA-256 of ``source_text`` encoded as UTF-8."""
        return self._sha256

    @property
    def path(self) -> str:
        """Where the scene came from (file path or ``builtin:<name>``)."""
        return self._path

    @property
    def run_mode(self) -> str:
        """``mode``, defaulting to lockstep when simulated and realtime otherwise."""
        return self.mode or ("lockstep" if self.simulation is not None else "realtime")

    @property
    def dt(self) -> float:
        """Control period 1/rate_hz (s)."""
        return 1.0 / self.rate_hz

    def device(self, name: str) -> Device:
        """The device called ``name`` (KeyError if absent). A group is returned as an actuator
        ``Device`` whose ``dof`` is the sum of its members'. Cached: scenes are not edited after
        loading (the runner looks devices up on every tick)."""
        cache = self.__dict__.setdefault("_device_cache", {})
        hit = cache.get(name)
        if hit is not None:
            return hit
        cache[name] = dev = self._find_device(name)
        return dev

    def _find_device(self, name: str) -> Device:
        for d in self.devices:
            if d.name == name:
                return d
        for g in self.groups:
            if g.name == name:
                members = [self.device(m) for m in g.devices]
                bodies = {m.body for m in members}
                return Device.model_construct(name=g.name, role="actuator", driver="(group)", params={},
                                              dof=sum(m.dof for m in members),
                                              body=bodies.pop() if len(bodies) == 1 else None, dofs=None,
                                              axes=None, sim=None)
        raise KeyError(name)

    def group(self, name: str) -> GroupCfg | None:
        """The group called ``name``, or None."""
        return next((g for g in self.groups if g.name == name), None)

    @property
    def actuators(self) -> list[Device]:
        return [d for d in self.devices if d.role == "actuator"]

    @property
    def force_sensors(self) -> list[Device]:
        return [d for d in self.devices if d.role == "force_sensor"]

    def port(self, name: str) -> PortCfg:
        """The network port called ``name`` (KeyError if absent)."""
        for p in self.network.ports:
            if p.name == name:
                return p
        raise KeyError(name)

    def controller_config(self) -> dict[str, Any]:
        """``controller`` as a plain dict for ``hil.controllers.make_controller``."""
        return self.controller.model_dump()

    def experiment_configs(self) -> list[dict[str, Any]]:
        """``experiments`` as plain dicts for ``hil.experiments.make_experiment`` (``name`` filled)."""
        out = []
        for i, e in enumerate(self.experiments):
            d = e.model_dump()
            d["name"] = e.name or _default_exp_name(self.experiments, i)
            out.append(d)
        return out


def _default_exp_name(exps: Sequence[Any], i: int) -> str:
    t = exps[i].type
    same = [k for k, e in enumerate(exps) if e.type == t and e.name is None]
    return t if len(same) == 1 else f"{t}_{same.index(i) + 1}"


# ---------------------------------------------------------------------------------------------
# cross-references (after the per-field validation)
# ---------------------------------------------------------------------------------------------


def _near(name: str, known: Sequence[str]) -> str:
    close = difflib.get_close_matches(name, list(known), n=1, cutoff=0.5)
    if close:
        return f" (did you mean {close[0]!r}?)"
    return f"; known: {', '.join(known) if known else '(none)'}"


def _cross_check(sc: Scene) -> None:
    """Raise ``_Where(path, message)`` for the first broken reference or shape."""
    names = [d.name for d in sc.devices]
    seen: set[str] = set()
    for i, d in enumerate(sc.devices):
        if d.name in seen:
            raise _Where(f"devices[{i}].name", f"duplicate device name {d.name!r}")
        seen.add(d.name)
    dev = {d.name: d for d in sc.devices}
    grouped: set[str] = set()
    for i, g in enumerate(sc.groups):
        if g.name in dev:
            raise _Where(f"groups[{i}].name", f"group name {g.name!r} is already a device name")
        for k, m in enumerate(g.devices):
            if m not in dev:
                raise _Where(f"groups[{i}].devices[{k}]", f"unknown device {m!r}{_near(m, names)}")
            if dev[m].role != "actuator":
                raise _Where(f"groups[{i}].devices[{k}]", f"device {m!r} is a {dev[m].role}; groups hold actuators")
            if m in grouped:
                raise _Where(f"groups[{i}].devices[{k}]", f"device {m!r} is already in another group")
            grouped.add(m)
        dev[g.name] = sc.device(g.name)
    names = names + [g.name for g in sc.groups]

    def need(path: str, name: str, role: str | None = None) -> Device:
        if name not in dev:
            raise _Where(path, f"unknown device {name!r}{_near(name, names)}")
        d = dev[name]
        if role is not None and d.role != role:
            raise _Where(path, f"device {name!r} is a {d.role}, expected a {role}")
        return d

    def check_gain(path: str, value: Any, rows: int, cols: int, what: str) -> None:
        s = _shape(value)
        if s is None:
            if rows != cols:
                raise _Where(path, f"a number means k*I, which needs a square gain; expected a {rows}x{cols} "
                                   f"matrix ({what})")
            return
        if s != (rows, cols):
            raise _Where(path, f"expected a {rows}x{cols} matrix ({what}), got {s[0]}x{s[1]}")

    # network
    pnames: set[str] = set()
    for i, p in enumerate(sc.network.ports):
        if p.name in pnames:
            raise _Where(f"network.ports[{i}].name", f"duplicate port name {p.name!r}")
        pnames.add(p.name)
        a = need(f"network.ports[{i}].actuator", p.actuator, "actuator")
        if a.dof != p.dofs:
            raise _Where(f"network.ports[{i}].dofs", f"port has {p.dofs} DOF but actuator {a.name!r} has {a.dof}")
        if p.force_sensor is not None:
            s = need(f"network.ports[{i}].force_sensor", p.force_sensor, "force_sensor")
            if s.dof != p.dofs:
                raise _Where(f"network.ports[{i}].force_sensor",
                             f"sensor {s.name!r} measures {s.dof} DOF, the port has {p.dofs}")
    # controller
    c = sc.controller
    if isinstance(c, PdPositionPosition):
        m = need("controller.master", c.master, "actuator")
        s = need("controller.slave", c.slave, "actuator")
        if m.dof != s.dof:
            raise _Where("controller.slave", f"master {m.name!r} has {m.dof} DOF, slave {s.name!r} has {s.dof}")
        for key in ("Kp_m", "Kv_m", "Kp_s", "Kv_s"):
            check_gain(f"controller.{key}", getattr(c, key), m.dof, m.dof, f"dof x dof of {m.name!r}/{s.name!r}")
            setattr(c, key, as_matrix(getattr(c, key), m.dof).tolist())  # dumps always hold full matrices
    elif isinstance(c, Mcet):
        for k, mname in enumerate(c.masters):
            d = need(f"controller.masters[{k}]", mname, "actuator")
            if d.dof != 1:
                raise _Where(f"controller.masters[{k}]", f"mcet needs 1-DOF robots; {mname!r} has {d.dof} DOF")
        d = need("controller.slave", c.slave, "actuator")
        if d.dof != 1:
            raise _Where("controller.slave", f"mcet needs 1-DOF robots; {c.slave!r} has {d.dof} DOF")
    elif isinstance(c, DualMaster):
        s = need("controller.slave", c.slave, "actuator")
        covered: list[int] = []
        for k, mm in enumerate(c.masters):
            d = need(f"controller.masters[{k}].device", mm.device, "actuator")
            if len(mm.slave_dofs) != d.dof:
                raise _Where(f"controller.masters[{k}].slave_dofs",
                             f"master {d.name!r} has {d.dof} DOF but maps {len(mm.slave_dofs)} slave DOF")
            bad = [j for j in mm.slave_dofs if j >= s.dof]
            if bad:
                raise _Where(f"controller.masters[{k}].slave_dofs",
                             f"slave {s.name!r} has {s.dof} DOF; index {bad[0]} is out of range")
            covered += mm.slave_dofs
        if sorted(covered) != list(range(s.dof)):
            raise _Where("controller.masters", f"the masters' slave_dofs must cover each of the slave's {s.dof} "
                                               f"DOF exactly once, got {covered}")
        for key in ("C_m", "C_4", "C_s", "C_1"):
            g = getattr(c, key)
            check_gain(f"controller.{key}.kp", g.kp, s.dof, s.dof, "n x n, n = slave DOF")
            check_gain(f"controller.{key}.kv", g.kv, s.dof, s.dof, "n x n, n = slave DOF")
            g.kp = as_matrix(g.kp, s.dof).tolist()
            g.kv = as_matrix(g.kv, s.dof).tolist()
    elif isinstance(c, Vsic):
        a = need("controller.actuator", c.actuator, "actuator")
        f = need("controller.force_sensor", c.force_sensor, "force_sensor")
        if a.dof != 1 or f.dof != 1:
            raise _Where("controller.actuator", "vsic controls a 1-DOF SDEA (actuator and sensor with dof 1)")
        if c.k22 == 0 and c.b22 == 0:
            raise _Where("controller.k22", "the virtual coupler needs k22 > 0 or b22 > 0")
    # experiments
    exp_names: dict[str, int] = {}
    for i, cfg in enumerate(sc.experiment_configs()):
        if cfg["name"] in exp_names:
            raise _Where(f"experiments[{i}].name", f"duplicate experiment name {cfg['name']!r} (also "
                                                   f"experiments[{exp_names[cfg['name']]}])")
        exp_names[cfg["name"]] = i
    for i, e in enumerate(sc.experiments):
        if isinstance(e, EnergyInjectionExperiment):
            if e.port not in pnames:
                raise _Where(f"experiments[{i}].port", f"unknown port {e.port!r}{_near(e.port, sorted(pnames))}")
            port = sc.port(e.port)
            if e.profile.direction is not None and len(e.profile.direction) != port.dofs:
                raise _Where(f"experiments[{i}].profile.direction",
                             f"port {port.name!r} has {port.dofs} DOF, direction has {len(e.profile.direction)}")
            continue
        d = need(f"experiments[{i}].target", e.target, "actuator")
        if e.dofs is not None and max(e.dofs) >= d.dof:
            raise _Where(f"experiments[{i}].dofs", f"device {d.name!r} has {d.dof} DOF")
        if getattr(e, "variant", None) is not None:
            sim = sc.simulation
            if sim is not None and (sim.sdea is None or sim.sdea.m_out is None) and e.variant == "free":
                raise _Where(f"experiments[{i}].variant",
                             "variant 'free' needs simulation.sdea.m_out (the output inertia)")
    for i, d in enumerate(sc.devices):
        if d.role == "actuator" and d.axes is not None:
            raise _Where(f"devices[{i}].axes", "axes applies to force sensors only")
        if d.driver == "cia402" and (sc.units == "linear" or d.dof != 1 or d.role != "actuator"):
            # hil.protocols.cia402: one rotary axis (rad, N.m) per drive node
            raise _Where(f"devices[{i}].driver", "a cia402 drive is one rotary actuator axis: role actuator, dof 1, "
                                                 "units rotary")
    if sc.simulation is not None:
        _check_simulation(sc, sc.simulation)
    if sc.certification is not None:
        _check_certification(sc, sc.certification)
    _check_link_budgets(sc)


def _check_link_budgets(sc: Scene) -> None:
    """Refuse a scene whose buses cannot carry the traffic it asks for: serial lines at baud/10
    bytes/s, CAN at the bit rate with worst-case stuffed frames (formulas and per-driver traffic:
    :mod:`hil.protocols.link_budget`)."""
    from hil.protocols.link_budget import over_budget

    for use in over_budget(sc.devices, sc.rate_hz):
        i = next(k for k, d in enumerate(sc.devices) if d.name == use.devices[0])
        raise _Where(f"devices[{i}].params", f"link budget exceeded: {use.message()}")


def _check_simulation(sc: Scene, sim: Simulation) -> None:
    bodies: dict[str, int] = {}
    for i, b in enumerate(sim.bodies):
        if b.name in bodies:
            raise _Where(f"simulation.bodies[{i}].name", f"duplicate body name {b.name!r}")
        s = _shape(b.M)
        if s is not None and s[0] != s[1]:
            raise _Where(f"simulation.bodies[{i}].M", f"mass matrix must be square, got {s[0]}x{s[1]}")
        for key in ("B", "K"):
            t = _shape(getattr(b, key))
            if t is not None and t != (b.dof, b.dof):
                raise _Where(f"simulation.bodies[{i}].{key}", f"expected a {b.dof}x{b.dof} matrix, got {t[0]}x{t[1]}")
        bodies[b.name] = b.dof
    if sim.sdea is not None:
        for nm in (sim.sdea.name, f"{sim.sdea.name}_out"):
            if nm in bodies:
                raise _Where("simulation.sdea.name", f"body name {nm!r} is already used")
    all_bodies = sim.body_dofs()
    if not all_bodies:
        raise _Where("simulation", "a simulation needs at least one body (bodies or sdea)")
    known = sorted(all_bodies)

    def body(path: str, name: str, dofs: list[int] | None) -> int:
        if name not in all_bodies:
            raise _Where(path, f"unknown body {name!r}{_near(name, known)}")
        n = all_bodies[name]
        if dofs is not None:
            bad = [j for j in dofs if j >= n]
            if bad:
                raise _Where(path, f"body {name!r} has {n} DOF; DOF index {bad[0]} is out of range")
            return len(dofs)
        return n

    def square(path: str, value: Any, n: int) -> None:
        t = _shape(value)
        if t is not None and t != (n, n):
            raise _Where(path, f"expected a {n}x{n} matrix (the port has {n} DOF), got {t[0]}x{t[1]}")

    for i, sp in enumerate(sim.springs):
        na = body(f"simulation.springs[{i}].a", sp.a, sp.a_dofs)
        if sp.b is not None:
            nb = body(f"simulation.springs[{i}].b", sp.b, sp.b_dofs)
            if nb != na:
                raise _Where(f"simulation.springs[{i}].b", f"ports have {na} and {nb} DOF")
        square(f"simulation.springs[{i}].stiffness", sp.stiffness, na)
        square(f"simulation.springs[{i}].damping", sp.damping, na)
    for i, t in enumerate(sim.terminations):
        n = body(f"simulation.terminations[{i}].port", t.port, t.dofs)
        if isinstance(t, ImpedanceTermination) and len(t.tf) != n:
            raise _Where(f"simulation.terminations[{i}].tf", f"expected a {n}x{n} transfer matrix (port DOF), "
                                                             f"got {len(t.tf)}x{len(t.tf)}")
        if isinstance(t, WallTermination):
            square(f"simulation.terminations[{i}].stiffness", t.stiffness, n)
            square(f"simulation.terminations[{i}].damping", t.damping, n)
        if isinstance(t, NamedTermination) and NAMED_TERMINATION_DOF[t.name] != n:
            raise _Where(f"simulation.terminations[{i}].name",
                         f"{t.name} has {NAMED_TERMINATION_DOF[t.name]} ports, the port has {n} DOF")
    hnames: set[str] = set()
    for i, h in enumerate(sim.humans):
        path = "simulation.human" if isinstance(sim.human, HumanCfg) else f"simulation.human[{i}]"
        n = body(f"{path}.port", h.port, h.dofs)
        for key in ("mass", "damping", "stiffness"):
            square(f"{path}.{key}", getattr(h, key), n)
        nm = h.name or ("human" if len(sim.humans) == 1 else f"human_{h.port}")
        if nm in hnames or nm in all_bodies:
            raise _Where(f"{path}.name", f"name {nm!r} is already used")
        hnames.add(nm)
    for i, d in enumerate(sc.devices):
        if d.body is None:
            raise _Where(f"devices[{i}].body", "required when the scene has a simulation (the simulated body "
                                               "the device is attached to)")
        n = body(f"devices[{i}].body", d.body, d.dofs)
        if n != d.dof:
            raise _Where(f"devices[{i}].dof", f"device has {d.dof} DOF but is attached to {n} DOF of body {d.body!r}")
        sel = d.dofs if d.dofs is not None else list(range(all_bodies[d.body]))
        if d.role == "actuator":
            for j, other in enumerate(sc.devices[:i]):
                if other.role == "actuator" and other.body == d.body:
                    osel = other.dofs if other.dofs is not None else list(range(all_bodies[d.body]))
                    if set(osel) & set(sel):
                        raise _Where(f"devices[{i}].dofs", f"DOF already driven by actuator {sc.devices[j].name!r}")


def _hint(name: str, known: Sequence[str], limit: int = 16) -> str:
    """`` (did you mean 'x'?)`` or ``; known: a, b, ...`` (at most ``limit`` names)."""
    close = difflib.get_close_matches(name, list(known), n=1, cutoff=0.5)
    if close:
        return f" (did you mean {close[0]!r}?)"
    shown = list(known)[:limit]
    more = f", ... ({len(known) - limit} more)" if len(known) > limit else ""
    return f"; known: {', '.join(shown) if shown else '(none)'}{more}"


_MBK_ENTRY = re.compile(r"^([MBK])_(\d)(\d)$")


def _network_parameters(model: str) -> tuple[list[str], Any]:
    """The parameters the network model ``model`` accepts: ``(names for messages, predicate)``.

    Most built-in models take exactly the keys of their defaults. ``mbk_impedance`` takes the
    upper-triangle entries ``M_ij``, ``B_ij``, ``K_ij`` (i <= j) of any size; ``bilateral_2dof``
    takes ``gains`` (a Table II set or a mapping), gains ``k_{p|v}[m|s]{yy|zz|yz|zy}`` and robot
    entries ``{m|b|k}[m|s]_{yy|zz|yz}`` (shared, master or slave)."""
    from hil.models import get_model

    m = get_model(model)
    if model == "mbk_impedance":
        names = sorted(m.defaults)

        def ok(k: str) -> bool:
            hit = _MBK_ENTRY.match(k)
            return bool(hit) and int(hit.group(2)) <= int(hit.group(3))

        return names, ok
    if model == "bilateral_2dof":
        known = {"gains"}
        for side in ("", "m", "s"):
            known |= {f"k_{pv}{side}{ax}" for pv in "pv" for ax in ("yy", "zz", "yz", "zy")}
            known |= {f"{key}{side}_{ax}" for key in "mbk" for ax in ("yy", "zz", "yz")}
        names = sorted(known)
        return names, known.__contains__
    names = sorted(m.defaults)
    return names, set(names).__contains__


def _identification_names(sc: Scene, path: str, spec: IdentifyCfg, exp: Any) -> tuple[str, list[str], list[str]]:
    """``(model, sampled parameter names, every name a map may use)`` of what identifying ``spec``
    from experiment ``exp`` yields; the model is inferred as :func:`hil.identify.records.plan_from_record`
    does (an SDEA variant, else a 1-DOF target with a force sensor, else an m-DOF MBK body)."""
    n = len(exp.dofs) if exp.dofs is not None else sc.device(exp.target).dof
    variant = getattr(exp, "variant", None)
    key = None if spec.model is None else spec.model.lower().replace("-", "_")
    if key == "sdea":
        key = "sdea_locked"
    if key is not None and key not in IDENTIFICATION_MODELS:
        raise _Where(f"{path}.model", f"unknown identification model {spec.model!r}"
                                      f"{_hint(spec.model or '', IDENTIFICATION_MODELS)}")
    sdea = ["K_f", "B_f", "M", "B"]

    def mbk(k: int) -> tuple[list[str], list[str]]:
        sampled = [f"L{m}_{i}{j}" for m in "MBK" for i in range(k) for j in range(i + 1)]
        derived = [f"{m}_{i}{j}" for m in "MBK" for i in range(k) for j in range(i, k)]
        return sampled, sampled + derived

    if key is None:
        if variant in ("locked", "free"):
            key = f"sdea_{variant}"
        elif n == 1:
            tdev = sc.device(exp.target)
            by_port = any(p.actuator == exp.target and p.force_sensor for p in sc.network.ports)
            same_body = [s for s in sc.force_sensors if s.body is not None and s.body == tdev.body]
            if by_port or len(same_body) == 1:
                key = "sdea_locked"
            elif sc.force_sensors:  # decided from the record's channels: either model
                ms, ma = mbk(1)
                return "sdea_locked or mbk", sdea + ms, sdea + ma
            else:
                key = "mbk"
        else:
            key = "mbk"
    if key.startswith("sdea"):
        if n != 1:
            raise _Where(f"{path}.model", f"{key} identifies a 1-DOF SDEA; experiment {spec.experiment!r} "
                                          f"excites {n} DOF")
        if key == "sdea_locked" and not sc.force_sensors:
            # the locked-output velocity alone carries B + B_f only: identification would refuse
            # after the runs (hil.identify's identifiability check)
            raise _Where(f"{path}.model", "sdea_locked needs the spring force: with only the motor velocity, "
                                          "B and B_f are inseparable; add a force sensor on the target's body "
                                          "or network port, or identify sdea_free from a free-output chirp")
        names = sdea + (["m_h"] if key == "sdea_free" else [])
        return key, names, names
    sampled, available = mbk(n)
    return key, sampled, available


def _check_certification(sc: Scene, cert: CertificationCfg) -> None:
    """Every name and range of the ``certification`` section, before anything runs: the network
    model and its parameters, the criterion for that network, the identify entries (experiment,
    identification model, map on both sides), the uncertain parameters, the design range."""
    from hil.models import get_model, model_names

    try:
        get_model(cert.model)
    except KeyError:
        raise _Where("certification.model", f"unknown model {cert.model!r}{_hint(cert.model, model_names())}"
                     ) from None
    names, accepts = _network_parameters(cert.model)

    def need_param(path: str, k: str) -> None:
        if not accepts(k):
            raise _Where(path, f"model {cert.model} has no parameter {k!r}{_hint(k, names)}")

    for k, v in cert.parameters.items():
        need_param(f"certification.parameters.{k}", k)
        if cert.model == "bilateral_2dof" and k == "gains":
            from hil.models.teleop import TWO_DOF_TABLE2

            if isinstance(v, str) and v not in TWO_DOF_TABLE2:
                raise _Where(f"certification.parameters.{k}", f"unknown gain set {v!r}"
                                                              f"{_hint(v, sorted(TWO_DOF_TABLE2))}")
            if isinstance(v, dict):
                for gk, gv in v.items():
                    need_param(f"certification.parameters.gains.{gk}", str(gk))
                    _param_number(f"certification.parameters.gains.{gk}", gv)
            elif not isinstance(v, str):
                raise _Where(f"certification.parameters.{k}", f"expected a gain set name ({', '.join(TWO_DOF_TABLE2)})"
                                                              f" or a mapping of gains, got {v!r}")
            continue
        _param_number(f"certification.parameters.{k}", v)
    for k in cert.uncertain:
        need_param(f"certification.uncertain.{k}", k)
    # identify entries
    exps = {c["name"]: (i, sc.experiments[i]) for i, c in enumerate(sc.experiment_configs())}
    identified: dict[str, str] = {}
    for i, spec in enumerate(cert.identify):
        path = f"certification.identify[{i}]"
        if spec.experiment not in exps:
            raise _Where(f"{path}.experiment", f"no experiment {spec.experiment!r} in the scene"
                                               f"{_hint(spec.experiment, sorted(exps))}")
        j, exp = exps[spec.experiment]
        if exp.type not in ("chirp", "multisine"):
            raise _Where(f"{path}.experiment", f"experiment {spec.experiment!r} (experiments[{j}]) is a {exp.type}; "
                                               "identification needs a chirp or a multisine")
        model, sampled, available = _identification_names(sc, path, spec, exp)
        mapping = spec.map or {n: n for n in sampled}
        for src, dst in mapping.items():
            where = f"{path}.map.{src}" if spec.map else f"{path}.map"
            if src not in available:
                raise _Where(where, f"identification model {model} has no parameter {src!r}{_hint(src, available)}")
            if not accepts(dst):
                what = (f"maps {src!r} to {dst!r}, which" if spec.map
                        else f"is empty: every identified parameter keeps its name, but {dst!r}")
                raise _Where(where, f"{what} is not a parameter of model {cert.model}{_hint(dst, names)}")
            if dst in identified:
                raise _Where(where, f"parameter {dst!r} is already identified by {identified[dst]}")
            if dst in cert.uncertain:
                raise _Where(where, f"parameter {dst!r} is also in certification.uncertain: identify it or "
                                    "give its uncertainty, not both")
            identified[dst] = path
    # design
    d = cert.design
    if d is not None:
        need_param("certification.design.parameter", d.parameter)
        if cert.model != "sdea" or d.parameter not in ("k22", "b22"):
            raise _Where("certification.design.parameter", "the design search is implemented for the SDEA "
                                                           "coupler (model sdea, parameter k22 or b22)")
        if d.range[0] < 0:
            raise _Where("certification.design.range", f"{d.parameter} must be >= 0, got [{d.range[0]:g}, "
                                                       f"{d.range[1]:g}]")
        if d.parameter in identified or d.parameter in cert.uncertain:
            raise _Where("certification.design.parameter", f"{d.parameter!r} is identified or uncertain; a design "
                                                           "parameter is chosen, not measured")
        if not identified and not cert.uncertain:
            raise _Where("certification.design", "the design search runs over the posterior: it needs identify "
                                                 "or uncertain entries")
    _check_network_builds(sc, cert)


def _param_number(path: str, v: Any) -> None:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(float(v)):
        raise _Where(path, f"expected a finite number, got {v!r}")


def _check_network_builds(sc: Scene, cert: CertificationCfg) -> None:
    """Build the nominal network once (fixed parameters from the controller and simulation,
    ``parameters``, the uncertain values; identified ones at the model defaults) and check that
    the criterion applies to its shape."""
    from hil.errors import HilError
    from hil.pipeline import build_network, model_params_from_scene

    q = model_params_from_scene(sc)
    q.update({k: u.value for k, u in cert.uncertain.items()})
    try:
        tm = build_network(cert.model, q)
    except (HilError, ValueError, TypeError, KeyError, ArithmeticError) as exc:
        msg = " ".join(str(exc).split()) or type(exc).__name__
        raise _Where("certification", f"the network model {cert.model} cannot be built from this scene: {msg}"
                     ) from None
    if cert.criterion == "llewellyn" and not (tm.n == 2 and tm.n_ports == 2):
        raise _Where("certification.criterion", f"llewellyn applies to 1-DOF two-ports; model {cert.model} is a "
                                                f"{tm.n_ports}-port with {tm.n} DOF (use absolute_stability or "
                                                "passivity)")


class _Where(Exception):
    def __init__(self, path: str, message: str) -> None:
        super().__init__(f"{path}: {message}")
        self.path = path
        self.message = message


# ---------------------------------------------------------------------------------------------
# loading and error formatting
# ---------------------------------------------------------------------------------------------


def _strip_tags(loc: Sequence[Any], data: Any) -> list[Any]:
    """Drop discriminator tags and union-member names that pydantic inserts in error locations."""
    out: list[Any] = []
    cur = data
    for part in loc:
        if isinstance(part, int):
            out.append(part)
            cur = cur[part] if isinstance(cur, list) and 0 <= part < len(cur) else None
            continue
        if isinstance(cur, dict) and part in cur:
            out.append(part)
            cur = cur[part]
            continue
        if isinstance(cur, dict) and cur.get("type") == part:
            continue  # discriminator tag
        if isinstance(part, str) and ("[" in part or part in ("float", "int", "str") or part in _model_names()):
            continue  # union member names ("float", "list[list[float]]", "HumanCfg", ...)
        out.append(part)
        cur = None
    return out


def _model_names() -> set[str]:
    names: set[str] = set()
    todo: list[type] = [_Strict]
    while todo:
        cls = todo.pop()
        names.add(cls.__name__)
        todo += cls.__subclasses__()
    return names


def _format_error(exc: ValidationError, data: Any) -> str:
    errs = exc.errors(include_url=False)
    # the deepest location is the most specific (for unions such as ``human: X | list[X]`` the
    # member whose shape matches the input fails deeper than the one that does not)
    err = max(errs, key=lambda e: len(_strip_tags(e["loc"], data)))
    loc = _strip_tags(err["loc"], data)
    ctx = err.get("ctx") or {}
    typ = err["type"]
    msg = str(err["msg"]).removeprefix("Value error, ")
    if typ == "unknown_key" or ("key" in ctx and typ in ("dofs", "axes", "band", "settle")):
        loc = [*loc, ctx["key"]]
    if typ == "union_tag_invalid":
        tag = ctx.get("tag")
        expected = str(ctx.get("expected_tags", "")).replace("'", "").split(", ")
        loc = [*loc, ctx.get("discriminator", "type").strip("'")]
        msg = f"unknown type {tag!r}{_near(str(tag), expected)}; expected one of: {', '.join(expected)}"
    elif typ == "union_tag_not_found":
        loc = [*loc, "type"]
        msg = "missing 'type'"
    elif typ == "missing":
        msg = "required field is missing"
    elif typ == "literal_error":
        msg = f"expected {ctx.get('expected', msg)}, got {err.get('input')!r}"
    elif typ in ("int_type", "int_parsing", "int_from_float", "bool_type", "bool_parsing", "string_type",
                 "dict_type", "list_type", "model_type", "model_attributes_type", "tuple_type"):
        msg = f"{msg} (got {err.get('input')!r})"
    elif typ in ("greater_than", "greater_than_equal", "less_than", "less_than_equal", "too_short", "too_long",
                 "string_pattern_mismatch"):
        inp = err.get("input")
        if not isinstance(inp, dict | list):
            msg = f"{msg} (got {inp!r})"
    return f"{field_path(loc)}: {msg}"


def _check_blocks(sc: Scene) -> None:
    """Build every experiment and the controller as the runner will (``make_experiment`` +
    ``check(scene)``, ``make_controller``), so their checks (band against the rate, peak effort
    against ``safety.max_effort``, a human for energy injection, ...) fail at load time, not after
    the experiments before them have run."""
    from hil.controllers import make_controller
    from hil.experiments import make_experiment

    for cfg in sc.experiment_configs():
        make_experiment(cfg, rate_hz=sc.rate_hz).check(sc)
    make_controller(sc.controller_config(), units=sc.units, scene=sc)


def parse_yaml(text: str, label: str) -> Any:
    """Parse scene YAML ``text`` (safe, duplicate keys refused at any depth); any problem is one
    :class:`SceneError` line ``label: ...`` (see :func:`hil.inputs.parse_yaml`)."""
    return _parse_yaml(text, label, SceneError)


def _builtin_dir() -> Path:
    return Path(str(resources.files(_BUILTIN_PACKAGE).joinpath(_BUILTIN_DIR)))


def builtin_scenes() -> list[tuple[str, str]]:
    """``(name, description)`` of every built-in scene, sorted by name."""
    import yaml

    out = []
    for p in sorted(_builtin_dir().glob("*.yaml")):
        try:
            data = yaml.safe_load(p.read_text(encoding="utf-8"))
            desc = str(data.get("description", "")) if isinstance(data, dict) else ""
        except yaml.YAMLError:
            desc = "(invalid YAML)"
        out.append((p.stem, " ".join(desc.split())))
    return out


def _resolve(src: str | Path) -> tuple[Path, str]:
    p = Path(src)
    if p.exists():
        return p, p.name
    s = str(src)
    if "/" not in s and "\\" not in s and not s.endswith((".yaml", ".yml")):
        cand = _builtin_dir() / f"{s}.yaml"
        if cand.exists():
            return cand, f"{s}.yaml"
        known = [n for n, _ in builtin_scenes()]
        raise SceneError(f"{s}: no such file or built-in scene{_near(s, known)}")
    raise SceneError(f"{p}: no such file")


def scene_from_dict(data: Any, *, label: str = "<scene>", source_text: str = "", path: str = "") -> Scene:
    """Validate a scene mapping (already parsed). Errors are one-line :class:`SceneError`s
    prefixed with ``label``. Without ``source_text`` the mapping's YAML dump becomes the scene's
    text, so records always carry the exact scene they ran."""
    if not isinstance(data, dict):
        got = "an empty file" if data is None else type(data).__name__
        raise SceneError(f"{label}: expected a mapping with 'name' and 'devices' at the top level, got {got}")
    try:
        sc = Scene.model_validate(data)
    except ValidationError as exc:
        raise SceneError(f"{label}: {_format_error(exc, data)}") from None
    try:
        _cross_check(sc)
    except _Where as w:
        raise SceneError(f"{label}: {w.path}: {w.message}") from None
    try:
        _check_blocks(sc)
    except SceneError as exc:  # hil.experiments / hil.controllers say "field.path: message"
        raise SceneError(f"{label}: {' '.join(str(exc).split())}") from None
    if not source_text:
        import yaml

        source_text = yaml.safe_dump(data, sort_keys=False)
    sc._source_text = source_text
    sc._sha256 = hashlib.sha256(source_text.encode("utf-8")).hexdigest()
    sc._path = path
    return sc


def load_scene(src: str | Path) -> Scene:
    """Load and validate a scene from a YAML path or a built-in scene name.

    Raises :class:`SceneError` with one line ``file: field: message`` on any problem (a duplicate
    key, at any depth, is one).
    """
    path, label = _resolve(src)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(f"{label}: cannot read: {exc}") from None
    data = parse_yaml(text, label)
    is_builtin = path.parent.resolve() == _builtin_dir().resolve()
    sc = scene_from_dict(data, label=label, source_text=text,
                         path=f"builtin:{path.stem}" if is_builtin else str(path))
    logger.debug("loaded scene %r from %s (sha256 %s)", sc.name, sc.path, sc.sha256[:12])
    return sc
