"""Built-in network models from the papers, selectable by name (``hil stability --model NAME``).

A model is one registered object (:class:`BuiltinModel`, looked up with :func:`get_model`): the
builder of its network from keyword parameters (:meth:`BuiltinModel.network`), the criterion that
fits the network (a name of :func:`hil.stability.criteria.check`), the parameters it accepts with
their defaults (so the CLI can validate ``--set NAME=VALUE``), how a scene's controller and
simulation map to those parameters (:meth:`BuiltinModel.params_from_scene`), and, optionally,
vectorized evaluators of a criterion over many parameter sets and the design parameters they can
search. ``hil certify`` and ``hil sweep`` use only these: adding a model is one builder, one
scene mapping and one entry in :func:`_defaults`, with no branch on the model's name elsewhere.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hil.errors import ModelError
from hil.plugins import load_group
from hil.stability.rational import TransferMatrix

__all__ = ["BUILTIN_MODELS", "BatchCriterion", "BuiltinModel", "DesignParameter", "build_network", "get_model",
           "model_names", "model_params_from_scene"]

#: a vectorized criterion: (draws: name -> (N,) arrays, fixed: name -> value, band: bool,
#: exact_fallback: bool) -> {"passive": (N,) bool, "margin": (N,)} and, only with band=True,
#: {"worst_omega", "band_lo", "band_hi": (N,) rad/s}
#: (the signature of :func:`hil.models.batch.sdea_passivity_batch`)
BatchCriterion = Callable[..., dict[str, np.ndarray]]


@dataclass(frozen=True)
class DesignParameter:
    """A free design parameter a vectorized criterion can search (``hil certify``'s design
    stage): its unit and, optionally, its parametric headroom at a plant,
    ``headroom(current, plant params) -> (limit, limit / current − 1)``."""

    unit: str
    headroom: Callable[[float, dict[str, float]], tuple[float, float]] | None = None


@dataclass(frozen=True)
class BuiltinModel:
    """A registered network model (module docstring). ``from_scene(scene, controller config)``
    gives the parameters a scene implies; ``table``: a parameter taking a named gain set or a
    mapping of gains (whose entries may also be given at the top level); ``batch``: vectorized
    evaluators by criterion name; ``design``: the design parameters those can search;
    ``band_condition(q)``: coefficients (t0, t1, ...) in x = ω² of the normalized condition whose
    critical band the certificate plots (q: parameter arrays); ``units``: the parameters' units
    (axis labels)."""

    name: str
    description: str
    criterion: str
    defaults: dict[str, Any] = field(default_factory=dict)
    _builder: Callable[..., TransferMatrix] | None = None
    from_scene: Callable[[Any, dict[str, Any]], dict[str, Any]] | None = None
    table: str | None = None
    batch: dict[str, BatchCriterion] = field(default_factory=dict)
    design: dict[str, DesignParameter] = field(default_factory=dict)
    band_condition: Callable[[Any], Any] | None = None
    units: dict[str, str] = field(default_factory=dict)
    #: allowed values of the string parameters (e.g. the gain sets of a table)
    choices: dict[str, tuple[str, ...]] = field(default_factory=dict)

    def check_params(self, params: dict[str, Any], *, allow_unknown: bool = False) -> None:
        """Refuse unknown names (unless ``allow_unknown``: builders such as ``mbk_impedance`` take
        more than their defaults list) and values of the wrong kind with a one-line
        :class:`ModelError` naming the parameter: a parameter whose default is a string (a gain-set
        name) takes a string, every other one a finite real number (not a boolean)."""
        for k, v in params.items():
            if k not in self.defaults and not allow_unknown:
                raise ModelError(f"model {self.name} has no parameter {k!r}")
            d = self.defaults.get(k)
            if isinstance(d, str):
                if not isinstance(v, str):
                    raise ModelError(f"model {self.name}: parameter {k} must be a name, got {v!r}")
                choices = self.choices.get(k)
                if choices is not None and v not in choices:
                    raise ModelError(f"model {self.name}: {k} must be one of {', '.join(choices)}, got {v!r}")
            elif isinstance(v, bool | np.bool_) or not isinstance(v, numbers.Real):
                raise ModelError(f"model {self.name}: parameter {k} must be a number, got {v!r}")
            elif not math.isfinite(v):
                raise ModelError(f"model {self.name}: parameter {k} must be finite, got {float(v)!r}")

    def build(self, **params: Any) -> TransferMatrix:
        assert self._builder is not None
        table = params.get(self.table) if self.table is not None else None
        if isinstance(table, Mapping):  # a gain table: checked by the builder
            rest = {k: v for k, v in params.items() if k != self.table}
            self.check_params(rest, allow_unknown=True)
        else:
            self.check_params(params, allow_unknown=True)
        return self._builder(**params)

    def network(self, params: Mapping[str, Any]) -> TransferMatrix:
        """The network with ``params``; a gain table (``table``: a mapping, as a scene's
        controller gives it) takes any of its entries given at the top level too (``k_pmyz=...``:
        a swept or overridden gain)."""
        q = dict(params)
        if self.table is not None:
            gains = q.get(self.table)
            if isinstance(gains, Mapping):
                q[self.table] = {**gains, **{k: q.pop(k) for k in list(q) if k in gains}}
        return self.build(**q)

    def params_from_scene(self, scene: Any) -> dict[str, Any]:
        """The parameters ``scene``'s controller and simulation imply (empty when the model has
        no scene mapping or the scene's controller is not the one it describes); the caller adds
        ``certification.parameters`` on top."""
        if self.from_scene is None:
            return {}
        return self.from_scene(scene, scene.controller_config())

    def vectorized(self, criterion: str) -> BatchCriterion | None:
        """The vectorized evaluator of ``criterion`` for this model, or None (then each
        parameter set goes through the exact criterion)."""
        return self.batch.get(criterion)


def _sdea_batch(*args: Any, **kw: Any) -> dict[str, np.ndarray]:
    from hil.models.batch import sdea_passivity_batch

    return sdea_passivity_batch(*args, **kw)


def _k22_headroom(current: float, plant: dict[str, float]) -> tuple[float, float]:
    """k22's parametric headroom under passivity at ``plant`` (Table I for what it lacks)."""
    from hil.models.design import k22_headroom
    from hil.models.sdea import SDEA_TABLE1

    base = {**SDEA_TABLE1, **plant}
    return k22_headroom(current, base["b22"], base["alpha"], "passivity", plant)


