"""DYNAMIXEL X-series (Protocol 2.0) control table, units and register conversions (pure; no SDK).
See :mod:`hil.protocols.dynamixel_x`."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from hil.errors import ProtocolError
from hil.protocols.codecs.crc import crc16_dynamixel

ADDR_MODEL_NUMBER = 0
ADDR_FIRMWARE_VERSION = 6
ADDR_BAUD_RATE = 8
ADDR_RETURN_DELAY = 9
ADDR_OPERATING_MODE = 11
ADDR_CURRENT_LIMIT = 38
ADDR_TORQUE_ENABLE = 64
ADDR_HARDWARE_ERROR = 70
ADDR_BUS_WATCHDOG = 98
BUS_WATCHDOG_UNIT_S = 0.020
BUS_WATCHDOG_ERROR = 0xFF
FAULT_BUS_WATCHDOG = 0x200
ADDR_GOAL_CURRENT = 102
ADDR_PRESENT_CURRENT = 126
ADDR_PRESENT_VELOCITY = 128
ADDR_PRESENT_POSITION = 132
PRESENT_BLOCK_LEN = 10  # 126..135
MODE_CURRENT = 0

#: Baud Rate(8) index -> bps (X-series e-manual, "Baud Rate(8)"); factory index 1 = 57 600 bps.
BAUD_RATES = {0: 9600, 1: 57600, 2: 115200, 3: 1_000_000, 4: 2_000_000, 5: 3_000_000, 6: 4_000_000,
              7: 4_500_000}
ERRBIT_ALERT = 0x80

CURRENT_UNIT_A = 2.69e-3
VELOCITY_UNIT_RAD_S = 0.229 * 2.0 * math.pi / 60.0
TICKS_PER_REV = 4096
RAD_PER_TICK = 2.0 * math.pi / TICKS_PER_REV


@dataclass(frozen=True)
class XModel:
    """Constants of one X-series model."""

    name: str
    model_number: int
    torque_constant: float  # N.m per A (output side)
    current_limit: int  # Current Limit(38) factory value, units of 2.69 mA


MODELS: dict[str, XModel] = {
    # e-manual: stall torque 4.1 N.m @ 12 V, 2.3 A -> 1.78 N.m/A; Current Limit initial value 1193
    "XM430-W350": XModel("XM430-W350", 1020, 4.1 / 2.3, 1193),
}


# ------------------------------------------------------------------------------------------------
# pure conversions
# ------------------------------------------------------------------------------------------------
def to_signed(value: int, nbytes: int) -> int:
    """Two's complement: unsigned ``nbytes`` integer -> signed."""
    bits = 8 * nbytes
    value = int(value) & ((1 << bits) - 1)
    return value - (1 << bits) if value >= 1 << (bits - 1) else value


def to_unsigned(value: int, nbytes: int) -> int:
    """Signed integer -> its ``nbytes`` two's complement (raises if it does not fit)."""
    bits = 8 * nbytes
    if not -(1 << (bits - 1)) <= int(value) < (1 << bits):
        raise OverflowError(f"{value} does not fit in {nbytes} bytes")
    return int(value) & ((1 << bits) - 1)


def effort_to_current_raw(
    effort: np.ndarray, torque_constant: np.ndarray, limit_raw: np.ndarray, directions: np.ndarray
) -> np.ndarray:
    """Effort (N.m) -> Goal Current register values (signed ints), clamped to +-limit."""
    raw = np.rint(directions * np.asarray(effort, dtype=float) / torque_constant / CURRENT_UNIT_A)
    out: np.ndarray = np.clip(raw, -limit_raw, limit_raw).astype(np.int64)
    return out


def bus_watchdog_units(seconds: float) -> int:
    """Bus Watchdog(98) value for a timeout of ``seconds``: rounded *up* to the 20 ms unit, in
    1..127 (so the servo never stops earlier than asked; at most 2.54 s)."""
    if not (math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"bus watchdog timeout must be > 0 s, got {seconds!r}")
    return int(min(127, max(1, math.ceil(seconds / BUS_WATCHDOG_UNIT_S - 1e-9))))


