"""Robotiq FT-300 six-axis force/torque sensor over Modbus (RTU, RTU-over-TCP or Modbus/TCP).

Role: :class:`hil.protocols.base.ForceSensor`, ``wrench = (Fx, Fy, Fz, Mx, My, Mz)`` in N and N.m,
in the sensor's own frame and sign convention (no axis remapping is done here).

Wire format (Robotiq "FT 300 Force Torque Sensor - Instruction Manual", section "Serial
communication / Modbus RTU"; firmware and serial-number layout as decoded by Robotiq's
``rq_sensor_com.c`` reference driver):

* serial line 19200 bps, 8 data bits, no parity, 1 stop bit; slave id 9;
* registers 180, 181, 182 = Fx, Fy, Fz as signed 16-bit, N = value / 100;
* registers 183, 184, 185 = Mx, My, Mz as signed 16-bit, N.m = value / 1000;
* registers 190-192 acceleration (g = value / 1000), 500-502 firmware version, 510-513 serial
  number, 514 production year; read with function code 03 (read holding registers). Manual's
  example: read the six values = ``09 03 00 B4 00 06 84 A6``;
* data-stream mode: writing 0x0200 to register 410 makes the sensor send, at 100 Hz, 16-byte
  frames ``20 4E  Fx_lo Fx_hi ... Mz_lo Mz_hi  CRC_lo CRC_hi`` (int16 little-endian, same scaling
  as the registers). The CRC is CRC-16/MODBUS over the first 14 bytes (header included), sent
  low byte first. The stream is stopped by sending about 50 bytes of 0xFF (~0.5 s).
* a sensor left streaming (a previous program, or its power-up in stream mode) does not answer
  Modbus: on a serial line the polled adapter first listens, and jams a running stream as
  Robotiq's ``rq_sensor_com.c`` does (``stop_stream_on_line``: 0xFF until the line is quiet, up
  to :data:`STREAM_STOP_S` = 0.5 s, then 0.1 s before the first Modbus request);

Transport URL scheme (only the URL differs between a bench and a simulated device):

====================================== ===============================================================
URL                                    transport
====================================== ===============================================================
``tcp://HOST:PORT``                    Modbus/TCP (MBAP framing), e.g. through an Ethernet gateway
``rtu-over-tcp://HOST:PORT``           Modbus RTU frames (with CRC) over a TCP socket, e.g. a serial
                                       device server in transparent mode
``rtu:///dev/ttyUSB0?baudrate=19200``  Modbus RTU on a serial port (pyserial)
``/dev/ttyUSB0`` or ``COM3``           same as ``rtu://`` with the sensor's default 19200 8N1
====================================== ===============================================================

Polling (:class:`RobotiqFT300`, driver ``robotiq_ft300``) goes through pymodbus. Stream mode
(:class:`RobotiqFT300Stream`, driver ``robotiq_ft300_stream``) needs a byte stream to the sensor's
serial line, opened with :func:`serial.serial_for_url`: ``/dev/ttyUSB0``, a pty path,
``socket://HOST:PORT`` (a serial device server in transparent mode), ``rtu:///dev/ttyUSB0`` (same
as the path). The frame codec is the pure :func:`encode_stream_frame` / :class:`StreamParser`.
Simulated devices: :mod:`hil.mocks.modbus_devices` (pymodbus server, polling) and
:mod:`hil.mocks.ft300_stream` (the streaming sensor on a pty).

Stream start/stop sequence (manual, "Data stream"; Robotiq's ``rq_sensor_com.c``, which writes
register 410 with function 16 *Preset Multiple Registers*, one register, and sends 50 x 0xFF)::

    host -> 09 10 01 9A 00 01 02 02 00 CRC   write 0x0200 to register 410 (FC16)
    host <- 09 10 01 9A 00 01 CRC            echo; the 16-byte frames follow at 100 Hz
    ...
    host -> FF x 50                          "jam": the sensor stops streaming, Modbus again

Assumptions (documented, not in the manual): ``tare()`` is a software offset (subtract the
current reading), as Robotiq's own driver does; the sensor frame is reported unchanged.
"""

from __future__ import annotations

import logging
import select
import struct
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from hil.errors import (
    ChecksumError,
    DeviceDisconnected,
    DeviceFault,
    DeviceTimeout,
    ProtocolError,
)
from hil.protocols.base import DeviceInfo, ForceSensor, StreamingSensor, WrenchSample, receive_bytes
from hil.protocols.codecs import forwarder
from hil.protocols.codecs import robotiq as _wire
from hil.protocols.codecs.robotiq import (
    DEFAULT_BAUDRATE,
    DEFAULT_SLAVE_ID,
    FC_READ_HOLDING,
    FC_WRITE_MULTIPLE,
    GATEWAY_EXCEPTION_CODES,
    MODBUS_EXCEPTION_CODES,
    RATED_FORCE,
    RATED_TORQUE,
    REG_FIRMWARE,
    REG_OUTPUT_SELECT,
    REG_PRODUCTION_YEAR,
    REG_SERIAL,
    REG_WRENCH,
    STREAM_START_VALUE,
    STREAM_STOP_JAM,
    STREAM_STOP_S,
    STREAM_TO_MODBUS_S,
    GatewayError,
    ModbusEndpoint,
    StreamParser,
    _modbus_crc_ok,
    _parse_rtu_reply,
    check_wrench_range,
    decode_firmware,
    decode_serial,
    decode_stream_frame,
    encode_stream_frame,
    mbap_frame,
    parse_mbap_reply,
    registers_to_wrench,
    rtu_frame,
    rtu_silence_s,
    stream_start_request,
    wrench_request_pdu,
)
from hil.protocols.waits import WALL, Waits

logger = logging.getLogger(__name__)


