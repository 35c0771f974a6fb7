"""What every controller shares: the :class:`Controller` protocol (``reset``, ``step(t, meas)`` ->
efforts), the config base :class:`ControllerConfig`, gain matrices (a scalar, a diagonal or a full
``dof x dof`` matrix), and the ``none`` controller."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Literal, Protocol, TypeAlias, runtime_checkable

import numpy as np
from pydantic_core import PydanticCustomError

from hil.errors import SceneError
from hil.protocols.base import JointSample, WrenchSample
from hil.schema import (
    FieldError,
    MatrixValue,
    SceneView,
    StrictModel,
    as_matrix,
    matrix_shape,
    parse_matrix,
)

DeviceSample: TypeAlias = JointSample | WrenchSample


Measurements: TypeAlias = Mapping[str, DeviceSample]


@runtime_checkable
class Controller(Protocol):
    """What the runner calls once per control period."""

    def reset(self) -> None:
        """Back to the initial state (integrators, virtual environment at rest)."""

    def update(self, t: float, dt: float, meas: Measurements) -> dict[str, np.ndarray]:
        """Efforts (N or N.m) per actuator device for the period starting at ``t`` (s)."""


def _field(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key


def gain_matrix(value: Any, dof: int | None, field: str) -> np.ndarray:
    """A ``dof x dof`` gain matrix from a scalar (``k I``), a vector (``diag``) or a matrix (as a
    scene writes it, or a parsed matrix field: :func:`hil.schema.parse_matrix`, the one parser).

    Raises :class:`SceneError` naming ``field`` for wrong shapes or non-finite entries. With
    ``dof=None`` a scalar gives a 1x1 matrix.
    """
    try:
        parsed = parse_matrix(value)
    except PydanticCustomError as exc:
        raise SceneError(f"{field}: {exc.message()}") from None
    shape = matrix_shape(parsed)
    if shape is not None and shape[0] != shape[1]:
        raise SceneError(f"{field}: must be a scalar, a vector or a square matrix, got shape {shape}")
    n = (shape[0] if shape is not None else 1) if dof is None else dof
    if shape is not None and shape[0] != n:
        raise SceneError(f"{field}: is {shape[0]}x{shape[1]}, expected {n}x{n}")
    return as_matrix(parsed, n)


def _gain_dof(dof: int | None, gains: Sequence[MatrixValue]) -> int:
    """``dof`` when given, else the size of the first gain that is a matrix (default 1)."""
    if dof is not None:
        return dof
    for g in gains:
        shape = matrix_shape(g)
        if shape is not None:
            return shape[0]
    return 1


def _square_gain(path: str, value: MatrixValue, n: int, what: str) -> None:
    """A pure check: ``value`` is a number (``k I``) or an ``n x n`` matrix."""
    shape = matrix_shape(value)
    if shape is not None and shape != (n, n):
        raise FieldError(path, f"expected a {n}x{n} matrix ({what}), got {shape[0]}x{shape[1]}")


def _full(value: MatrixValue, n: int) -> MatrixValue:
    """A gain as the full ``n x n`` matrix it stands for (scalars expanded: the final values that
    the scene's dumps, the network models and the records see)."""
    return as_matrix(value, n).tolist() if matrix_shape(value) is None else value


def _joint(meas: Measurements, name: str, field: str) -> JointSample:
    try:
        s = meas[name]
    except KeyError as exc:
        raise SceneError(f"{field}: no measurement from device {name!r} (have {sorted(meas)})") from exc
    if not isinstance(s, JointSample):
        raise SceneError(f"{field}: device {name!r} is not an actuator (got {type(s).__name__})")
    return s


class NullController:
    """``type: none``: zero effort on every actuator present in the measurements."""

    name = "none"

    def reset(self) -> None:
        """Nothing to reset."""

    def update(self, t: float, dt: float, meas: Measurements) -> dict[str, np.ndarray]:
        return {k: np.zeros(np.asarray(s.position).size) for k, s in meas.items() if isinstance(s, JointSample)}


class ControllerConfig(StrictModel):
    """A scene's ``controller`` block; ``type`` selects the schema (:data:`CONTROLLER_TYPES`).

    Subclasses may add two scene-level steps, both called by :mod:`hil.scene.spec` after validation:
    :meth:`normalized` (the final values: gains expanded to the devices' sizes) and
    :meth:`check_scene` (pure: cross-references and shapes; raises :class:`hil.schema.FieldError`)."""

    type: str

    def normalized(self, scene: SceneView) -> ControllerConfig:
        """This configuration with its final values for ``scene`` (a copy; unknown devices are left
        for :meth:`check_scene` to report)."""
        return self

    def check_scene(self, scene: SceneView) -> None:
        """Refuse broken references to ``scene``'s devices (pure: changes nothing)."""


def _dof_of(scene: SceneView, name: str) -> int | None:
    try:
        return scene.device(name).dof
    except KeyError:
        return None


class NoController(ControllerConfig):
    """No controller: the experiment's excitation is the only effort."""

    type: Literal["none"]
