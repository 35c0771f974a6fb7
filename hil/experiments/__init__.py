"""Experiments the runner plays on the bench (``docs/RUNNER_SPEC.md``): chirp, multisine, energy
injection, static hold.

Each experiment type has one pydantic schema next to its implementation (:class:`ChirpExperiment`,
:class:`MultisineExperiment`, :class:`EnergyInjectionExperiment`, :class:`StaticHoldExperiment`) and
one implementation, registered in :data:`EXPERIMENT_TYPES` (``register_experiment``); :mod:`hil.scene.spec`
composes the scene's ``experiments`` list from that registry. Each experiment is built from one
validated entry by :func:`make_experiment` and then

* ``check(scene)`` -- before anything moves: band below Nyquist/5 (``f1 <= rate_hz / 10``; the
  zero-order hold costs ``ω T/2`` of phase, 18° at that limit), amplitude within
  ``safety.max_effort``, ``duration > 0``, target device and DOFs exist. Raises
  :class:`hil.errors.SceneError` naming the field (``experiments[<name>].<field>: ...``). It also
  resolves scene-dependent details (port devices, force-sensor axes and sign, noise levels);
* ``excitation(k, t, meas) -> Excitation`` -- once per tick ``k`` (``t = k / rate_hz``): efforts
  added to the controller output (held over the tick) and active forces of simulated humans;
* ``finish(data, meta) -> dict`` -- analysis of the recorded channels (``"t"``,
  ``"<device>.position"``, ``"<device>.velocity"``, ``"<sensor>.wrench"``, ...; arrays with time on
  axis 0), stored in the run record.

Signals are computed from the tick index ``k`` (not from accumulated time), so periodic
excitations are *exactly* periodic in samples: ``u[k + N_p] == u[k]`` bit for bit.

Units SI: efforts N or N.m, positions m or rad, frequencies Hz, times s, energies J.


Modules: :mod:`~hil.experiments.base` (the config base, the :class:`Experiment` protocol, the
shared implementation base), :mod:`~hil.experiments.signals` (chirp, multisine, fades),
:mod:`~hil.experiments.energy` (port energy), one module per type
(:mod:`~hil.experiments.periodic`: chirp and multisine; :mod:`~hil.experiments.energy_injection`;
:mod:`~hil.experiments.static_hold`); the registry and :func:`make_experiment` are here.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from hil.errors import SceneError
from hil.experiments.base import Excitation, Experiment, ExperimentConfig
from hil.experiments.energy import EnergyResult, port_energy
from hil.experiments.energy_injection import EnergyInjection, EnergyInjectionExperiment, ForceProfileCfg, force_profile
from hil.experiments.periodic import Chirp, ChirpExperiment, Multisine, MultisineExperiment, ServoCfg
from hil.experiments.signals import chirp_signal, multisine_lines, raised_cosine_fade, schroeder_phases
from hil.experiments.static_hold import StaticHold, StaticHoldExperiment
from hil.plugins import load_group
from hil.schema import register_tagged, validate

logger = logging.getLogger(__name__)


__all__ = [
    "EXPERIMENT_TYPES",
    "Chirp",
    "ChirpExperiment",
    "EnergyInjection",
    "EnergyInjectionExperiment",
    "EnergyResult",
    "Excitation",
    "Experiment",
    "ExperimentConfig",
    "ExperimentType",
    "ForceProfileCfg",
    "Multisine",
    "MultisineExperiment",
    "ServoCfg",
    "StaticHold",
    "StaticHoldExperiment",
    "chirp_signal",
    "experiment_schemas",
    "force_profile",
    "make_experiment",
    "multisine_lines",
    "port_energy",
    "raised_cosine_fade",
    "register_experiment",
    "schroeder_phases",
]


@dataclass(frozen=True)
class ExperimentType:
    """One experiment type: its scene ``type`` name, its schema and its implementation (built as
    ``impl(validated_config, rate_hz)``)."""

    name: str
    schema: type[ExperimentConfig]
    impl: Callable[[Any, float], Experiment]


#: experiment type name -> (schema, implementation); :mod:`hil.scene.spec` builds its ``experiments``
#: union from it (register before importing :mod:`hil.scene.spec`)
EXPERIMENT_TYPES: dict[str, ExperimentType] = {}


def register_experiment(name: str, schema: type[ExperimentConfig], impl: Callable[[Any, float], Experiment]) -> None:
    """Add an experiment type: ``schema`` is a :class:`ExperimentConfig` whose ``type`` field is
    ``Literal[name]``; ``impl(cfg, rate_hz)`` builds the :class:`Experiment` from a validated ``cfg``."""
    register_tagged(EXPERIMENT_TYPES, name, schema, ExperimentType(name, schema, impl), "experiment type")


def experiment_schemas() -> tuple[type[ExperimentConfig], ...]:
    """The schemas of every registered experiment type (registration order), after those of the
    ``hil_certify.experiments`` entry points (:mod:`hil.plugins`, read once)."""
    load_group("experiments", ExperimentType, lambda t: register_experiment(t.name, t.schema, t.impl))
    return tuple(t.schema for t in EXPERIMENT_TYPES.values())


register_experiment("chirp", ChirpExperiment, Chirp)


register_experiment("multisine", MultisineExperiment, Multisine)


register_experiment("energy_injection", EnergyInjectionExperiment, EnergyInjection)


register_experiment("static_hold", StaticHoldExperiment, StaticHold)


def make_experiment(cfg: ExperimentConfig | Mapping[str, Any], *, rate_hz: float) -> Experiment:
    """Build one experiment at the control rate from its validated configuration (a scene's
    ``experiments`` entry, e.g. :meth:`hil.scene.spec.Scene.experiment_models`), or from a mapping,
    which is validated here against the schema of its ``type``."""
    if isinstance(cfg, ExperimentConfig):
        etype = cfg.type
        if etype not in EXPERIMENT_TYPES:
            raise SceneError(f"experiments[{cfg.name or '?'}].type: unknown experiment {etype!r}; "
                             f"one of {sorted(EXPERIMENT_TYPES)}")
        model = cfg
    else:
        raw = {k: v for k, v in dict(cfg).items() if v is not None}
        etype = str(raw.get("type", ""))
        if etype not in EXPERIMENT_TYPES:
            raise SceneError(f"experiments[{raw.get('name') or '?'}].type: unknown experiment {etype!r}; "
                             f"one of {sorted(EXPERIMENT_TYPES)}")
        model = validate(EXPERIMENT_TYPES[etype].schema, raw, f"experiments[{raw.get('name') or etype}]")
    exp = EXPERIMENT_TYPES[etype].impl(model, rate_hz)
    logger.debug("experiment %s (%s), %.3f s", exp.name, etype, exp.duration)
    return exp
