"""Bota Systems binary stream frame: layout, status bits, baud codes, CRC-16/X-25 framing and an
incremental parser (pure; no serial library). See :mod:`hil.protocols.serial_bota`."""

from __future__ import annotations

import re
import struct
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass

from hil.protocols.codecs.crc import crc16_x25
from hil.protocols.link_budget import BOTA_BASE_HZ as BOTA_BASE_HZ  # period = sinc_length / BOTA_BASE_HZ

HEADER = 0xAA
PAYLOAD = struct.Struct("<H6fIf")  # 34 bytes
FRAME_LEN = 1 + PAYLOAD.size + 2  # 37

STATUS_APP_TOOK_TOO_LONG = 0x1
STATUS_OVERRANGE = 0x2
STATUS_INVALID = 0x4
STATUS_RAW = 0x8

#: Baud codes of the ``c,...`` command (Bota's example: 0: 9600, 1: 57600, 2: 115200, 3: 230400, 4: 460800).
BOTA_BAUD_CODES = {0: 9600, 1: 57600, 2: 115200, 3: 230400, 4: 460800}


@dataclass(frozen=True)
class BotaFrame:
    status: int
    wrench: tuple[float, float, float, float, float, float]
    timestamp: int
    temperature: float


def encode_frame(status: int, wrench: Iterable[float], timestamp: int, temperature: float) -> bytes:
    """One binary frame (header, payload, CRC-16/X-25 little endian)."""
    payload = PAYLOAD.pack(status & 0xFFFF, *(float(w) for w in wrench), timestamp & 0xFFFFFFFF, temperature)
    return bytes((HEADER,)) + payload + struct.pack("<H", crc16_x25(payload))


def decode_payload(payload: bytes) -> BotaFrame:
    status, fx, fy, fz, tx, ty, tz, ts, temp = PAYLOAD.unpack(payload)
    return BotaFrame(status, (fx, fy, fz, tx, ty, tz), ts, temp)


class FrameParser:
    """Incremental parser: :meth:`feed` bytes, get the valid frames; never raises on bad data."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self.stats: Counter[str] = Counter()

    def feed(self, data: bytes) -> list[BotaFrame]:
        buf = self._buf
        buf += data
        out: list[BotaFrame] = []
        i = 0
        n = len(buf)
        while True:
            j = buf.find(HEADER, i)
            if j < 0:
                self.stats["resync_bytes"] += n - i
                i = n
                break
            if j > i:
                self.stats["resync_bytes"] += j - i
            i = j
            if n - i < FRAME_LEN:
                break
            payload = bytes(buf[i + 1 : i + 1 + PAYLOAD.size])
            (crc,) = struct.unpack_from("<H", buf, i + 1 + PAYLOAD.size)
            if crc16_x25(payload) == crc:
                out.append(decode_payload(payload))
                self.stats["frames"] += 1
                i += FRAME_LEN
            else:
                self.stats["crc_errors"] += 1
                self.stats["resync_bytes"] += 1
                i += 1  # resynchronise: look for the next header after this one
        del buf[:i]
        return out


#: Bota boot text (Bota's rokubimini_serial driver, RokubiminiSerialCommunication.hpp: parsed after
#: a hardware reset ``#``, once ``App Init`` is seen)
BOTA_BOOT = {"name": re.compile(rb"name:\s(.*?)\r"), "serial": re.compile(rb"S/N:\s(.*?)\r"),
              "firmware": re.compile(rb"FW version:\s(.*?)\r")}


def parse_bota_boot(text: bytes) -> dict[str, str]:
    """Product name, serial number and firmware of a Bota serial sensor from its boot text (bytes
    after ``App Init``; binary frames around it are ignored). Missing fields are left out."""
    k = text.find(b"App Init")
    if k < 0:
        return {}
    out: dict[str, str] = {}
    for key, rx in BOTA_BOOT.items():
        m = rx.search(text, k)
        if m:
            out[key] = m.group(1).decode("ascii", errors="replace").strip()
    return out
