"""CRC-16 variants against the catalogue check values and published frames."""

from __future__ import annotations

import pytest

from hil.protocols.crc import crc16_dynamixel, crc16_modbus, crc16_x25, crc_bytes_le

# (function, data, expected) -- check values from the reveng CRC catalogue (CRC of b"123456789")
# and frames from public manuals.
VECTORS = [
    (crc16_x25, b"123456789", 0x906E),  # CRC-16/X-25 (IBM-SDLC) check
    (crc16_dynamixel, b"123456789", 0xFEE8),  # CRC-16/UMTS (BUYPASS) check
    (crc16_modbus, b"123456789", 0x4B37),  # CRC-16/MODBUS check
    (crc16_x25, b"", 0x0000),
    (crc16_modbus, b"", 0xFFFF),
    (crc16_dynamixel, b"", 0x0000),
    # Modbus RTU "read holding registers" example: 01 03 00 00 00 0A -> CRC C5CD (sent CD C5)
    (crc16_modbus, bytes.fromhex("01030000000A"), 0xCDC5),
    # Dynamixel 2.0 e-manual ping instruction to ID 1: FF FF FD 00 01 03 00 01 -> CRC 0x4E19 (19 4E)
    (crc16_dynamixel, bytes.fromhex("FFFFFD0001030001"), 0x4E19),
]


@pytest.mark.parametrize(("fn", "data", "expected"), VECTORS)
def test_check_values(fn, data, expected):
    assert fn(data) == expected


def test_little_endian_bytes():
    assert crc_bytes_le(0x906E) == b"\x6e\x90"


def test_dynamixel_incremental():
    data = b"123456789"
    assert crc16_dynamixel(data[4:], init=crc16_dynamixel(data[:4])) == 0xFEE8


def test_x25_detects_single_bit_flips():
    data = bytes(range(34))
    ref = crc16_x25(data)
    for i in range(len(data)):
        for bit in range(8):
            d = bytearray(data)
            d[i] ^= 1 << bit
            assert crc16_x25(d) != ref