def stop_stream_on_line(ser: Any, *, listen_s: float = 0.05, stop_s: float = STREAM_STOP_S,
                        quiet_s: float = 0.05, poll_s: float = 0.01, waits: Waits = WALL) -> bool | None:
    """Stop an FT-300 stream left running on an open serial line, as Robotiq's driver does after
    boot (``rq_com_tentative_connexion`` / ``rq_com_stop_stream_after_boot``): listen for
    ``listen_s``; if bytes arrive, send the 0xFF jam (:data:`STREAM_STOP_JAM`, again every 0.1 s)
    until no byte arrives for ``quiet_s``, for at most ``stop_s``, then wait
    :data:`STREAM_TO_MODBUS_S`. Returns None if the line was quiet (no stream), True if a stream
    was stopped, False if it was still streaming after ``stop_s``. Times are measured on ``waits``
    (:mod:`hil.protocols.waits`); a single wait for input lasts at most ``poll_s``."""
    deadline = waits.monotonic() + listen_s
    heard = False
    while (left := deadline - waits.monotonic()) > 0 and not heard:
        heard = bool(receive_bytes(ser, min(left, poll_s), waits))
    if not heard:
        return None
    logger.info("FT-300: a data stream is running; jamming it with 0xFF (Robotiq's stop sequence)")
    end = waits.monotonic() + stop_s
    next_jam = -np.inf
    quiet_since = waits.monotonic()
    while True:
        now = waits.monotonic()
        if now >= next_jam:
            ser.write(STREAM_STOP_JAM)
            ser.flush()
            next_jam = now + 0.1
        if receive_bytes(ser, poll_s, waits):
            quiet_since = waits.monotonic()
        elif waits.monotonic() - quiet_since >= quiet_s:
            waits.sleep(STREAM_TO_MODBUS_S)
            ser.reset_input_buffer()
            return True
        if waits.monotonic() >= end:
            return False


#: wall-clock bound (s) of pymodbus' serial receive, on a lockstep bench, once the barrier has put
#: every byte of the answer on the host's port (its "line quiet" check ends at its first look)
SERIAL_QUIET_S = 0.001


def _waiting_client(base: Any, waits: Waits) -> Any:
    """A pymodbus sync client class whose receive waits through ``waits``: at a bench exactly
    pymodbus' own wait (a select on the socket for the client's timeout); on a lockstep bench the
    barrier first (the simulated server has answered every request sent), then no wall-clock wait:
    the reply is there, or it will never come and the timeout passes in simulated time. Each
    request sent (pymodbus' sync client sends one frame per ``send``) and the bytes taken are
    reported to ``waits`` (a lockstep link's counts)."""

    class WaitingClient(base):  # type: ignore[misc]  # pymodbus client classes (Any to mypy)
        def send(self, request: bytes, addr: tuple[Any, ...] | None = None) -> int:
            n: int = base.send(self, request, addr)
            if request:
                waits.sent(1)
            return n

        def recv(self, size: int | None) -> bytes:
            params = self.comm_params
            timeout = float(params.timeout_connect or 0.0)

            def poll(t: float) -> bytes | None:
                line = getattr(self.socket, "in_waiting", None)  # a serial client (pyserial port)
                if t <= 0.0 and line is not None:
                    # pymodbus' serial receive first waits for the line to go quiet, on the wall
                    # clock: with nothing there nothing is coming; with bytes there (all of them:
                    # the barrier ran) that wait ends at its first look
                    if not line:
                        return None
                    t = SERIAL_QUIET_S
                params.timeout_connect = t
                try:
                    got: bytes = base.recv(self, size)
                finally:
                    params.timeout_connect = timeout
                return got or None

            data = waits.receive(poll, timeout) or b""
            waits.received(len(data))
            return data

    WaitingClient.__name__ = WaitingClient.__qualname__ = f"Waiting{base.__name__}"
    return WaitingClient


