"""How an adapter waits for its device: on the host's clock at a real bench, on simulated time in lockstep.

Every adapter takes a ``waits`` parameter (default :data:`WALL`) and measures every deadline, sleep
and readiness wait through it, never through :mod:`time` or :mod:`select` directly:

* :class:`Waits` (:data:`WALL`, a real bench and realtime runs): ``monotonic()`` is
  :func:`time.monotonic`, ``sleep`` is :func:`time.sleep`, ``readable`` is :func:`select.select`,
  ``receive(poll, timeout)`` calls ``poll(timeout)`` (a transport's own blocking receive) and
  :meth:`Waits.settle` does nothing.
* :class:`LockstepWaits` (a mocked lockstep bench, :class:`hil.bench.runtime.Bench`): the simulated
  devices run in step with the host (no device thread races the host), so a wait has only two
  outcomes, decided without the wall clock. :meth:`LockstepWaits.settle` is the *barrier*: it
  returns once every simulated device has processed everything the host sent and everything it
  answered can be read by the host, however long the machine takes. A wait first settles; what
  it waits for is then either there (the wait ends at once) or will not come before the simulated
  clock moves (the device dropped the reply, a sensor has no new sample this tick): the wait then
  lasts its whole timeout *in simulated time* only (``monotonic()`` moves on by it, plus
  :data:`WAIT_QUANTUM_S`; the wall clock is not consulted). ``monotonic()`` is the simulated clock
  plus the simulated time the host has spent in such waits. So a reply deadline, a watchdog or a
  retry delay gives the same result on an idle laptop and on a loaded box.

An adapter's wait loop therefore reads the same at a bench and in lockstep::

    deadline = self._waits.monotonic() + timeout
    while not done:
        left = deadline - self._waits.monotonic()
        if left <= 0:
            raise DeviceTimeout(...)
        if self._waits.readable(port, left):
            ...read and parse...

Sample times (``JointSample.t``, ``produced_at``) stay on the adapter's ``clock`` (the simulated
clock in lockstep); ``waits`` only decides how long the host waits.

:meth:`Waits.sent` / :meth:`Waits.received` tell a lockstep link what the adapter put on / took off
a transport whose delivery the kernel does asynchronously (TCP); no-ops at a bench.
"""

from __future__ import annotations

import logging
import select
import time
from collections.abc import Callable
from typing import Any, TypeVar

logger = logging.getLogger(__name__)

T = TypeVar("T")

#: simulated time (s) a lockstep wait that finds nothing lasts beyond its timeout: every such wait moves
#: the clock, so a loop that waits (or polls with timeout 0) until a deadline always passes it, whatever
#: the rounding of ``deadline - monotonic()`` (1 ns: far below any timeout or sample period)
WAIT_QUANTUM_S = 1e-9

#: wall-clock period (s) of a lockstep wait for bytes a simulated device has already written and the
#: kernel has not delivered yet (TCP): how often it looks, never how long (no deadline)
DELIVERY_POLL_S = 0.05


class Waits:
    """The host's clock and waits (a real bench; realtime runs). See the module docstring."""

    #: True on a mocked lockstep bench (simulated time): adapters that run a receive thread at a
    #: bench dispatch what they receive in the waiting thread instead (see :meth:`settle`)
    lockstep: bool = False

    def monotonic(self) -> float:
        """Seconds on the host's monotonic clock (deadlines, ages of arrivals)."""
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        """Wait ``seconds`` (a retry delay, a line's silence)."""
        if seconds > 0:
            time.sleep(seconds)

    def readable(self, fileobj: Any, timeout: float) -> bool:
        """True when ``fileobj`` (an fd, a socket, a pyserial port) has input, waiting at most
        ``timeout`` s for it."""
        return bool(select.select([fileobj], [], [], max(0.0, timeout))[0])

    def receive(self, poll: Callable[[float], T | None], timeout: float) -> T | None:
        """What ``poll(timeout)`` returns: a transport's own wait for one item (a CAN frame, a
        queued reply), None when nothing came within ``timeout`` s."""
        return poll(max(0.0, timeout))

    def settle(self) -> None:
        """The lockstep barrier (see :class:`LockstepWaits`); nothing at a bench."""

    def sent(self, n: int = 1) -> None:
        """``n`` units (bytes or requests, as the link counts) went out on the transport (lockstep
        accounting of asynchronously delivered transports; nothing at a bench)."""

    def received(self, n: int) -> None:
        """``n`` bytes were taken off the transport (lockstep accounting; nothing at a bench)."""


