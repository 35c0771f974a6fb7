"""Simulated serial devices: a Bota-style F/T sensor streaming binary frames into a pty.

The simulator owns the *master* side of a pseudo terminal (:func:`os.openpty`); the adapter opens
the slave path (:attr:`SimBota.path`) with ``serial.serial_for_url`` exactly as it would open
``/dev/ttyUSB0``. The frame format is :mod:`hil.protocols.serial_bota`'s.

Modes:

* **lockstep**: call :meth:`SimBota.emit` once per control period; it writes one frame built from
  ``joints.measured_force()`` and the simulated timestamp (``tick * period_us``), so the byte
  stream is a pure function of the plant state, the plan and the seed.
* **free running**: :meth:`SimBota.start` emits at ``rate_hz`` from a thread.

Faults (:mod:`hil.mocks.faults`), decided per emitted frame: drop (nothing written, the timestamp
still advances -> the adapter records a gap), corrupt (one byte after the header flipped -> CRC
failure), garbage (random bytes before the frame -> resynchronisation), stale (the previous frame
is re-sent byte for byte), late (the frame is held and written after the next one), device error
(the code is OR-ed into ``status``), disconnect (silent from tick N to M). :meth:`hangup` closes
the master side: the adapter then gets an I/O error -> DeviceDisconnected.

Lockstep reads: a pty delivers the bytes written on the master asynchronously (the kernel moves
them to the slave side in a worker), so "written" does not mean "readable yet". :attr:`SimBota.tx_bytes`
counts the bytes actually written; a lockstep reader waits until it has received that many
(:meth:`hil.protocols.serial_bota.BotaSerial.wait_rx`) before it decides what is new, which makes
the outcome independent of the machine's load.
"""

from __future__ import annotations

import logging
import threading
from collections import Counter
from collections.abc import Callable
from typing import Any

import numpy as np

from hil.mocks.faults import ByteStreamFaults, FaultInjector, FaultPlan
from hil.mocks.interfaces import SimulatedJoints
from hil.mocks.periodic import PeriodicThread
from hil.mocks.pty import close_fds, open_raw_pty, write_dropping
from hil.protocols.serial_bota import encode_frame

log = logging.getLogger(__name__)


class SimBota:
    """Simulated Bota serial sensor on a pty.

    ``wrench_fn(joints) -> 6-vector`` maps the plant to the measured wrench; by default the
    joints' ``measured_force()`` goes to the axes in ``axes`` (default: first DOF -> Fz).
    ``period_s`` sets the timestamp increment per frame (and the thread rate if started).
    """

    kind = "bota"

    def __init__(
        self,
        joints: SimulatedJoints,
        *,
        period_s: float = 0.001,
        faults: FaultPlan | FaultInjector | None = None,
        seed: int | None = 0,
        axes: tuple[int, ...] = (2,),
        wrench_fn: Callable[[SimulatedJoints], Any] | None = None,
        temperature: float = 25.0,
        status: int = 0,
    ) -> None:
        self.joints = joints
        self.period_s = period_s
        self.period_us = round(period_s * 1e6)
        self.injector = faults if isinstance(faults, FaultInjector) else FaultInjector(faults, seed)
        self.axes = axes
        self.wrench_fn = wrench_fn
        self.temperature = temperature
        self.status = status
        self.tick_count = 0
        self.tx_bytes = 0  # bytes written to the pty (what the host will receive)
        self.stats: Counter[str] = Counter()
        self._frame_faults = ByteStreamFaults(self.injector, self.stats, corrupt_start=1)  # after the 0xAA header
        self._lock = threading.Lock()
        self._emitter = PeriodicThread(self.emit, self.period_s, "sim-bota")
        self._master, self._slave, self.path = open_raw_pty()
        self._closed = False

    def wrench(self) -> np.ndarray:
        if self.wrench_fn is not None:
            return np.asarray(self.wrench_fn(self.joints), dtype=float).reshape(6)
        w = np.zeros(6)
        f = np.asarray(self.joints.measured_force(), dtype=float).reshape(-1)
        for k, axis in enumerate(self.axes):
            w[axis] = f[k]
        return w

    def _write(self, data: bytes) -> None:
        self.tx_bytes += write_dropping(self._master, data, self.stats)

    def emit(self) -> None:
        """Build and write one frame (lockstep). Advances the device tick / timestamp."""
        with self._lock:
            if self._closed:
                return
            self.tick_count += 1
            t = self.tick_count
            inj = self.injector
            if inj.is_disconnected(t):
                return
            status = self.status | inj.error_code(t)
            frame = encode_frame(status, self.wrench(), t * self.period_us, self.temperature)
            data = self._frame_faults.bytes_to_send(frame, t)
            if data is None:
                return
            self._write(data)
            self.stats["frames"] += 1

    def write_raw(self, data: bytes) -> None:
        """Write arbitrary bytes to the stream (tests)."""
        self._write(data)

    def start(self, rate_hz: float | None = None) -> None:
        """Emit frames from a thread at ``rate_hz`` (default: 1/period_s)."""
        if self._emitter.running:
            return
        self._emitter.period = 1.0 / rate_hz if rate_hz else self.period_s
        self._emitter.start()

    def stop(self) -> None:
        self._emitter.stop()

    def hangup(self) -> None:
        """Close both pty ends (like unplugging the USB adapter)."""
        self.stop()
        with self._lock:
            if self._closed:
                return
            self._closed = True
            close_fds(self._master, self._slave)

    def close(self) -> None:
        self.hangup()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


__all__ = ["SimBota"]
