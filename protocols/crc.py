"""The CRC-16 variants of the device protocols; moved to :mod:`hil.protocols.codecs.crc` (importable
from here as before)."""

from hil.protocols.codecs.crc import crc16_dynamixel, crc16_modbus, crc16_x25, crc_bytes_le

__all__ = ["crc16_dynamixel", "crc16_modbus", "crc16_x25", "crc_bytes_le"]