#: the host's clock and waits: every adapter's default
WALL = Waits()


def _nothing() -> None:
    """An empty barrier (see :meth:`LockstepWaits.settle`)."""


#: the barrier of a device with nothing to serve before a wait: set ``link.barrier = NO_BARRIER``
NO_BARRIER = _NOTHING = _nothing


class _SimulatedHost:
    """What every :class:`LockstepWaits` of one bench shares: the simulated clock, the barrier and
    the simulated time the host spent waiting (one host thread waits for all its devices)."""

    def __init__(self, clock: Callable[[], float], settle: Callable[[], None]) -> None:
        self.clock = clock
        self.settle = settle
        self.waited = 0.0
        self.settles = 0
        self.settling = False


class LockstepWaits(Waits):
    """Simulated time for the adapters of a mocked lockstep bench (see the module docstring).

    ``clock``: the simulation's clock (s); ``settle``: the bench's barrier (every simulated device
    processes what the host sent and makes its answers readable; it may block for as long as the
    machine needs, never on a deadline). :attr:`waited` (s) is the simulated time the host spent in
    waits whose object never came; ``monotonic() = clock() + waited``.

    :meth:`link` gives one device's view: the same clock and ``waited``, its own barrier
    (:attr:`barrier`: serving that device is enough for a wait on it; None: the bench's) and its own
    counters :attr:`tx_units` / :attr:`rx_bytes` (:meth:`sent` / :meth:`received`) and
    :attr:`device_tx` (written by the device), which a barrier over an asynchronously delivering
    transport needs (TCP: the server has answered every request the host sent; a receive then waits,
    without deadline, until the host has taken every byte of the answers).
    """

    lockstep = True

    def __init__(self, clock: Callable[[], float], settle: Callable[[], None],
                 _host: _SimulatedHost | None = None) -> None:
        self._host = _host if _host is not None else _SimulatedHost(clock, settle)
        #: this view's barrier (a device's own: see :meth:`link`); None: the bench's
        self.barrier: Callable[[], None] | None = None
        self.tx_units = 0
        self.rx_bytes = 0
        #: bytes the device has written on this link (a device behind an asynchronously delivering
        #: transport counts them: a TCP server); more than ``rx_bytes``: some are still on their way
        self.device_tx = 0

    def link(self) -> LockstepWaits:
        """A view for one device (shared time and barrier, own counters)."""
        return LockstepWaits(self._host.clock, self._host.settle, self._host)

    @property
    def waited(self) -> float:
        """Simulated time (s) the host spent in waits that found nothing."""
        return self._host.waited

    @property
    def settles(self) -> int:
        """Barriers run so far (diagnostics, benchmarks)."""
        return self._host.settles

    def monotonic(self) -> float:
        h = self._host
        return h.clock() + h.waited

    def settle(self) -> None:
        h = self._host
        if self.barrier is _NOTHING:  # a device that answers in the sender's thread (a sync CAN node)
            return
        if h.settling:  # re-entrant (a device's reply path waiting inside the barrier): already settling
            return
        h.settling = True
        try:
            h.settles += 1
            (self.barrier or h.settle)()
        finally:
            h.settling = False

    def sleep(self, seconds: float) -> None:
        self.settle()
        if seconds > 0:
            self._host.waited += seconds + WAIT_QUANTUM_S

    def readable(self, fileobj: Any, timeout: float) -> bool:
        self.settle()
        if select.select([fileobj], [], [], 0.0)[0]:
            return True
        self._host.waited += max(0.0, timeout) + WAIT_QUANTUM_S
        return False

    def receive(self, poll: Callable[[float], T | None], timeout: float) -> T | None:
        self.settle()
        got = poll(0.0)
        while got is None and self.device_tx > self.rx_bytes:
            # written by the device, still on its way through the kernel (TCP): it will arrive,
            # so wait for it (a polling period, not a deadline)
            got = poll(DELIVERY_POLL_S)
        if got is None:
            self._host.waited += max(0.0, timeout) + WAIT_QUANTUM_S
        return got

    def sent(self, n: int = 1) -> None:
        self.tx_units += n

    def received(self, n: int) -> None:
        self.rx_bytes += n


__all__ = ["DELIVERY_POLL_S", "NO_BARRIER", "WAIT_QUANTUM_S", "WALL", "LockstepWaits", "Waits"]
