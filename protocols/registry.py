"""Driver registry: a scene names a driver, the registry imports only that driver's module.

Modelled on python-can's backend registry: each name maps to a ``"module:Class"`` string that is
resolved with :mod:`importlib` on first use, so a scene using only CAN never imports
``pymodbus`` or ``dynamixel_sdk``.

>>> from hil.protocols.registry import open_device
>>> dev = open_device("odrive_can", interface="virtual", channel="bench0", node_id=3)  # doctest: +SKIP

The same table says which optional distribution (and ``hil-certify`` extra) each driver needs,
for its adapter and for its simulated counterpart in :mod:`hil.mocks`: :func:`missing_extras` /
:func:`extras_message` answer a base install (``pip install hil-certify``) with one line naming
the extra, before a command creates anything on disk.
"""

from __future__ import annotations

import difflib
import importlib
import importlib.util
import logging
import sys
from collections.abc import Iterable
from dataclasses import dataclass
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
    "cia402": "hil.protocols.cia402:CiA402Drive",
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
        extras = ",".join(dict.fromkeys(r.extra for r in ADAPTER_REQUIRES.get(name, ()))) or "devices"
        raise DeviceError(
            f"driver {name!r} needs module {module_name!r} which failed to import ({exc}); "
            f"pip install 'hil-certify[{extras}]'"
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


# ---------------------------------------------------------------------------------------------
# optional dependencies (extras) per driver


@dataclass(frozen=True)
class Requirement:
    """An optional import: ``module`` (import name), ``distribution`` (pip name), ``extra`` (the
    ``hil-certify[...]`` extra that installs it)."""

    module: str
    distribution: str
    extra: str


CAN = Requirement("can", "python-can", "can")
SERIAL = Requirement("serial", "pyserial", "serial")
MODBUS = Requirement("pymodbus", "pymodbus", "modbus")
CANOPEN = Requirement("canopen", "canopen", "canopen")
DYNAMIXEL_SDK = Requirement("dynamixel_sdk", "dynamixel-sdk", "dynamixel")
DYNAMIXEL_SERIAL = Requirement("serial", "pyserial", "dynamixel")  # dynamixel-sdk imports pyserial
REPORT = (Requirement("matplotlib", "matplotlib", "report"), Requirement("jinja2", "jinja2", "report"))

#: what a driver's adapter imports (hil.protocols): needed by ``hil run`` / ``hil certify``, real or simulated
ADAPTER_REQUIRES: dict[str, tuple[Requirement, ...]] = {
    "odrive_can": (CAN,),
    "cubemars_mit": (CAN,),
    "bota_serial": (SERIAL,),
    "robotiq_ft300": (MODBUS,),
    "robotiq_ft300_stream": (SERIAL,),
    "dynamixel_x": (DYNAMIXEL_SDK, DYNAMIXEL_SERIAL),
    "cia402": (CAN, CANOPEN),
}
#: what a driver's simulated counterpart imports (hil.mocks): needed on a simulated bench and by
#: ``hil mock serve`` (the DYNAMIXEL chain and the FT-300 stream are plain ptys)
SIMULATOR_REQUIRES: dict[str, tuple[Requirement, ...]] = {
    "odrive_can": (CAN,),
    "cubemars_mit": (CAN,),
    "bota_serial": (SERIAL,),  # the simulator frames with hil.protocols.serial_bota
    "robotiq_ft300": (MODBUS,),
    "robotiq_ft300_stream": (),
    "dynamixel_x": (),
    "cia402": (CAN, CANOPEN),  # the simulated drive is a canopen LocalNode
}
DEVICE_LABELS: dict[str, str] = {
    "odrive_can": "ODrive",
    "cubemars_mit": "CubeMars motor",
    "bota_serial": "Bota F/T sensor",
    "robotiq_ft300": "Robotiq FT-300 (Modbus)",
    "robotiq_ft300_stream": "Robotiq FT-300 (stream)",
    "dynamixel_x": "DYNAMIXEL servo",
    "cia402": "CiA 402 drive",
}


def importable(module: str) -> bool:
    """Whether ``module`` can be found (``importlib.util.find_spec``; does not import it)."""
    if module in sys.modules:
        return sys.modules[module] is not None
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


def _missing(drivers: Iterable[str], *, simulated: bool, adapters: bool,
             report: bool) -> list[tuple[str, Requirement]]:
    out: list[tuple[str, Requirement]] = []
    for drv in dict.fromkeys(drivers):
        label = DEVICE_LABELS.get(drv, f"driver {drv!r}")
        who = f"the simulated {label}" if simulated else f"the {label} driver"
        reqs = (ADAPTER_REQUIRES.get(drv, ()) if adapters else ()) + (SIMULATOR_REQUIRES.get(drv, ()) if simulated
                                                                      else ())
        for r in dict.fromkeys(reqs):
            if not importable(r.module) and (who, r) not in out:
                out.append((who, r))
    if report:
        out += [("the report", r) for r in REPORT if not importable(r.module)]
    return out


def missing_extras(scene: Any = None, *, adapters: bool = True, report: bool = False) -> list[str]:
    """What a command on ``scene`` cannot import, one phrase per device kind and distribution,
    e.g. ``the simulated ODrive needs python-can``. ``adapters``: the devices are opened (``hil
    run``, ``hil certify``; ``False`` for ``hil mock serve``, which starts the simulated
    counterparts only); the simulated counterparts count when the scene has a ``simulation``
    section; ``report``: the HTML/PDF report (matplotlib, jinja2). ``scene=None``: the report only."""
    drivers = [d.driver for d in scene.devices] if scene is not None else []
    simulated = scene is not None and getattr(scene, "simulation", None) is not None
    miss = _missing(drivers, simulated=simulated, adapters=adapters, report=report)
    phrases: dict[str, list[str]] = {}
    for who, r in miss:
        phrases.setdefault(who, [])
        if r.distribution not in phrases[who]:
            phrases[who].append(r.distribution)
    return [f"{who} needs {' and '.join(dists)}" for who, dists in phrases.items()]


def extras_message(scene: Any = None, *, adapters: bool = True, report: bool = False) -> str | None:
    """None when everything is installed, else ONE line naming what is missing and the extra to
    install: ``the simulated ODrive needs python-can: pip install 'hil-certify[can]'`` (see
    :func:`missing_extras` for the arguments)."""
    drivers = [d.driver for d in scene.devices] if scene is not None else []
    simulated = scene is not None and getattr(scene, "simulation", None) is not None
    miss = _missing(drivers, simulated=simulated, adapters=adapters, report=report)
    if not miss:
        return None
    extras = ",".join(dict.fromkeys(r.extra for _, r in miss))
    phrases = missing_extras(scene, adapters=adapters, report=report)
    return f"{', '.join(phrases)}: pip install 'hil-certify[{extras}]'"
