"""Role interfaces: what the runner and experiments see, independent of any vendor.

Conventions (SI units throughout):

* positions in m (prismatic) or rad (revolute), velocities in m/s or rad/s,
  forces in N or torques in N.m; a device declares which with ``units``.
* Sign: a positive force/torque command accelerates the joint in its positive direction.
* Every sample carries ``t`` (seconds, monotonic clock of the host or the simulated clock in
  lockstep mode) and ``seq`` (per-device sequence number, increasing by one per sample).
* Multi-DOF devices expose vectors of length ``dof``; 1-DOF devices use length-1 arrays.

Every blocking call takes a ``timeout`` (seconds) and raises :class:`hil.errors.DeviceTimeout`
when it expires. Adapters are context managers; ``close()`` is idempotent.
"""

from __future__ import annotations

import abc
import contextlib
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

Units = Literal["linear", "rotary"]


@dataclass(frozen=True)
class JointSample:
    """Feedback of an actuator: position, velocity and (if the device reports it) effort."""

    t: float
    seq: int
    position: np.ndarray  # (dof,) m or rad
    velocity: np.ndarray  # (dof,) m/s or rad/s
    effort: np.ndarray | None = None  # (dof,) N or N.m, measured/estimated by the drive
    fault: int = 0  # raw device fault code, 0 = none


@dataclass(frozen=True)
class WrenchSample:
    """Feedback of a force/torque sensor: ``wrench`` = (Fx, Fy, Fz, Tx, Ty, Tz) in N and N.m,
    or a shorter vector for sensors with fewer axes."""

    t: float
    seq: int
    wrench: np.ndarray
    status: int = 0


@dataclass
class DeviceInfo:
    """Identity recorded in every run record."""

    driver: str
    transport: str
    vendor: str = ""
    model: str = ""
    serial: str = ""
    firmware: str = ""
    extra: dict = field(default_factory=dict)


class Device(abc.ABC):
    """Common lifecycle of every adapter: open on construction or ``open()``, idempotent close."""

    info: DeviceInfo

    @abc.abstractmethod
    def close(self) -> None:
        """Release the transport. Safe to call more than once."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class Actuator(Device):
    """A force/torque (or current) commanded joint group reporting position and velocity."""

    dof: int
    units: Units

    @abc.abstractmethod
    def command_effort(self, effort: np.ndarray, timeout: float = 0.1) -> None:
        """Command force/torque (N or N.m) on every DOF. Must not block longer than ``timeout``."""

    @abc.abstractmethod
    def read(self, timeout: float = 0.1) -> JointSample:
        """Latest feedback. Raises DeviceTimeout when no fresh sample arrives in ``timeout``."""

    def safe_stop(self) -> None:
        """Command zero effort (and disable if the device supports it). Never raises."""
        with contextlib.suppress(Exception):
            self.command_effort(np.zeros(self.dof), timeout=0.05)


class ForceSensor(Device):
    """A force/torque sensor."""

    axes: int

    @abc.abstractmethod
    def read(self, timeout: float = 0.1) -> WrenchSample:
        """Latest wrench. Raises DeviceTimeout when no fresh sample arrives in ``timeout``."""

    def tare(self, timeout: float = 0.5) -> None:  # pragma: no cover - optional
        """Zero the sensor if supported."""
        raise NotImplementedError
