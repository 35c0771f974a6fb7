"""The SDEA's velocity-sourced impedance control with a virtual coupler (paper 002): the coupler
``k22``, ``b22`` between the device and a virtual environment; trapezoidal integration."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BeforeValidator, Field, model_validator
from pydantic_core import PydanticCustomError

from hil.controllers.base import ControllerConfig, Measurements, _field, _joint
from hil.errors import SceneError
from hil.protocols.base import WrenchSample
from hil.schema import (
    DampNonneg,
    FieldError,
    Fraction,
    Name,
    SceneView,
    StiffNonneg,
    StrictModel,
    number,
    validate,
)

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
