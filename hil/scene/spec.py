"""Scene files: what a run talks to (devices), what it simulates, how it is controlled and excited.

A scene is pure data (YAML), never code. See docs/RUNNER_SPEC.md for the format. Each block's
schema (pydantic, ``extra="forbid"`` everywhere, built on :mod:`hil.schema`) lives next to the code
that uses it: devices, simulation, network, safety and certification here; each experiment type in
:mod:`hil.experiments` and each controller in :mod:`hil.controllers`, whose registries
(``EXPERIMENT_TYPES``, ``CONTROLLER_TYPES``: type name -> schema, implementation) this module
composes into the discriminated unions of ``experiments[]`` and ``controller``.

* :func:`load_scene` takes a YAML path or the name of a built-in scene (``hil/scene/builtin/<name>.yaml``,
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

Loading is three steps: validation (every field, by the schemas), normalization (a model
validator, ``Scene._final_values``: each block's final values, e.g. the controller's gains as full
``dof x dof`` matrices; :meth:`hil.controllers.ControllerConfig.normalized`), then pure checks
(:func:`hil.scene.checks.cross_check` and the blocks' ``check_scene``, then every experiment and the controller
built once). The validated models go to the implementations as they are:
``hil.controllers.make_controller(scene.controller, units=scene.units, scene=scene)`` and
``hil.experiments.make_experiment(exp, rate_hz=scene.rate_hz)`` for ``exp`` in
:meth:`Scene.experiment_models`; nothing validates a dict twice.

Additions to the spec (documented in each model): ``devices[].axes`` (wrench components of a
force sensor that correspond to the body DOFs), ``devices[].sim`` options, ``experiments[].controller``
(``none`` runs that experiment open loop, e.g. identification chirps), ``variant`` on static holds
and multisines, ``human`` may be a list (one per port).
"""

from __future__ import annotations

import difflib
import hashlib
import logging
from collections.abc import Sequence
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, Union

