"""Pseudo-terminal plumbing shared by the serial-line simulators (Bota, FT-300 stream, Dynamixel).

The simulator owns the *master* end; the adapter under test opens the *slave* path like a real
USB-serial port. The slave is put in raw mode so bytes pass unchanged (no line discipline).
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import threading
import time
import tty
from collections import Counter
from collections.abc import Iterator, MutableMapping

logger = logging.getLogger(__name__)


def open_raw_pty(*, nonblocking_master: bool = True) -> tuple[int, int, str]:
    """Open a pty pair; return ``(master_fd, slave_fd, slave_path)`` with the slave in raw mode."""
    master, slave = os.openpty()
    tty.setraw(slave)
    if nonblocking_master:
        os.set_blocking(master, False)
    return master, slave, os.ttyname(slave)


def write_dropping(fd: int, data: bytes, stats: MutableMapping[str, int] | Counter) -> int:
    """Write to a non-blocking master like a device UART: what does not fit is lost, and counted.

    ``stats["overflow_bytes"]`` counts bytes of partial writes, ``stats["overflow_frames"]``
    frames dropped whole because nobody reads the port. Returns the number of bytes written (what
    the host will receive; a lockstep reader waits for exactly that many, see ``tx_bytes``).
    """
    try:
        n = os.write(fd, data)
        if n < len(data):
            stats["overflow_bytes"] += len(data) - n
        return n
    except BlockingIOError:  # nobody reads: the pty buffer is full -> frame lost
        stats["overflow_frames"] += 1
    except OSError as exc:
        logger.debug("pty write failed: %s", exc)
    return 0


def close_fds(*fds: int) -> None:
    """Close file descriptors, ignoring those already closed (like unplugging the adapter)."""
    for fd in fds:
        with contextlib.suppress(OSError):
            os.close(fd)


def host_writes(fd: int, stop: threading.Event, poll_s: float = 0.05) -> Iterator[bytes]:
    """Yield the bytes the host writes to the pty, chunk by chunk, until ``stop`` is set or the
    master is closed. EIO while no slave end is open (host not yet connected, or reconnecting)
    is waited out, as a device waits for its cable to be plugged back in."""
    while not stop.is_set():
        try:
            ready, _, _ = select.select([fd], [], [], poll_s)
        except (OSError, ValueError):  # master closed under us
            return
        if not ready:
            continue
        try:
            data = os.read(fd, 4096)
        except BlockingIOError:
            continue
        except OSError:  # EIO while no slave is open
            time.sleep(0.01)
            continue
        if data:
            yield data


def pending_host_bytes(fd: int) -> Iterator[bytes]:
    """Yield, without waiting, every chunk the host has written to the pty so far (a device served
    in the host's thread: a lockstep bench). A poll of a pty that finds no input first runs the
    kernel's worker that moves bytes to this end (Linux ``n_tty_poll`` -> ``tty_buffer_flush_work``),
    so "written by the host" is "readable here" with no clock involved. Ends at the first poll
    without input; an I/O error (no slave end open, master closed) ends it too."""
    while True:
        try:
            if not select.select([fd], [], [], 0.0)[0]:
                return
            data = os.read(fd, 4096)
        except (OSError, ValueError):
            return
        if not data:
            return
        yield data


def push_to_host(slave_fd: int) -> None:
    """Make what the device wrote on the master visible to the host's ``in_waiting`` now: pyserial's
    ``in_waiting`` (FIONREAD) does not run the kernel's worker that moves pty bytes to the slave's
    input queue, a poll of the slave does (see :func:`pending_host_bytes`). ``slave_fd`` is the
    device's own descriptor of the slave end (the same terminal as the host's)."""
    with contextlib.suppress(OSError, ValueError):
        select.select([slave_fd], [], [], 0.0)


class LinkBudget:
    """What a simulated serial line can still carry: ``baud / 10`` bytes per *simulated* second
    (8N1: 10 bit times per byte; :mod:`hil.protocols.link_budget`).

    The device calls :meth:`advance` with the simulated time that passed (a lockstep tick, or the
    period of its free-running thread) and :meth:`take` before writing a frame: a frame that does
    not fit in the bytes accumulated so far is not sent (the UART could not have sent it in that
    time). Nothing sleeps: lockstep runs are not slowed down, and the result does not depend on
    the machine. Up to ``burst_s`` seconds of unused capacity (plus 64 bytes) are kept, so that
    frames produced in bursts by the tick discretization pass when the average rate fits.
    """

    def __init__(self, baud: float, burst_s: float = 0.02) -> None:
        if not baud > 0:
            raise ValueError(f"baud must be > 0, got {baud!r}")
        self.baud = float(baud)
        self.bytes_per_s = self.baud / 10.0
        self.cap = self.bytes_per_s * float(burst_s) + 64.0
        self.credit = self.cap
        self.refused_frames = 0
        self.refused_bytes = 0

    def advance(self, seconds: float) -> None:
        """``seconds`` of simulated time passed: add their capacity (up to the cap)."""
        self.credit = min(self.cap, self.credit + self.bytes_per_s * max(0.0, float(seconds)))

    def take(self, n: int) -> bool:
        """True (and the bytes are used) if ``n`` more bytes fit now; else count the refusal."""
        if n <= self.credit:
            self.credit -= n
            return True
        self.refused_frames += 1
        self.refused_bytes += n
        return False
