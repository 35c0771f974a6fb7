"""What identification reads: arrays, or a run record through a small interface (issue 13).

:mod:`hil.identify` does not import the suite's record, scene or importer modules. It takes

* arrays (:func:`hil.identify.api.identify_arrays`, :func:`~hil.identify.api.identify_experiments`), or
* a record through :class:`RecordSource` -- the few attributes :func:`hil.identify.records.plan_from_record`
  reads (time base, rate, meta, per-experiment results, the parsed scene or None, 1-D signals) -- or
* a record FILE, opened by a :class:`RecordBackend`: an object that opens files of its suffixes as
  :class:`RecordSource`, adapts its own record objects to one, stores a result back into a file and
  imports foreign files (CSV, .mat) into one.

Backends are registered by the side that owns the file format: :func:`register_backend` at import, or
the entry-point group ``hil.identify.record_backends`` (the suite's own HDF5 run records register
``hil.record.identify_source:BACKEND`` there, see pyproject.toml), looked up the first time a file or a
foreign record object is handed to identification. ``.npz`` files (``t``, signals, a JSON ``meta``)
are read here with numpy alone.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from hil.identify.errors import ModelSpecError

logger = logging.getLogger(__name__)

__all__ = ["ENTRY_POINT_GROUP", "RecordBackend", "RecordSource", "as_source", "backend_for", "register_backend"]

#: entry-point group of record backends
ENTRY_POINT_GROUP = "hil.identify.record_backends"


@runtime_checkable
class RecordSource(Protocol):
    """A run record as identification reads it (a structural type: any object with these members).

    ``path``: where it came from (for messages and provenance); ``t`` [s] the time base; ``rate_hz`` its
    nominal rate (NaN if unknown); ``meta`` the run's meta (``experiment``: the experiment's config,
    ``units``, ...); ``results`` per experiment (``period``, ``skip``, ``band``, ``segments``, ``dofs``,
    ``target``, ``type``); ``scene`` the validated scene object of the run or None (attributes read:
    ``device(name).body``, ``force_sensors[].name/body/wrench_axes``, ``network.ports[].actuator/
    force_sensor/name``, ``units``, ``controller.type``); ``scene_sha256`` its hash ("" if none);
    :meth:`to_identify_dict` the 1-D signals (``{"t", "signals", "meta"}``, vector channels split as
    ``name[i]``)."""

    path: Any
    t: NDArray[np.float64]
    rate_hz: float
    meta: Mapping[str, Any]
    results: Mapping[str, Any]
    scene: Any
    scene_sha256: str

    def to_identify_dict(self) -> dict[str, Any]: ...


class RecordBackend(Protocol):
    """Opens, adapts and writes records of one family (module docstring). ``suffixes``: lower-case file
    suffixes it opens (``".h5"``; ``"*"``: any suffix no other backend claims); ``error``: its error
    class (a :class:`hil.errors.HilError`)."""

    suffixes: tuple[str, ...]
    error: type[Exception]

    def open(self, path: Path) -> RecordSource:
        """The record at ``path`` (foreign formats imported into a temporary record); raises ``error``
        with one line naming the file when it cannot be read."""
        ...

    def adapt(self, obj: Any) -> RecordSource | None:
        """``obj`` (one of the backend's record objects) as a :class:`RecordSource`, else None."""
        ...

    def store(self, path: str | Path, name: str, samples: NDArray[np.float64], summary: Mapping[str, Any]) -> None:
        """Write an identification (posterior draws, JSON summary) into the record file at ``path``."""
        ...

    def import_to(self, src: str | Path, out: str | Path, *, overwrite: bool = False) -> Path:
        """Import a foreign file ``src`` (CSV, .mat) into a record at ``out``; returns its path."""
        ...


_BACKENDS: list[Any] = []
_ENTRY_POINTS_LOADED = False


def register_backend(backend: Any) -> None:
    """Make ``backend`` (a :class:`RecordBackend`) available; registering it again is a no-op."""
    if not any(b is backend for b in _BACKENDS):
        _BACKENDS.append(backend)


def _backends() -> list[Any]:
    global _ENTRY_POINTS_LOADED
    if not _ENTRY_POINTS_LOADED:
        _ENTRY_POINTS_LOADED = True
        from importlib.metadata import entry_points  # 15-20 ms of imports: only when the plug-ins are read

        for ep in entry_points(group=ENTRY_POINT_GROUP):
            try:
                register_backend(ep.load())
            except Exception as exc:  # a broken third-party plug-in must not break identification
                logger.warning("record backend %s (%s) cannot be loaded: %s", ep.name, ep.value, exc)
    return list(_BACKENDS)


def backend_for(path: str | Path | None = None) -> Any:
    """The registered backend opening files with ``path``'s suffix (the first one registered when
    ``path`` is None). Raises :class:`ModelSpecError` when none does."""
    have = _backends()
    if path is None:
        if have:
            return have[0]
        raise ModelSpecError(f"no record backend registered (entry-point group {ENTRY_POINT_GROUP})")
    suffix = Path(path).suffix.lower()
    for b in have:
        if suffix in b.suffixes:
            return b
    for b in have:  # a backend that reads whatever no other claims
        if "*" in b.suffixes:
            return b
    known = sorted({s for b in have for s in b.suffixes} | {".npz"})
    raise ModelSpecError(f"{path}: no reader for {suffix or 'files without a suffix'} records (known: "
                         f"{', '.join(known)}; a backend registers in the entry-point group {ENTRY_POINT_GROUP})")


def as_source(obj: Any) -> RecordSource | None:
    """``obj`` as a :class:`RecordSource`: itself when it has the interface, else the first backend's
    adaptation of it, else None (a record dict, for instance)."""
    if isinstance(obj, Mapping):
        return None
    if isinstance(obj, RecordSource):
        return obj
    for b in _backends():
        src = b.adapt(obj)
        if src is not None:
            return src
    return None
