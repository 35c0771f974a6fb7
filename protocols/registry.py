"""Driver registry: a scene names a driver, the registry imports only that driver's module.

Modelled on python-can's backend registry (and its ``can.interface`` entry points): one
:class:`DeviceKind` per device kind names the adapter (``"module:Class"``), its simulated twin
(``"module:attribute"``, a :class:`hil.mocks.twins.Twin`: what :mod:`hil.bench.runtime` needs to start,
tick, flush and serve it), its transport and its optional imports; the strings are resolved with
:mod:`importlib` on first use, so a scene using only CAN never imports ``pymodbus`` or
``dynamixel_sdk``. Another distribution adds a device with an entry point in the
``hil_certify.devices`` group naming a :class:`DeviceKind` (read on first lookup,
:func:`load_entry_points`).

>>> from hil.protocols.registry import open_device
>>> dev = open_device("odrive_can", interface="virtual", channel="bench0", node_id=3)  # doctest: +SKIP

The same table says which optional distribution (and ``hil-certify`` extra) each driver needs,
for its adapter and for its simulated counterpart in :mod:`hil.mocks`: :func:`missing_extras` /
:func:`extras_message` answer a base install (``pip install hil-certify``) with one line naming
the extra, before a command creates anything on disk.
"""

from __future__ import annotations

import dataclasses
import difflib
import importlib
import importlib.util
import logging
import sys
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from hil.errors import DeviceError

logger = logging.getLogger(__name__)


class UnknownDriverError(DeviceError, KeyError):
    """The scene names a driver that is not registered. The message lists the known names."""

    def __str__(self) -> str:  # KeyError would repr() the message
        return str(self.args[0]) if self.args else ""


@dataclass(frozen=True)
class DeviceKind:
    """One registration per device kind (python-can's backend table, plus the simulated twin).

    ``name``: the scene's ``devices[].driver``; ``adapter``: ``"module:Class"`` of the adapter
    (imported on first use); ``transport``: ``"can"``, ``"serial"``, ``"modbus"`` or
    ``"dynamixel"`` (or another word for a third-party transport); ``twin``: ``"module:attribute"``
    of its :class:`hil.mocks.twins.Twin` (None: no simulated counterpart); ``label``: how messages
    name it; ``adapter_requires`` / ``simulator_requires``: the optional imports of the adapter and
    of the twin (:class:`Requirement`); ``watchdog_param``: the adapter parameter (seconds) that
    arms the device's own watchdog from the scene's ``watchdog_ms`` (None: it has none), and
    ``watchdog_needs``: a parameter that must be set on a real bench for that (ODrive: the
    endpoint ids), on a simulated bench the twin provides it."""

    name: str
    adapter: str
    transport: str
    twin: str | None = None
    label: str = ""
    adapter_requires: tuple[Requirement, ...] = ()
    simulator_requires: tuple[Requirement, ...] = ()
    watchdog_param: str | None = None
    watchdog_needs: str | None = None

    def __post_init__(self) -> None:
        for what, target in (("adapter", self.adapter), ("twin", self.twin)):
            if target is not None and ":" not in target:
                raise ValueError(f"device kind {self.name!r}: {what} must look like 'module:attribute', got {target!r}")

    def watchdog_params(self, params: dict[str, Any], watchdog_s: float, simulated: bool) -> None:
        """Arm the device's own watchdog (``watchdog_param`` = ``watchdog_s``) unless the scene's
        params set it, where it has one."""
        if self.watchdog_param is None:
            return
        if self.watchdog_needs is None or simulated or params.get(self.watchdog_needs):
            params.setdefault(self.watchdog_param, watchdog_s)


_KINDS: dict[str, DeviceKind] = {}
#: ``name -> "module:Class"`` of every registered adapter (a view kept for old callers)
_DRIVERS: dict[str, str] = {}
ENTRY_POINT_GROUP = "hil_certify.devices"
_entry_points_loaded = False


def register_device(kind: DeviceKind, *, replace: bool = False) -> DeviceKind:
    """Register a device kind (its adapter, simulated twin, transport, extras). A name already
    registered differently is a ValueError unless ``replace``."""
    old = _KINDS.get(kind.name)
    if old is not None and old != kind and not replace:
        raise ValueError(f"device kind {kind.name!r} already registered as {old.adapter!r}")
    _KINDS[kind.name] = kind
    _DRIVERS[kind.name] = kind.adapter
    ADAPTER_REQUIRES[kind.name] = kind.adapter_requires
    SIMULATOR_REQUIRES[kind.name] = kind.simulator_requires
    DEVICE_LABELS[kind.name] = kind.label or f"driver {kind.name!r}"
    return kind


def register_driver(name: str, target: str, *, replace: bool = False) -> None:
    """Register ``name`` -> ``"package.module:ClassName"`` (not imported until opened), without a
    simulated twin (see :func:`register_device`)."""
    if ":" not in target:
        raise ValueError(f"driver target must look like 'module:Class', got {target!r}")
    if name in _DRIVERS and not replace and _DRIVERS[name] != target:
        raise ValueError(f"driver {name!r} already registered as {_DRIVERS[name]!r}")
    old = _KINDS.get(name)
    register_device(dataclasses.replace(old, adapter=target) if old is not None
                    else DeviceKind(name, target, "other"), replace=True)


