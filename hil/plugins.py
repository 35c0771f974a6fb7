"""Extensions from other distributions, through entry points (python-can's ``can.interface`` style).

An outside package adds an experiment type, a controller or a network model by declaring an entry
point in one of these groups (``pyproject.toml``: ``[project.entry-points."hil_certify.models"]``,
``my_model = "my_pkg.my_module:MODEL"``); each entry point loads an instance of the group's type,
or a zero-argument callable returning one or a list of them:

=============================  =============================================  ======================
group                          loads                                          registered with
=============================  =============================================  ======================
``hil_certify.experiments``    :class:`hil.experiments.ExperimentType`        ``register_experiment``
``hil_certify.controllers``    :class:`hil.controllers.ControllerType`        ``register_controller``
``hil_certify.models``         :class:`hil.models.BuiltinModel`               ``register_model``
``hil_certify.importers``      :class:`hil.record.importers.Importer`         ``register`` (importers)
=============================  =============================================  ======================

Devices (``hil_certify.devices``, :mod:`hil.protocols.registry`) and criteria
(``hil_certify.criteria``, :mod:`hil.stability.criteria`) read their own groups, because those
packages import nothing else of ``hil`` (the import rule, docs/ARCHITECTURE.md).

Each group is read once, on first use, by the registry that owns it (this module imports nothing of
``hil``): experiments and controllers when :mod:`hil.scene.spec` composes its schema (so a plugin module
must not import :mod:`hil.scene.spec` at import time), models on the first lookup of a name that is not
built in (or a listing). A broken entry point is logged and skipped, never fatal: the suite keeps
working without it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

logger = logging.getLogger(__name__)

__all__ = ["GROUPS", "load_group"]

#: short name -> entry-point group
GROUPS = {"experiments": "hil_certify.experiments", "controllers": "hil_certify.controllers",
          "models": "hil_certify.models", "importers": "hil_certify.importers"}

_loaded: set[str] = set()


def load_group(kind: str, want: type, register: Callable[[Any], None]) -> list[str]:
    """Register, with ``register``, every ``want`` instance the entry points of group
    ``GROUPS[kind]`` declare (once per process; later calls return []). Returns their names."""
    if kind in _loaded:
        return []
    _loaded.add(kind)
    from importlib.metadata import entry_points  # 15-20 ms of imports: only when a group is read
    out: list[str] = []
    for ep in entry_points(group=GROUPS[kind]):
        try:
            obj = ep.load()
            got = obj() if callable(obj) and not isinstance(obj, want) else obj
            for item in got if isinstance(got, list | tuple) else [got]:
                if not isinstance(item, want):
                    raise TypeError(f"{ep.value} gives a {type(item).__name__}, not a {want.__name__}")
                register(item)
                out.append(str(getattr(item, "name", item)))
        except Exception:
            logger.warning("%s entry point %r (%s) could not be registered", kind, ep.name, ep.value, exc_info=True)
    if out:
        logger.info("%s from entry points: %s", kind, ", ".join(out))
    return out