class RobotiqFT300(ForceSensor):
    """Robotiq FT-300 polled over Modbus: one FC03 read of registers 180-185 per :meth:`read`.

    ``timeout`` is the default per-call timeout (s); every call can override it. A missing reply
    raises :class:`DeviceTimeout` at once (no retry: the wait is already the whole budget). A
    garbled RTU reply (bad CRC) raises :class:`ChecksumError`; a Modbus exception response raises
    :class:`DeviceFault` with ``code`` = the Modbus exception code.

    Reply validation: Modbus/TCP has no CRC of its own (the TCP checksum protects the wire, not a
    gateway), so every reply is checked: function code and exception code valid, byte count = 2 x
    registers asked, and, on Modbus/TCP (RTU replies carry their CRC), the wrench within the rated
    range (``max_force`` N, ``max_torque`` N.m; default the FT-300's +-300 N, +-30 N.m). A reply
    failing a check is never returned as data: the request is repeated up to ``retries`` times,
    then :class:`ProtocolError` (or ChecksumError) is raised. A damaged low byte that keeps the
    value in range cannot be detected on Modbus/TCP.

    Freshness: ``produced_at`` is the arrival of the reply (adapter clock). The registers carry no
    timestamp or counter. Frozen readings (``frozen_is_stale``, default on; issue 27): a reply whose
    six values are exactly those of the previous fresh reply is not new data -- the previous
    sample is returned again (same ``seq`` and ``produced_at``: stale) and counted in
    ``repeated`` -- so a sensor that stopped refreshing its registers ages, and the runner's
    watchdog stops the run once it is ``watchdog_ms`` old ("a frozen sensor value for longer than
    the watchdog is a stale device"). A live strain-gauge sensor's readings move by several register
    counts from one sample to the next (the FT 300-S's signal noise is about 0.1 N on the forces,
    ten counts of 0.01 N), and its registers are refreshed at 100 Hz, so equal values over a whole
    watchdog period do not happen on a working sensor; a simulated one needs sensor noise of at
    least one count (``simulation.sensor_noise.force_std``) for the same reason. Counters
    (:meth:`counters`): ``crc_errors``, ``invalid_replies`` (bad function
    code / byte count / exception code / undecodable), ``out_of_range``, ``gateway_errors``
    (exceptions 10/11 from a Modbus/TCP gateway: the sensor's serial reply was missing or failed its
    CRC; retried like a bad reply, :class:`GatewayError` in the end), ``exceptions`` (other Modbus
    exception replies: DeviceFault), ``retries``, ``timeouts``, ``repeated`` (frozen readings).

    ``clock`` gives the sample time ``t`` (host monotonic clock by default; the lockstep runner
    passes the simulated clock).

    Non-blocking reads (``read(timeout=0)``, the realtime loop): the FC03 transaction is split
    into its request and its reply, framed by the adapter itself on the transport pymodbus opened
    (RTU: slave, PDU, CRC-16; Modbus/TCP: MBAP header with the adapter's own transaction ids). A
    read takes the bytes received since the request sent ahead; a complete reply that passes the
    checks above is a fresh sample (``produced_at`` = that read, adapter clock); an incomplete one
    (split over reads), none, or one failing a check (CRC: dropped, ``crc_errors``; bad byte count,
    out of range, gateway exception: counted as above) gives the previous sample again (stale,
    ``counters()["stale"]``); a Modbus exception from the sensor raises DeviceFault as usual. A
    request unanswered after ``timeout`` (host clock) is given up (``timeouts``) and sent again:
    the samples' age grows and the runner's watchdog judges it. Modbus RTU timing ("Modbus over
    serial line" V1.02 §2.5.1.1): a frame is separated from the next by t3.5 of silence
    (:func:`~hil.protocols.codecs.robotiq.rtu_silence_s`: 3.5 characters of 11 bits, 2.0 ms at
    19200 bps; 1.75 ms above 19200), so on RTU framing (a serial line, or the serial side of an RTU
    device server) the next request is sent by the first read at least t3.5 after the read that saw
    the reply's last byte (a reply seen just now may have ended just now). At 19200 bps a
    request/reply takes about 13 ms: a fast loop gets a fresh sample every ~15 ms and stale ones in
    between, with their age recorded. The first non-blocking read (or the first after blocking
    ones: nothing was requested ahead) polls once with ``timeout``; a blocking call after
    non-blocking reads first waits (at most its timeout) for the outstanding reply, drops it and
    keeps t3.5, then uses pymodbus as before.
    """

    axes = 6

    def __init__(
        self,
        url: str = "/dev/ttyUSB0",
        slave: int = DEFAULT_SLAVE_ID,
        timeout: float = 0.1,
        *,
        read_info: bool = True,
        clock: Callable[[], float] = time.monotonic,
        retries: int = 1,
        max_force: float = RATED_FORCE,
        max_torque: float = RATED_TORQUE,
        stop_stream: bool = True,
        frozen_is_stale: bool = True,
        waits: Waits = WALL,
    ) -> None:
        from pymodbus import FramerType
        from pymodbus.client import ModbusSerialClient, ModbusTcpClient

        self.endpoint = ModbusEndpoint.parse(url)
        self.url = url
        self.slave = int(slave)
        self.timeout = float(timeout)
        self._clock = clock
        self._waits = waits
        self.label = f"FT-300 on {url}"
        self._offset = np.zeros(6)
        self._rx = b""
        self.retries = max(0, int(retries))
        self.max_force = float(max_force)
        self.max_torque = float(max_torque)
        self._counts = {"crc_errors": 0, "invalid_replies": 0, "out_of_range": 0, "gateway_errors": 0,
                        "exceptions": 0, "retries": 0, "timeouts": 0}
        self.frozen_is_stale = bool(frozen_is_stale)
        self._last_raw = np.full(6, np.nan)
        # non-blocking reads (timeout 0): the request sent ahead and its reply so far
        self._ahead = False
        self._ahead_at = 0.0  # host monotonic time the request went out
        self._abuf = bytearray()
        self._tid = 0x8000  # Modbus/TCP transaction ids of the requests sent ahead
        self._quiet_since = -float("inf")  # host monotonic: no reply byte has arrived since then
        self._nb_reads = 0
        self._reading_ahead = False  # non-blocking reads since the last blocking one
        self._late = 0
        self._last: WrenchSample | None = None
        self._stale_reads = 0
        ep = self.endpoint
        #: t3.5 before the next request on a serial line (RTU framing; the serial side of an RTU
        #: device server too), 0 on Modbus/TCP (the gateway keeps the serial timing)
        self.silence_s = 0.0 if ep.kind == "tcp" else rtu_silence_s(ep.baudrate)
        client: Any
        self.stream_stopped: bool | None = None
        if ep.kind == "rtu" and stop_stream:
            self.stream_stopped = self._stop_stream(ep)
        if ep.kind == "rtu":
            client = _waiting_client(ModbusSerialClient, waits)(
                ep.device, framer=FramerType.RTU, baudrate=ep.baudrate, bytesize=8, parity="N",
                stopbits=1, timeout=self.timeout, retries=0, trace_packet=self._trace_packet,
            )
        else:
            framer = FramerType.RTU if ep.kind == "rtu-over-tcp" else FramerType.SOCKET
            client = _waiting_client(ModbusTcpClient, waits)(
                ep.host, port=ep.port, framer=framer, timeout=self.timeout, retries=0,
                reconnect_delay=0.0, trace_packet=self._trace_packet,
            )
        self._client = client
        self.info = DeviceInfo(
            driver="robotiq_ft300", transport=f"modbus-{ep.kind}", vendor="Robotiq", model="FT-300",
            extra={"url": url, "slave": self.slave},
        )
        try:
            if not client.connect():
                raise DeviceDisconnected(f"FT-300: cannot connect to {url}")
            if read_info:
                self._read_info()
        except BaseException:
            self.close()
            raise
        logger.info("FT-300 opened on %s (slave %d, %s)", url, self.slave, self.info.firmware or "fw ?")

    def _stop_stream(self, ep: ModbusEndpoint) -> bool | None:
        """Open the serial line raw and stop a data stream left running (:func:`stop_stream_on_line`);
        a sensor still streaming after the jam is a ProtocolError."""
        import serial

        try:
            with serial.Serial(ep.device, ep.baudrate, bytesize=8, parity="N", stopbits=1, timeout=0.01,
                               write_timeout=None if self._waits.lockstep else 0.5) as ser:
                stopped = stop_stream_on_line(ser, waits=self._waits)
        except (serial.SerialException, OSError) as exc:
            raise DeviceDisconnected(f"FT-300: cannot open {ep.device}: {exc}") from exc
        if stopped is False:
            raise ProtocolError(f"FT-300 on {ep.device}: the data stream did not stop after "
                                f"{STREAM_STOP_S:.1f} s of 0xFF jam")
        return stopped

    # -- ForceSensor ------------------------------------------------------------------------------
    def _read_sample(self, timeout: float) -> WrenchSample:
        """Poll Fx..Mz once (validated, see the class doc). Raises DeviceTimeout / ChecksumError /
        ProtocolError / DeviceFault."""
        if timeout == 0.0:
            return self._read_ahead()
        self._reading_ahead = False
        if self._ahead:
            self._settle(timeout)
        raw = self._read_wrench(timeout)
        self._quiet_since = self._waits.monotonic()  # the reply is complete: the line's silence starts
        return self._sample(raw)

    def _sample(self, raw: np.ndarray) -> WrenchSample:
        """A sample from the six values of a valid reply: fresh, or -- ``frozen_is_stale`` and the
        values exactly those of the previous fresh reply -- the previous sample again (stale, counted
        in ``repeated``): see the class doc, "Frozen readings"."""
        produced = self._clock()
        if self.frozen_is_stale and self._last is not None and np.array_equal(raw, self._last_raw):
            self._counts["repeated"] = self._counts.get("repeated", 0) + 1  # listed once there is one
            return self._stale(self._last, produced, f"{self.label}: readings frozen")
        self._last_raw = raw
        self._last = WrenchSample(t=produced, seq=self._next_seq(), wrench=raw - self._offset, produced_at=produced)
        return self._last

    def counters(self) -> dict[str, int]:
        """crc_errors, invalid_replies, out_of_range, gateway_errors, exceptions, retries, timeouts,
        repeated (frozen readings, class doc; listed once there is one); once a non-blocking read
        ran also ``stale`` (reads that returned the previous sample) and ``late`` (reply bytes of an
        abandoned request, discarded)."""
        out = dict(self._counts)
        if self._nb_reads:
            out["stale"], out["late"] = self._stale_reads, self._late
        return out

    # -- non-blocking reads (timeout 0) ----------------------------------------------------------
    def _read_ahead(self) -> WrenchSample:
        """Collect the reply to the request sent ahead (fresh sample when it is complete and valid,
        else the previous one again: stale), then send the next request when the line allows it
        (see the class doc). The first one, or the first after blocking reads, polls once with
        ``timeout`` (the sample it returns is not older than the read)."""
        self._nb_reads += 1
        if not self._reading_ahead:  # the first one, or the first after blocking reads: poll once
            sample = self._read_sample(self.timeout)
            self._reading_ahead = True
            self._request_if_quiet()
            return sample
        fresh = self._collect()
        self._request_if_quiet()
        if fresh is not None:
            return fresh
        return self._stale(self._last, self._clock(), f"FT-300 on {self.url}: no reply yet")

    def _raw(self) -> Any:
        sock = self._client.socket
        if sock is None:
            raise DeviceDisconnected(f"FT-300 on {self.url}: connection closed")
        return sock

    def _pump(self) -> bytes:
        """What the transport has received, without waiting."""
        self._check_open()
        sock = self._raw()
        try:
            if self.endpoint.kind == "rtu":
                n = sock.in_waiting
                return bytes(sock.read(n)) if n else b""
            if not select.select([sock], [], [], 0.0)[0]:
                return b""
            data = bytes(sock.recv(4096))
        except OSError as exc:  # pyserial's SerialException is an OSError
            raise DeviceDisconnected(f"FT-300 on {self.url}: {exc}") from exc
        if not data:  # the peer closed the connection
            raise DeviceDisconnected(f"FT-300 on {self.url}: connection closed by the peer")
        return data

    def _request_if_quiet(self) -> None:
        """Send the wrench request ahead unless one is outstanding or the line's t3.5 silence
        since the last reply byte seen is not over (RTU framing)."""
        if self._ahead or self._waits.monotonic() - self._quiet_since < self.silence_s:
            return
        late = self._pump()  # bytes of an abandoned request: not an answer to the next one
        if late:
            self._late += len(late)
            self._quiet_since = self._waits.monotonic()
            return
        pdu = wrench_request_pdu()
        if self.endpoint.kind == "tcp":
            self._tid = 0x8000 + (self._tid + 1) % 0x8000
            frame = mbap_frame(self._tid, self.slave, pdu)
        else:
            frame = rtu_frame(self.slave, pdu)
        sock = self._raw()
        try:
            sent = sock.write(frame) if self.endpoint.kind == "rtu" else sock.send(frame)
        except OSError as exc:
            raise DeviceDisconnected(f"FT-300 on {self.url}: {exc}") from exc
        if sent != len(frame):
            raise DeviceDisconnected(f"FT-300 on {self.url}: request not sent ({sent} of {len(frame)} bytes)")
        self._waits.sent(1)
        self._abuf.clear()
        self._ahead, self._ahead_at = True, self._waits.monotonic()

    def _give_up(self) -> None:
        self._ahead = False
        self._abuf.clear()
        self._quiet_since = self._waits.monotonic()

    def _collect(self) -> WrenchSample | None:
        """The outstanding request's reply if it is complete: validated as a blocking read's (a
        reply failing a check is dropped and counted, the read is stale, the request is sent
        again once the line is quiet); a Modbus exception other than a gateway's raises."""
        if not self._ahead:
            return None
        data = self._pump()
        if data:
            self._abuf += data
            self._quiet_since = self._waits.monotonic()
        if self.endpoint.kind == "tcp":
            pdu, used = parse_mbap_reply(self._abuf, self._tid, self.slave)
            if used and pdu is None:  # another transaction's reply or a broken header
                self._late += used
                del self._abuf[:used]
                return None
            bad_crc = False
        else:
            frame, _end, bad_crc = _parse_rtu_reply(self._abuf, self.slave, FC_READ_HOLDING)
            pdu = None if frame is None else frame[1:-2]
        if bad_crc:
            self._counts["crc_errors"] += 1
            self._give_up()
            return None
        if pdu is None:
            if self._waits.monotonic() - self._ahead_at > self.timeout:  # the reply never came
                self._counts["timeouts"] += 1
                self._give_up()
            return None
        self._give_up()
        return self._decode(pdu)

    def _decode(self, pdu: bytes) -> WrenchSample | None:
        fc = pdu[0]
        if fc & 0x80:
            code = pdu[1] if len(pdu) > 1 else None
            if code not in MODBUS_EXCEPTION_CODES:
                self._counts["invalid_replies"] += 1
                return None
            if code in GATEWAY_EXCEPTION_CODES:
                self._counts["gateway_errors"] += 1
                return None
            self._counts["exceptions"] += 1
            raise DeviceFault(f"FT-300 answered with Modbus exception {code}", code=code)
        if fc != FC_READ_HOLDING or len(pdu) != 14 or pdu[1] != 12:
            self._counts["invalid_replies"] += 1
            return None
        w = registers_to_wrench(list(struct.unpack(">6H", pdu[2:14])))
        if self.endpoint.kind == "tcp":  # RTU replies are CRC-checked
            try:
                check_wrench_range(w, self.max_force, self.max_torque)
            except ProtocolError:
                self._counts["out_of_range"] += 1
                return None
        return self._sample(w)

    def _settle(self, limit: float) -> None:
        """Before a pymodbus transaction: wait (at most ``limit`` s) for the reply to the request
        sent ahead, so that it is not taken for the transaction's answer, then drop it and keep
        the line's t3.5 silence."""
        waits = self._waits
        deadline = waits.monotonic() + limit
        while self._ahead and waits.monotonic() < deadline:
            self._collect_quietly()
            if self._ahead:
                waits.sleep(0.0005)
        self._give_up()
        waits.sleep(self._quiet_since + self.silence_s - waits.monotonic())

    def _collect_quietly(self) -> None:
        """One :meth:`_collect` whose sample is dropped (a Modbus exception too: the transaction
        that follows reports its own)."""
        try:
            self._collect()
        except DeviceFault:
            self._give_up()

    def _read_wrench(self, timeout: float | None) -> np.ndarray:
        for attempt in range(self.retries + 1):
            try:
                w = registers_to_wrench(self._read_registers(REG_WRENCH, 6, timeout))
                if self.endpoint.kind == "tcp":  # RTU replies are CRC-checked
                    try:
                        check_wrench_range(w, self.max_force, self.max_torque)
                    except ProtocolError:
                        self._counts["out_of_range"] += 1
                        raise
                return w
            except (ProtocolError, ChecksumError) as exc:
                if attempt == self.retries:
                    raise
                self._counts["retries"] += 1
                logger.debug("FT-300: %s; asking again", exc)
        raise AssertionError("unreachable")  # pragma: no cover

    def tare(self, timeout: float = 0.5) -> None:
        """Software zero: later readings are reported relative to the current one."""
        self._offset = self._read_wrench(timeout)

    def start_stream(self, timeout: float | None = None) -> None:
        """Write 0x0200 to register 410: a serial sensor then switches to its 100 Hz stream and no
        longer answers Modbus until jammed with 0xFF bytes (see :data:`STREAM_STOP_JAM`)."""
        self._write_register(REG_OUTPUT_SELECT, STREAM_START_VALUE, timeout)

    def _release(self) -> None:
        self._client.close()

    # -- internals --------------------------------------------------------------------------------
    def _read_info(self) -> None:
        self.info.firmware = decode_firmware(self._read_registers(REG_FIRMWARE, 3, None))
        self.info.serial = decode_serial(self._read_registers(REG_SERIAL, 4, None))
        self.info.extra["production_year"] = self._read_registers(REG_PRODUCTION_YEAR, 1, None)[0]

    def _trace_packet(self, sending: bool, data: bytes) -> bytes:
        if sending:
            self._rx = b""
        else:
            self._rx = bytes(data)  # pymodbus hands over the whole receive buffer so far
        return data

    def _call(self, fn: Callable[..., Any], timeout: float | None, *args: Any, **kw: Any) -> Any:
        from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

        self._check_open()
        t = self.timeout if timeout is None else float(timeout)
        if self._ahead:
            self._settle(t)
        self._client.comm_params.timeout_connect = t
        self._rx = b""
        try:
            resp = fn(*args, device_id=self.slave, **kw)
        except ConnectionException as exc:
            raise DeviceDisconnected(f"FT-300 on {self.url}: {exc}") from exc
        except ModbusIOException as exc:
            rx = self._rx
            if rx and self.endpoint.kind != "tcp" and not _modbus_crc_ok(rx):
                self._counts["crc_errors"] += 1
                raise ChecksumError(f"FT-300: reply with bad CRC ({rx.hex(' ')})") from exc
            if rx:
                self._counts["invalid_replies"] += 1
                raise ProtocolError(f"FT-300: undecodable reply ({rx.hex(' ')})") from exc
            self._counts["timeouts"] += 1
            raise DeviceTimeout(f"FT-300 on {self.url}: no reply within {t:.3f} s") from exc
        except ModbusException as exc:
            self._counts["invalid_replies"] += 1
            raise ProtocolError(f"FT-300: {exc}") from exc
        if resp.isError():
            code = getattr(resp, "exception_code", None)
            if code not in MODBUS_EXCEPTION_CODES:  # a damaged function code with its high bit set
                self._counts["invalid_replies"] += 1
                raise ProtocolError(f"FT-300: reply with an invalid exception code {code!r} (damaged reply?)")
            if code in GATEWAY_EXCEPTION_CODES:  # the gateway got no (valid) reply from the sensor
                self._counts["gateway_errors"] += 1
                raise GatewayError(f"FT-300 on {self.url}: gateway exception {code} (no valid reply from the sensor)")
            self._counts["exceptions"] += 1
            raise DeviceFault(f"FT-300 answered with Modbus exception {code}", code=code)
        return resp

    def _read_registers(self, address: int, count: int, timeout: float | None) -> list[int]:
        resp = self._call(self._client.read_holding_registers, timeout, address, count=count)
        if int(getattr(resp, "function_code", FC_READ_HOLDING)) != FC_READ_HOLDING:
            self._counts["invalid_replies"] += 1
            raise ProtocolError(f"FT-300: reply with function code {resp.function_code}, expected {FC_READ_HOLDING}")
        regs = list(resp.registers)
        if len(regs) != count:
            self._counts["invalid_replies"] += 1
            raise ProtocolError(f"FT-300: asked {count} registers at {address}, got {len(regs)}")
        rx = self._rx  # the raw reply: its byte count field must match too (MBAP: byte 8, RTU: byte 2)
        bc_at = 8 if self.endpoint.kind == "tcp" else 2
        if len(rx) > bc_at and rx[bc_at - 1] == FC_READ_HOLDING and rx[bc_at] != 2 * count:
            self._counts["invalid_replies"] += 1
            raise ProtocolError(f"FT-300: byte count {rx[bc_at]} for {count} registers")
        return regs

    def _write_register(self, address: int, value: int, timeout: float | None) -> None:
        self._call(self._client.write_register, timeout, address, value)



