"""Simulated Robotiq FT-300 on a serial line (pty): Modbus RTU until told to stream, then frames.

The simulator owns the *master* side of a pseudo terminal; an adapter opens the slave path
(:attr:`SimFT300Stream.path`) exactly as it would open ``/dev/ttyUSB0``
(:class:`hil.protocols.modbus_robotiq.RobotiqFT300Stream` for stream mode, or the polled
:class:`~hil.protocols.modbus_robotiq.RobotiqFT300` with ``rtu://PATH``).

Behaviour (FT-300 manual, "Serial communication": Modbus RTU, slave 9, then "Data stream"):

* **Modbus mode** (at power-up): a background thread (``threaded=False``, what a lockstep bench
  builds: the host's barrier :meth:`SimFT300Stream.serve_pending`, in the host's thread) answers
  RTU requests addressed to the slave id: FC03/FC04 reads of the register map of
  :mod:`hil.mocks.modbus_devices` (180-185 wrench, 190-192 acceleration = 0, 410, 500-502
  firmware, 510-513 serial number, 514 production year; other addresses -> exception 2), FC06/FC16
  writes of register 410 (echo; other addresses -> exception 2). Requests with a bad CRC or for
  another id get no reply, as on an RS-485 bus.
  Writing 0x0200 to register 410 switches to stream mode right after the echo.
* **Stream mode**: 16-byte frames ``20 4E Fx..Mz CRC`` (:func:`encode_stream_frame`), either one
  per :meth:`emit` call (lockstep: the byte stream is a pure function of the plant state, the
  fault plan and the seed) or at ``rate_hz`` from a thread (:meth:`start`; 100 Hz like the
  sensor). The device ignores everything it receives except 0xFF: ``jam_bytes`` consecutive 0xFF
  (the manual: about 50) stop the stream and it answers Modbus again.

The wrench source is a :class:`SimulatedJoints` (``measured_force()``) or a callable returning up
to 6 values (N, N.m); shorter vectors fill Fx, Fy, ... in order. Values saturate at the int16
range like the real sensor.

Faults (:mod:`hil.mocks.faults`), decided per emitted frame; the *tick* is the index of the frame
(1, 2, ... counted while streaming): drop (nothing written), corrupt (one byte after the header
flipped -> CRC failure), garbage (random bytes before the frame -> resynchronisation), stale (the
previous frame re-sent byte for byte), late (held and written after the next frame), disconnect
(silent from tick N to M). ``error_code`` has no place in the stream format and is ignored; Modbus
replies are never faulted. :meth:`hangup` closes the pty (the adapter gets an I/O error).
"""

from __future__ import annotations

import logging
import math
import struct
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

import numpy as np

from hil.mocks.faults import BoundedLog, ByteStreamFaults, FaultInjector, FaultPlan
from hil.mocks.interfaces import SimulatedJoints
from hil.mocks.modbus_devices import (
    firmware_registers,
    serial_registers,
    wrench_source,
    wrench_to_registers,
)
from hil.mocks.periodic import PeriodicThread
from hil.mocks.pty import (
    LinkBudget,
    close_fds,
    host_writes,
    open_raw_pty,
    pending_host_bytes,
    push_to_host,
    write_dropping,
)
from hil.protocols.codecs.crc import crc16_modbus
from hil.protocols.codecs.robotiq import (
    DEFAULT_SLAVE_ID,
    REG_OUTPUT_SELECT,
    REG_WRENCH,
    STREAM_START_VALUE,
    encode_stream_frame,
    rtu_frame,
)

logger = logging.getLogger(__name__)

WrenchSource = Callable[[], Any]

REG_ACCEL = 190
REG_FIRMWARE = 500
REG_SERIAL = 510
REG_PRODUCTION_YEAR = 514
EXC_ILLEGAL_FUNCTION = 1
EXC_ILLEGAL_ADDRESS = 2
EXC_ILLEGAL_VALUE = 3


