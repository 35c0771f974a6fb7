"""Robotiq FT-300 wire format: registers and scaling, the 16-byte stream frame and its parser, Modbus
RTU framing, transport URLs (pure; no Modbus or serial library). See :mod:`hil.protocols.modbus_robotiq`."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from urllib.parse import parse_qs, urlsplit

import numpy as np

from hil.errors import ChecksumError, ProtocolError
from hil.protocols.codecs.crc import crc16_modbus

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
    wrench: np.ndarray = signed / WRENCH_SCALES
    return wrench


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
    wrench: np.ndarray = np.array(struct.unpack_from("<6h", frame, 2), dtype=float) / WRENCH_SCALES
    return wrench


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


#: Exception codes a Modbus server may answer with (Modbus Application Protocol v1.1b3, 7).
MODBUS_EXCEPTION_CODES = frozenset({1, 2, 3, 4, 5, 6, 8, 10, 11})
#: Gateway exceptions: 10 path unavailable, 11 target device failed to respond (its reply was
#: missing or failed the serial CRC): a missed reply, not a device fault.
GATEWAY_EXCEPTION_CODES = frozenset({10, 11})


class GatewayError(ProtocolError):
    """A Modbus gateway answered exception 10/11: the sensor behind it gave no valid reply."""


#: FT-300 rated measuring range: |Fx|, |Fy|, |Fz| <= 300 N, |Mx|, |My|, |Mz| <= 30 N.m.
RATED_FORCE = 300.0
RATED_TORQUE = 30.0


def check_wrench_range(wrench: np.ndarray, max_force: float, max_torque: float) -> None:
    """Raise :class:`ProtocolError` if a decoded wrench lies outside the sensor's range (a
    damaged reply on a transport without a CRC, e.g. Modbus/TCP)."""
    w = np.asarray(wrench, dtype=float).reshape(6)
    if np.any(np.abs(w[:3]) > max_force) or np.any(np.abs(w[3:]) > max_torque):
        raise ProtocolError(f"FT-300: wrench {np.round(w, 3).tolist()} outside the range "
                            f"+-{max_force:g} N, +-{max_torque:g} N.m (damaged reply?)")


#: How long the stream stop sends the jam and waits for the line to go quiet (s; manual: ~0.5 s).
STREAM_STOP_S = 0.5
#: Pause after the stream stopped before the first Modbus request (Robotiq's rq_sensor_com.c:
#: ``usleep(100000)`` "give some time to the sensor to switch to modbus").
STREAM_TO_MODBUS_S = 0.1


FC_READ_HOLDING = 0x03
FC_READ_INPUT = 0x04
FC_WRITE_SINGLE = 0x06
FC_WRITE_MULTIPLE = 0x10


def rtu_frame(slave: int, pdu: bytes) -> bytes:
    """``slave | pdu | CRC-16/MODBUS`` (CRC low byte first): one Modbus RTU frame."""
    body = bytes([slave & 0xFF]) + bytes(pdu)
    return body + struct.pack("<H", crc16_modbus(body))


def stream_start_request(slave: int = DEFAULT_SLAVE_ID) -> bytes:
    """The RTU request that starts the data stream: FC16, register 410, one register, 0x0200
    (as Robotiq's ``rq_com_start_stream`` sends it)."""
    pdu = struct.pack(">BHHBH", FC_WRITE_MULTIPLE, REG_OUTPUT_SELECT, 1, 2, STREAM_START_VALUE)
    return rtu_frame(slave, pdu)


def _rtu_reply_length(buf: bytes | bytearray, i: int, fc: int) -> int | None:
    """Expected length of the RTU reply to function ``fc`` starting at ``buf[i]`` (None: need more
    bytes to tell)."""
    if len(buf) - i < 3:
        return None
    if buf[i + 1] == (fc | 0x80):
        return 5  # slave, fc | 0x80, exception code, CRC
    if fc in (FC_READ_HOLDING, FC_READ_INPUT):
        return 5 + buf[i + 2]
    return 8  # FC06 / FC16 echo: slave, fc, address, value or count, CRC


def _parse_rtu_reply(buf: bytearray, slave: int, fc: int) -> tuple[bytes | None, int, bool]:
    """Find the reply of ``slave`` to ``fc`` in ``buf``: (frame or None, end index, bad CRC seen).

    Bytes before a candidate (line noise, the tail of a stream) are skipped; a candidate whose CRC
    fails is skipped too (a real master would discard it) but reported.
    """
    bad_crc = False
    start = 0
    while True:
        i = buf.find(bytes([slave & 0xFF]), start)
        if i < 0 or len(buf) - i < 2:
            return None, 0, bad_crc
        if buf[i + 1] not in (fc, fc | 0x80):
            start = i + 1
            continue
        n = _rtu_reply_length(buf, i, fc)
        if n is None or len(buf) - i < n:
            return None, 0, bad_crc
        frame = bytes(buf[i : i + n])
        if _modbus_crc_ok(frame):
            return frame, i + n, bad_crc
        bad_crc = True
        start = i + 1


# ------------------------------------------------------------------------------------------------
# the wrench request and its reply on the wire (the non-blocking read frames them itself)
# ------------------------------------------------------------------------------------------------
#: bits of one character on a Modbus serial line as the spec counts them (start, 8 data, parity
#: or a second stop bit, stop: "Modbus over serial line" V1.02 §2.5.1): 11
MODBUS_CHAR_BITS = 11


def rtu_silence_s(baudrate: float) -> float:
    """t3.5 (s), the silent interval that separates Modbus RTU frames ("Modbus over serial line"
    V1.02 §2.5.1.1): 3.5 character times, fixed 1.750 ms above 19200 bps."""
    if baudrate > 19200:
        return 1.750e-3
    return 3.5 * MODBUS_CHAR_BITS / float(baudrate)


def wrench_request_pdu() -> bytes:
    """FC03, registers 180..185 (the manual's ``09 03 00 B4 00 06 84 A6`` without address / CRC)."""
    return struct.pack(">BHH", FC_READ_HOLDING, REG_WRENCH, 6)


def mbap_frame(transaction: int, unit: int, pdu: bytes) -> bytes:
    """Modbus/TCP ADU: MBAP header (transaction id, protocol 0, length = unit + PDU, unit id), PDU."""
    return struct.pack(">HHHB", transaction & 0xFFFF, 0, len(pdu) + 1, unit & 0xFF) + bytes(pdu)


def parse_mbap_reply(buf: bytearray, transaction: int, unit: int) -> tuple[bytes | None, int]:
    """The PDU of the Modbus/TCP reply to ``transaction`` at the start of ``buf``: (PDU or None if
    incomplete, bytes to drop). An ADU of another transaction (a late reply) is dropped whole;
    a header that cannot be one (protocol id not 0, length out of 2..254) drops everything."""
    if len(buf) < 7:
        return None, 0
    tid, pid, length = struct.unpack_from(">HHH", buf, 0)
    if pid != 0 or not 2 <= length <= 254:
        return None, len(buf)
    total = 6 + length
    if len(buf) < total:
        return None, 0
    if tid != (transaction & 0xFFFF) or buf[6] != (unit & 0xFF):
        return None, total
    return bytes(buf[7:total]), total
