"""Simulated serial devices: a Bota-style F/T sensor streaming binary frames into a pty.

The simulator owns the *master* side of a pseudo terminal (:func:`os.openpty`); the adapter opens
the slave path (:attr:`SimBota.path`) with ``serial.serial_for_url`` exactly as it would open
``/dev/ttyUSB0``. The frame format is :mod:`hil.protocols.serial_bota`'s.

Modes:

* **lockstep**: call :meth:`SimBota.emit` once per control period; it writes the frames due
  (built from ``joints.measured_force()`` and the simulated timestamp, see ``tick_s``), so the
  byte stream is a pure function of the plant state, the plan, the seed and the host's
  configuration commands.
* **free running**: :meth:`SimBota.start` emits at ``rate_hz`` from a thread.

Configuration commands from the host are taken by a reader thread, or, built with
``threaded=False`` (a lockstep bench), by :meth:`SimBota.serve_pending` in the host's thread (the
bench's barrier), so an answer never depends on how fast the machine schedules a thread.

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
import math
import threading
from collections import Counter
from collections.abc import Callable
from typing import Any

import numpy as np

from hil.mocks.faults import ByteStreamFaults, FaultInjector, FaultPlan
from hil.mocks.interfaces import SimulatedJoints
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
from hil.protocols.codecs.bota import BOTA_BASE_HZ, BOTA_BAUD_CODES, STATUS_RAW, encode_frame

logger = logging.getLogger(__name__)


class SimBota:
    """Simulated Bota serial sensor on a pty.

    ``wrench_fn(joints) -> 6-vector`` maps the plant to the measured wrench; by default the
    joints' ``measured_force()`` goes to the axes in ``axes`` (default: first DOF -> Fz).

    Sample rate: ``period_s`` (s per frame; the device timestamp advances by it, in us) until the
    host sends a filter setup ``f,SINC,...``, which sets ``period_s = SINC / 51200`` (Bota's
    example: ``time_step = 0.00001953125 * SINC_LENGTH``); ``sinc_length`` sets it at start.
    ``tick_s``: simulated time per :meth:`emit` call. ``None`` (default): each call is one sample
    of the sensor (one frame). Given (a lockstep bench passes its control period): each call
    advances the sensor's clock by ``tick_s`` and writes the frames whose sample times passed
    (0, 1 or more), so a sensor slower than the loop leaves ticks without a new frame.

    Link budget: at most ``baudrate / 10`` bytes per simulated second leave the sensor
    (:class:`hil.mocks.pty.LinkBudget`); frames beyond it are lost (``stats["link_dropped"]``), as
    they would be on a real line that cannot carry them. ``baudrate`` follows the ``c,...`` baud
    code (0..4 = 9 600, 57 600, 115 200, 230 400, 460 800).

    ASCII configuration protocol (Bota's ``bota_serial_example.py``): on power-up the sensor prints
    ``App Init`` (then ``name: PRODUCT``, ``S/N: N``, ``FW version: V``: Bota's ``rokubimini_serial``
    driver reads the product name, serial number and firmware from this boot text; ``#`` is its
    hardware reset, which reboots the sensor and prints it again) and streams (RUN mode). ``C`` ->
    CONFIG mode (streaming stops), answer
    ``r,0,C,0``; ``c,TEMP_COMP,USE_CALIB,DATA_FORMAT,BAUD_CODE`` -> ``r,0,c,0``;
    ``f,SINC,CHOP,FAST,FIR_DISABLE`` -> ``r,0,f,0``; ``R`` -> RUN mode, ``r,0,R,0``. The example
    sends no terminator: a ``c``/``f`` command ends with the one-digit fourth field (all of them are
    0/1 flags or a 0..4 code). Other bytes are ignored. ``use_calibration = 0`` sets status bit 3
    (raw measurements); only binary output (data format 0) is simulated. :meth:`power_on` is a
    power cycle (``App Init``, default configuration, RUN). ``boot_message``: print ``App Init`` at
    construction too (off by default: a sensor powered before the host opened the port printed it
    to nobody, and the host's open flushes its input; it would also upset ``tx_bytes``).
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
        sinc_length: int | None = None,
        tick_s: float | None = None,
        baudrate: int = 460_800,
        boot_message: bool = False,
        product_name: str = "BFT-SENS-SER-M8",
        serial_number: int = 0,
        firmware: str = "1.0.0",
        threaded: bool = True,
    ) -> None:
        self.joints = joints
        self.threaded = bool(threaded)
        self.product_name, self.serial_number, self.firmware = str(product_name), int(serial_number), str(firmware)
        self._default_period = float(period_s) if sinc_length is None else sinc_length / BOTA_BASE_HZ
        self.period_s = self._default_period
        self.tick_s = None if tick_s is None else float(tick_s)
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
        self._default_baud = int(baudrate)
        self.link = LinkBudget(self._default_baud)
        self.running = True  # RUN mode (streaming); False in CONFIG mode
        self.config: dict[str, int] = {}
        self.commands: list[str] = []  # ASCII commands received, in order
        self._time = 0.0  # sensor clock (s of simulated time)
        self._samples = 0  # frames sampled so far (timestamp = samples * period)
        self._stamp_us = 0.0
        self._cmd = bytearray()
        self._stop = threading.Event()
        self._reader: threading.Thread | None = None
        if self.threaded:
            self._reader = threading.Thread(target=self._serve, name="sim-bota-rx", daemon=True)
            self._reader.start()
        if boot_message:
            self.power_on()

    @property
    def period_us(self) -> int:
        return round(self.period_s * 1e6)

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

    # -- power and configuration ----------------------------------------------------------------
    def boot_text(self) -> bytes:
        """What the sensor prints when it boots: ``App Init``, then ``name: PRODUCT``, ``S/N: N``,
        ``FW version: V``, each ended by CR (Bota's ``rokubimini_serial`` driver parses exactly these
        after a reset: ``RokubiminiSerialCommunication.hpp`` regexes ``App Init``,
        ``name:\\s(.*)\\r``, ``S/N:\\s(.*)\\r``, ``FW version:\\s(.*)\\r``)."""
        return (f"App Init\r\nname: {self.product_name}\r\nS/N: {self.serial_number}\r\n"
                f"FW version: {self.firmware}\r\n").encode("ascii")

    def power_on(self) -> None:
        """Power cycle (or hardware reset ``#``): boot text (:meth:`boot_text`), default
        configuration, RUN mode."""
        with self._lock:
            self._boot()

    def _boot(self) -> None:
        if self._closed:
            return
        self.period_s = self._default_period
        self.link = LinkBudget(self._default_baud)
        self.running = True
        self.config = {}
        self._cmd.clear()
        self._write(self.boot_text())

    def _serve(self) -> None:
        for data in host_writes(self._master, self._stop, poll_s=0.02):
            with self._lock:
                if self._closed:
                    return
                for b in data:
                    self._command_byte(b)

    def serve_pending(self) -> int:
        """Lockstep barrier of a sensor built with ``threaded=False`` (served in the host's thread):
        take every configuration byte the host has written so far (answered at once) and make
        everything written to the line readable by the host; never waits on a clock (see
        :func:`hil.mocks.pty.pending_host_bytes`). Returns the number of bytes processed."""
        n = 0
        for data in pending_host_bytes(self._master):
            n += len(data)
            with self._lock:
                if self._closed:
                    return n
                for b in data:
                    self._command_byte(b)
        push_to_host(self._slave)
        return n

    def _command_byte(self, b: int) -> None:
        ch = chr(b)
        buf = self._cmd
        if not buf:
            if ch == "#":  # hardware reset (rokubimini_serial's RokubiminiSerialCommandHardReset): reboot
                self.commands.append(ch)
                self._boot()
            elif ch in "CR":
                self._finish(ch)
            elif ch in "cf":
                buf.append(b)
            return  # anything else (0xFF, newlines, garbage) is ignored
        buf.append(b)
        text = buf.decode("ascii", errors="replace")
        fields = text.split(",")
        if len(fields) == 5 and fields[4]:  # letter + 4 fields, the last one digit long
            buf.clear()
            self._finish(text)
        elif len(buf) > 40 or not all(c.isdigit() or c == "," for c in text[1:]):
            buf.clear()  # not a command after all

    def _finish(self, cmd: str) -> None:
        self.commands.append(cmd)
        letter = cmd[0]
        if letter == "C":
            self.running = False
        elif letter == "R":
            self.running = True
            self._samples = math.floor(self._time / self.period_s + 1e-9)  # resume from now
        elif letter == "c":
            temp, calib, fmt, baud = (int(x) for x in cmd.split(",")[1:])
            self.config.update(temp_compensation=temp, use_calibration=calib, data_format=fmt, baud_code=baud)
            if baud in BOTA_BAUD_CODES:
                self.link = LinkBudget(BOTA_BAUD_CODES[baud])
        elif letter == "f":
            sinc, chop, fast, fir = (int(x) for x in cmd.split(",")[1:])
            self.config.update(sinc_length=sinc, chop_enable=chop, fast_enable=fast, fir_disable=fir)
            if sinc > 0:
                self.period_s = sinc / BOTA_BASE_HZ
        self.injector.hold_up()
        self._write(f"r,0,{letter},0".encode("ascii"))

    # -- streaming ------------------------------------------------------------------------------
    def emit(self) -> None:
        """One call of the sensor's clock (lockstep): see ``tick_s`` in the class docstring.
        Advances the device tick (fault schedule) by one."""
        with self._lock:
            if self._closed:
                return
            self.tick_count += 1
            step = self.period_s if self.tick_s is None else self.tick_s
            now = self._time  # samples at 0, period, 2 period, ...: due up to now, this call
            self._time += step
            self.link.advance(step)
            if not self.running:
                return
            due = 1 if self.tick_s is None else max(0, math.floor(now / self.period_s + 1e-9) + 1 - self._samples)
            for _ in range(due):
                self._samples += 1
                self._stamp_us += self.period_s * 1e6
                self._emit_frame()

    def _emit_frame(self) -> None:
        t = self.tick_count
        inj = self.injector
        if inj.is_disconnected(t):
            return
        inj.hold_up()
        status = self.status | inj.error_code(t)
        if self.config.get("use_calibration") == 0:
            status |= STATUS_RAW
        frame = encode_frame(status, self.wrench(), round(self._stamp_us), self.temperature)
        data = self._frame_faults.bytes_to_send(frame, t)
        if data is None:
            return
        if not self.link.take(len(frame)):  # line noise (garbage) is not sent by the sensor
            self.stats["link_dropped"] += 1  # the line cannot carry it
            return
        self._write(data)
        self.stats["frames"] += 1

    def write_raw(self, data: bytes) -> None:
        """Write arbitrary bytes to the stream (tests)."""
        with self._lock:
            self._write(data)

    def start(self, rate_hz: float | None = None) -> None:
        """Emit frames from a thread at ``rate_hz`` (default: 1/period_s)."""
        if self._emitter.running:
            return
        self._emitter.period = 1.0 / rate_hz if rate_hz else self.period_s
        if self.tick_s is not None:  # free running: each call stands for one thread period of time
            self.tick_s = self._emitter.period
        self._emitter.start()

    def stop(self) -> None:
        self._emitter.stop()

    def hangup(self) -> None:
        """Close both pty ends (like unplugging the USB adapter)."""
        self.stop()
        self._stop.set()
        if self._reader is not None and self._reader.is_alive() and self._reader is not threading.current_thread():
            # before the fds are closed: a reader still polling a closed fd number would steal
            # the bytes of the next pty that reuses it
            self._reader.join(timeout=2.0)
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