def load_entry_points() -> list[str]:
    """Register the device kinds other distributions declare in the ``hil_certify.devices``
    entry-point group (each entry point loads a :class:`DeviceKind`, or a callable returning one).
    Runs once (later calls return []); a broken entry point is logged and skipped. Returns the
    names registered."""
    global _entry_points_loaded
    if _entry_points_loaded:
        return []
    _entry_points_loaded = True
    import importlib.metadata  # 15-20 ms of imports: only when the entry points are read

    out: list[str] = []
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        try:
            obj = ep.load()
            kind = obj() if callable(obj) and not isinstance(obj, DeviceKind) else obj
            if not isinstance(kind, DeviceKind):
                raise TypeError(f"{ep.value} is not a DeviceKind")
            register_device(kind)
            out.append(kind.name)
        except Exception:
            logger.warning("device entry point %r (%s) could not be registered", ep.name, ep.value, exc_info=True)
    return out


def device_kind(name: str) -> DeviceKind:
    """The registration of ``name`` (entry points included); UnknownDriverError otherwise."""
    load_entry_points()
    try:
        return _KINDS[name]
    except KeyError:
        raise _unknown(name) from None


def simulated_drivers() -> list[str]:
    """Sorted names of the device kinds with a simulated twin."""
    load_entry_points()
    return sorted(n for n, k in _KINDS.items() if k.twin is not None)


def resolve_twin(name: str) -> Any:
    """Import and return the :class:`hil.mocks.twins.Twin` of device kind ``name``; DeviceError
    when it has none or its module cannot be imported."""
    kind = device_kind(name)
    if kind.twin is None:
        raise DeviceError(f"driver {name!r} has no simulated counterpart (simulated: {', '.join(simulated_drivers())})")
    return _import_target(name, kind.twin, kind.simulator_requires)


def _import_target(name: str, target: str, requires: tuple[Requirement, ...], what: str = "attribute") -> Any:
    module_name, _, attr = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        extras = ",".join(dict.fromkeys(r.extra for r in requires)) or "devices"
        raise DeviceError(
            f"driver {name!r} needs module {module_name!r} which failed to import ({exc}); "
            f"pip install 'hil-certify[{extras}]'"
        ) from exc
    try:
        return getattr(module, attr)
    except AttributeError:
        raise DeviceError(f"driver {name!r}: {module_name} has no {what} {attr!r}") from None


def available_drivers() -> list[str]:
    """Sorted names of all registered drivers (whether or not their dependencies are installed)."""
    load_entry_points()
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
    kind = device_kind(name)
    cls: type = _import_target(name, kind.adapter, kind.adapter_requires, "class")
    return cls


def open_device(driver: str, **params: Any) -> Any:
    """Instantiate the adapter registered as ``driver`` with ``params`` (its constructor args)."""
    cls = resolve_driver(driver)
    logger.debug("opening %s (%s.%s) with %s", driver, cls.__module__, cls.__name__, params)
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
ADAPTER_REQUIRES: dict[str, tuple[Requirement, ...]] = {}
#: what a driver's simulated counterpart imports (hil.mocks): needed on a simulated bench and by
#: ``hil mock serve`` (the DYNAMIXEL chain and the FT-300 stream are plain ptys)
SIMULATOR_REQUIRES: dict[str, tuple[Requirement, ...]] = {}
DEVICE_LABELS: dict[str, str] = {}

# -- the built-in device kinds (one registration each) --------------------------------------------
for _kind in (
    DeviceKind("odrive_can", "hil.protocols.can_odrive:ODriveCAN", "can", "hil.mocks.twins:ODRIVE", "ODrive",
               (CAN,), (CAN,), watchdog_param="watchdog_s", watchdog_needs="watchdog_endpoints"),
    DeviceKind("cubemars_mit", "hil.protocols.can_cubemars:CubeMarsMIT", "can", "hil.mocks.twins:CUBEMARS",
               "CubeMars motor", (CAN,), (CAN,)),
    DeviceKind("bota_serial", "hil.protocols.serial_bota:BotaSerial", "serial", "hil.mocks.twins:BOTA",
               "Bota F/T sensor", (SERIAL,), (SERIAL,)),
    DeviceKind("robotiq_ft300", "hil.protocols.modbus_robotiq:RobotiqFT300", "modbus", "hil.mocks.twins:FT300",
               "Robotiq FT-300 (Modbus)", (MODBUS,), (MODBUS,)),
    DeviceKind("robotiq_ft300_stream", "hil.protocols.modbus_robotiq:RobotiqFT300Stream", "serial",
               "hil.mocks.twins:FT300_STREAM", "Robotiq FT-300 (stream)", (SERIAL,), ()),
    DeviceKind("dynamixel_x", "hil.protocols.dynamixel_x:DynamixelX", "dynamixel", "hil.mocks.twins:DYNAMIXEL",
               "DYNAMIXEL servo", (DYNAMIXEL_SDK, DYNAMIXEL_SERIAL), (), watchdog_param="bus_watchdog_s"),
    # the simulated drive is a canopen LocalNode
    DeviceKind("cia402", "hil.protocols.cia402:CiA402Drive", "can", "hil.mocks.twins:CIA402", "CiA 402 drive",
               (CAN, CANOPEN), (CAN, CANOPEN)),
):
    register_device(_kind)


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
