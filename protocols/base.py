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
import dataclasses
import logging
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal, Self, TypeVar

import numpy as np

from hil.errors import DeviceDisconnected, DeviceTimeout
from hil.protocols.waits import WALL, Waits

logger = logging.getLogger(__name__)

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


SampleT = TypeVar("SampleT", JointSample, WrenchSample)


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
    extra: dict[str, Any] = field(default_factory=dict)


class Device(abc.ABC):
    """Common lifecycle of every adapter (template methods, as python-can's ``BusABC``).

    The public methods own the lifecycle; a driver implements one hook per concern:

    * :meth:`close` is idempotent: the first call runs :meth:`_on_close` (the final commands on the
      wire, e.g. an actuator's safe stop) and then, *always* (also when the final commands raise),
      marks the adapter closed and calls :meth:`_release` (free the transport: shut the bus down,
      close the port). A failure to release is logged, never raised; a failure of the final
      commands reaches the caller after the transport was released.
    * :meth:`_check_open` raises :class:`hil.errors.DeviceDisconnected` once closed; the public
      ``read`` / ``command_effort`` call it before their hook, transport helpers call it too.
    * :meth:`_next_seq` advances the per-device sample sequence number (``JointSample.seq``).
    * :meth:`_timeout` turns a call's ``timeout`` argument (``None``: the adapter's ``timeout``
      attribute, default 0.1 s) into seconds, clamped at 0; NaN is a ValueError.
    """

    info: DeviceInfo
    #: default per-call timeout (s) when a call passes ``timeout=None``
    timeout: float = 0.1
    #: how this adapter names itself in errors (e.g. ``"ODrive node 3"``); default: the class name
    label: str = ""
    _closed: bool = False  # class defaults: a constructor that fails early can still close()
    _seq: int = 0
    _stale_reads: int = 0
    _timeouts: int = 0

    @property
    def closed(self) -> bool:
        """True once :meth:`close` ran (further I/O raises DeviceDisconnected)."""
        return self._closed

    def counters(self) -> dict[str, int]:
        """Fault counters of this adapter since it was opened (name -> count), e.g. ``crc_errors``,
        ``resyncs``, ``dropped``, ``late``, ``stale``, ``retries``, ``timeouts``; each adapter
        documents which it has. Default: none."""
        return {}

    def close(self) -> None:
        """Final commands (:meth:`_on_close`), then release the transport (:meth:`_release`) even
        when they fail. Safe to call more than once."""
        if self._closed:
            return
        try:
            self._on_close()
        finally:  # a failed final stop still releases the transport (and the caller sees the failure)
            self._closed = True
            try:
                self._release()
            except Exception:
                logger.debug("%s: releasing the transport failed", self._label(), exc_info=True)

    def _on_close(self) -> None:  # noqa: B027 - optional hook (default: nothing to send)
        """Hook: what to send before the transport is released (default nothing)."""

    @abc.abstractmethod
    def _release(self) -> None:
        """Hook: release the transport (close the port, shut the bus down). Called once."""

    def _label(self) -> str:
        return self.label or type(self).__name__

    def _check_open(self) -> None:
        if self._closed:
            raise DeviceDisconnected(f"{self._label()} is closed")

    def _next_seq(self) -> int:
        self._seq += 1
        return self._seq

    def _stale(self, last: SampleT | None, t: float, why: str) -> SampleT:
        """A read that found no new data: the previous sample again, read at ``t`` (a *stale*
        sample, counted in ``_stale_reads``), or, before the first sample, DeviceTimeout(``why``)
        (counted in ``_timeouts``)."""
        if last is None:
            self._timeouts += 1
            raise DeviceTimeout(why)
        self._stale_reads += 1
        return dataclasses.replace(last, t=t)

    def _timeout(self, timeout: float | None) -> float:
        t = float(self.timeout if timeout is None else timeout)
        if math.isnan(t):
            raise ValueError("timeout must be a number of seconds, got NaN")
        return max(0.0, t)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


#: one step of a safe stop (a bus call with a short timeout of its own)
StopStep = Callable[[], object]


def run_steps(steps: Iterable[StopStep], who: str) -> None:
    """Attempt every step in order: an exception is logged and the next step still runs; an
    interruption (KeyboardInterrupt, SystemExit) is held until every step ran, then re-raised.
    Ordinary exceptions are never raised."""
    interrupted: BaseException | None = None
    for step in steps:
        try:
            step()
        except Exception:
            logger.debug("%s: safe-stop step failed", who, exc_info=True)
        except BaseException as exc:  # held, re-raised once every step ran
            interrupted = interrupted or exc
    if interrupted is not None:
        raise interrupted


