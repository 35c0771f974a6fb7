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

Modules: :mod:`~hil.controllers.base` (the :class:`Controller` protocol, the config base, gain
matrices, ``none``), one module per controller family (:mod:`~hil.controllers.position_pd`:
``pd_position_position`` and ``dual_master``; :mod:`~hil.controllers.mcet`; :mod:`~hil.controllers.vsic`);
the registry and :func:`make_controller` are here.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Literal, TypeAlias

from hil.controllers.base import Controller, ControllerConfig, Measurements, NoController, NullController, gain_matrix
from hil.controllers.mcet import FourChannelMCET, Mcet, McetForceAxes, McetForceSensors, mcet_controller
from hil.controllers.position_pd import (
    DualMaster,
    MasterMap,
    PdGain,
    PdPositionPosition,
    PositionPD,
    dual_master_controller,
    pd_position_position,
)
from hil.controllers.vsic import VSIC, Vsic, VsicEnvironment, virtual_environment, vsic_controller
from hil.errors import SceneError
from hil.plugins import load_group
from hil.schema import register_tagged, validate

logger = logging.getLogger(__name__)


__all__ = [
    "CONTROLLER_TYPES",
    "VSIC",
    "Controller",
    "ControllerConfig",
    "ControllerType",
    "DualMaster",
    "FourChannelMCET",
    "MasterMap",
    "Mcet",
    "McetForceAxes",
    "McetForceSensors",
    "Measurements",
    "NoController",
    "NullController",
    "PdGain",
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
    "virtual_environment",
    "vsic_controller",
]


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
