"""The package's error hierarchy: every error the suite raises on purpose derives from :class:`HilError`.

Errors that have a natural builtin meaning also derive from that builtin, so callers can catch
them either way (e.g. :class:`DeviceTimeout` is a :class:`TimeoutError`).
"""

from __future__ import annotations


class HilError(Exception):
    """Root of every error raised on purpose by the suite."""


class ModelError(HilError, ValueError):
    """A network model is malformed (bad coefficients, wrong shape, non-proper entries, ...)."""


class ConversionError(ModelError):
    """An immittance conversion does not exist for this network (e.g. singular h22 for h -> z)."""


class SceneError(HilError, ValueError):
    """A scene or network description file is invalid. The message names the file and the field."""


class DeviceError(HilError):
    """Root of errors raised by device adapters and transports."""


class DeviceTimeout(DeviceError, TimeoutError):
    """A device did not answer within the call's timeout."""


class ProtocolError(DeviceError):
    """A frame could not be decoded (bad header, length, CRC, unexpected reply)."""


class ChecksumError(ProtocolError):
    """A frame's checksum / CRC did not match."""


class DeviceFault(DeviceError):
    """The device reported a fault code. ``code`` holds the device's raw code."""

    def __init__(self, message: str, code: int | None = None) -> None:
        super().__init__(message)
        self.code = code


class DeviceDisconnected(DeviceError, ConnectionError):
    """The transport was closed or lost."""


class SafetyStop(HilError):
    """An experiment was stopped by a safety limit, the watchdog or a signal."""