# ------------------------------------------------------------------------------------------------
# Modbus RTU on a raw byte stream (what stream mode needs: the same serial line carries both)
# ------------------------------------------------------------------------------------------------
class RobotiqFT300Stream(StreamingSensor):
    """Robotiq FT-300 in data-stream mode on a serial line (see the module docstring).

    On open: the port is opened with :func:`serial.serial_for_url` (19200 8N1 by default) and its
    input flushed; if valid stream frames arrive within ``probe_s`` the sensor is already streaming
    (left so by a previous program) and is used as it is (``info.extra["start"] ==
    "already-streaming"``); otherwise, optionally, firmware / serial number / production year are
    read with FC03 (``read_info``), then 0x0200 is written to register 410 with FC16 and the echo
    awaited (``"handshake"``). If no echo but valid stream frames arrive, the stream is accepted
    (Robotiq's driver does the same). No echo and no stream -> :class:`DeviceTimeout`; a Modbus
    exception reply -> :class:`DeviceFault` (``code`` = exception code); only garbled replies ->
    :class:`ChecksumError`.

    :meth:`read` returns the newest frame received since the previous read. Freshness: frames carry
    no sequence number or timestamp, so ``produced_at`` is the *arrival* of the frame (adapter
    clock) and ``seq`` advances only with a new frame. Without a new frame a read waits for one
    until the newest data is ``timeout`` old (host clock), then returns the previous sample again
    (same ``seq`` and ``produced_at``: stale, ``counters()["stale"]``); the runner's watchdog judges
    its age. ``max_age`` > 0: a previous sample at most that old (s, host clock) is returned at once
    instead of waiting (a loop faster than the 100 Hz stream). Only a read before any frame raises
    :class:`DeviceTimeout`. Garbage is skipped (the parser resynchronises on the 0x20 0x4E header);
    frames failing their CRC are dropped and counted in ``stats["crc_errors"]`` and
    ``stats["gaps"]`` (each is a missing sample), or raise :class:`ChecksumError` with
    ``on_crc_error="raise"``. A dropped frame shows only as a longer wait. A frame whose six values
    are exactly those of the newest frame accepted is no new data (``frozen_is_stale``, default on;
    issue 27: the sensor's readings always move by a few counts, see :class:`RobotiqFT300`,
    "Frozen readings"): it is counted in ``repeated`` and ignored, so a frozen sensor's samples age
    and the runner's watchdog stops the run. :meth:`wait_rx` is the lockstep byte-count barrier (see
    :mod:`hil.mocks.ft300_stream`). Counters (:meth:`counters`): ``crc_errors``, ``resync_bytes``,
    ``skipped`` (frames superseded before a read), ``stale``, ``timeouts``, ``repeated``.

    :meth:`close` (idempotent, never raises) stops the stream with the 0xFF jam, waiting up to
    ``stop_timeout`` for the line to go quiet (``stream_stopped`` tells whether it did), then
    closes the port.
    """

    axes = 6

    def __init__(
        self,
        url: str = "/dev/ttyUSB0",
        slave: int = DEFAULT_SLAVE_ID,
        timeout: float = 0.1,
        *,
        baudrate: int = DEFAULT_BAUDRATE,
        read_info: bool = True,
        probe_s: float = 0.02,
        max_age: float = 0.0,
        on_crc_error: str = "count",
        clock: Callable[[], float] = time.monotonic,
        poll_s: float = 0.002,
        stop_timeout: float = STREAM_STOP_S,
        quiet_s: float = 0.05,
        frozen_is_stale: bool = True,
        waits: Waits = WALL,
    ) -> None:
        import serial  # optional dependency (extra "serial")

        if on_crc_error not in ("count", "raise"):
            raise ValueError("on_crc_error must be 'count' or 'raise'")
        self.url = url
        self.slave = int(slave)
        self.timeout = float(timeout)
        self.max_age = float(max_age)
        self.on_crc_error = on_crc_error
        self.stop_timeout = float(stop_timeout)
        self.quiet_s = float(quiet_s)
        self._clock = clock
        self._waits = waits
        self.poll_s = float(poll_s)
        self._serial_errors = (serial.SerialException, OSError)
        self.parser = StreamParser()
        self.label = f"FT-300 stream on {url}"
        self._offset = np.zeros(6)
        self._pending: np.ndarray | None = None
        self._last: WrenchSample | None = None
        self._last_rx = -np.inf
        self._pending_at = np.nan
        self.rx_bytes = 0
        self._stale_reads = 0
        self._timeouts = 0
        self._crc_seen = 0
        self._skipped = 0
        self.frozen_is_stale = bool(frozen_is_stale)
        self._ref: np.ndarray | None = None  # the newest values accepted as new data
        self._repeated = 0
        self.streaming = False
        self.stream_stopped: bool | None = None
        port_url, baud = self._port_url(url, baudrate)
        self.info = DeviceInfo(
            driver="robotiq_ft300_stream", transport="serial-stream", vendor="Robotiq", model="FT-300",
            extra={"url": url, "slave": self.slave},
        )
        try:
            self._ser = serial.serial_for_url(
                port_url, baudrate=baud, bytesize=8, parity="N", stopbits=1, timeout=poll_s,
                write_timeout=None if waits.lockstep else max(self.timeout, 0.05),  # wall clock: not in lockstep
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            self._closed = True  # nothing to release
            raise DeviceDisconnected(f"FT-300: cannot open {url!r}: {exc}") from exc
        try:
            self._start(read_info, probe_s)
        except BaseException:
            self.close()
            raise
        logger.info("FT-300 stream on %s (%s, %s)", url, self.info.extra["start"], self.info.firmware or "fw ?")

    # -- ForceSensor ------------------------------------------------------------------------------
    @property
    def stats(self) -> dict[str, int]:
        """frames (valid), crc_errors, gaps (= samples lost to CRC failures), skipped_bytes
        (resynchronisation), skipped_frames (decoded but superseded by a newer one before a read)."""
        p = self.parser
        return {"frames": p.frames, "crc_errors": p.crc_errors, "gaps": p.crc_errors,
                "skipped_bytes": p.skipped_bytes, "skipped_frames": self._skipped}

    def counters(self) -> dict[str, int]:
        """crc_errors, resync_bytes, skipped, stale, timeouts, repeated (listed once there is one)
        (see the class doc)."""
        p = self.parser
        out = {"crc_errors": p.crc_errors, "resync_bytes": p.skipped_bytes, "skipped": self._skipped,
               "stale": self._stale_reads, "timeouts": self._timeouts}
        if self._repeated:  # listed once there is one
            out["repeated"] = self._repeated
        return out

    def _read_sample(self, t: float) -> WrenchSample:
        """Newest stream sample (N, N.m); see the class doc for freshness and waiting."""
        waits = self._waits
        deadline = waits.monotonic() + t
        if self._last is not None:
            deadline = min(deadline, self._last_rx + t)
        self._pump(0.0)
        while self._pending is None:
            now = waits.monotonic()
            young = self._last is not None and self.max_age > 0 and now - self._last_rx <= self.max_age
            if young or now >= deadline:
                return self._stale(self._last, self._clock(), f"FT-300 stream on {self.url}: no frame within {t:.3f} s")
            self._pump(min(deadline - now, self.poll_s))
        wrench, self._pending = self._pending, None
        self._last = WrenchSample(t=self._clock(), seq=self._next_seq(), wrench=wrench - self._offset,
                                  produced_at=self._pending_at)
        return self._last

    def tare(self, timeout: float = 0.5) -> None:
        """Software zero: later readings are relative to the next streamed one."""
        self._offset = np.zeros(6)
        self._offset = self.read(timeout).wrench.copy()

    def stop_stream(self, timeout: float | None = None) -> bool:
        """Send the 0xFF jam (again every 0.1 s) until no byte arrives for ``quiet_s``; True if the
        line went quiet within ``timeout`` (default ``stop_timeout``). Never raises."""
        limit = self.stop_timeout if timeout is None else float(timeout)
        waits = self._waits
        deadline = waits.monotonic() + limit
        stopped = False
        try:
            next_jam = -np.inf
            quiet_since = waits.monotonic()
            while True:
                now = waits.monotonic()
                if now >= next_jam:
                    self._ser.write(STREAM_STOP_JAM)
                    self._ser.flush()
                    next_jam = now + 0.1
                data = self._receive_bytes(self._ser, self.poll_s)
                now = waits.monotonic()
                if data:
                    quiet_since = now
                elif now - quiet_since >= self.quiet_s:
                    stopped = True
                    break
                if now >= deadline:
                    break
        except Exception as exc:  # a lost port cannot be stopped; close anyway
            logger.debug("FT-300: stopping the stream failed: %s", exc)
        self.streaming = False
        self.stream_stopped = stopped
        return stopped

    def _on_close(self) -> None:
        if self.streaming or self.info.extra.get("start") is None:
            self.stop_stream()  # also after a failed start: the sensor may have switched anyway

    def _release(self) -> None:
        self._ser.close()

    # -- internals --------------------------------------------------------------------------------
    @staticmethod
    def _port_url(url: str, baudrate: int) -> tuple[str, int]:
        scheme = url.split("://", 1)[0].lower() if "://" in url else ""
        if scheme == "rtu":
            ep = ModbusEndpoint.parse(url)
            return ep.device, ep.baudrate if "baudrate=" in url else baudrate
        if scheme in ("tcp", "modbus+tcp", "rtu-over-tcp"):
            raise ValueError(f"{url!r}: stream mode needs a byte stream to the sensor's serial line "
                             "(a device path, or socket://HOST:PORT for a transparent serial server)")
        return url, baudrate

    def _io_error(self, exc: BaseException) -> DeviceDisconnected:
        return DeviceDisconnected(f"FT-300 on {self.url}: port lost: {exc}")

    def _recv(self, wait: float) -> bytes:
        """What the port has; when nothing, wait up to ``wait`` s (``waits``) for it (0: never)."""
        self._check_open()
        try:
            data = self._receive_bytes(self._ser, wait)
        except self._serial_errors as exc:
            raise self._io_error(exc) from exc
        self.rx_bytes += len(data)
        return data

    def _send(self, data: bytes) -> None:
        try:
            self._ser.write(data)
            self._ser.flush()
        except self._serial_errors as exc:
            raise self._io_error(exc) from exc

    def _feed(self, data: bytes) -> None:
        if not data:
            return
        frames = self.parser.feed(data)
        if frames and self.frozen_is_stale:  # a frame repeating the newest values is no new data
            fresh = []
            for w in frames:
                if self._ref is not None and np.array_equal(w, self._ref):
                    self._repeated += 1
                    continue
                fresh.append(w)
                self._ref = w
            frames = fresh
        if frames:
            self._skipped += len(frames) - 1 + (self._pending is not None)
            self._pending = frames[-1]
            self._pending_at = self._clock()
            self._last_rx = self._waits.monotonic()
        n = self.parser.crc_errors
        if n != self._crc_seen:
            new, self._crc_seen = n - self._crc_seen, n
            if self.on_crc_error == "raise":
                raise ChecksumError(f"FT-300 stream on {self.url}: {new} frame(s) failed CRC-16/MODBUS")

    def _pump(self, wait: float) -> None:
        self._feed(self._recv(wait))

    def _start(self, read_info: bool, probe_s: float) -> None:
        try:
            self._ser.reset_input_buffer()
        except self._serial_errors as exc:
            raise self._io_error(exc) from exc
        if probe_s > 0:
            waits = self._waits
            end = waits.monotonic() + probe_s
            while (left := end - waits.monotonic()) > 0 and self._pending is None:
                self._pump(min(left, self.poll_s))
            if self._pending is not None:
                self.streaming = True
                self.info.extra["start"] = "already-streaming"
                return
            self.parser = StreamParser()  # forget noise seen while probing
            self._crc_seen = 0
        if read_info:
            self.info.firmware = decode_firmware(self._read_registers(REG_FIRMWARE, 3))
            self.info.serial = decode_serial(self._read_registers(REG_SERIAL, 4))
            self.info.extra["production_year"] = self._read_registers(REG_PRODUCTION_YEAR, 1)[0]
        try:
            echo, rest = self._transact(stream_start_request(self.slave), FC_WRITE_MULTIPLE)
        except (DeviceTimeout, ChecksumError):
            if StreamParser().feed(bytes(self._rx_buf)):  # no echo, but the stream is there
                self._feed(bytes(self._rx_buf))
                self.streaming = True
                self.info.extra["start"] = "stream-without-echo"
                return
            raise
        if echo[2:6] != struct.pack(">HH", REG_OUTPUT_SELECT, 1):
            raise ProtocolError(f"FT-300: unexpected echo to the stream start request ({echo.hex(' ')})")
        self.streaming = True
        self.info.extra["start"] = "handshake"
        self._feed(rest)

    def _transact(self, request: bytes, fc: int) -> tuple[bytes, bytes]:
        """Send one RTU request; return (reply frame, bytes received after it)."""
        self._rx_buf = bytearray()
        self._send(request)
        waits = self._waits
        deadline = waits.monotonic() + self.timeout
        bad_crc = False
        while True:
            self._rx_buf += self._recv(max(0.0, min(deadline - waits.monotonic(), self.poll_s)))
            frame, end, bad = _parse_rtu_reply(self._rx_buf, self.slave, fc)
            bad_crc |= bad
            if frame is not None:
                if frame[1] & 0x80:
                    raise DeviceFault(f"FT-300 answered with Modbus exception {frame[2]}", code=frame[2])
                return frame, bytes(self._rx_buf[end:])
            if waits.monotonic() >= deadline:
                if bad_crc:
                    raise ChecksumError(f"FT-300: reply with bad CRC ({bytes(self._rx_buf).hex(' ')})")
                raise DeviceTimeout(f"FT-300 on {self.url}: no reply within {self.timeout:.3f} s")

    def _read_registers(self, address: int, count: int) -> list[int]:
        frame, _ = self._transact(rtu_frame(self.slave, struct.pack(">BHH", FC_READ_HOLDING, address, count)),
                                  FC_READ_HOLDING)
        if frame[2] != 2 * count:
            raise ProtocolError(f"FT-300: asked {count} registers at {address}, got {frame[2]} bytes")
        return list(struct.unpack(f">{count}H", frame[3 : 3 + 2 * count]))

__all__ = [
    "GatewayError",
    "ModbusEndpoint",
    "RobotiqFT300",
    "RobotiqFT300Stream",
    "StreamParser",
    "decode_firmware",
    "decode_serial",
    "decode_stream_frame",
    "encode_stream_frame",
    "registers_to_wrench",
    "rtu_frame",
    "stream_start_request",
]


#: the wire-format names (:mod:`hil.protocols.codecs`) stay importable from this module
__getattr__ = forwarder(_wire, __name__)
