"""What every experiment type shares: the config base :class:`ExperimentConfig`, the
:class:`Experiment` protocol the runner plays, :class:`Excitation`, the implementation base
``_Base`` and the scene-access helpers (they work on the validated scene and on plain mappings).
Units SI."""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from types import ModuleType
from typing import Any, Generic, Literal, Protocol, TypeVar

import numpy as np
from pydantic_core import PydanticCustomError

from hil.errors import SceneError
from hil.schema import (
    FieldError,
    Name,
    SceneView,
    StrictModel,
)


def _sps() -> ModuleType:  # scipy.signal takes seconds to import: only some profiles need it
    from scipy import signal

    return signal


#: Highest excitation frequency as a fraction of the sampling rate (Nyquist/5).
BAND_LIMIT_FRACTION = 0.1


@dataclass
class Excitation:
    """One tick of excitation: ``effort`` per actuator (added to the controller output, N or
    N.m, shape (dof,)) and ``human`` active force per network port (simulated operator)."""

    effort: dict[str, np.ndarray] = field(default_factory=dict)
    human: dict[str, np.ndarray] = field(default_factory=dict)


class Experiment(Protocol):
    """What the runner plays: built from one validated scene entry (module doc)."""

    name: str
    duration: float

    def check(self, scene: Any) -> None: ...
    def excitation(self, k: int, t: float, meas: Mapping[str, Any]) -> Excitation: ...
    def finish(self, data: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> dict[str, Any]: ...


class ExperimentConfig(StrictModel):
    """Fields every experiment has. ``controller``: ``scene`` runs the scene's controller during
    the experiment, ``none`` runs it open loop (identification). ``name`` defaults to the type
    (``<type>_<n>`` when several of one type are unnamed; filled in by :class:`hil.scene.spec.Scene`)."""

    type: str
    name: Name | None = None
    controller: Literal["scene", "none"] = "scene"

    def check_scene(self, scene: SceneView, path: str) -> None:
        """Refuse broken references to ``scene`` (pure; ``path``: ``experiments[i]``). The checks
        that need the control rate run when the experiment is built (:meth:`Experiment.check`)."""


def _check_target(cfg: Any, scene: SceneView, path: str) -> None:
    d = scene.require(f"{path}.target", cfg.target, "actuator")
    if cfg.dofs is not None and max(cfg.dofs) >= d.dof:
        raise FieldError(f"{path}.dofs", f"device {d.name!r} has {d.dof} DOF")
    sim = scene.simulation
    if cfg.variant == "free" and sim is not None and (sim.sdea is None or sim.sdea.m_out is None):
        raise FieldError(f"{path}.variant", "variant 'free' needs simulation.sdea.m_out (the output inertia)")


def _band_ok(f0: float, f1: float) -> None:
    if not f0 < f1:
        raise PydanticCustomError("band", "f1 ({f1} Hz) must exceed f0 ({f0} Hz)", {"f0": f0, "f1": f1, "key": "f1"})


def _get(obj: Any, key: str, default: Any = None) -> Any:
    if obj is None:
        return default
    if isinstance(obj, Mapping):
        return obj.get(key, default)
    return getattr(obj, key, default)


def _devices(scene: Any) -> dict[str, Any]:
    """Devices by name, plus device groups (as the scene's group actuator) when the scene has them."""
    out = {str(_get(d, "name")): d for d in (_get(scene, "devices") or [])}
    for g in _get(scene, "groups") or []:
        name = str(_get(g, "name"))
        out[name] = scene.device(name) if hasattr(scene, "device") else g
    return out


def _wrench_axes(dev: Any) -> list[int]:
    axes = _get(dev, "axes")
    return [int(a) for a in axes] if axes is not None else list(range(int(_get(dev, "dof", 1))))


C = TypeVar("C", bound=ExperimentConfig)


class _Base(Generic[C]):
    """Common handling of a validated configuration ``cfg`` (one schema of this module)."""

    kind = "experiment"
    duration: float

    def __init__(self, cfg: C, rate_hz: float) -> None:
        if not (isinstance(rate_hz, int | float) and rate_hz > 0 and math.isfinite(rate_hz)):
            raise SceneError(f"rate_hz: must be positive, got {rate_hz!r}")
        self.cfg = cfg
        self.rate_hz = float(rate_hz)
        self.dt = 1.0 / self.rate_hz
        self.name = str(cfg.name or self.kind)
        self.where = f"experiments[{self.name}]"

    def f(self, key: str) -> str:
        """Field path for messages."""
        return f"{self.where}.{key}"

    def _check_target(self, scene: Any, target: str, dofs: Sequence[int] | None) -> tuple[Any, list[int]]:
        devs = _devices(scene)
        if target not in devs:
            raise SceneError(f"{self.f('target')}: no device {target!r} in the scene (have {sorted(devs)})")
        dev = devs[target]
        if _get(dev, "role", "actuator") != "actuator":
            raise SceneError(f"{self.f('target')}: device {target!r} is not an actuator")
        n = int(_get(dev, "dof", 1))
        sel = list(range(n)) if dofs is None else [int(i) for i in dofs]
        if not sel or any(i < 0 or i >= n for i in sel) or len(set(sel)) != len(sel):
            raise SceneError(f"{self.f('dofs')}: {sel} not distinct DOF indices of {target!r} ({n} DOF)")
        return dev, sel

    def _check_band(self, f0: float, f1: float) -> None:
        lim = BAND_LIMIT_FRACTION * self.rate_hz
        if f1 > lim:
            raise SceneError(f"{self.f('f1')}: {f1} Hz exceeds Nyquist/5 = {lim:g} Hz at rate_hz {self.rate_hz:g} "
                             "(zero-order hold phase lag ωT/2 > 18°); lower f1 or raise rate_hz")

    def _check_effort(self, scene: Any, peak: float, field_name: str) -> None:
        max_effort = _get(_get(scene, "safety"), "max_effort")
        if max_effort is not None and peak > float(max_effort):
            raise SceneError(f"{self.f(field_name)}: peak effort {peak:g} exceeds safety.max_effort "
                             f"{float(max_effort):g}")


_BLOCK_ROWS = 65536


def _row_blocks(ds: Any, n: int) -> Iterator[tuple[int, np.ndarray]]:
    """``(start, rows)`` blocks of the first ``n`` rows of an array or h5py dataset, as float arrays
    (``rows`` is (m,) for 1-D data, (m, k) otherwise)."""
    for i in range(0, n, _BLOCK_ROWS):
        blk = np.asarray(ds[i:min(n, i + _BLOCK_ROWS)], dtype=float)
        yield i, blk if blk.ndim == 1 else blk.reshape(blk.shape[0], -1)