class SimFT300Stream:
    """Simulated FT-300 on a pty (see the module docstring). Use as a context manager or call
    :meth:`close` (idempotent)."""

    kind = "ft300_stream"

    def __init__(
        self,
        source: SimulatedJoints | WrenchSource | None = None,
        *,
        rate_hz: float = 100.0,
        slave: int = DEFAULT_SLAVE_ID,
        faults: FaultPlan | FaultInjector | None = None,
        seed: int | None = 0,
        jam_bytes: int = 50,
        firmware: tuple[int, int, int] = (1, 0, 3),
        serial: tuple[str, int] = ("SIM", 1),
        production_year: int = 2024,
        streaming: bool = False,
        tick_s: float | None = None,
        baudrate: int = 19_200,
        threaded: bool = True,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.rate_hz = float(rate_hz)
        self.threaded = bool(threaded)
        self._clock = clock  # RTU inter-frame silence
        # tick_s None: each emit() is one stream frame (1/rate_hz of simulated time); given (a
        # lockstep bench's control period): each emit() advances the sensor clock by tick_s and
        # sends the frames due at rate_hz. The line carries at most baudrate/10 bytes per
        # simulated second (LinkBudget): frames beyond it are lost (stats["link_dropped"]).
        self.tick_s = None if tick_s is None else float(tick_s)
        self.link = LinkBudget(baudrate)
        self._time = 0.0
        self._samples = 0
        self.slave = int(slave)
        self.injector = faults if isinstance(faults, FaultInjector) else FaultInjector(faults, seed)
        self.jam_bytes = int(jam_bytes)
        self._source = wrench_source(source)
        self._static: dict[int, int] = {REG_OUTPUT_SELECT: 0, REG_PRODUCTION_YEAR: production_year & 0xFFFF}
        for k in range(3):
            self._static[REG_ACCEL + k] = 0
        for k, v in enumerate(firmware_registers(firmware)):
            self._static[REG_FIRMWARE + k] = v
        for k, v in enumerate(serial_registers(*serial)):
            self._static[REG_SERIAL + k] = v
        self.tick_count = 0
        self.stats: Counter[str] = Counter()
        self.tx_bytes = 0  # bytes written to the pty (what the host will receive)
        self._tx_lock = threading.Lock()
        self._frame_faults = ByteStreamFaults(self.injector, self.stats, corrupt_start=2)  # after 0x20 0x4E
        self.written: BoundedLog = BoundedLog()  # newest (function, address, values)
        self._streaming = bool(streaming)
        self._ff_run = 0
        self._rx = bytearray()
        self._rx_t = 0.0
        self._lock = threading.RLock()
        self._state = threading.Condition(self._lock)
        self._stop = threading.Event()
        self._emitter = PeriodicThread(self.emit, 1.0 / self.rate_hz, "sim-ft300-stream")
        self._closed = False
        self._master, self._slave, self.path = open_raw_pty()
        self._rx_thread: threading.Thread | None = None
        if self.threaded:
            self._rx_thread = threading.Thread(target=self._serve, name="sim-ft300-stream-rx", daemon=True)
            self._rx_thread.start()
        logger.debug("simulated FT-300 (stream) on %s", self.path)

    # -- public -----------------------------------------------------------------------------------
    @property
    def streaming(self) -> bool:
        """True while the device is in stream mode."""
        return self._streaming

    def wait_streaming(self, state: bool = True, timeout: float = 1.0) -> bool:
        """Wait until :attr:`streaming` equals ``state``; returns whether it does."""
        with self._state:
            return self._state.wait_for(lambda: self._streaming == state, timeout)

    def wrench(self) -> np.ndarray:
        """The current wrench (6,) from the source (N, N.m)."""
        w = np.zeros(6)
        src = np.asarray(self._source(), dtype=float).reshape(-1)[:6]
        w[: src.size] = src
        return w

    def emit(self) -> bool:
        """One lockstep call of the sensor's clock: write the stream frame(s) due (one per call
        without ``tick_s``). False (and no tick) when not streaming."""
        with self._lock:
            if self._closed or not self._streaming:
                return False
            period = 1.0 / self.rate_hz
            step = period if self.tick_s is None else self.tick_s
            now = self._time
            self._time += step
            self.link.advance(step)
            due = 1 if self.tick_s is None else max(0, math.floor(now / period + 1e-9) + 1 - self._samples)
            for _ in range(due):
                self._samples += 1
                self._emit_frame()
            return True

    def _emit_frame(self) -> None:
        self.tick_count += 1
        t = self.tick_count
        inj = self.injector
        if inj.is_disconnected(t):
            self.stats["silent"] += 1
            return
        inj.hold_up()
        frame = encode_stream_frame(self.wrench())
        data = self._frame_faults.bytes_to_send(frame, t)
        if data is None:
            return
        if not self.link.take(len(frame)):  # line noise (garbage) is not sent by the sensor
            self.stats["link_dropped"] += 1  # the 19 200 baud line cannot carry it
            return
        self._write(data)
        self.stats["frames"] += 1

    def start(self, rate_hz: float | None = None) -> None:
        """Emit frames from a thread at ``rate_hz`` (default :attr:`rate_hz`) while streaming."""
        if self._emitter.running:
            return
        self._emitter.period = 1.0 / (rate_hz or self.rate_hz)
        if self.tick_s is not None:  # free running: each call stands for one thread period of time
            self.tick_s = self._emitter.period
        self._emitter.start()

    def stop(self) -> None:
        """Stop the emitting thread (the device stays in its mode)."""
        self._emitter.stop()

    def write_raw(self, data: bytes) -> None:
        """Write arbitrary bytes to the line (tests)."""
        with self._lock:
            self._write(data)

    def hangup(self) -> None:
        """Stop every thread and close both pty ends (like unplugging the USB adapter)."""
        self.stop()
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self._stop.set()
        if self._rx_thread is not None:
            self._rx_thread.join(timeout=2.0)
        close_fds(self._master, self._slave)

    def close(self) -> None:
        self.hangup()

    def __enter__(self) -> SimFT300Stream:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- internals --------------------------------------------------------------------------------
    def _write(self, data: bytes) -> None:
        n = write_dropping(self._master, data, self.stats)
        with self._tx_lock:
            self.tx_bytes += n

    def _serve(self) -> None:
        for data in host_writes(self._master, self._stop):
            self._receive(data)

    def serve_pending(self) -> int:
        """Lockstep barrier of a sensor built with ``threaded=False`` (served in the host's thread):
        process every byte the host has written so far (Modbus requests answered, a jam taken) and
        make everything written to the line readable by the host; never waits on a clock (see
        :func:`hil.mocks.pty.pending_host_bytes`). Returns the number of bytes processed."""
        n = 0
        for data in pending_host_bytes(self._master):
            n += len(data)
            self._receive(data)
        push_to_host(self._slave)
        return n

    def _receive(self, data: bytes) -> None:
        with self._lock:
            if self._closed:
                return
            if self._streaming:
                for b in data:
                    self._ff_run = self._ff_run + 1 if b == 0xFF else 0
                    if self._ff_run >= self.jam_bytes:
                        self._set_streaming(False)
                        self.stats["jams"] += 1
                        self._ff_run = 0
                        self._rx.clear()
                        break
                return
            now = self._clock()
            if self._rx and now - self._rx_t > 0.05:  # RTU: a long silence ends any partial frame
                self._rx.clear()
            self._rx_t = now
            self._rx += data
            self._process_requests()

    def _set_streaming(self, on: bool) -> None:
        self._streaming = on
        self._state.notify_all()

    def _process_requests(self) -> None:
        buf = self._rx
        while buf:
            n = self._request_length(buf)
            if n == 0:  # cannot be a request start: drop one byte
                del buf[:1]
                continue
            if n < 0 or len(buf) < n:
                return  # need more bytes
            frame = bytes(buf[:n])
            if crc16_modbus(frame[:-2]) != int.from_bytes(frame[-2:], "little"):
                self.stats["bad_requests"] += 1
                del buf[:1]
                continue
            del buf[:n]
            if frame[0] != self.slave:
                continue  # another slave's request: stay silent
            self.stats["requests"] += 1
            reply, start = self._handle(frame[1:-2])
            if start:  # in stream mode from the echo on; emit() takes the same lock: no frame before it
                self._set_streaming(True)
                self._ff_run = 0
            self.injector.hold_up()
            self._write(rtu_frame(self.slave, reply))
            if start:
                return

    @staticmethod
    def _request_length(buf: bytearray) -> int:
        """Length of the request at ``buf[0]``; -1 = need more bytes, 0 = not a request start."""
        if len(buf) < 2:
            return -1
        fc = buf[1]
        if fc in (3, 4, 6):
            return 8
        if fc == 16:
            if len(buf) < 7:
                return -1
            count = int.from_bytes(buf[4:6], "big")
            return 9 + buf[6] if 1 <= count <= 123 and buf[6] == 2 * count else 0
        return 0

    def _register(self, addr: int, wrench_regs: list[int]) -> int | None:
        if REG_WRENCH <= addr < REG_WRENCH + 6:
            return wrench_regs[addr - REG_WRENCH]
        return self._static.get(addr)

    def _handle(self, pdu: bytes) -> tuple[bytes, bool]:
        """Reply PDU to a request PDU, and whether the stream starts after it."""
        fc = pdu[0]
        if fc in (3, 4):
            addr, count = struct.unpack_from(">HH", pdu, 1)
            if not 1 <= count <= 125:
                return bytes([fc | 0x80, EXC_ILLEGAL_VALUE]), False
            regs = wrench_to_registers(self.wrench())
            found = [self._register(a, regs) for a in range(addr, addr + count)]
            if any(v is None for v in found):
                return bytes([fc | 0x80, EXC_ILLEGAL_ADDRESS]), False
            return bytes([fc, 2 * count]) + struct.pack(f">{count}H", *found), False
        if fc == 6:
            addr, value = struct.unpack_from(">HH", pdu, 1)
            values = [value]
        else:  # 16
            addr, count = struct.unpack_from(">HH", pdu, 1)
            values = list(struct.unpack_from(f">{count}H", pdu, 6))
        if addr != REG_OUTPUT_SELECT or len(values) != 1:
            return bytes([fc | 0x80, EXC_ILLEGAL_ADDRESS]), False
        self.written.append((fc, addr, values))
        self._static[REG_OUTPUT_SELECT] = values[0]
        echo = pdu[:5]  # FC06: address + value; FC16: address + count
        return echo, values[0] == STREAM_START_VALUE


__all__ = ["SimFT300Stream"]