from pydantic import (
    BeforeValidator,
    Field,
    PrivateAttr,
    ValidationError,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError

from hil.controllers import (
    DEFAULT_UNITS,
    ControllerConfig,
    DualMaster,
    MasterMap,
    Mcet,
    NoController,
    PdGain,
    PdPositionPosition,
    Units,
    Vsic,
    VsicEnvironment,
    controller_schemas,
)
from hil.errors import SceneError
from hil.experiments import (
    ChirpExperiment,
    EnergyInjectionExperiment,
    ExperimentConfig,
    ForceProfileCfg,
    MultisineExperiment,
    StaticHoldExperiment,
    experiment_schemas,
)
from hil.inputs import SEED_MAX, DuplicateKeyError, unique_key_loader
from hil.inputs import parse_yaml as _parse_yaml
from hil.schema import (
    CriterionName,
    DampMat,
    DampNonneg,
    DofList,
    FieldError,
    MassMat,
    MassPos,
    Name,
    Number,
    Position,
    Probability,
    Seed,
    StiffMat,
    StiffPos,
    StrictModel,
    as_matrix,
    format_validation_error,
    matrix_shape,
    near,
    number,
    unknown_key_message,
)

__all__ = [
    "DEFAULT_UNITS",
    "ChirpExperiment",
    "Device",
    "DualMaster",
    "DuplicateKeyError",
    "EnergyInjectionExperiment",
    "ExperimentConfig",
    "ForceProfileCfg",
    "MasterMap",
    "Mcet",
    "MultisineExperiment",
    "NoController",
    "PdGain",
    "PdPositionPosition",
    "Scene",
    "Simulation",
    "StaticHoldExperiment",
    "Vsic",
    "VsicEnvironment",
    "as_matrix",
    "builtin_scenes",
    "check_seed",
    "load_scene",
    "parse_yaml",
    "refresh_schema",
    "scene_from_dict",
    "unique_key_loader",
    "unknown_key_message",
]

logger = logging.getLogger(__name__)

_BUILTIN_PACKAGE = "hil.scene"
_BUILTIN_DIR = "builtin"

_Strict = StrictModel
_number = number
_shape = matrix_shape
_near = near


def check_seed(value: Any, what: str = "--seed") -> int:
    """``value`` as a seed, or :class:`SceneError` ``what: expected an integer seed in [0, 2**32-1]``
    (for seeds given outside a scene file, e.g. ``hil run --seed``)."""
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= SEED_MAX:
        raise SceneError(f"{what}: expected an integer seed in [0, 2**32-1], got {value!r}")
    return int(value)



# ---------------------------------------------------------------------------------------------
# devices
# ---------------------------------------------------------------------------------------------


class FrictionCfg(_Strict):
    """Friction a simulated actuator adds to the body DOFs it drives (:mod:`hil.mocks.friction`):
    ``coulomb`` F_c (N or N.m), ``static`` F_s >= F_c (breakaway level; default F_c), ``stribeck_velocity``
    v_s (m/s or rad/s; needed when static > coulomb: sliding friction F_c + (F_s - F_c) exp(-(v/v_s)^2)),
    ``viscous`` (N.s/m or N.m.s/rad, added to the body's B). A given block replaces the device kind's
    default (docs/guide/friction-twins.md) as a whole."""

    coulomb: Annotated[float, BeforeValidator(lambda v: _number(v, "N or N.m")), Field(ge=0)] = 0.0
    static: Annotated[float, BeforeValidator(lambda v: _number(v, "N or N.m")), Field(ge=0)] | None = None
    stribeck_velocity: Annotated[float, BeforeValidator(lambda v: _number(v, "m/s or rad/s")),
                                 Field(gt=0)] | None = None
    viscous: Annotated[float, BeforeValidator(lambda v: _number(v, "N.s/m or N.m.s/rad")), Field(ge=0)] = 0.0

    @model_validator(mode="after")
    def _levels(self) -> FrictionCfg:
        if self.static is not None and self.static < self.coulomb:
            raise PydanticCustomError("static", "static ({s}) must be >= coulomb ({c})",
                                      {"s": self.static, "c": self.coulomb, "key": "static"})
        if self.static is not None and self.static > self.coulomb and self.stribeck_velocity is None:
            raise PydanticCustomError("stribeck_velocity", "static > coulomb needs a stribeck_velocity (m/s or "
                                      "rad/s: how fast friction falls from static to Coulomb)",
                                      {"key": "stribeck_velocity"})
        return self


class EncoderCfg(_Strict):
    """A simulated actuator's position encoder: quantization ``step`` (m or rad; 0: none) and the
    velocity the device reports (``estimate``: the joint velocity plus the scene's velocity noise;
    ``difference``: (q_k - q_(k-1)) / dt of the quantized positions, one control period apart)."""

    step: Annotated[float, BeforeValidator(lambda v: _number(v, "m or rad")), Field(ge=0)] = 0.0
    velocity: Literal["estimate", "difference"] = "estimate"


class DeviceSim(_Strict):
    """Options of a device's simulated counterpart (ignored on real hardware).

    ``seed``: seed of its fault injector and noise (default: derived from the bench seed and the
    device index). ``faults``: a :class:`hil.mocks.faults.FaultPlan` mapping. ``noise_std``:
    Gaussian noise on the device's measurement (force in N/N.m for sensors, position in m/rad for
    actuators), on top of ``simulation.sensor_noise``. ``measure`` (force sensors): ``body`` = the
    force the body exerts on everything attached (SDEA: the spring force), ``human`` = the force
    the operator's hand exerts on the device (F_h, positive along the port velocity), ``auto`` =
    ``human`` when a human holds that body, else ``body``. ``framing`` (FT-300): Modbus/TCP or RTU
    over TCP. ``friction``, ``encoder`` (actuators): see :class:`FrictionCfg`, :class:`EncoderCfg`;
    absent, the device kind's defaults (``hil.mocks.twins``, docs/guide/friction-twins.md).
    """

    seed: Seed | None = None
    faults: dict[str, Any] | None = None
    noise_std: Annotated[float, BeforeValidator(lambda v: _number(v, "N, N.m, m or rad")), Field(ge=0)] = 0.0
    measure: Literal["auto", "body", "human"] = "auto"
    framing: Literal["tcp", "rtu"] = "tcp"
    friction: FrictionCfg | None = None
    encoder: EncoderCfg | None = None

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
        for opt in ("friction", "encoder"):
            if getattr(self.sim, opt) is not None and self.role != "actuator":
                raise PydanticCustomError("sim", "sim.{opt} applies to actuators only", {"opt": opt, "key": "sim"})
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
    name: Literal["T1", "T2"]


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


def _discriminated(schemas: Sequence[type], what: str) -> Any:
    """The discriminated union (on ``type``) of the registered ``schemas`` of one kind."""
    if not schemas:
        raise RuntimeError(f"no {what} types are registered")
    return Annotated[Union[tuple(schemas)], Field(discriminator="type")]  # noqa: UP007  # built at run time


# the controller block: one of the schemas registered in hil.controllers.CONTROLLER_TYPES
if TYPE_CHECKING:
    Controller = ControllerConfig
else:
    Controller = _discriminated(controller_schemas(), "controller")


class Safety(_Strict):
    """Limits checked every tick (per DOF, SI): effort N or N.m, velocity m/s or rad/s, position
    m or rad, energy J (|E_s| at any port), watchdog ms; realtime loop: ``max_lateness_ms`` (default
    ``watchdog_ms``) and ``max_overrun_fraction`` (see :mod:`hil.run.realtime`)."""

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
# experiments: one of the schemas registered in hil.experiments.EXPERIMENT_TYPES
# ---------------------------------------------------------------------------------------------

if TYPE_CHECKING:
    Experiment = ExperimentConfig
else:
    Experiment = _discriminated(experiment_schemas(), "experiment")

# ---------------------------------------------------------------------------------------------
# certification
# ---------------------------------------------------------------------------------------------


#: identification models of :mod:`hil.identify.models` (``sdea`` is an alias of ``sdea_locked``)
IDENTIFICATION_MODELS = ("sdea_locked", "sdea_free", "mbk")


#: friction terms an identification model may add (hil.identify.api.identify_record's ``friction``)
FRICTION_TERMS = ("coulomb", "stribeck", "offset")
#: the parameters each friction term adds (hil.identify.friction.PARAMETERS; ``stribeck`` implies ``coulomb``)
FRICTION_PARAMETERS = {"coulomb": ("F_c",), "stribeck": ("F_c", "F_s", "v_s"), "offset": ("F_0",)}
#: every friction parameter name: identified, shown, never fed to the network model (not a damping)
FRICTION_NAMES = frozenset(p for ps in FRICTION_PARAMETERS.values() for p in ps)


def is_friction_name(name: str) -> bool:
    """A dry-friction parameter: one of :data:`FRICTION_NAMES`, or one with a joint index (``F_c_0``,
    ``F_0_1``: the multi-DOF ``mbk`` model with friction, :mod:`hil.identify.inverse_models`)."""
    base, _, idx = name.rpartition("_")
    return name in FRICTION_NAMES or (idx.isdigit() and base in FRICTION_NAMES)


def _friction_terms(v: Any) -> Any:
    if isinstance(v, str):  # "coulomb,offset" as on the command line
        v = [t.strip() for t in v.split(",") if t.strip()]
    if not isinstance(v, list):
        raise PydanticCustomError("friction", "expected a list of friction terms from {terms}, got {got}",
                                  {"terms": ", ".join(FRICTION_TERMS), "got": v})
    for t in v:
        if t not in FRICTION_TERMS:
            raise PydanticCustomError("friction", "unknown friction term '{got}'; expected some of {terms}",
                                      {"got": t, "terms": ", ".join(FRICTION_TERMS)})
    if len(set(v)) != len(v):
        raise PydanticCustomError("friction", "friction term listed twice in {v}", {"v": v})
    return v


class IdentifyCfg(_Strict):
    """Identify plant parameters from an experiment's record: ``experiment`` names a chirp or
    multisine of ``experiments``; ``model`` one of :data:`IDENTIFICATION_MODELS` (default: inferred
    as ``hil identify`` does); ``friction`` the friction terms the model adds on its actuated DOFs
    (:data:`FRICTION_TERMS`; empty: linear model; the certificate counts only the viscous B as
    damping, docs/CERTIFICATION.md "Friction"); ``output`` the measured output of a 1-DOF ``mbk``
    model (``position``: the encoder's, velocity derived inside identification; default: the
    identification's, velocity for the linear model, position with friction); ``map`` renames
    identified parameters to the network model's (e.g. ``{M: M, B: B, K_f: K_f, B_f: B_f}``; empty:
    every identified parameter under its own name, dry friction excepted). Checked at load time
    against both models (see :func:`_check_certification`)."""

    experiment: Name
    model: str | None = None
    friction: Annotated[list[str], BeforeValidator(_friction_terms)] = Field(default_factory=list)
    output: Literal["position", "velocity"] | None = None
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


class PolicyCfg(_Strict):
    """The verdict policy (:class:`hil.certify.statistics.Policy`): probabilities strictly inside (0, 1)."""

    required_probability: Probability = 0.95
    confidence: Probability = 0.95
    credible: Probability = 0.90


class CertificationCfg(_Strict):
    """What ``hil certify`` checks: the network model (a built-in model of ``hil.models``), its
    fixed parameters (controller gains, ...), the parameters identified from experiments or known
    only with an uncertainty, the criterion, a design parameter and the verdict policy."""

    model: str
    criterion: CriterionName = "auto"
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
    units: Units = DEFAULT_UNITS
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

    def require(self, path: str, name: str, role: str | None = None) -> Device:
        """The device (or group) ``name`` referenced at scene field ``path``, of ``role`` when given;
        else :class:`hil.schema.FieldError` ``path: unknown device 'x' (did you mean 'y'?)``."""
        try:
            d = self.device(name)
        except KeyError:
            known = [d.name for d in self.devices] + [g.name for g in self.groups]
            raise FieldError(path, f"unknown device {name!r}{near(name, known)}") from None
        if role is not None and d.role != role:
            raise FieldError(path, f"device {name!r} is a {d.role}, expected a {role}")
        return d

    def controller_config(self) -> dict[str, Any]:
        """``controller`` as a plain dict (its final values: gains as full matrices)."""
        return self.controller.model_dump()

    def experiment_models(self) -> list[ExperimentConfig]:
        """``experiments`` with ``name`` filled (the type, or ``<type>_<n>`` when several of one
        type are unnamed): what ``hil.experiments.make_experiment`` builds and the runner runs."""
        return [e if e.name else e.model_copy(update={"name": _default_exp_name(self.experiments, i)})
                for i, e in enumerate(self.experiments)]

    def experiment_configs(self) -> list[dict[str, Any]]:
        """:meth:`experiment_models` as plain dicts (as stored in a record's ``meta.experiment``)."""
        return [e.model_dump() for e in self.experiment_models()]

    @model_validator(mode="after")
    def _final_values(self) -> Scene:
        """Normalization (not a check): each block's final values for this scene, e.g. the
        controller's gains expanded to full ``dof x dof`` matrices of the devices they act on
        (:meth:`hil.controllers.ControllerConfig.normalized`). The checks (:func:`hil.scene.checks.cross_check`)
        run afterwards and change nothing."""
        self.__dict__.pop("_device_cache", None)
        self.controller = self.controller.normalized(self)
        self.__dict__.pop("_device_cache", None)  # groups are checked later: look them up afresh
        return self


def refresh_schema() -> None:
    """Recompose :class:`Scene`'s ``experiments`` and ``controller`` unions from the registries of
    :mod:`hil.experiments` and :mod:`hil.controllers` (they are composed when this module is
    imported; call this after registering a type later)."""
    fields = Scene.model_fields
    # unions built at run time: typed Any (a type checker sees the registries' base classes)
    union: Any = _discriminated(experiment_schemas(), "experiment")
    fields["experiments"].annotation = list[union]
    assert fields["controller"].discriminator == "type"
    members: Any = Union[tuple(controller_schemas())]  # noqa: UP007
    fields["controller"].annotation = members
    Scene.model_rebuild(force=True)
    logger.debug("scene schema: experiments %s, controllers %s", [c.__name__ for c in experiment_schemas()],
                 [c.__name__ for c in controller_schemas()])


def _default_exp_name(exps: Sequence[Any], i: int) -> str:
    t = exps[i].type
    same = [k for k, e in enumerate(exps) if e.type == t and e.name is None]
    return t if len(same) == 1 else f"{t}_{same.index(i) + 1}"


# ---------------------------------------------------------------------------------------------
# loading and error formatting
# ---------------------------------------------------------------------------------------------


#: the most ticks one experiment may last (duration × rate_hz): 5·10⁷ is 6.9 h at 2 kHz; its signal
#: and its record's channels are arrays of that length (400 MB per float64 channel), so a longer one
#: is refused at load time, naming the field and the size, instead of failing to allocate later
MAX_EXPERIMENT_TICKS = 50_000_000


def _check_length(i: int, cfg: Any, rate_hz: float) -> None:
    """Refuse an experiment longer than :data:`MAX_EXPERIMENT_TICKS` (one line naming the field)."""
    duration = float(getattr(cfg, "duration", 0.0) or 0.0) + float(getattr(cfg, "settle", 0.0) or 0.0)
    ticks = duration * float(rate_hz)
    if ticks > MAX_EXPERIMENT_TICKS:
        gib = ticks * 8 / 2**30
        raise FieldError(f"experiments[{i}].duration", f"{duration:g} s at {rate_hz:g} Hz is {ticks:.3g} ticks, "
                         f"{gib:.3g} GiB per float64 channel; an experiment may last at most "
                         f"{MAX_EXPERIMENT_TICKS:.3g} ticks ({MAX_EXPERIMENT_TICKS / rate_hz / 3600:.3g} h at "
                         f"{rate_hz:g} Hz)")


def _check_blocks(sc: Scene) -> None:
    """Build every experiment and the controller as the runner will (``make_experiment`` +
    ``check(scene)``, ``make_controller``), so their checks (band against the rate, peak effort
    against ``safety.max_effort``, a human for energy injection, ...) fail at load time, not after
    the experiments before them have run."""
    from hil.controllers import make_controller
    from hil.experiments import make_experiment

    tick_ms = 1000.0 / sc.rate_hz
    if sc.safety.watchdog_ms < tick_ms:  # a sample is at least one tick old when read: never fresh enough
        raise FieldError("safety.watchdog_ms", f"{sc.safety.watchdog_ms:g} ms is shorter than one tick "
                         f"({tick_ms:.4g} ms at {sc.rate_hz:g} Hz): every sample would be stale; give at least "
                         f"{tick_ms:.4g} ms")
    for i, cfg in enumerate(sc.experiment_models()):
        _check_length(i, cfg, sc.rate_hz)  # before anything is built: an experiment's signals are arrays
        make_experiment(cfg, rate_hz=sc.rate_hz).check(sc)
    make_controller(sc.controller, units=sc.units, scene=sc)


def parse_yaml(text: str, label: str) -> Any:
    """Parse scene YAML ``text`` (safe, duplicate keys refused at any depth); any problem is one
    :class:`SceneError` line ``label: ...`` (see :func:`hil.inputs.parse_yaml`)."""
    return _parse_yaml(text, label, SceneError)


def _builtin_dir() -> Path:
    return Path(str(resources.files(_BUILTIN_PACKAGE).joinpath(_BUILTIN_DIR)))


def builtin_scenes() -> list[tuple[str, str]]:
    """``(name, description)`` of every built-in scene, sorted by name."""
    import yaml  # type: ignore[import-untyped]  # no types-PyYAML in the environment

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
        raise SceneError(f"{label}: {format_validation_error(exc, data)}") from None
    try:
        from hil.scene.checks import cross_check  # (it imports this module's schema)

        cross_check(sc)
    except FieldError as w:
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


#: the largest scene file read: the built-in scenes are 2-5 kB; a megabyte of YAML (a pasted data
#: set under a mistyped key) would only be parsed to be refused
SCENE_MAX_BYTES = 1024 * 1024


def load_scene(src: str | Path) -> Scene:
    """Load and validate a scene from a YAML path or a built-in scene name.

    Raises :class:`SceneError` with one line ``file: field: message`` on any problem (a duplicate
    key, at any depth, is one).
    """
    path, label = _resolve(src)
    from hil.inputs import read_text_file

    # size-limited (a scene is a few kB: SCENE_MAX_BYTES), NUL bytes and non-UTF-8 refused in one line
    try:
        text = read_text_file(path, "scene", SceneError, max_bytes=SCENE_MAX_BYTES)
    except SceneError as exc:
        raise SceneError(f"{label}: cannot read: {str(exc).removeprefix(f'{path}: ')}") from None
    data = parse_yaml(text, label)
    is_builtin = path.parent.resolve() == _builtin_dir().resolve()
    sc = scene_from_dict(data, label=label, source_text=text,
                         path=f"builtin:{path.stem}" if is_builtin else str(path))
    logger.debug("loaded scene %r from %s (sha256 %s)", sc.name, sc.path, sc.sha256[:12])
    return sc
