"""Table-driven CRC-16 variants used by the device protocols.

Parameters follow the Rocksoft/Williams model used by the "Catalogue of parametrised CRC
algorithms" (reveng): width 16, ``poly``, ``init``, ``refin``/``refout``, ``xorout``; the
``check`` value is the CRC of the ASCII bytes ``b"123456789"``.

=================  ======  ======  =====  ======  ======  ======================================
name               poly    init    refl.  xorout  check   used by
=================  ======  ======  =====  ======  ======  ======================================
CRC-16/X-25        0x1021  0xFFFF  yes    0xFFFF  0x906E  Bota Systems serial F/T stream
CRC-16/UMTS        0x8005  0x0000  no     0x0000  0xFEE8  Dynamixel Protocol 2.0 (aka BUYPASS)
CRC-16/MODBUS      0x8005  0xFFFF  yes    0x0000  0x4B37  Modbus RTU
=================  ======  ======  =====  ======  ======  ======================================

Byte order on the wire is the protocol's business: X-25 (Bota) and Modbus send the CRC low byte
first; Dynamixel 2.0 also sends it little-endian. Use :func:`crc_bytes_le` for that.
"""

from __future__ import annotations

import binascii
from collections.abc import Callable


def _reflected_table(poly: int) -> tuple[int, ...]:
    rpoly = int(f"{poly:016b}"[::-1], 2)
    table = []
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ rpoly if c & 1 else c >> 1
        table.append(c)
    return tuple(table)


def _normal_table(poly: int) -> tuple[int, ...]:
    table = []
    for i in range(256):
        c = i << 8
        for _ in range(8):
            c = ((c << 1) ^ poly) if c & 0x8000 else (c << 1)
            c &= 0xFFFF
        table.append(c)
    return tuple(table)


_X25_TABLE = _reflected_table(0x1021)
_MODBUS_TABLE = _reflected_table(0x8005)
_DXL_TABLE = _normal_table(0x8005)


def _crc_reflected(data: bytes | bytearray | memoryview, table: tuple[int, ...], init: int) -> int:
    crc = init
    for b in bytes(data):
        crc = (crc >> 8) ^ table[(crc ^ b) & 0xFF]
    return crc


#: bit-reversed bytes (bytes.translate table)
_REV8 = bytes(int(f"{i:08b}"[::-1], 2) for i in range(256))


def crc16_x25(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/X-25 (a.k.a. CRC-16/IBM-SDLC): poly 0x1021 reflected, init 0xFFFF, xorout 0xFFFF.

    Computed in C: a reflected CRC is the bit reversal of the non-reflected one (binascii.crc_hqx,
    CRC-CCITT poly 0x1021) over the bit-reversed bytes, with the (symmetric) init 0xFFFF; equal to
    the table-driven :func:`_crc_reflected` with the X-25 table (tests/bench/test_lockstep_crc.py)."""
    c = binascii.crc_hqx(bytes(data).translate(_REV8), 0xFFFF)
    return ((_REV8[c & 0xFF] << 8) | _REV8[c >> 8]) ^ 0xFFFF


def crc16_modbus(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/MODBUS: poly 0x8005 reflected, init 0xFFFF, xorout 0."""
    return _crc_reflected(data, _MODBUS_TABLE, 0xFFFF)


def crc16_dynamixel(data: bytes | bytearray | memoryview, init: int = 0) -> int:
    """CRC-16 of Dynamixel Protocol 2.0 (CRC-16/UMTS = BUYPASS): poly 0x8005, init 0, not reflected.

    Computed over the whole packet from the header ``FF FF FD 00`` up to the last parameter.
    ``init`` allows incremental computation (pass the previous result).
    """
    crc = init & 0xFFFF
    for b in bytes(data):
        crc = ((crc << 8) & 0xFFFF) ^ _DXL_TABLE[((crc >> 8) ^ b) & 0xFF]
    return crc


def crc_bytes_le(crc: int) -> bytes:
    """The 16-bit CRC as 2 bytes, low byte first (the order of all three protocols above)."""
    return bytes((crc & 0xFF, (crc >> 8) & 0xFF))


CRC16: dict[str, Callable[[bytes], int]] = {
    "x25": crc16_x25,
    "modbus": crc16_modbus,
    "dynamixel": crc16_dynamixel,
}