class Actuator(Device):
    """A force/torque (or current) commanded joint group reporting position and velocity.

    Template methods: :meth:`command_effort` checks state and input (open; ``dof`` finite values;
    the symmetric clamp ``effort_limit`` when set) and calls :meth:`_send_effort`; :meth:`read`
    checks state and the timeout and calls :meth:`_read_sample`; :meth:`safe_stop` runs every step of
    :meth:`_stop_steps` (each attempted even if an earlier one fails or is interrupted) and never
    raises; :meth:`close` runs the safe stop and then :meth:`_close_steps` when :meth:`_armed`,
    and releases the transport in any case.
    """

    dof: int
    units: Units
    #: symmetric clamp (N or N.m) of :meth:`command_effort`, None: no clamp
    effort_limit: float | None = None

    def command_effort(self, effort: np.ndarray, timeout: float | None = 0.1) -> None:
        """Command force/torque (N or N.m) on every DOF. Must not block longer than ``timeout``.
        ValueError (nothing sent) for a wrong size or a non-finite value."""
        self._check_open()
        self._send_effort(self._checked_effort(effort), self._timeout(timeout))

    def read(self, timeout: float | None = 0.1) -> JointSample:
        """Latest feedback. Raises DeviceTimeout when no fresh sample arrives in ``timeout``."""
        self._check_open()
        return self._read_sample(self._timeout(timeout))

    @abc.abstractmethod
    def _send_effort(self, effort: np.ndarray, timeout: float) -> None:
        """Hook: send ``effort`` ((dof,), finite, clamped) within ``timeout`` s."""

    @abc.abstractmethod
    def _read_sample(self, timeout: float) -> JointSample:
        """Hook: one sample within ``timeout`` s (the adapter is open)."""

    def _checked_effort(self, effort: np.ndarray) -> np.ndarray:
        u = np.asarray(effort, dtype=float).reshape(-1)
        if u.size != self.dof:
            raise ValueError(f"{self._label()}: {self.dof} effort values expected, got {u.size}")
        if not np.all(np.isfinite(u)):
            raise ValueError(f"non-finite effort {u.tolist()!r}")
        if self.effort_limit is not None:
            u = np.clip(u, -self.effort_limit, self.effort_limit)
        return u

    def safe_stop(self) -> None:
        """Command zero effort (and disable if the device supports it). Never raises: every step
        is attempted (see :func:`run_steps`)."""
        run_steps(self._stop_steps(), self._label())

    def _stop_steps(self) -> Sequence[StopStep]:
        """Hook: the safe stop, in order (default: zero effort with a 0.05 s timeout)."""
        return (lambda: self.command_effort(np.zeros(self.dof), timeout=0.05),)

    def _close_steps(self) -> Sequence[StopStep]:
        """Hook: what :meth:`close` sends after the safe stop (e.g. leave motor mode)."""
        return ()

    def _armed(self) -> bool:
        """Hook: whether :meth:`close` must stop the device (default: always)."""
        return True

    def _on_close(self) -> None:
        if self._armed():
            self.safe_stop()
            run_steps(self._close_steps(), self._label())


class ForceSensor(Device):
    """A force/torque sensor. Template method: :meth:`read` checks state and the timeout, then
    calls :meth:`_read_sample`."""

    axes: int

    def read(self, timeout: float | None = None) -> WrenchSample:
        """Latest wrench. Raises DeviceTimeout when no fresh sample arrives in ``timeout`` (s;
        ``None``: the adapter's ``timeout``)."""
        self._check_open()
        return self._read_sample(self._timeout(timeout))

    @abc.abstractmethod
    def _read_sample(self, timeout: float) -> WrenchSample:
        """Hook: one sample within ``timeout`` s (the adapter is open)."""

    def tare(self, timeout: float = 0.5) -> None:  # pragma: no cover - optional
        """Zero the sensor if supported."""
        raise NotImplementedError


def receive_bytes(port: Any, wait: float, waits: Waits = WALL) -> bytes:
    """What the pyserial ``port`` has received; when nothing, wait up to ``wait`` s (through
    ``waits``: the host's clock, or simulated time in lockstep) for it (0: never wait). pyserial's
    ``in_waiting`` can miss bytes the kernel has not moved to the port's input queue yet; the wait's
    poll moves them (Linux ``n_tty_poll``). A port without a descriptor (pyserial's ``loop://``)
    waits its own read timeout instead."""
    n = port.in_waiting
    if not n:
        if wait <= 0:
            return b""
        try:
            fd = port.fileno()
        except (AttributeError, OSError, ValueError):
            first: bytes = port.read(1)
            return first
        if not waits.readable(fd, wait):
            return b""
        n = port.in_waiting or 1
    data: bytes = port.read(n)
    return data


class StreamingSensor(ForceSensor):
    """A force sensor that streams frames over a byte transport (Bota serial, FT-300 stream mode).

    Subclasses count the bytes received in ``rx_bytes`` and decode what :meth:`_pump` reads; every
    wait goes through ``_waits`` (:mod:`hil.protocols.waits`: the host's clock at a bench, simulated
    time on a lockstep bench). :meth:`wait_rx` is the lockstep byte-count barrier: a simulated
    sensor reports how many bytes it wrote, and the host takes exactly those before reading, so a
    test run does not depend on when the kernel delivers them.
    """

    rx_bytes: int = 0
    _waits: Waits = WALL

    @abc.abstractmethod
    def _pump(self, wait: float) -> None:
        """Read what the transport has, waiting up to ``wait`` s for a first byte when it has none
        (0: never wait), and decode it."""

    def _receive_bytes(self, port: Any, wait: float) -> bytes:
        """:func:`receive_bytes` through this sensor's ``_waits``."""
        return receive_bytes(port, wait, self._waits)

    def wait_rx(self, total_bytes: int, timeout: float) -> bool:
        """Receive (and decode, without consuming) until ``rx_bytes >= total_bytes`` or ``timeout``
        (s, on ``_waits``) passes; True if reached."""
        waits = self._waits
        deadline = waits.monotonic() + timeout
        while self.rx_bytes < total_bytes:
            left = deadline - waits.monotonic()
            if left <= 0:
                return False
            self._pump(left)
        return True
