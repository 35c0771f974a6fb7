"""Bota Systems serial force/torque sensors (binary streaming mode) as a :class:`ForceSensor`.

Frame format (source: Bota Systems' ``bota_serial_example.py`` from their python_interface
repository, as vendored in ``tud-phi/bota_ft_sensors``, and the ArduPilot BotaSys driver's
``AppOutput`` struct, consulted through the search tool)::

    0xAA | status u16 | Fx Fy Fz Tx Ty Tz f32 | timestamp u32 | temperature f32 | CRC16 u16
    1      2            24                      4               4                 2   = 37 bytes

* All fields little-endian. The CRC is CRC-16/X-25 over the 34 payload bytes (header excluded),
  sent low byte first.
* Forces in N, torques in N.m, in the sensor frame (calibrated output, ``use_calibration=1``).
* ``status`` bits: 0 app_took_too_long, 1 overrange, 2 invalid_measurements, 3 raw_measurements.
* ``timestamp``: a free-running u32 counter. **Assumption**: microseconds (the example code does
  not state the unit); only differences are used (gap detection), modulo 2**32.
* ``temperature`` in deg C.

Configuration (as Bota's ``bota_serial_example.py`` does on start; ``configure=True``, default):
the adapter sends ``C`` (CONFIG mode) and waits for ``r,0,C,0``, then the communication setup
``c,TEMP_COMPENSATION,USE_CALIBRATION,DATA_FORMAT,BAUD_CODE`` (``r,0,c,0``; data format 0 =
binary, baud code 0..4 = 9 600, 57 600, 115 200, 230 400, 460 800: :data:`BOTA_BAUD_CODES`), the
filter setup ``f,SINC_LENGTH,CHOP_ENABLE,FAST_ENABLE,FIR_DISABLE`` (``r,0,f,0``) and ``R`` (RUN
mode, ``r,0,R,0``), each reply within ``config_timeout``, else DeviceTimeout naming the command.
The sample period is ``SINC_LENGTH / 51200`` s (the example's ``time_step = 0.00001953125 *
SINC_LENGTH``); ``sinc_length`` defaults to ``round(51200 * period_s)`` when ``period_s`` is
given, else the example's 512 (100 Hz). Defaults follow the example (no temperature compensation,
calibration on, binary, chop off, fast off, FIR disabled). A reply ``r,0,X,N`` with N != 0 is
taken as a refusal (DeviceError; assumption: the example only ever checks for ``,0``). The frame
rate must fit the line: 37 bytes per frame at ``baudrate / 10`` bytes/s carries at most 1 245
frames/s at 460 800 baud (checked for scenes by :mod:`hil.protocols.link_budget`).

Error handling (documented behaviour):

* Garbage bytes: the parser resynchronises on the next 0xAA whose 37-byte frame has a valid CRC;
  skipped bytes are counted in ``stats["resync_bytes"]``.
* CRC failure: the frame is dropped and counted in ``stats["crc_errors"]`` (a gap in the data);
  :meth:`BotaSerial.read` raises :class:`hil.errors.ChecksumError` only with
  ``on_crc_error="raise"``.
* Missing samples: detected from timestamp jumps larger than the sample period (``period_s``
  given, or learned from the first two frames); counted in ``stats["gaps"]`` (events) and
  ``stats["missed_samples"]``.
* Stale data (a frame repeating the previous timestamp) is not new data: counted in
  ``stats["stale"]`` (``counters()["repeated_frames"]``). A frame *older* than the newest one
  (its 32-bit microsecond timestamp behind it, modulo the wrap: delivered late) is not new data
  either: counted in ``stats["late"]``, never read as a gap of 2^32 us.
* Status bit 0 (app_took_too_long, not a fault by default): counted per frame in
  ``stats["app_took_too_long"]``.
* Freshness: ``WrenchSample.produced_at`` is the arrival (adapter clock) of the frame that
  carried a *new* device timestamp; ``seq`` advances only with one. A read that finds no new frame
  waits for one until the newest data is ``timeout`` old (host clock, ``waits``), then returns the previous
  sample again (same ``seq`` and ``produced_at``; ``counters()["stale"]``): the runner's watchdog
  judges its age against ``watchdog_ms``. Only a read before any frame ever arrived raises
  DeviceTimeout.
* Lockstep: :meth:`BotaSerial.wait_rx` blocks until a given number of bytes has been received
  (what a simulated sensor reports it wrote), so that what a read finds does not depend on how
  fast the kernel moves pty bytes.
* ``status & fault_mask`` (default overrange | invalid_measurements) raises
  :class:`hil.errors.DeviceFault` with ``code = status``.
* A closed / lost port raises :class:`hil.errors.DeviceDisconnected`. Nothing blocks longer than
  the call's timeout.
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Callable
from typing import Literal

import numpy as np
import serial

from hil.errors import ChecksumError, DeviceDisconnected, DeviceError, DeviceFault, DeviceTimeout
from hil.protocols.base import DeviceInfo, StreamingSensor, WrenchSample
from hil.protocols.codecs import bota as _wire
from hil.protocols.codecs import forwarder
from hil.protocols.codecs.bota import (
    BOTA_BASE_HZ,
    BOTA_BAUD_CODES,
    STATUS_APP_TOOK_TOO_LONG,
    STATUS_INVALID,
    STATUS_OVERRANGE,
    BotaFrame,
    FrameParser,
)
from hil.protocols.waits import WALL, Waits

logger = logging.getLogger(__name__)


class BotaSerial(StreamingSensor):
    """A Bota serial F/T sensor streaming binary frames; 6 axes (Fx, Fy, Fz, Tx, Ty, Tz).

    Parameters
    ----------
    url: anything :func:`serial.serial_for_url` opens: ``/dev/ttyUSB0``, a pty path,
        ``socket://host:port``, ``loop://``.
    baudrate: 460800 is the sensor's default fast rate.
    period_s: nominal sample period for gap detection (``None``: learned from the stream).
    fault_mask: status bits that raise DeviceFault.
    on_crc_error: ``"count"`` (default, a recorded gap) or ``"raise"`` (ChecksumError).
    clock: time source for ``WrenchSample.t``.
    poll_s: longest single wait for input inside a read (never exceeds the call's timeout).
    configure: send the example's configuration sequence on open (see the module docstring).
    sinc_length, chop_enable, fast_enable, fir_disable, temp_compensation, use_calibration: the
        configuration sent (``sinc_length`` default: from ``period_s``, else 512).
    config_timeout: seconds to wait for each configuration reply.
    waits: how deadlines and waits are measured (:mod:`hil.protocols.waits`: the host's clock,
        simulated time on a lockstep bench).
    """

    axes = 6

    def __init__(
        self,
        url: str,
        baudrate: int = 460800,
        *,
        period_s: float | None = None,
        fault_mask: int = STATUS_OVERRANGE | STATUS_INVALID,
        on_crc_error: Literal["count", "raise"] = "count",
        clock: Callable[[], float] = time.monotonic,
        poll_s: float = 0.002,
        timeout: float = 0.1,
        configure: bool = True,
        sinc_length: int | None = None,
        chop_enable: int = 0,
        fast_enable: int = 0,
        fir_disable: int = 1,
        temp_compensation: int = 0,
        use_calibration: int = 1,
        config_timeout: float = 1.0,
        waits: Waits = WALL,
    ) -> None:
        if on_crc_error not in ("count", "raise"):
            raise ValueError("on_crc_error must be 'count' or 'raise'")
        codes = {v: k for k, v in BOTA_BAUD_CODES.items()}
        if configure and int(baudrate) not in codes:
            raise ValueError(f"Bota baud rate must be one of {sorted(codes)}, got {baudrate}")
        if sinc_length is None:
            sinc_length = max(1, round(BOTA_BASE_HZ * period_s)) if period_s is not None else 512
        self.sinc_length = int(sinc_length)
        if configure and period_s is None:
            period_s = self.sinc_length / BOTA_BASE_HZ
        self.url = url
        self.period_s = period_s
        self._learned_period = False
        self.fault_mask = fault_mask
        self.on_crc_error = on_crc_error
        self.clock = clock
        self._waits = waits
        self.timeout = timeout
        self.poll_s = float(poll_s)
        self.parser = FrameParser()
        self.label = f"Bota sensor on {url}"
        self._last_ts: int | None = None
        self._offset = np.zeros(6)
        self._crc_seen = 0
        self.last_frame: BotaFrame | None = None
        self.rx_bytes = 0  # bytes received from the port so far
        self._pending: list[BotaFrame] = []  # decoded, not yet accepted
        self._last: WrenchSample | None = None
        self._last_rx_wall = -float("inf")  # host monotonic time of the newest fresh frame
        self._stale_reads = 0
        self._timeouts = 0
        try:
            # a write that takes longer than the timeout is an error at a bench; on a lockstep bench
            # nothing is measured on the wall clock (pyserial's write timeout is). While the sensor is
            # configured (open, read_identity) the configuration timeout applies: pyserial's POSIX write
            # raises "Write timeout" when the whole call, preemption included, took longer than the
            # timeout even though every byte went out, which a loaded machine makes of a 5 ms watchdog
            self._run_write_timeout = None if waits.lockstep else timeout
            self._ser = serial.serial_for_url(url, baudrate=baudrate, timeout=poll_s,
                                              write_timeout=self._config_write_timeout(config_timeout))
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DeviceDisconnected(f"cannot open {url!r}: {exc}") from exc
        self.info = DeviceInfo(driver="bota_serial", transport=f"serial:{url}", vendor="Bota Systems",
                               extra={"sinc_length": self.sinc_length, "baudrate": int(baudrate)})
        self._setup: list[str] = []  # the configuration commands sent on open (read_identity re-sends them)
        if configure:
            setup = [
                "C",
                f"c,{int(temp_compensation)},{int(use_calibration)},0,{codes[int(baudrate)]}",
                f"f,{self.sinc_length},{int(chop_enable)},{int(fast_enable)},{int(fir_disable)}",
                "R",
            ]
            self._setup = setup
            try:
                for cmd in setup:
                    self._command(cmd, float(config_timeout))
            except BaseException:
                self.close()
                raise
        self._ser.write_timeout = self._run_write_timeout

    def _config_write_timeout(self, config_timeout: float) -> float | None:
        """pyserial's write timeout while configuring [s]: the larger of the run's and ``config_timeout``
        (None on a lockstep bench)."""
        run = self._run_write_timeout
        return None if run is None else max(run, float(config_timeout))

    def _command(self, cmd: str, timeout: float) -> None:
        """Send one ASCII configuration command and wait for its ``r,0,X,N`` reply; bytes after the
        reply go to the frame parser."""
        try:
            self._ser.write(cmd.encode("ascii"))
            self._ser.flush()
        except (serial.SerialException, OSError) as exc:
            raise DeviceDisconnected(f"{self.url}: port lost: {exc}") from exc
        token = f"r,0,{cmd[0]},".encode("ascii")
        buf = bytearray()
        waits = self._waits
        deadline = waits.monotonic() + timeout
        while True:
            k = buf.find(token)
            if k >= 0 and len(buf) > k + len(token):
                code = buf[k + len(token)]
                rest = bytes(buf[k + len(token) + 1 :])
                if cmd[0] == "R":
                    self._pending += self.parser.feed(rest)
                if code != ord("0"):
                    reply = bytes(buf[k : k + len(token) + 1])
                    raise DeviceError(f"{self.url}: Bota sensor refused {cmd!r} (reply {reply!r})")
                return
            left = deadline - waits.monotonic()
            if left <= 0:
                raise DeviceTimeout(f"{self.url}: no {token.decode()}0 reply to {cmd!r} within {timeout:.2f} s "
                                    f"(is it a Bota serial sensor at this baud rate?)")
            buf += self._read_bytes(left)

    @property
    def stats(self) -> Counter[str]:
        """Counters: frames, crc_errors, resync_bytes, gaps, missed_samples, stale, skipped."""
        return self.parser.stats

    def counters(self) -> dict[str, int]:
        """crc_errors, resync_bytes, dropped (samples missing from timestamp gaps), gaps,
        repeated_frames (same timestamp again), skipped (superseded before a read), stale (reads
        without new data), timeouts; listed once non-zero: late (frames older than the newest one:
        out of order, not used), app_took_too_long (frames with status bit 0: the sensor's own loop
        overran)."""
        st = self.parser.stats
        return {"crc_errors": st["crc_errors"], "resync_bytes": st["resync_bytes"], "dropped": st["missed_samples"],
                "gaps": st["gaps"], "repeated_frames": st["stale"], "skipped": st["skipped"],
                "stale": self._stale_reads, "timeouts": self._timeouts,
                **{k: st[k] for k in ("late", "app_took_too_long") if st[k]}}  # listed once there is one

    def _read_bytes(self, wait: float) -> bytes:
        """What the port has; when nothing, wait up to ``wait`` s (``waits``) for it (0: never)."""
        self._check_open()
        try:
            data = self._receive_bytes(self._ser, wait)
        except (serial.SerialException, OSError) as exc:
            raise DeviceDisconnected(f"{self.url}: port lost: {exc}") from exc
        self.rx_bytes += len(data)
        return data

    def _pump(self, wait: float) -> None:
        self._pending += self.parser.feed(self._read_bytes(wait))

    def _accept(self, frames: list[BotaFrame]) -> BotaFrame | None:
        """Newest fresh frame among ``frames`` (updates gap / stale counters)."""
        newest = None
        st = self.parser.stats
        for f in frames:
            if f.status & STATUS_APP_TOOK_TOO_LONG:  # the sensor's own loop overran (not a fault bit)
                st["app_took_too_long"] += 1
            if self._last_ts is not None:
                dt = (f.timestamp - self._last_ts) & 0xFFFFFFFF
                if dt == 0:
                    st["stale"] += 1
                    continue
                if dt >= 1 << 31:  # older than the newest frame (delivered late): not new data
                    st["late"] += 1
                    continue
                if self._learned_period and self.period_s is not None and dt * 1e-6 < self.period_s:
                    self.period_s = dt * 1e-6  # learned period: keep the smallest step seen
                if self.period_s is None:
                    self.period_s = dt * 1e-6
                    self._learned_period = True
                else:
                    missing = round(dt * 1e-6 / self.period_s) - 1
                    if missing > 0:
                        st["gaps"] += 1
                        st["missed_samples"] += missing
            self._last_ts = f.timestamp
            if newest is not None:
                st["skipped"] += 1
            newest = f
        return newest

    def _check_crc(self) -> None:
        n = self.parser.stats["crc_errors"]
        if n != self._crc_seen:
            new = n - self._crc_seen
            self._crc_seen = n
            if self.on_crc_error == "raise":
                raise ChecksumError(f"{self.url}: {new} frame(s) failed CRC-16/X-25")

    def _take(self) -> BotaFrame | None:
        frames, self._pending = self._pending, []
        frame = self._accept(frames)
        self._check_crc()
        return frame

    def _read_sample(self, timeout: float) -> WrenchSample:
        """Newest wrench (N, N.m) with a new device timestamp; see "Freshness" in the module
        docstring for what a read without one returns."""
        waits = self._waits
        deadline = waits.monotonic() + timeout
        if self._last is not None:  # wait only until the newest data is `timeout` old
            deadline = min(deadline, self._last_rx_wall + timeout)
        self._pump(0.0)
        frame = self._take()
        while frame is None and (left := deadline - waits.monotonic()) > 0:
            self._pump(min(left, self.poll_s))
            frame = self._take()
        if frame is None:
            return self._stale(self._last, self.clock(), f"{self.url}: no fresh frame within {timeout:.3f} s")
        self._last_rx_wall = waits.monotonic()
        produced = self.clock()
        self.last_frame = frame
        if frame.status & self.fault_mask:
            raise DeviceFault(f"{self.url}: sensor status 0x{frame.status:04X}", code=frame.status)
        self._last = WrenchSample(t=produced, seq=self._next_seq(), wrench=np.asarray(frame.wrench) - self._offset,
                                  status=frame.status, produced_at=produced)
        return self._last

    def read_identity(self, timeout: float = 2.0, config_timeout: float = 1.0) -> dict[str, str]:
        """Product name, serial number and firmware of the sensor: the hardware reset ``#`` makes it
        reboot and print them after ``App Init`` (Bota's ``rokubimini_serial`` driver does this at
        every start: RokubiminiSerialImpl.cpp ``parseCommunicationMsgs``; parsed with
        :func:`hil.protocols.codecs.bota.parse_bota_boot`). Sets ``info.model``, ``info.serial``, ``info.firmware``.
        The sensor comes back with its *saved* configuration, so the configuration sent on open is
        sent again. Not during a run (the stream pauses for the reboot). Returns what was found
        (``{}`` if no boot text arrived within ``timeout`` s)."""
        self._ser.write_timeout = self._config_write_timeout(config_timeout)
        try:
            return self._read_identity(timeout, config_timeout)
        finally:
            if self._ser.is_open:
                self._ser.write_timeout = self._run_write_timeout

    def _read_identity(self, timeout: float, config_timeout: float) -> dict[str, str]:
        from hil.protocols.codecs.bota import parse_bota_boot

        try:
            self._ser.reset_input_buffer()
            self._ser.write(b"#")
            self._ser.flush()
        except (serial.SerialException, OSError) as exc:
            raise DeviceDisconnected(f"{self.url}: port lost: {exc}") from exc
        buf = bytearray()
        got: dict[str, str] = {}
        waits = self._waits
        deadline = waits.monotonic() + timeout
        while (left := deadline - waits.monotonic()) > 0 and len(got) < 3:
            buf += self._read_bytes(left)
            got = parse_bota_boot(bytes(buf))
        self.info.model = got.get("name", self.info.model)
        self.info.serial = got.get("serial", self.info.serial)
        self.info.firmware = got.get("firmware", self.info.firmware)
        self.parser = FrameParser()  # the reboot broke the stream: resynchronise on the next header
        for cmd in self._setup:
            self._command(cmd, float(config_timeout))
        return got

    def tare(self, timeout: float = 0.5) -> None:
        """Software tare: subtract the current reading from all later readings."""
        self._offset = np.zeros(6)
        self._offset = self.read(timeout).wrench.copy()

    def _release(self) -> None:
        self._ser.close()


#: the wire-format names (:mod:`hil.protocols.codecs`) stay importable from this module
__getattr__ = forwarder(_wire, __name__)