def _sdea_coupler_condition(q: Any) -> Any:
    from hil.models.sdea import sdea_polynomials

    return sdea_polynomials(q)["t"]


def _sdea(**p: Any) -> TransferMatrix:
    from hil.models.sdea import sdea_vsic

    return sdea_vsic(p)


def _mcet(**p: Any) -> TransferMatrix:
    from hil.models.teleop import mcet_trilateral

    return mcet_trilateral(p)


def _bilateral(gains: str = "A1", **p: Any) -> TransferMatrix:
    from hil.models.teleop import bilateral_2dof

    return bilateral_2dof(gains, **p)


def _bilateral1(**p: Any) -> TransferMatrix:
    from hil.models.teleop import bilateral_1dof

    return bilateral_1dof(p)


def _mbk(**p: Any) -> TransferMatrix:
    from hil.models.teleop import mbk_impedance

    return mbk_impedance(p)


def _dual(**p: Any) -> TransferMatrix:
    from hil.models.teleop import dual_master_3dof

    return dual_master_3dof(p)


def _t1(**_: Any) -> TransferMatrix:
    from hil.models.teleop import termination_T1

    return termination_T1()


def _t2(**_: Any) -> TransferMatrix:
    from hil.models.teleop import termination_T2

    return termination_T2()


#: units of the SDEA's parameters (rotary SI)
SDEA_UNITS = {"M": "kg.m²", "B": "N.m.s/rad", "B_f": "N.m.s/rad", "P_m": "N.m.s/rad", "b22": "N.m.s/rad",
              "K_f": "N.m/rad", "I_m": "N.m/rad", "k22": "N.m/rad", "P_f": "rad/(N.m.s)", "I_f": "rad/(N.m.s²)",
              "alpha": "1"}


# The scene mappings import hil.models.scene_params (and through it hil.schema, i.e. pydantic) only
# when a scene is mapped: importing them in _defaults() cost ~90 ms of the start-up of every
# ``hil stability --model NAME`` (issue 15), which never maps a scene.
def _sdea_from_scene(scene: Any, cfg: dict[str, Any]) -> dict[str, Any]:
    from hil.models.scene_params import sdea_params

    return sdea_params(scene, cfg)


def _mcet_from_scene(scene: Any, cfg: dict[str, Any]) -> dict[str, Any]:
    from hil.models.scene_params import mcet_params

    return mcet_params(scene, cfg)


def _bilateral_2dof_from_scene(scene: Any, cfg: dict[str, Any]) -> dict[str, Any]:
    from hil.models.scene_params import bilateral_2dof_params

    return bilateral_2dof_params(scene, cfg)


def _bilateral_1dof_from_scene(scene: Any, cfg: dict[str, Any]) -> dict[str, Any]:
    from hil.models.scene_params import bilateral_1dof_params

    return bilateral_1dof_params(scene, cfg)


def _dual_master_3dof_from_scene(scene: Any, cfg: dict[str, Any]) -> dict[str, Any]:
    from hil.models.scene_params import dual_master_3dof_params

    return dual_master_3dof_params(scene, cfg)


