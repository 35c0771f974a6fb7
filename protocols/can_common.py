"""CAN transport shared by the CAN adapters: python-can errors mapped onto the package's error
hierarchy (a send that cannot complete in time is a :class:`DeviceTimeout`, any other bus error a
:class:`DeviceDisconnected`) and :class:`CanActuator`, the lifecycle of an actuator on a bus."""

from __future__ import annotations

import abc
import logging
from typing import Any

import can

from hil.errors import DeviceDisconnected, DeviceTimeout
from hil.protocols.base import Actuator
from hil.protocols.waits import WALL, Waits

logger = logging.getLogger(__name__)


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


def open_can_bus(
    interface: str, channel: str, bitrate: int | None, filters: list[dict[str, Any]] | None, **kw: Any
) -> can.BusABC:
    """Open a python-can bus, mapping failures to :class:`hil.errors.DeviceDisconnected`."""
    kwargs: dict[str, Any] = dict(kw)
    if bitrate is not None:
        kwargs["bitrate"] = bitrate
    try:
        return can.Bus(interface=interface, channel=channel, can_filters=filters, **kwargs)
    except (can.CanError, OSError, ValueError) as exc:
        raise DeviceDisconnected(f"cannot open CAN bus {interface}:{channel}: {exc}") from exc


class CanActuator(Actuator):
    """An actuator on a python-can bus: the bus is opened here (or borrowed: ``bus=...``, then
    :meth:`close` leaves it running), frames are sent and received with the closed check and the
    package's errors, and :meth:`_drain` digests what is queued with the driver's one hook
    :meth:`_handle`. :meth:`_release` shuts an owned bus down."""

    _bus: can.BusABC
    _own_bus: bool = False
    #: how the adapter waits (:mod:`hil.protocols.waits`); drivers set it from their ``waits`` parameter
    _waits: Waits = WALL

    def _open_bus(self, interface: str, channel: str, bitrate: int | None, bus: can.BusABC | None,
                  bus_kwargs: dict[str, Any]) -> None:
        if bus is None:
            self._bus = open_can_bus(interface, channel, bitrate, None, **bus_kwargs)
            self._own_bus = True
        else:
            self._bus, self._own_bus = bus, False

    def _send_frame(self, msg: can.Message, timeout: float, what: str = "send") -> None:
        self._check_open()
        send(self._bus, msg, timeout, self._label(), what)

    def _recv(self, timeout: float) -> can.Message | None:
        """One frame within ``timeout`` s, waited for through ``_waits`` (the host's clock at a
        bench; on a lockstep bench the simulated nodes answer in the sender's thread, so after the
        barrier a frame is there or will not come: the timeout passes in simulated time)."""
        self._check_open()
        bus, who = self._bus, self._label()
        return self._waits.receive(lambda t: recv(bus, t, who), timeout)

    def _drain(self) -> None:
        """Digest every frame already queued (no waiting)."""
        while (msg := self._recv(0.0)) is not None:
            self._handle(msg)

    @abc.abstractmethod
    def _handle(self, msg: can.Message) -> object:
        """Hook: digest one received frame."""

    def _release(self) -> None:
        if self._own_bus:
            self._bus.shutdown()
