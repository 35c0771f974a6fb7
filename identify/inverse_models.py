"""Plant models with friction on their actuated joints, in the form the inverse-dynamics estimator
(:mod:`hil.identify.inverse_ml`) needs: equations linear in the parameters given the measured motion.

A model (:class:`InverseDynamicsModel`) has measured *coordinates* (positions [m or rad], e.g. the
joints of an ``mbk`` device, or the motor and the output of an SDEA) and *equations*, each a force
balance ``y_e = sum_p theta_p X_e,p`` whose left side ``y_e`` is (:class:`Equation`)

* ``"input"``: an actuator force held over each sample period (the bench's zero-order hold);
* ``"measured"``: a force sampled at the instants (a force sensor: the SDEA's spring torque);
* ``"zero"``: nothing (a body without actuator: the free SDEA's output).

The regressors come from the filtered measured positions (:class:`hil.identify.idim.Motion`: averaged
columns for held forces, point columns for sampled ones). Friction acts on the *joints*
(:class:`Joint`: a coordinate, the equation its force enters, a name suffix) with the terms of
:func:`normalize_friction`::

    F_f,j = B_j v_j + (F_c,j + F_s,j exp(-(v_j/v_s,j)^2)) sgn(v_j) + F_0,j

(the viscous part is in the model's own damping parameters). Parameter names: ``F_c``, ``F_s``,
``v_s``, ``F_0`` for a model with one friction joint, ``F_c_0``, ``F_c_1``, ... (the joint's index, as
the multi-DOF model's channels ``force_0``, ``position_0``) for several; units from :data:`PARAMETERS`.

SDEA (:class:`SdeaFrictionModel`, paper 002's series damped elastic actuator, rotary): friction on the
motor, the spring ``K_f`` and damper ``B_f`` to the output. Locked output (``x_e = 0``)::

    tau = M x'' + B x' + K_f x + B_f x' + F_f(x')        (motor; held torque)
    F   = K_f x + B_f x'                                  (spring torque, when measured)

Without the spring torque ``B`` and ``B_f`` enter only as ``B + B_f``: the model refuses
(:class:`NotIdentifiableError`). Free output of inertia ``m_h`` (angle ``x_2``, deflection ``d = x - x_2``)::

    tau = M x'' + B x' + K_f d + B_f d' + F_f(x')         (motor; held torque)
    0   = m_h x_2'' - K_f d - B_f d'                      (output body)
    F   = K_f d + B_f d'                                  (spring torque, when measured)

which needs the output's motion (an output encoder; ``output_position`` or ``output_velocity``).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from hil.identify.errors import ModelSpecError, NotIdentifiableError
from hil.identify.models import SDEA_NOMINAL, GreyBoxModel, Parameter

if TYPE_CHECKING:
    from hil.identify.idim import Motion

logger = logging.getLogger(__name__)

__all__ = ["FRICTION_TERMS", "PARAMETERS", "Equation", "InverseDynamicsModel", "Joint", "SdeaFrictionModel",
           "friction_names", "normalize_friction"]

#: selectable friction terms (the viscous term ``B`` is always in the model)
FRICTION_TERMS = ("coulomb", "stribeck", "offset")

#: name -> (linear unit, rotary unit, description)
PARAMETERS: dict[str, tuple[str, str, str]] = {
    "M": ("kg", "kg.m^2", "mass (inertia)"),
    "B": ("N.s/m", "N.m.s/rad", "viscous damping"),
    "K": ("N/m", "N.m/rad", "stiffness"),
    "F_c": ("N", "N.m", "Coulomb friction level"),
    "F_s": ("N", "N.m", "Stribeck excess at rest (break-away force F_c + F_s)"),
    "v_s": ("m/s", "rad/s", "Stribeck velocity"),
    "F_0": ("N", "N.m", "constant force offset (inverse model u = M a + F(v) + F_0)"),
}

_TERM_PARAMETERS = (("coulomb", ("F_c",)), ("stribeck", ("F_s", "v_s")), ("offset", ("F_0",)))


def normalize_friction(spec: str | Iterable[str] | None) -> tuple[str, ...]:
    """The friction terms as a canonical tuple (order of :data:`FRICTION_TERMS`): ``"coulomb,offset"``,
    ``["stribeck"]`` (-> coulomb + stribeck), ``None``/``""``/``"none"``/``()`` -> ``()`` (linear).
    Raises :class:`ModelSpecError` naming an unknown term."""
    if spec is None:
        return ()
    items = spec.split(",") if isinstance(spec, str) else list(spec)
    terms = {str(s).strip().lower() for s in items} - {"", "none", "linear", "viscous"}
    unknown = sorted(terms - set(FRICTION_TERMS))
    if unknown:
        raise ModelSpecError(f"unknown friction term(s) {unknown}; known: {', '.join(FRICTION_TERMS)} "
                             "(the viscous term B is always included)")
    if "stribeck" in terms:
        terms.add("coulomb")
    return tuple(t for t in FRICTION_TERMS if t in terms)


def friction_names(terms: Sequence[str], suffix: str = "") -> tuple[str, ...]:
    """Friction parameter names of one joint (``F_c``, ``F_s``, ``v_s``, ``F_0`` present in ``terms``),
    each followed by ``suffix`` (``""`` or ``"_<joint>"``)."""
    return tuple(n + suffix for t, names in _TERM_PARAMETERS if t in terms for n in names)


@dataclass(frozen=True)
class Equation:
    """One force balance: its ``name`` (the left side's channel) and ``lhs`` (``"input"``, ``"measured"``
    or ``"zero"``; module docstring)."""

    name: str
    lhs: str


@dataclass(frozen=True)
class Joint:
    """A joint with friction: the ``coordinate`` whose velocity the friction law reads, the ``equation``
    its force enters and the ``suffix`` of its parameter names."""

    coordinate: int
    equation: int
    suffix: str = ""


def model_parameter(name: str, kind: str, unit: str, description: str, nominal: float, *, span: float,
                    scale: float) -> Parameter:
    """A parameter with bounds from its nominal (data-derived) value. ``kind``: ``"positive"`` (log,
    ``nominal / span .. nominal * span``), ``"level"`` (a friction level ``F_c``/``F_s``: log, from
    ``1e-6 scale`` up to ``max(nominal span, 2 scale)``), ``"free"`` (any sign, ``+-max(span |nominal|,
    scale)``) or ``"offset"`` (``F_0``: ``+-max(scale, 2 |nominal|)``); ``scale`` [the parameter's unit]
    sets the free ranges (for friction: the force scale)."""
    v = float(nominal)
    if kind == "positive":
        if not v > 0:
            raise ModelSpecError(f"nominal {name} must be positive, got {v}")
        return Parameter(name, unit, v / span, v * span, v, True, description)
    if kind == "level":
        v = max(v, 1e-6 * scale)
        return Parameter(name, unit, min(1e-6 * scale, v / span), max(v * span, 2 * scale), v, True, description)
    lim = max(scale, 2 * abs(v)) if kind == "offset" else max(span * abs(v), scale, 1e-300)
    return Parameter(name, unit, -lim, lim, v, False, description)


class InverseDynamicsModel(GreyBoxModel):
    """Base of the models of the module docstring. Subclasses set ``coordinates``, ``equations``,
    ``joints``, ``terms``, ``units_kind`` and implement :meth:`structural_columns`; the friction
    columns and the parameter bookkeeping are here."""

    coordinates: tuple[str, ...] = ()
    equations: tuple[Equation, ...] = ()
    joints: tuple[Joint, ...] = ()
    terms: tuple[str, ...] = ()
    units_kind: str = "linear"

    @property
    def friction(self) -> tuple[str, ...]:
        return self.terms

    def friction_parameters(self, nominal: dict[str, float], span: float, force_scale: float) -> list[Parameter]:
        """The friction parameters of every joint (:func:`friction_names`), bounds from ``nominal``."""
        col = 0 if self.units_kind == "linear" else 1
        out = []
        for jt in self.joints:
            for base in friction_names(self.terms):
                name = base + jt.suffix
                unit, desc = PARAMETERS[base][col], PARAMETERS[base][2]
                kind = {"F_0": "offset", "v_s": "positive"}.get(base, "level")
                default = {"F_c": 1.0, "F_s": 0.5, "v_s": 0.01, "F_0": 0.0}[base]
                out.append(model_parameter(name, kind, unit, desc, nominal.get(name, default), span=span,
                                           scale=force_scale))
        return out

    def structural_columns(self, m: Motion) -> list[tuple[int, int, NDArray]]:
        """``(parameter index, equation, full-length column)`` of the non-friction parameters."""
        raise NotImplementedError

    def columns(self, m: Motion) -> list[tuple[int, int, NDArray]]:
        """Every column that does not depend on a Stribeck velocity (the Stribeck ones:
        :meth:`stribeck_column`), as :meth:`structural_columns`."""
        out = list(self.structural_columns(m))
        idx = {n: i for i, n in enumerate(self.names)}
        for jt in self.joints:
            kind = self.equations[jt.equation].lhs
            if "coulomb" in self.terms:
                out.append((idx["F_c" + jt.suffix], jt.equation, m.friction(jt.coordinate, np.sign, kind)))
            if "offset" in self.terms:
                out.append((idx["F_0" + jt.suffix], jt.equation, m.offset(jt.coordinate, kind)))
        return out

    def stick_joints(self) -> tuple[Joint, ...]:
        """The joints whose stuck periods are left out of their equation
        (:func:`hil.identify.idim.stuck_periods`): those whose equation balances a held force against
        their own motion only, so that while stuck the equation is exactly ``u = f`` (none here)."""
        return ()

    def held_input(self, theta: NDArray[np.float64], Y: NDArray[np.float64]
                   ) -> tuple[NDArray[np.float64], list[float], list[float]] | None:
        """The acceleration jumps a held force makes (:meth:`hil.identify.idim.Motion.set_held_input`) at
        parameters ``theta`` for the left sides ``Y`` (n, n_e) of a record: ``(node_jumps (n, n_c),
        kinks (n_c,), damping_rates (n_c,))``, or None (the default: the point kinematics are taken as
        smooth; the models whose equations are all held forces use averaged columns, which need no jumps)."""
        return None

    def stribeck(self) -> list[tuple[int, int, Joint]]:
        """``(index of F_s, index of v_s, joint)`` per joint with a Stribeck term."""
        if "stribeck" not in self.terms:
            return []
        idx = {n: i for i, n in enumerate(self.names)}
        return [(idx["F_s" + jt.suffix], idx["v_s" + jt.suffix], jt) for jt in self.joints]

    def stribeck_column(self, m: Motion, joint: Joint, v_s: float) -> NDArray:
        """The column of ``F_s`` of ``joint`` at Stribeck velocity ``v_s``: ``exp(-(v/v_s)^2) sgn(v)``."""
        return m.friction(joint.coordinate, lambda v: np.exp(-((v / v_s) ** 2)) * np.sign(v),
                          self.equations[joint.equation].lhs)

    def omitted_columns(self, m: Motion, missing: Sequence[str]) -> list[tuple[int, NDArray]]:
        """``(equation, column)`` of the friction terms ``missing`` (``coulomb``, ``offset``) per joint: the
        directions of the omitted-friction score test."""
        out = []
        for jt in self.joints:
            kind = self.equations[jt.equation].lhs
            if "coulomb" in missing:
                out.append((jt.equation, m.friction(jt.coordinate, np.sign, kind)))
            if "offset" in missing:
                out.append((jt.equation, m.offset(jt.coordinate, kind)))
        return out


_SDEA_UNITS = {"K_f": ("N.m/rad", "series spring stiffness"),
               "B_f": ("N.m.s/rad", "series (parallel-to-spring) damping"),
               "M": ("kg.m^2", "motor inertia"), "B": ("N.m.s/rad", "motor viscous damping"),
               "m_h": ("kg.m^2", "output-side (handle) inertia")}


class SdeaFrictionModel(InverseDynamicsModel):
    """The SDEA with friction on the motor (module docstring). ``variant``: ``"locked"`` or ``"free"``;
    ``force``: the spring torque is measured (an equation of its own); ``nominal``: data-derived values
    (default: paper 002 Table I); rotary units. Parameters ``K_f, B_f, M, B`` (+ ``m_h`` free), then the
    motor's ``F_c``, ``F_s``, ``v_s``, ``F_0``. Input ``torque``, outputs the measured coordinates and
    the spring torque."""

    def __init__(self, variant: str = "locked", friction: Sequence[str] = ("coulomb",), *, force: bool = True,
                 nominal: dict[str, float] | None = None, span: float = 100.0, force_scale: float | None = None,
                 zoh_fs: float = 2000.0) -> None:
        if variant not in ("locked", "free"):
            raise ModelSpecError(f"SDEA variant must be 'locked' or 'free', got {variant!r}")
        self.variant = variant
        self.name = f"sdea_{variant}"
        self.terms = normalize_friction(friction)
        self.units_kind = "rotary"
        self.has_force = bool(force)
        if variant == "locked" and not force:
            raise NotIdentifiableError(
                "sdea_locked with friction: B and B_f enter the motor equation only as B + B_f; measure the spring "
                "torque (--output force=SIGNAL) to separate them")
        nom = {**SDEA_NOMINAL, "m_h": 2e-3, **(nominal or {})}
        fscale = float(force_scale) if force_scale else max(abs(nom.get("F_c", 0.0)) * 10, 1e-3)
        names = ("K_f", "B_f", "M", "B") + (("m_h",) if variant == "free" else ())
        core = [model_parameter(n, "positive", _SDEA_UNITS[n][0], _SDEA_UNITS[n][1], abs(nom[n]) or 1.0, span=span,
                                scale=1.0) for n in names]
        self.coordinates = ("position",) if variant == "locked" else ("position", "output_position")
        eqs = [Equation("torque", "input")]
        if variant == "free":
            eqs.append(Equation("output", "zero"))
        if force:
            eqs.append(Equation("force", "measured"))
        self.equations = tuple(eqs)
        self.joints = (Joint(0, 0, ""),)
        core += self.friction_parameters(nom, span=30.0, force_scale=fscale)
        super().__init__(core, ("torque",), self.coordinates + (("force",) if force else ()), zoh_fs=zoh_fs)

    def structural_columns(self, m: Motion) -> list[tuple[int, int, NDArray]]:
        idx = {n: i for i, n in enumerate(self.names)}
        out: list[tuple[int, int, NDArray]] = []
        for e, eq in enumerate(self.equations):
            k = eq.lhs
            if self.variant == "locked":
                d, dv = m.q(0, k), m.v(0, k)
            else:
                d, dv = m.q(0, k) - m.q(1, k), m.v(0, k) - m.v(1, k)
            sgn = -1.0 if eq.name == "output" else 1.0
            out += [(idx["K_f"], e, sgn * d), (idx["B_f"], e, sgn * dv)]
            if eq.name == "torque":
                out += [(idx["M"], e, m.a(0, k)), (idx["B"], e, m.v(0, k))]
            elif eq.name == "output":
                out.append((idx["m_h"], e, m.a(1, k)))
        return out

    def held_input(self, theta: NDArray[np.float64], Y: NDArray[np.float64]
                   ) -> tuple[NDArray[np.float64], list[float], list[float]] | None:
        """The held motor torque ``tau_k`` (the ``torque`` equation's left side) steps the motor's
        acceleration by ``(tau_k - tau_k-1) / M`` at every sample instant; a motor reversal steps it by
        ``-2 (F_c + F_s) / M`` per unit of the new sign, and each step of the acceleration steps its derivative
        by ``-(B + B_f) / M`` times it (the damping forces follow the velocity); the output's acceleration
        is continuous (the spring and damper forces are). Used for the point columns of the spring-torque
        and output equations and the motor's velocity between samples (:mod:`hil.identify.held_kinematics`)."""
        idx = {n: i for i, n in enumerate(self.names)}
        M = float(theta[idx["M"]])
        if not (np.isfinite(M) and M > 0):
            return None
        tau = np.asarray(Y, float)[:, 0]
        jumps = np.zeros((tau.size, len(self.coordinates)))
        jumps[1:, 0] = np.diff(tau) / M
        brk = sum(max(float(theta[idx[k]]), 0.0) for k in ("F_c", "F_s") if k in idx)
        kinks = [-2.0 * brk / M] + [0.0] * (len(self.coordinates) - 1)
        damping = max(float(theta[idx["B"]]), 0.0) + max(float(theta[idx["B_f"]]), 0.0)
        return jumps, kinks, [damping / M] + [0.0] * (len(self.coordinates) - 1)

    def _state_space(self, theta: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                                                  NDArray[np.float64]]:
        """The viscous (linear) part, state (x, v) locked or (x, v, x_2, v_2) free; outputs the
        coordinates and the spring torque."""
        K, Bf, M, B = (theta[..., i] for i in range(4))
        sh = K.shape
        if self.variant == "locked":
            A = np.zeros((*sh, 2, 2))
            A[..., 0, 1] = 1.0
            A[..., 1, 0], A[..., 1, 1] = -K / M, -(B + Bf) / M
            Bm = np.zeros((*sh, 2, 1))
            Bm[..., 1, 0] = 1.0 / M
            C = np.zeros((*sh, len(self.output_names), 2))
            C[..., 0, 0] = 1.0
            if self.has_force:
                C[..., -1, 0], C[..., -1, 1] = K, Bf
            return A, Bm, C
        mh = theta[..., 4]
        A = np.zeros((*sh, 4, 4))
        A[..., 0, 1] = A[..., 2, 3] = 1.0
        A[..., 1, 0], A[..., 1, 1], A[..., 1, 2], A[..., 1, 3] = -K / M, -(B + Bf) / M, K / M, Bf / M
        A[..., 3, 0], A[..., 3, 1], A[..., 3, 2], A[..., 3, 3] = K / mh, Bf / mh, -K / mh, -Bf / mh
        Bm = np.zeros((*sh, 4, 1))
        Bm[..., 1, 0] = 1.0 / M
        C = np.zeros((*sh, len(self.output_names), 4))
        C[..., 0, 0] = 1.0
        C[..., 1, 2] = 1.0
        if self.has_force:
            C[..., -1, 0], C[..., -1, 1], C[..., -1, 2], C[..., -1, 3] = K, Bf, -K, -Bf
        return A, Bm, C
