"""Start simulated devices on their own and report where each one listens (``hil mock serve``).

``hil mock serve SCENE`` (a scene file or a built-in scene name) builds the scene's physics and
simulated devices exactly as :class:`hil.bench.runtime.Bench` does (:class:`hil.bench.runtime.SimulatedScene`), steps
the plant in real time at the scene's rate, and prints one line per device: its name, driver and the
``open_device(...)`` call that connects an adapter to it (pty path, TCP URL, CAN interface +
channel); ``--json`` prints the same as one JSON line. It runs for ``--duration`` seconds or until
Ctrl-C / SIGTERM, then stops every thread and closes every pty, socket and bus.

CAN: python-can's ``virtual`` interface exists only inside one process, so CAN devices served on
it are reachable from the serving process only (the output says so). ``--can-interface
udp_multicast`` puts them on python-can's UDP multicast bus (one group per scene channel,
239.74.163.2, .3, ...; needs ``msgpack``: ``pip install 'python-can[multicast]'``), which every
process on the host can join; ``--can-channel hil0=vcan0 --can-interface socketcan`` maps a scene
channel onto a real (virtual) SocketCAN interface.

Without a scene, a *spec* (the interface that predates scenes) is a list of dicts (JSON/YAML file or
Python objects)::

    [
      {"kind": "odrive",   "channel": "hil0", "node_id": 3, "gear_ratio": 1.0,
       "interface": "virtual", "rate_hz": 1000, "encoder_every": 0, "heartbeat_every": 10},
      {"kind": "cubemars", "channel": "hil0", "motor_id": 1, "model": "AK80-9", "rate_hz": 1000},
      {"kind": "bota",     "rate_hz": 1000},
      {"kind": "cia402",   "channel": "hil0", "node_id": 2, "rate_hz": 1000},
      {"kind": "dynamixel", "ids": [1, 2]},
      {"kind": "ft300",    "slave": 9, "port": 0},           # Modbus/TCP on 127.0.0.1 (0: a free port)
      {"kind": "ft300_stream", "slave": 9, "rate_hz": 100},   # pty
    ]

Single devices from the command line (no spec file): ``hil mock serve --device KIND`` with
``--can-channel CH --can-interface IFACE --node N`` (odrive, cubemars: motor id, cia402),
``--ids 1,2`` (dynamixel), ``--unit N`` (ft300, ft300_stream: Modbus slave id), ``--port P``
(ft300: TCP port, default a free one), ``--pty`` (serial devices; the default and only transport
of bota, ft300_stream and dynamixel), ``--rate HZ``. It prints where to connect: the pty path, TCP
URL or CAN channel and node, and the ``open_device(...)`` call of the matching adapter.

Common optional keys: ``seed`` (int, default 0), ``faults`` (a :class:`FaultPlan` mapping),
``mass`` (kg or kg.m^2 of the stand-in :class:`FreeJoints` plant, default 1.0).
``rate_hz`` is the device's tick rate (CAN: cyclic frames / fault schedule; Bota: frame rate).
Each device gets its own ``FreeJoints`` plant, stepped at ``plant_rate_hz`` (default 1 kHz) by one
background thread; the full physics engine replaces this once scenes exist.

Note: ``interface="virtual"`` CAN buses exist only inside one Python process. To reach a served
CAN device from another process use ``"udp_multicast"`` (channel e.g. ``"239.74.163.2"``) or a
socketcan ``vcan`` channel; pty paths work across processes.

Each :class:`Endpoint` carries ``driver`` and ``params`` such that
``hil.protocols.registry.open_device(ep.driver, **ep.params)`` connects an adapter to it.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hil.errors import EXIT_OK, EXIT_USAGE, HilError
from hil.mocks.faults import FaultPlan
from hil.mocks.interfaces import FreeJoints

logger = logging.getLogger(__name__)

DEFAULT_SPEC: list[dict[str, Any]] = [
    {"kind": "odrive", "channel": "hil0", "node_id": 0},
    {"kind": "bota"},
]


class _PlantStepper:
    """Steps a set of FreeJoints plants in real time from one thread."""

    def __init__(self, rate_hz: float) -> None:
        self.period = 1.0 / rate_hz
        self.plants: list[FreeJoints] = []
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, name="mock-plants", daemon=True)

    def _run(self) -> None:
        next_t = time.monotonic()
        while not self._stop.is_set():
            with self._lock:
                for p in self.plants:
                    p.step(self.period)
            next_t += self.period
            delay = next_t - time.monotonic()
            if delay > 0:
                self._stop.wait(delay)
            elif delay < -100 * self.period:
                next_t = time.monotonic()

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)


@dataclass
class Endpoint:
    """Where one simulated device listens, and how to open an adapter on it."""

    kind: str
    address: str  # human readable: "can virtual:hil0 node 3" / "/dev/pts/5"
    driver: str  # registry name of the matching adapter
    params: dict[str, Any]  # open_device(driver, **params)
    device: Any = field(repr=False, default=None)
    joints: Any = field(repr=False, default=None)
    _stepper: _PlantStepper | None = field(repr=False, default=None)

    def close(self) -> None:
        if self.device is not None:
            self.device.close()


def _make(spec: dict[str, Any]) -> tuple[Endpoint, float]:
    from hil.mocks.cubemars_device import SimCubeMars
    from hil.mocks.odrive_device import SimODrive
    from hil.mocks.serial_devices import SimBota

    s = dict(spec)
    dev: Any  # the simulated device of this kind
    kind = s.pop("kind")
    seed = s.pop("seed", 0)
    faults = FaultPlan.from_dict(s.pop("faults", None))
    joints = FreeJoints(dof=1, mass=float(s.pop("mass", 1.0)))
    rate = float(s.pop("rate_hz", 1000.0))
    if kind == "odrive":
        ch, iface = s.pop("channel", "hil0"), s.pop("interface", "virtual")
        node_id = int(s.pop("node_id", 0))
        gear, lin = s.pop("gear_ratio", 1.0), s.pop("linear_scale", None)
        dev = SimODrive(joints, ch, node_id, iface, gear_ratio=gear, linear_scale=lin, faults=faults, seed=seed, **s)
        params = {"interface": iface, "channel": ch, "node_id": node_id, "gear_ratio": gear, "linear_scale": lin}
        if dev.encoder_every:
            params["feedback"] = "cyclic"
        ep = Endpoint(kind, f"can {iface}:{ch} node {node_id}", "odrive_can", params, dev, joints)
    elif kind == "cubemars":
        ch, iface = s.pop("channel", "hil0"), s.pop("interface", "virtual")
        motor_id, model = int(s.pop("motor_id", 1)), s.pop("model", "AK80-9")
        dev = SimCubeMars(joints, ch, motor_id, iface, model=model, faults=faults, seed=seed, **s)
        params = {"interface": iface, "channel": ch, "motor_id": motor_id, "model": model}
        ep = Endpoint(kind, f"can {iface}:{ch} motor {motor_id}", "cubemars_mit", params, dev, joints)
    elif kind == "bota":
        dev = SimBota(joints, period_s=1.0 / rate, faults=faults, seed=seed, **s)
        ep = Endpoint(kind, dev.path, "bota_serial", {"url": dev.path, "period_s": 1.0 / rate}, dev, joints)
    elif kind == "cia402":
        from hil.mocks.cia402_drive import SimCiA402

        ch, iface = s.pop("channel", "hil0"), s.pop("interface", "virtual")
        node_id, gear = int(s.pop("node_id", 1)), float(s.pop("gear_ratio", 1.0))
        dev = SimCiA402(joints, ch, node_id, iface, gear_ratio=gear, faults=faults, seed=seed, dt=1.0 / rate, **s)
        params = {"interface": iface, "channel": ch, "node_id": node_id, "gear_ratio": gear}
        ep = Endpoint(kind, f"can {iface}:{ch} node {node_id}", "cia402", params, dev, joints)
    elif kind == "dynamixel":
        from hil.mocks.dynamixel_devices import DynamixelChain

        ids = [int(i) for i in s.pop("ids", [1])]
        joints = FreeJoints(dof=len(ids), mass=joints.mass)
        dev = DynamixelChain(joints, ids, faults=faults, seed=seed, **s)
        ep = Endpoint(kind, f"{dev.port} ids {ids}", "dynamixel_x", {"port": dev.port, "ids": ids}, dev, joints)
    elif kind == "ft300":
        from hil.mocks.modbus_devices import SimulatedFT300

        slave = int(s.pop("slave", 9))
        dev = SimulatedFT300(joints, port=int(s.pop("port", 0)), slave=slave, faults=faults, seed=seed, **s)
        ep = Endpoint(kind, dev.url, "robotiq_ft300", {"url": dev.url, "slave": slave}, dev, joints)
    elif kind == "ft300_stream":
        from hil.mocks.ft300_stream import SimFT300Stream

        slave = int(s.pop("slave", 9))
        rate = float(spec.get("rate_hz", 100.0))
        dev = SimFT300Stream(joints, rate_hz=rate, slave=slave, faults=faults, seed=seed, **s)
        ep = Endpoint(kind, dev.path, "robotiq_ft300_stream", {"url": dev.path, "slave": slave}, dev, joints)
    else:
        raise ValueError(f"unknown mock kind {kind!r}; known: {', '.join(MOCK_KINDS)}")
    return ep, rate


#: ``kind`` of a spec entry / ``--device`` -> registry driver of the matching adapter
MOCK_KINDS = {"odrive": "odrive_can", "cubemars": "cubemars_mit", "cia402": "cia402", "bota": "bota_serial",
              "ft300": "robotiq_ft300", "ft300_stream": "robotiq_ft300_stream", "dynamixel": "dynamixel_x"}


def serve(specs: list[dict[str, Any]] | None = None, *, plant_rate_hz: float = 1000.0) -> list[Endpoint]:
    """Start every device in ``specs`` free-running (threads) and return their endpoints.

    Stop them with :func:`shutdown`.
    """
    specs = DEFAULT_SPEC if specs is None else specs
    stepper = _PlantStepper(plant_rate_hz)
    endpoints: list[Endpoint] = []
    try:
        for spec in specs:
            ep, rate = _make(spec)
            ep._stepper = stepper
            endpoints.append(ep)
            stepper.plants.append(ep.joints)
            if ep.kind not in ("dynamixel", "ft300"):  # those serve from their own threads already
                ep.device.start(rate)
            logger.info("mock %s listening on %s", ep.kind, ep.address)
    except Exception:
        shutdown(endpoints)
        stepper.stop()
        raise
    stepper.start()
    return endpoints


def shutdown(endpoints: list[Endpoint]) -> None:
    """Stop and close every endpoint (and the plant thread). Idempotent."""
    for ep in endpoints:
        if ep._stepper is not None:
            ep._stepper.stop()
        ep.close()


def load_spec(text_or_path: str) -> list[dict[str, Any]]:
    """A spec from a JSON string, or a ``.json`` / ``.yaml`` / ``.yml`` file."""
    p = Path(text_or_path)
    if p.suffix in (".json", ".yaml", ".yml") and p.exists():
        text = p.read_text()
        if p.suffix != ".json":
            import yaml  # type: ignore[import-untyped]  # PyYAML ships no type hints

            data = yaml.safe_load(text)
        else:
            data = json.loads(text)
    else:
        data = json.loads(text_or_path)
    if isinstance(data, dict):
        data = data.get("devices", [data])
    if not isinstance(data, list):
        raise ValueError("a mock spec is a list of device dicts")
    return data


def serve_scene(scene: Any, *, seed: int | None = None, variant: str | None = None,
                can_interface: str = "virtual", can_channels: dict[str, str] | None = None,
                stream_rate_hz: float = 100.0, can_ports: dict[str, int] | None = None) -> Any:
    """Build and start a scene's simulated devices (a :class:`hil.bench.runtime.SimulatedScene`; a
    :class:`hil.scene.spec.Scene`, a path or a built-in name). Stop it with ``.close()``."""
    from hil.bench.runtime import SimulatedScene
    from hil.scene.spec import load_scene

    sc = scene if hasattr(scene, "devices") else load_scene(scene)
    sim = SimulatedScene(sc, seed=seed, variant=variant, can_interface=can_interface,
                         can_channels=can_channels, stream_rate_hz=stream_rate_hz, can_ports=can_ports)
    try:
        sim.start()
    except BaseException:
        sim.close()
        raise
    return sim


def open_device_call(driver: str, params: dict[str, Any]) -> str:
    """``open_device("driver", key=value, ...)`` as Python source (values as ``repr``)."""
    args = "".join(f", {k}={v!r}" for k, v in params.items())
    return f"open_device({driver!r}{args})"


VIRTUAL_CAN_NOTE = ("python-can's 'virtual' CAN interface is reachable from the serving process only; "
                    "serve with --can-interface udp_multicast (pip install 'python-can[multicast]') "
                    "to reach the CAN devices from another process")


def _parse_can_channels(items: list[str]) -> dict[str, str]:
    out = {}
    for item in items:
        scene_ch, sep, ch = item.partition("=")
        if not sep or not scene_ch or not ch:
            raise SystemExit(f"hil mock serve: --can-channel expects SCENE_CHANNEL=CHANNEL, got {item!r}")
        out[scene_ch] = ch
    return out


def _parse_can_ports(items: list[str]) -> dict[str, int]:
    """``--can-port SCENE_CHANNEL=PORT`` items (ValueError, one line, on a bad one)."""
    out = {}
    for item in items:
        scene_ch, sep, port = item.partition("=")
        if not sep or not scene_ch or not port.isdigit() or not 0 < int(port) < 65536:
            raise ValueError(f"argument --can-port: expects SCENE_CHANNEL=PORT (1..65535), got {item!r}")
        out[scene_ch] = int(port)
    return out


def _scene_report(sim: Any) -> dict[str, Any]:
    sc = sim.scene
    eps = sim.endpoints
    notes = [VIRTUAL_CAN_NOTE] if any(not ep.cross_process for ep in eps) else []
    return {
        "scene": sc.name, "source": sc.path, "rate_hz": sc.rate_hz, "seed": sim.seed, "pid": os.getpid(),
        "devices": [{"name": ep.name, "driver": ep.driver, "role": ep.role, "address": ep.address,
                     "params": ep.params, "cross_process": ep.cross_process} for ep in eps],
        "notes": notes,
    }


def _wait(duration: float | None, stop: threading.Event) -> None:
    t_end = None if duration is None else time.monotonic() + duration
    while not stop.is_set():
        left = 0.2 if t_end is None else t_end - time.monotonic()
        if left <= 0:
            return
        stop.wait(min(0.2, left))


def run(args: argparse.Namespace) -> int:
    """``hil mock serve [SCENE | --spec SPEC | --device KIND] [--duration S] [--json] ...`` (the
    arguments are parsed by hil.cli.main): serve simulated devices and print their endpoints (see the
    module docstring). A bad combination of options raises ValueError (one line, exit 2)."""
    if sum(map(bool, (args.scene, args.spec, args.device))) > 1:
        raise ValueError("give one of SCENE, --spec or --device")
    if args.device:
        if args.device not in MOCK_KINDS:
            raise ValueError(f"argument --device: invalid choice: {args.device!r} "
                             f"(choose from {', '.join(sorted(MOCK_KINDS))})")
        args.spec = json.dumps([_device_spec(args)])
        args.can_channel = []
    for item in args.can_channel:
        scene_ch, sep, ch = item.partition("=")
        if not sep or not scene_ch or not ch:
            raise ValueError(f"argument --can-channel: expects SCENE_CHANNEL=CHANNEL, got {item!r}")
    if getattr(args, "can_port", None):
        if not args.scene:
            raise ValueError("argument --can-port: only with a SCENE (served CAN channels)")
        _parse_can_ports(args.can_port)
    if args.spec:
        try:
            load_spec(args.spec)
        except (ValueError, OSError) as exc:
            raise ValueError(f"argument --spec: not a JSON device list or a .json/.yaml spec file ({exc})") from None

    stop = threading.Event()
    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        if args.scene:
            return _serve_scene_main(args, stop)
        return _serve_spec_main(args, stop)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _device_spec(args: argparse.Namespace) -> dict[str, Any]:
    """The spec entry of ``--device KIND`` and its options (ValueError on a bad combination)."""
    kind = args.device
    spec: dict[str, Any] = {"kind": kind}
    can_kinds = ("odrive", "cubemars", "cia402")
    if args.can_channel:
        if kind not in can_kinds or len(args.can_channel) != 1 or "=" in args.can_channel[0]:
            raise ValueError(f"argument --can-channel: --device {kind} takes one CAN channel name"
                             if kind in can_kinds else f"argument --can-channel: --device {kind} is not a CAN device")
        spec["channel"] = args.can_channel[0]
    if kind in can_kinds:
        spec["interface"] = args.can_interface
        if args.node is not None:
            lo, hi = {"odrive": (0, 63), "cubemars": (0, 0x7FF), "cia402": (1, 127)}[kind]
            if not lo <= args.node <= hi:
                raise ValueError(f"argument --node: {kind} ids are {lo}..{hi}, got {args.node}")
            spec["motor_id" if kind == "cubemars" else "node_id"] = args.node
    elif args.node is not None:
        raise ValueError(f"argument --node: --device {kind} has no CAN node id")
    if args.ids is not None:
        if kind != "dynamixel":
            raise ValueError("argument --ids: only --device dynamixel has servo ids")
        try:
            spec["ids"] = [int(x) for x in args.ids.split(",") if x.strip()]
        except ValueError:
            raise ValueError(f"argument --ids: expects comma-separated integers, got {args.ids!r}") from None
    if args.unit is not None:
        if kind not in ("ft300", "ft300_stream"):
            raise ValueError("argument --unit: only --device ft300 / ft300_stream have a Modbus slave id")
        spec["slave"] = args.unit
    if args.port is not None:
        if kind != "ft300":
            raise ValueError("argument --port: only --device ft300 listens on a TCP port")
        spec["port"] = args.port
    if args.pty and kind not in ("bota", "ft300_stream", "dynamixel"):
        raise ValueError(f"argument --pty: --device {kind} does not serve on a pty")
    if args.rate is not None:
        spec["rate_hz"] = args.rate
    return spec


def _serve_scene_main(args: argparse.Namespace, stop: threading.Event) -> int:
    from hil.protocols.registry import extras_message
    from hil.scene.spec import load_scene

    scene = load_scene(args.scene)
    if need := extras_message(scene, adapters=False):  # a base install: name the extra, start nothing
        print(f"hil mock serve {args.scene}: {need}", file=sys.stderr)
        return EXIT_USAGE
    try:
        sim = serve_scene(scene, seed=args.seed, variant=args.variant, can_interface=args.can_interface,
                          can_channels=_parse_can_channels(args.can_channel), stream_rate_hz=args.stream_rate,
                          can_ports=_parse_can_ports(getattr(args, "can_port", [])))
    except HilError:
        raise
    except Exception as exc:  # e.g. a CAN interface python-can cannot open here
        print(f"hil mock serve: error: cannot start the devices of {args.scene!r}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    t0 = time.monotonic()
    try:
        report = _scene_report(sim)
        if args.json:
            print(json.dumps(report, separators=(",", ":")), flush=True)
        else:
            print(f"scene {report['scene']} ({report['source']}): {len(report['devices'])} simulated devices, "
                  f"plant at {report['rate_hz']:g} Hz, seed {report['seed']}, pid {report['pid']}", flush=True)
            width = max((len(ep.name) for ep in sim.endpoints), default=0)
            for ep in sim.endpoints:
                where = "" if ep.cross_process else "   # this process only"
                print(f"{ep.name:{width}s}  {ep.driver:20s}  {open_device_call(ep.driver, ep.params)}{where}",
                      flush=True)
            for note in report["notes"]:
                print(f"note: {note}", file=sys.stderr, flush=True)
        _wait(args.duration, stop)
    except KeyboardInterrupt:
        pass
    finally:
        sim.close()
    print(f"hil mock serve: stopped after {time.monotonic() - t0:.1f} s ({sim.ticks} plant ticks, "
          f"{sim.overruns} overruns)", file=sys.stderr, flush=True)
    return EXIT_OK


def _serve_spec_main(args: argparse.Namespace, stop: threading.Event) -> int:
    from hil.protocols.registry import SIMULATOR_REQUIRES, importable

    specs = load_spec(args.spec) if args.spec else None
    kinds = MOCK_KINDS
    need = {r for s in (specs or DEFAULT_SPEC) for r in SIMULATOR_REQUIRES.get(kinds.get(str(s.get("kind")), ""), ())
            if not importable(r.module)}
    if need:
        print(f"hil mock serve: the simulated devices need {' and '.join(sorted(r.distribution for r in need))}: "
              f"pip install 'hil-certify[{','.join(sorted(r.extra for r in need))}]'", file=sys.stderr)
        return EXIT_USAGE
    try:
        endpoints = serve(specs, plant_rate_hz=args.plant_rate)
    except (ValueError, TypeError, OSError) as exc:
        print(f"hil mock serve: error: cannot start the simulated devices: {exc}", file=sys.stderr)
        return EXIT_USAGE
    try:
        if args.json:
            print(json.dumps({"pid": os.getpid(), "devices": [
                {"name": ep.kind, "driver": ep.driver, "address": ep.address, "params": ep.params,
                 "cross_process": ep.params.get("interface") != "virtual"} for ep in endpoints]},
                separators=(",", ":")), flush=True)
        else:
            for ep in endpoints:
                print(f"{ep.kind:9s} {ep.address:32s} driver={ep.driver} params={json.dumps(ep.params)}", flush=True)
                print(f"          connect: {open_device_call(ep.driver, ep.params)}", flush=True)
        if any(ep.params.get("interface") == "virtual" for ep in endpoints):
            print("note: interface 'virtual' is reachable from this process only", file=sys.stderr)
        _wait(args.duration, stop)
    except KeyboardInterrupt:
        pass
    finally:
        shutdown(endpoints)
    return EXIT_OK

