"""Start simulated devices on their own and report where each one listens (``hil mock serve``).

Until the scene format exists, a spec is a list of dicts (JSON/YAML file or Python objects)::

    [
      {"kind": "odrive",   "channel": "hil0", "node_id": 3, "gear_ratio": 1.0,
       "interface": "virtual", "rate_hz": 1000, "encoder_every": 0, "heartbeat_every": 10},
      {"kind": "cubemars", "channel": "hil0", "motor_id": 1, "model": "AK80-9", "rate_hz": 1000},
      {"kind": "bota",     "rate_hz": 1000},
    ]

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
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hil.mocks.faults import FaultPlan
from hil.mocks.interfaces import FreeJoints

log = logging.getLogger(__name__)

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
    from hil.mocks.can_devices import SimCubeMars, SimODrive
    from hil.mocks.serial_devices import SimBota

    s = dict(spec)
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
    else:
        raise ValueError(f"unknown mock kind {kind!r}; known: odrive, cubemars, bota")
    return ep, rate


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
            ep.device.start(rate)
            log.info("mock %s listening on %s", ep.kind, ep.address)
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
            import yaml

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


def main(argv: list[str] | None = None) -> int:
    """``hil mock serve [--spec SPEC] [--duration S]``: serve mocks and print their endpoints."""
    ap = argparse.ArgumentParser(prog="hil mock serve", description=__doc__.split("\n", 1)[0])
    ap.add_argument("--spec", help="JSON string or .json/.yaml file (see module doc); default: odrive + bota")
    ap.add_argument("--duration", type=float, default=None, help="seconds to run (default: until Ctrl-C)")
    ap.add_argument("--plant-rate", type=float, default=1000.0, help="FreeJoints step rate [Hz]")
    args = ap.parse_args(argv)
    specs = load_spec(args.spec) if args.spec else None
    endpoints = serve(specs, plant_rate_hz=args.plant_rate)
    try:
        for ep in endpoints:
            print(f"{ep.kind:9s} {ep.address:32s} driver={ep.driver} params={json.dumps(ep.params)}", flush=True)
        if any(ep.params.get("interface") == "virtual" for ep in endpoints):
            print("note: interface 'virtual' is reachable from this process only", file=sys.stderr)
        t_end = None if args.duration is None else time.monotonic() + args.duration
        while t_end is None or time.monotonic() < t_end:
            time.sleep(0.1 if t_end is None else max(0.0, min(0.1, t_end - time.monotonic())))
    except KeyboardInterrupt:
        pass
    finally:
        shutdown(endpoints)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
