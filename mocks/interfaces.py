"""The small contract between simulated devices (which speak wire protocols) and the physics.

A simulated device never integrates physics itself. It reads the state of, and applies
effort to, a :class:`SimulatedJoints` handle that the physics engine (``hil.mocks.physics``)
provides. The scene simulator advances the physics by exactly one control period per tick in
lockstep mode, so a seeded mocked run is bit-identical on any machine.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np


class SimulatedJoints(Protocol):
    """The physical side of a simulated device: ``dof`` joints of one body in the plant."""

    dof: int

    def apply_effort(self, effort: np.ndarray) -> None:
        """Set the effort (N or N.m) held constant over the next step (zero-order hold)."""

    def position(self) -> np.ndarray:
        """Current joint positions (m or rad)."""

    def velocity(self) -> np.ndarray:
        """Current joint velocities (m/s or rad/s)."""

    def measured_force(self) -> np.ndarray:
        """Force/torque that a sensor on this body measures (N or N.m), e.g. the spring force."""


class FreeJoints:
    """A minimal stand-in plant: unit-free integrator of a point mass per DOF, stepped explicitly.

    Useful for protocol tests that need *some* physics without the full engine. ``step(dt)``
    integrates exactly (constant effort over the step).
    """

    def __init__(self, dof: int = 1, mass: float = 1.0) -> None:
        self.dof = dof
        self.mass = float(mass)
        self._x = np.zeros(dof)
        self._v = np.zeros(dof)
        self._u = np.zeros(dof)

    def apply_effort(self, effort: np.ndarray) -> None:
        self._u = np.asarray(effort, dtype=float).reshape(self.dof).copy()

    def position(self) -> np.ndarray:
        return self._x.copy()

    def velocity(self) -> np.ndarray:
        return self._v.copy()

    def measured_force(self) -> np.ndarray:
        return self._u.copy()

    def step(self, dt: float) -> None:
        a = self._u / self.mass
        self._x = self._x + self._v * dt + 0.5 * a * dt * dt
        self._v = self._v + a * dt
