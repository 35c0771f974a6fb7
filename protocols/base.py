"""Role interfaces: what the runner and experiments see, independent of any vendor.

Conventions (SI units throughout):

* positions in m (prismatic) or rad (revolute), velocities in m/s or rad/s,
  forces in N or torques in N.m; a device declares which with ``units``.
* Sign: a positive force/torque command accelerates the joint in its positive direction.
* Every sample carries ``t`` (seconds: when it was *read*, on the adapter's ``clock``: the
  host's monotonic clock, or the simulated clock in lockstep mode), ``produced_at`` (seconds, the
  same clock: when the device *produced* the data: a new device timestamp, a cyclic frame or a
  reply arriving; see each adapter) and ``seq`` (per-device sequence number that advances by one
  only when new data arrived). ``t - produced_at`` is the age of the data; a read that found
  nothing new returns the previous data again with the same ``seq`` and ``produced_at`` (a
  *stale* sample), and the runner's watchdog compares that age with the scene's ``watchdog_ms``.
* Fault counters: :meth:`Device.counters` (CRC errors, resyncs, dropped, late, stale frames,
  retries, ... as the protocol has them), plain ``int`` values that only grow.
* Multi-DOF devices expose vectors of length ``dof``; 1-DOF devices use length-1 arrays.

Every blocking call takes a ``timeout`` (seconds) and raises :class:`hil.errors.DeviceTimeout`
when it expires without an answer (request/response devices), or, for devices that stream data
(cyclic frames, serial streams), when no data at all has arrived yet. Adapters are context
managers; ``close()`` is idempotent.
"""

from __future__ import annotations

import abc
import contextlib
import dataclasses
import math
import time
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
    produced_at: float = math.nan  # s, adapter clock: when the device produced the data (NaN: = t)

    @property
    def age(self) -> float:
        """``t - produced_at`` (s): how old the data was when read (0 when unknown)."""
        return sample_age(self)


@dataclass(frozen=True)
class WrenchSample:
    """Feedback of a force/torque sensor: ``wrench`` = (Fx, Fy, Fz, Tx, Ty, Tz) in N and N.m,
    or a shorter vector for sensors with fewer axes."""

    t: float
    seq: int
    wrench: np.ndarray
    status: int = 0
    produced_at: float = math.nan  # s, adapter clock: when the device produced the data (NaN: = t)

    @property
    def age(self) -> float:
        """``t - produced_at`` (s): how old the data was when read (0 when unknown)."""
        return sample_age(self)


def sample_age(sample: object) -> float:
    """Age (s) of a sample's data when it was read: ``t - produced_at``; 0.0 when the sample has
    no ``produced_at`` (NaN or missing)."""
    produced = float(getattr(sample, "produced_at", math.nan))
    if math.isnan(produced):
        return 0.0
    return float(getattr(sample, "t", produced)) - produced


def repeat_sample(last: JointSample | WrenchSample, t: float) -> JointSample | WrenchSample:
    """The stale sample a read returns when no new data arrived: the previous data, ``seq`` and
    ``produced_at`` unchanged, read at ``t``."""
    return dataclasses.replace(last, t=t)


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

    def counters(self) -> dict[str, int]:
        """Fault counters of this adapter since it was opened (name -> count), e.g. ``crc_errors``,
        ``resyncs``, ``dropped``, ``late``, ``stale``, ``retries``, ``timeouts``; each adapter
        documents which it has. Default: none."""
        return {}

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


class StreamingSensor(ForceSensor):
    """A force sensor that streams frames over a byte transport (Bota serial, FT-300 stream mode).

    Subclasses count the bytes received in ``rx_bytes`` and decode what :meth:`_pump` reads.
    :meth:`wait_rx` is the lockstep barrier: a simulated sensor reports how many bytes it wrote,
    and the host waits for exactly those before reading, so a test run does not depend on when
    the kernel delivers them.
    """

    rx_bytes: int = 0

    @abc.abstractmethod
    def _pump(self, block: bool) -> None:
        """Read what the transport has (waiting up to its read timeout when ``block``) and decode it."""

    def wait_rx(self, total_bytes: int, timeout: float) -> bool:
        """Receive (and decode, without consuming) until ``rx_bytes >= total_bytes`` or ``timeout``
        (s) passes; True if reached."""
        deadline = time.monotonic() + timeout
        while self.rx_bytes < total_bytes:
            if time.monotonic() >= deadline:
                return False
            self._pump(block=True)
        return True
