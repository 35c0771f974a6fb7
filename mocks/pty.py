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

log = logging.getLogger(__name__)


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
        log.debug("pty write failed: %s", exc)
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
