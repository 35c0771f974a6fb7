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

Polling is fully implemented through pymodbus. The stream format is implemented as pure
functions (:func:`encode_stream_frame`, :class:`StreamParser`); see also the simulated devices
in :mod:`hil.mocks.modbus_devices`.

Assumptions (documented, not in the manual): ``tare()`` is a software offset (subtract the
current reading), as Robotiq's own driver does; the sensor frame is reported unchanged.
"""

from __future__ import annotations

import logging
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any
from urllib.parse import parse_qs, urlsplit

import numpy as np

from hil.errors import (
    ChecksumError,
    DeviceDisconnected,
    DeviceFault,
    DeviceTimeout,
    ProtocolError,
)
from hil.protocols.base import DeviceInfo, ForceSensor, WrenchSample
from hil.protocols.crc import crc16_modbus

log = logging.getLogger(__name__)

DEFAULT_SLAVE_ID = 9
DEFAULT_BAUDRATE = 19200
REG_WRENCH = 180
REG_OUTPUT_SELECT = 410
REG_FIRMWARE = 500
REG_SERIAL = 510
REG_PRODUCTION_YEAR = 514
STREAM_START_VALUE = 0x0200
STREAM_HEADER = b"\x20\x4e"
STREAM_FRAME_LEN = 16
STREAM_STOP_JAM = b"\xff" * 50
FORCE_SCALE = 100.0
TORQUE_SCALE = 1000.0
WRENCH_SCALES = np.array([FORCE_SCALE] * 3 + [TORQUE_SCALE] * 3)


# ------------------------------------------------------------------------------------------------
# pure conversions
# ------------------------------------------------------------------------------------------------
def registers_to_wrench(registers: list[int] | tuple[int, ...]) -> np.ndarray:
    """Six raw 16-bit registers (180..185) -> wrench in N / N.m (signed, scaled)."""
    if len(registers) != 6:
        raise ProtocolError(f"expected 6 registers, got {len(registers)}")
    raw = np.array([int(r) & 0xFFFF for r in registers], dtype=np.int64)
    signed = np.where(raw >= 0x8000, raw - 0x10000, raw)
    return signed / WRENCH_SCALES


def decode_firmware(registers: list[int]) -> str:
    """Registers 500..502 -> e.g. ``"FTS-1.0.3"`` (layout of Robotiq's reference driver)."""
    r = [int(x) & 0xFFFF for x in registers[:3]]
    chars = bytes([r[0] >> 8, r[0] & 0xFF, r[1] >> 8]).decode("ascii", errors="replace")
    return f"{chars}-{r[1] & 0xFF}.{r[2] >> 8}.{r[2] & 0xFF}"


def decode_serial(registers: list[int]) -> str:
    """Registers 510..513 -> e.g. ``"SIM-0001"``; ``"UNKNOWN"`` when the number is 0."""
    r = [int(x) & 0xFFFF for x in registers[:4]]
    number = (r[3] << 16) | r[2]
    if number == 0:
        return "UNKNOWN"
    chars = bytes([r[0] >> 8, r[0] & 0xFF, r[1] >> 8]).decode("ascii", errors="replace")
    return f"{chars}-{number:04d}"


def encode_stream_frame(wrench: np.ndarray) -> bytes:
    """One 16-byte stream frame for ``wrench`` (N, N.m), saturated to the int16 range."""
    counts = np.clip(np.rint(np.asarray(wrench, dtype=float).reshape(6) * WRENCH_SCALES), -32768, 32767)
    body = STREAM_HEADER + struct.pack("<6h", *(int(c) for c in counts))
    return body + struct.pack("<H", crc16_modbus(body))


def decode_stream_frame(frame: bytes) -> np.ndarray:
    """Decode one complete 16-byte frame; raises :class:`ProtocolError` / :class:`ChecksumError`."""
    if len(frame) != STREAM_FRAME_LEN:
        raise ProtocolError(f"stream frame must be {STREAM_FRAME_LEN} bytes, got {len(frame)}")
    if frame[:2] != STREAM_HEADER:
        raise ProtocolError(f"bad stream header {frame[:2].hex()}")
    (crc,) = struct.unpack_from("<H", frame, 14)
    if crc16_modbus(frame[:14]) != crc:
        raise ChecksumError("FT-300 stream frame CRC mismatch")
    return np.array(struct.unpack_from("<6h", frame, 2), dtype=float) / WRENCH_SCALES


class StreamParser:
    """Incremental parser of the FT-300 byte stream: resynchronises on the 0x20 0x4E header.

    ``feed(data)`` returns the decoded wrenches of every complete, CRC-valid frame; bytes that do
    not start a valid frame are skipped (counted in ``skipped_bytes``), frames with a bad CRC are
    counted in ``crc_errors`` and skipped by one byte so a header hidden inside them is found.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self.frames = 0
        self.crc_errors = 0
        self.skipped_bytes = 0

    def feed(self, data: bytes) -> list[np.ndarray]:
        self._buf += data
        out: list[np.ndarray] = []
        buf = self._buf
        while True:
            i = buf.find(STREAM_HEADER)
            if i < 0:
                keep = 1 if buf[-1:] == STREAM_HEADER[:1] else 0
                self.skipped_bytes += len(buf) - keep
                del buf[: len(buf) - keep]
                break
            if i:
                self.skipped_bytes += i
                del buf[:i]
            if len(buf) < STREAM_FRAME_LEN:
                break
            frame = bytes(buf[:STREAM_FRAME_LEN])
            try:
                out.append(decode_stream_frame(frame))
            except ChecksumError:
                self.crc_errors += 1
                self.skipped_bytes += 1
                del buf[:1]
                continue
            self.frames += 1
            del buf[:STREAM_FRAME_LEN]
        return out


# ------------------------------------------------------------------------------------------------
# transport selection
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ModbusEndpoint:
    """A parsed transport URL (see the module docstring)."""

    kind: str  # "tcp" | "rtu-over-tcp" | "rtu"
    host: str = ""
    port: int = 502
    device: str = ""
    baudrate: int = DEFAULT_BAUDRATE

    @classmethod
    def parse(cls, url: str) -> ModbusEndpoint:
        if "://" not in url:
            return cls(kind="rtu", device=url)
        parts = urlsplit(url)
        scheme = parts.scheme.lower()
        if scheme in ("tcp", "modbus+tcp", "rtu-over-tcp"):
            if not parts.hostname:
                raise ValueError(f"{url!r}: missing host")
            kind = "tcp" if scheme != "rtu-over-tcp" else "rtu-over-tcp"
            return cls(kind=kind, host=parts.hostname, port=parts.port or 502)
        if scheme == "rtu":
            query = parse_qs(parts.query)
            baud = int(query.get("baudrate", [DEFAULT_BAUDRATE])[0])
            device = parts.path or parts.netloc
            if not device:
                raise ValueError(f"{url!r}: missing serial device path")
            return cls(kind="rtu", device=device, baudrate=baud)
        raise ValueError(f"unsupported Modbus URL scheme {scheme!r} in {url!r}")


def _modbus_crc_ok(frame: bytes) -> bool:
    return len(frame) >= 4 and crc16_modbus(frame[:-2]) == int.from_bytes(frame[-2:], "little")


class RobotiqFT300(ForceSensor):
    """Robotiq FT-300 polled over Modbus: one FC03 read of registers 180-185 per :meth:`read`.

    ``timeout`` is the default per-call timeout (s); every call can override it. No automatic
    retries: a missing reply raises :class:`DeviceTimeout` at once (the runner decides whether to
    record a gap). A garbled RTU reply (bad CRC) raises :class:`ChecksumError`; a Modbus exception
    response raises :class:`DeviceFault` with ``code`` = the Modbus exception code.

    ``clock`` gives the sample time ``t`` (host monotonic clock by default; the lockstep runner
    passes the simulated clock).
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
    ) -> None:
        from pymodbus import FramerType
        from pymodbus.client import ModbusSerialClient, ModbusTcpClient

        self.endpoint = ModbusEndpoint.parse(url)
        self.url = url
        self.slave = int(slave)
        self.timeout = float(timeout)
        self._clock = clock
        self._seq = 0
        self._offset = np.zeros(6)
        self._closed = False
        self._rx = b""
        ep = self.endpoint
        client: Any
        if ep.kind == "rtu":
            client = ModbusSerialClient(
                ep.device, framer=FramerType.RTU, baudrate=ep.baudrate, bytesize=8, parity="N",
                stopbits=1, timeout=self.timeout, retries=0, trace_packet=self._trace_packet,
            )
        else:
            framer = FramerType.RTU if ep.kind == "rtu-over-tcp" else FramerType.SOCKET
            client = ModbusTcpClient(
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
        log.info("FT-300 opened on %s (slave %d, %s)", url, self.slave, self.info.firmware or "fw ?")

    # -- ForceSensor ------------------------------------------------------------------------------
    def read(self, timeout: float | None = None) -> WrenchSample:
        """Poll Fx..Mz once. Raises DeviceTimeout / ChecksumError / DeviceFault (see class doc)."""
        regs = self._read_registers(REG_WRENCH, 6, timeout)
        wrench = registers_to_wrench(regs) - self._offset
        self._seq += 1
        return WrenchSample(t=self._clock(), seq=self._seq, wrench=wrench)

    def tare(self, timeout: float = 0.5) -> None:
        """Software zero: later readings are reported relative to the current one."""
        self._offset = registers_to_wrench(self._read_registers(REG_WRENCH, 6, timeout))

    def start_stream(self, timeout: float | None = None) -> None:
        """Write 0x0200 to register 410: a serial sensor then switches to its 100 Hz stream and no
        longer answers Modbus until jammed with 0xFF bytes (see :data:`STREAM_STOP_JAM`)."""
        self._write_register(REG_OUTPUT_SELECT, STREAM_START_VALUE, timeout)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._client.close()
        except Exception:
            log.debug("FT-300: error while closing the client", exc_info=True)

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

        if self._closed:
            raise DeviceDisconnected("FT-300 adapter is closed")
        t = self.timeout if timeout is None else float(timeout)
        self._client.comm_params.timeout_connect = t
        self._rx = b""
        try:
            resp = fn(*args, device_id=self.slave, **kw)
        except ConnectionException as exc:
            raise DeviceDisconnected(f"FT-300 on {self.url}: {exc}") from exc
        except ModbusIOException as exc:
            rx = self._rx
            if rx and self.endpoint.kind != "tcp" and not _modbus_crc_ok(rx):
                raise ChecksumError(f"FT-300: reply with bad CRC ({rx.hex(' ')})") from exc
            if rx:
                raise ProtocolError(f"FT-300: undecodable reply ({rx.hex(' ')})") from exc
            raise DeviceTimeout(f"FT-300 on {self.url}: no reply within {t:.3f} s") from exc
        except ModbusException as exc:
            raise ProtocolError(f"FT-300: {exc}") from exc
        if resp.isError():
            code = getattr(resp, "exception_code", None)
            raise DeviceFault(f"FT-300 answered with Modbus exception {code}", code=code)
        return resp

    def _read_registers(self, address: int, count: int, timeout: float | None) -> list[int]:
        resp = self._call(self._client.read_holding_registers, timeout, address, count=count)
        regs = list(resp.registers)
        if len(regs) != count:
            raise ProtocolError(f"FT-300: asked {count} registers at {address}, got {len(regs)}")
        return regs

    def _write_register(self, address: int, value: int, timeout: float | None) -> None:
        self._call(self._client.write_register, timeout, address, value)


__all__ = [
    "ModbusEndpoint",
    "RobotiqFT300",
    "StreamParser",
    "decode_firmware",
    "decode_serial",
    "decode_stream_frame",
    "encode_stream_frame",
    "registers_to_wrench",
]
