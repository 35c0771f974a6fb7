"""Built-in network models from the papers, selectable by name (``hil stability --model NAME``).

Each entry gives a builder taking keyword parameters, the criterion that fits the network, and
the parameters it accepts (with their defaults), so the CLI can validate ``--set NAME=VALUE``.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hil.errors import ModelError
from hil.stability.rational import TransferMatrix

__all__ = ["BUILTIN_MODELS", "BuiltinModel", "get_model"]


@dataclass(frozen=True)
class BuiltinModel:
    name: str
    description: str
    criterion: str
    defaults: dict[str, Any] = field(default_factory=dict)
    _builder: Callable[..., TransferMatrix] | None = None

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

    @property
    def choices(self) -> dict[str, tuple[str, ...]]:
        """Allowed values of the string parameters (e.g. the gain sets of a table)."""
        if self.name == "bilateral_2dof":
            from hil.models.teleop import TWO_DOF_TABLE2

            return {"gains": tuple(TWO_DOF_TABLE2)}
        return {}

    def build(self, **params: Any) -> TransferMatrix:
        assert self._builder is not None
        self.check_params(params, allow_unknown=True)
        return self._builder(**params)


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


def _defaults() -> dict[str, BuiltinModel]:
    from hil.models.sdea import SDEA_TABLE1
    from hil.models.teleop import BILATERAL_1DOF, DUAL_MASTER_TABLE1, MBK_2DOF, MCET_TABLE1, TWO_DOF_ROBOT

    return {
        "sdea": BuiltinModel("sdea", "SDEA under VSIC with virtual coupler (002 eq. 12, Table I)", "passivity",
                             dict(SDEA_TABLE1), _sdea),
        "mcet_trilateral": BuiltinModel("mcet_trilateral", "dual-user MCET trilateral system (000 eq. 25, Table I)",
                                        "absolute_stability", dict(MCET_TABLE1), _mcet),
        "bilateral_2dof": BuiltinModel("bilateral_2dof", "2-DOF bilateral position-position (000 eq. 44, Table II)",
                                       "absolute_stability",
                                       {"gains": "A1", **{f"k_{p}{a}": None for p in "pv" for a in ("yy", "zz", "yz")},
                                        **TWO_DOF_ROBOT}, _bilateral),
        "bilateral_1dof": BuiltinModel("bilateral_1dof", "1-DOF bilateral position-position (eq. 44, m = 1)",
                                       "llewellyn", dict(BILATERAL_1DOF), _bilateral1),
        "dual_master_3dof": BuiltinModel("dual_master_3dof", "dual-master/single-slave 3-DOF (001 eq. 17, Table I)",
                                         "absolute_stability", dict(DUAL_MASTER_TABLE1), _dual),
        "mbk_impedance": BuiltinModel("mbk_impedance", "m-DOF mass-damper-spring device, Z = (M s² + B s + K)/s",
                                      "positive_real", {**MBK_2DOF, "dof": 2}, _mbk),
        "T1": BuiltinModel("T1", "2-DOF termination T1 of 000 eq. (1) (not passive)", "positive_real", {}, _t1),
        "T2": BuiltinModel("T2", "3-DOF termination T2 of 001 (passive)", "positive_real", {}, _t2),
    }


BUILTIN_MODELS: dict[str, BuiltinModel] = {}


def get_model(name: str) -> BuiltinModel:
    """Look a built-in model up by name (KeyError with the known names otherwise)."""
    if not BUILTIN_MODELS:
        BUILTIN_MODELS.update(_defaults())
    try:
        return BUILTIN_MODELS[name]
    except KeyError:
        raise KeyError(name) from None


def model_names() -> list[str]:
    if not BUILTIN_MODELS:
        BUILTIN_MODELS.update(_defaults())
    return list(BUILTIN_MODELS)
