"""Driver registry: a scene names a driver, the registry imports only that driver's module.

Modelled on python-can's backend registry: each name maps to a ``"module:Class"`` string that is
resolved with :mod:`importlib` on first use, so a scene using only CAN never imports
``pymodbus`` or ``dynamixel_sdk``.

>>> from hil.protocols.registry import open_device
>>> dev = open_device("odrive_can", interface="virtual", channel="bench0", node_id=3)  # doctest: +SKIP
"""

from __future__ import annotations

import difflib
import importlib
import logging
from typing import Any

from hil.errors import DeviceError

log = logging.getLogger(__name__)


class UnknownDriverError(DeviceError, KeyError):
    """The scene names a driver that is not registered. The message lists the known names."""

    def __str__(self) -> str:  # KeyError would repr() the message
        return str(self.args[0]) if self.args else ""


_DRIVERS: dict[str, str] = {
    "odrive_can": "hil.protocols.can_odrive:ODriveCAN",
    "cubemars_mit": "hil.protocols.can_cubemars:CubeMarsMIT",
    "bota_serial": "hil.protocols.serial_bota:BotaSerial",
    # implemented by another engineer (same registry, lazily imported as well)
    "robotiq_ft300": "hil.protocols.modbus_robotiq:RobotiqFT300",
    "robotiq_ft300_stream": "hil.protocols.modbus_robotiq:RobotiqFT300Stream",
    "dynamixel_x": "hil.protocols.dynamixel_x:DynamixelX",
}


def register_driver(name: str, target: str, *, replace: bool = False) -> None:
    """Register ``name`` -> ``"package.module:ClassName"`` (not imported until opened)."""
    if ":" not in target:
        raise ValueError(f"driver target must look like 'module:Class', got {target!r}")
    if name in _DRIVERS and not replace and _DRIVERS[name] != target:
        raise ValueError(f"driver {name!r} already registered as {_DRIVERS[name]!r}")
    _DRIVERS[name] = target


def available_drivers() -> list[str]:
    """Sorted names of all registered drivers (whether or not their dependencies are installed)."""
    return sorted(_DRIVERS)


def _unknown(name: str) -> UnknownDriverError:
    known = available_drivers()
    close = difflib.get_close_matches(name, known, n=1, cutoff=0.5)
    hint = f" Did you mean {close[0]!r}?" if close else ""
    return UnknownDriverError(f"unknown driver {name!r}.{hint} Known drivers: {', '.join(known)}")


def resolve_driver(name: str) -> type:
    """Import and return the adapter class registered as ``name``.

    Raises :class:`UnknownDriverError` for unregistered names and :class:`hil.errors.DeviceError`
    when the driver's module or its optional dependency cannot be imported.
    """
    try:
        target = _DRIVERS[name]
    except KeyError:
        raise _unknown(name) from None
    module_name, _, cls_name = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise DeviceError(
            f"driver {name!r} needs module {module_name!r} which failed to import ({exc}); "
            "install the matching extra, e.g. pip install 'hil-certify[devices]'"
        ) from exc
    try:
        return getattr(module, cls_name)
    except AttributeError:
        raise DeviceError(f"driver {name!r}: {module_name} has no class {cls_name!r}") from None


def open_device(driver: str, **params: Any) -> Any:
    """Instantiate the adapter registered as ``driver`` with ``params`` (its constructor args)."""
    cls = resolve_driver(driver)
    log.debug("opening %s (%s.%s) with %s", driver, cls.__module__, cls.__name__, params)
    return cls(**params)