def _defaults() -> dict[str, BuiltinModel]:
    from hil.models.sdea import SDEA_TABLE1
    from hil.models.teleop import (
        BILATERAL_1DOF,
        DUAL_MASTER_TABLE1,
        MBK_2DOF,
        MCET_TABLE1,
        TWO_DOF_ROBOT,
        TWO_DOF_TABLE2,
    )

    return {
        "sdea": BuiltinModel("sdea", "SDEA under VSIC with virtual coupler (002 eq. 12, Table I)", "passivity",
                             dict(SDEA_TABLE1), _sdea, from_scene=_sdea_from_scene, batch={"passivity": _sdea_batch},
                             design={"k22": DesignParameter("N.m/rad", _k22_headroom),
                                     "b22": DesignParameter("N.m.s/rad")},
                             band_condition=_sdea_coupler_condition, units=dict(SDEA_UNITS)),
        "mcet_trilateral": BuiltinModel("mcet_trilateral", "dual-user MCET trilateral system (000 eq. 25, Table I)",
                                        "absolute_stability", dict(MCET_TABLE1), _mcet, from_scene=_mcet_from_scene),
        "bilateral_2dof": BuiltinModel("bilateral_2dof", "2-DOF bilateral position-position (000 eq. 44, Table II)",
                                       "absolute_stability",
                                       {"gains": "A1", **{f"k_{p}{a}": None for p in "pv" for a in ("yy", "zz", "yz")},
                                        **TWO_DOF_ROBOT}, _bilateral, from_scene=_bilateral_2dof_from_scene,
                                       table="gains", choices={"gains": tuple(TWO_DOF_TABLE2)}),
        "bilateral_1dof": BuiltinModel("bilateral_1dof", "1-DOF bilateral position-position (eq. 44, m = 1)",
                                       "llewellyn", dict(BILATERAL_1DOF), _bilateral1,
                                       from_scene=_bilateral_1dof_from_scene),
        "dual_master_3dof": BuiltinModel("dual_master_3dof", "dual-master/single-slave 3-DOF (001 eq. 17, Table I)",
                                         "absolute_stability", dict(DUAL_MASTER_TABLE1), _dual,
                                         from_scene=_dual_master_3dof_from_scene),
        "mbk_impedance": BuiltinModel("mbk_impedance", "m-DOF mass-damper-spring device, Z = (M s² + B s + K)/s",
                                      "positive_real", {**MBK_2DOF, "dof": 2}, _mbk),
        "T1": BuiltinModel("T1", "2-DOF termination T1 of 000 eq. (1) (not passive)", "positive_real", {}, _t1),
        "T2": BuiltinModel("T2", "3-DOF termination T2 of 001 (passive)", "positive_real", {}, _t2),
    }


BUILTIN_MODELS: dict[str, BuiltinModel] = {}


def register_model(model: BuiltinModel, *, replace: bool = False) -> None:
    """Add a network model (``hil stability --model``, scenes' ``certification.model``, ``hil
    sweep``); refuses to shadow a registered name unless ``replace``."""
    _fill()
    if model.name in BUILTIN_MODELS and not replace and BUILTIN_MODELS[model.name] is not model:
        raise ValueError(f"model {model.name!r} is already registered")
    BUILTIN_MODELS[model.name] = model


def _fill() -> None:
    """The built-in models (entry points are read by :func:`_plugins`)."""
    if not BUILTIN_MODELS:
        BUILTIN_MODELS.update(_defaults())


def _plugins() -> None:
    """The models of the ``hil_certify.models`` entry points (:mod:`hil.plugins`; read once, and
    only when a name is not built in or the list is asked for: start-up time)."""
    _fill()
    load_group("models", BuiltinModel, register_model)


def get_model(name: str) -> BuiltinModel:
    """Look a model up by name (KeyError with the known names otherwise)."""
    _fill()
    if name not in BUILTIN_MODELS:
        _plugins()
    try:
        return BUILTIN_MODELS[name]
    except KeyError:
        raise KeyError(name) from None


def model_names() -> list[str]:
    """The names of the registered models."""
    _plugins()
    return list(BUILTIN_MODELS)


def model_params_from_scene(scene: Any) -> dict[str, Any]:
    """The network model's fixed parameters implied by the scene's controller and simulation
    (the model's :meth:`~hil.models.BuiltinModel.params_from_scene`), overridden by
    ``certification.parameters``."""
    cert = scene.certification
    p = get_model(cert.model).params_from_scene(scene)
    p.update(cert.parameters)
    return p


def build_network(model: str, params: Mapping[str, Any]) -> TransferMatrix:
    """The network (immittance matrix) of built-in ``model`` with ``params``. A gain table
    (``gains``: a mapping, as a scene's controller gives it) takes any of its entries given at the
    top level too (``k_pmyz=...``: a swept or overridden gain); see
    :meth:`hil.models.BuiltinModel.network`."""
    return get_model(model).network(params)
