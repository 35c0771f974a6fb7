"""CAN send/receive with python-can errors mapped onto the package's error hierarchy (shared by
the CAN adapters): a send that cannot complete in time is a :class:`DeviceTimeout`, any other bus
error a :class:`DeviceDisconnected`."""

from __future__ import annotations

import can

from hil.errors import DeviceDisconnected, DeviceTimeout


def send(bus: can.BusABC, msg: can.Message, timeout: float, who: str, what: str = "send") -> None:
    """Send ``msg``; ``who`` names the device in error messages (e.g. ``"ODrive node 3"``)."""
    try:
        bus.send(msg, timeout=timeout)
    except can.CanOperationError as exc:
        raise DeviceTimeout(f"{who}: {what} failed: {exc}") from exc
    except can.CanError as exc:
        raise DeviceDisconnected(f"{who}: bus error: {exc}") from exc


def recv(bus: can.BusABC, timeout: float, who: str) -> can.Message | None:
    """Receive one frame within ``timeout`` seconds (None if none arrived)."""
    try:
        return bus.recv(timeout=max(0.0, timeout))
    except can.CanError as exc:
        raise DeviceDisconnected(f"{who}: bus error: {exc}") from exc