def decode_present_block(block: bytes | Sequence[int]) -> tuple[int, int, int]:
    """The 10-byte block read at 126 -> (current, velocity, position) raw signed integers."""
    b = bytes(block)
    if len(b) != PRESENT_BLOCK_LEN:
        raise ProtocolError(f"present block must be {PRESENT_BLOCK_LEN} bytes, got {len(b)}")
    cur = to_signed(int.from_bytes(b[0:2], "little"), 2)
    vel = to_signed(int.from_bytes(b[2:6], "little"), 4)
    pos = to_signed(int.from_bytes(b[6:10], "little"), 4)
    return cur, vel, pos


# ------------------------------------------------------------------------------------------------
# Protocol 2.0 status packets on a byte stream (the non-blocking read collects them itself)
# ------------------------------------------------------------------------------------------------
STATUS_HEADER = b"\xff\xff\xfd\x00"
INST_STATUS = 0x55
#: bytes of a status packet around its data: header 4, id 1, length 2, instruction 1, error 1, CRC 2
STATUS_OVERHEAD = 11


def _unstuff(body: bytes) -> bytes:
    """Protocol 2.0 byte stuffing undone: the ``FD`` inserted after each ``FF FF FD`` is dropped."""
    if b"\xff\xff\xfd\xfd" not in body:
        return body
    return body.replace(b"\xff\xff\xfd\xfd", b"\xff\xff\xfd")


@dataclass
class StatusParser:
    """Incremental parser of Protocol 2.0 status packets (ROBOTIS e-manual, "Protocol 2.0": status
    packet ``FF FF FD 00 ID LEN_L LEN_H 55 ERR PARAM... CRC_L CRC_H``, ``LEN`` = stuffed bytes
    from the instruction to the CRC inclusive, CRC-16 (poly 0x8005) over everything before it).

    :meth:`feed` takes bytes as they arrive (a packet may be split over several calls) and returns
    the complete packets as ``(id, error, params)`` (``params`` unstuffed). A frame whose CRC fails
    is dropped and counted in ``crc_errors``; bytes before a header are skipped (``skipped_bytes``).
    """

    crc_errors: int = 0
    skipped_bytes: int = 0

    def __post_init__(self) -> None:
        self._buf = bytearray()

    @property
    def pending(self) -> int:
        """Bytes held (the start of a packet not complete yet)."""
        return len(self._buf)

    def clear(self) -> None:
        """Forget the bytes held (a request abandoned: its late bytes must not start a packet)."""
        self._buf.clear()

    def feed(self, data: bytes) -> list[tuple[int, int, bytes]]:
        buf = self._buf
        buf += data
        out: list[tuple[int, int, bytes]] = []
        while True:
            j = buf.find(STATUS_HEADER)
            if j < 0:
                keep = 3 if buf.endswith(b"\xff\xff\xfd") else 2 if buf.endswith(b"\xff\xff") else (
                    1 if buf.endswith(b"\xff") else 0)
                self.skipped_bytes += len(buf) - keep
                del buf[: len(buf) - keep]
                return out
            if j:
                self.skipped_bytes += j
                del buf[:j]
            if len(buf) < 7:
                return out
            length = buf[5] | (buf[6] << 8)
            if length < 4 or length > 1024:  # not a status packet header: resynchronise after it
                self.skipped_bytes += 1
                del buf[:1]
                continue
            total = 7 + length
            if len(buf) < total:
                return out
            frame = bytes(buf[:total])
            del buf[:total]
            if crc16_dynamixel(frame[:-2]) != int.from_bytes(frame[-2:], "little"):
                self.crc_errors += 1
                continue
            if frame[7] != INST_STATUS or length < 4:  # an instruction packet (an echoing line): not ours
                self.skipped_bytes += total
                continue
            body = _unstuff(frame[8:-2])
            out.append((frame[4], body[0], body[1:]))
