"""Simulated twins: what a bench needs of each device kind's simulated counterpart.

A device kind registered in :mod:`hil.protocols.registry` names, next to its adapter, a *twin*
(``"module:attribute"``, an instance of a :class:`Twin` subclass). :class:`hil.bench.runtime.Bench` and
:class:`hil.bench.runtime.SimulatedScene` call only these methods, so they have no per-kind branches:

* :meth:`Twin.start` builds the simulated device on its transport for one scene device (the
  :class:`TwinContext` carries its measurement point, seed, fault plan, clock, private channel
  names, ...) and returns the adapter parameters that reach it;
* :meth:`Twin.publish` (first samples at t = 0), :meth:`Twin.tick` (once per lockstep period,
  after the plant stepped), :meth:`Twin.flush` (let it process what the host sent) and
  :meth:`Twin.run_free` (``hil mock serve``: own threads at the scene's rate);
* :meth:`Twin.address` (where a served device listens, for people);
* :attr:`Twin.mechanics`: the friction and encoder the device adds to the body DOFs it drives,
  unless the scene's ``devices[].sim.friction`` / ``sim.encoder`` say otherwise
  (:class:`hil.mocks.friction.Mechanics`; the values and their sources: docs/guide/friction-twins.md).

A device with a simulated twin is one module with its simulated device and one ``Twin``
subclass, plus one registration (:func:`hil.protocols.registry.register_device`, or the
``hil_certify.devices`` entry-point group for another distribution).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hil.errors import SceneError
from hil.mocks.friction import Friction, Mechanics
from hil.protocols import link_budget as lb

logger = logging.getLogger(__name__)


@dataclass
class TwinContext:
    """What a twin gets from the bench to start the simulated counterpart of one scene device.

    ``index``/``cfg``: the scene's ``devices[index]``; ``point``: the SimulatedJoints of its body's
    DOFs (noise included); ``seed``/``faults``: its generator seed and
    :class:`hil.mocks.faults.FaultPlan`; ``dt`` (s) and ``rate_hz``: the control period;
    ``clock``: the simulated clock (s) for the adapter; ``timeout`` (s): the adapter's per-call
    timeout; ``lockstep``: True on a :class:`hil.bench.runtime.Bench` (the bench ticks the device), False
    when served free-running; ``can_interface``: the python-can interface the simulated CAN nodes
    use; ``channel(interface, scene_channel)``: the private channel standing for a scene channel;
    ``devices``: every opened device record of the bench (``.cfg``, ``.point``, ``.host``), for
    twins that serve several devices on one transport; ``label``: the scene file or name;
    ``can_port(scene_channel)``: the UDP port of a served ``udp_multicast`` channel (each channel its
    own group *and* port: python-can binds its socket to the port on every address, so channels
    sharing a port would hear each other), None elsewhere; ``waits``: on a lockstep bench, this
    device's view of the adapters' simulated time (:meth:`hil.protocols.waits.LockstepWaits.link`; a
    twin gives it to the adapter as its ``waits`` parameter and builds its device to be served by the
    barrier, :meth:`Twin.flush`, which the bench makes this link's own barrier), None when served
    free-running."""

    index: int
    cfg: Any
    point: Any
    seed: int
    faults: Any
    dt: float
    rate_hz: float
    clock: Callable[[], float]
    timeout: float
    lockstep: bool
    can_interface: str
    channel: Callable[[str, str], str]
    devices: Sequence[Any] = field(default_factory=list)
    label: str = ""
    can_port: Callable[[str], int | None] = field(default=lambda scene_channel: None)
    waits: Any = None


class Twin:
    """The simulated counterpart of one device kind (see the module docstring). Defaults: nothing
    to publish, tick, flush or run."""

    #: served over python-can's UDP multicast in another process with a ``port`` parameter
    udp_multicast: bool = False
    #: friction, viscous damping, encoder step the device adds to the DOFs it drives (default: none,
    #: a drive whose mechanics are the scene's bodies)
    mechanics: Mechanics = Mechanics(source="a drive: the mechanics and their friction are the scene's bodies")

    def start(self, ctx: TwinContext, params: dict[str, Any]) -> tuple[Any, dict[str, Any]]:
        """Build the simulated device for ``ctx``; return it (None when another device's twin
        serves this one too, see :meth:`host`) and the adapter parameters (``params`` updated)."""
        raise NotImplementedError

    def host(self, ctx: TwinContext, sim: Any) -> Any:
        """The simulated object serving this device (default: its own)."""
        return sim

    def publish(self, sim: Any) -> None:
        """First samples, at t = 0 (default: the same as :meth:`tick`)."""
        self.tick(sim)

    def tick(self, sim: Any) -> None:
        """Once per lockstep period, after the plant stepped."""

    def answers_in_sender_thread(self, sim: Any) -> bool:
        """True when the device handles what the host sends in the host's sending call (a ``sync``
        CAN node): a lockstep wait then has nothing to serve first (its barrier is empty)."""
        return False

    def flush(self, sim: Any, adapters: Sequence[Any], timeout: float) -> None:
        """The lockstep barrier for this device: it has processed everything the host's
        ``adapters`` sent and everything it answered can be read by the host when this returns,
        however long that takes (``timeout``: only a bound for devices served by threads of their
        own in tests). Called by the bench before each plant step and whenever an adapter waits
        (:meth:`hil.protocols.waits.LockstepWaits.settle`)."""

    def run_free(self, sim: Any, rate_hz: float, stream_rate_hz: float) -> None:
        """Start the device's own threads (``hil mock serve``)."""

    def address(self, driver: str, params: dict[str, Any]) -> tuple[str, bool]:
        """(where it listens, for people; whether another process can reach it)."""
        return str(params.get("url", "")), True


def _can_params(ctx: TwinContext, params: dict[str, Any]) -> tuple[str, dict[str, Any]]:
    """Point the adapter at the private channel of its scene channel; returns that channel and the
    bus keywords the simulated node needs on it (the channel's UDP port when it has one; the
    adapter gets it too)."""
    scene_ch = str(params.get("channel", "hil0"))
    ch = ctx.channel(str(params.get("interface", "virtual")), scene_ch)
    params.update(interface=ctx.can_interface, channel=ch, clock=ctx.clock, timeout=ctx.timeout)
    params.pop("bus", None)
    _lockstep_waits(ctx, params)
    port = ctx.can_port(scene_ch)
    if port is None:
        return ch, {}
    params["port"] = int(port)
    return ch, {"port": int(port)}


def _lockstep_waits(ctx: TwinContext, params: dict[str, Any]) -> None:
    """On a lockstep bench the adapter waits on simulated time (``waits``)."""
    if ctx.waits is not None:
        params["waits"] = ctx.waits


class CanTwin(Twin):
    """A simulated CAN node (python-can bus, lockstep tick per control period)."""

    #: the adapter parameter naming the node, how addresses call it, and its default
    node_param, node_word, node_default = "node_id", "node", 1

    def tick(self, sim: Any) -> None:
        sim.tick()

    def publish(self, sim: Any) -> None:
        """CAN nodes answer requests; nothing to publish at t = 0."""

    def flush(self, sim: Any, adapters: Sequence[Any], timeout: float) -> None:
        sim.process_pending()

    def answers_in_sender_thread(self, sim: Any) -> bool:
        return bool(sim.sync)

    def run_free(self, sim: Any, rate_hz: float, stream_rate_hz: float) -> None:
        sim.start(rate_hz)

    def address(self, driver: str, params: dict[str, Any]) -> tuple[str, bool]:
        node = params.get(self.node_param, self.node_default)
        iface = params["interface"]
        return f"can {iface}:{params['channel']} {self.node_word} {node}", iface != "virtual"


def _lockstep_host_bus(ctx: TwinContext, sim: Any, params: dict[str, Any]) -> None:
    """Lockstep on the virtual bus: the adapter gets a connection opened by the node
    (:meth:`hil.mocks.can_devices.SimCanNode.host_bus`, python-can's virtual bus without its
    per-frame deepcopy; same frames, same order, same transport name), closed with the node."""
    if ctx.lockstep and ctx.can_interface == "virtual":
        params["bus"] = sim.host_bus()


def _bitrate(params: dict[str, Any], default: int) -> int:
    """The scene's CAN bit rate (bit/s), else the driver's factory default: in lockstep the simulated
    bus carries at most that many bits per simulated second (hil.protocols.link_budget)."""
    return int(params.get("bitrate") or default)


class ODriveTwin(CanTwin):
    udp_multicast = True
    node_default = 0
    mechanics = Mechanics(source="a drive for any motor: no friction of its own; pos_estimate is the encoder "
                                 "PLL's interpolated estimate (not counts), sent as float32 turns")

    def start(self, ctx: TwinContext, params: dict[str, Any]) -> tuple[Any, dict[str, Any]]:
        from hil.mocks.odrive_device import SIM_WATCHDOG_ENDPOINTS, SimODrive

        ch, bus_kw = _can_params(ctx, params)
        # configured as the scene's bench has its drive: estimates every tick with feedback "cyclic",
        # none with "poll" (encoder_msg_rate_ms 0; a factory drive sends them every 10 ms)
        kw: dict[str, Any] = {"encoder_every": 1 if params.get("feedback") == "cyclic" else 0, **bus_kw}
        if ctx.lockstep:
            # heartbeat every 10 ms, no cyclic Get_Version (a factory drive: 100 ms and 100 ms): on the
            # simulated bus every frame is copied to every node, so fewer frames = faster runs
            kw.update(sync=True, heartbeat_every=max(1, round(0.01 * ctx.rate_hz)), cyclic_ms={"Get_Version": 0}
                      if str(params.get("firmware", "0.6")) == "0.6" else {},
                      bitrate=_bitrate(params, lb.ODRIVE_DEFAULT_BITRATE))
            params.setdefault("watchdog_endpoints", dict(SIM_WATCHDOG_ENDPOINTS))
        sim = SimODrive(ctx.point, ch, int(params.get("node_id", 0)), ctx.can_interface,
                        gear_ratio=float(params.get("gear_ratio", 1.0)), linear_scale=params.get("linear_scale"),
                        faults=ctx.faults, seed=ctx.seed, dt=ctx.dt, firmware=str(params.get("firmware", "0.6")),
                        **kw)
        _lockstep_host_bus(ctx, sim, params)
        return sim, params

    def publish(self, sim: Any) -> None:
        if sim.encoder_every:  # cyclic estimates
            sim.publish_estimate()



class CubeMarsTwin(CanTwin):
    udp_multicast = True
    node_param, node_word = "motor_id", "motor"
    #: AK-series quasi-direct-drive actuator: Coulomb friction identified on the AK80-6 (6:1) as 0.093 and
    #: 0.078 N.m (dfki-ric-underactuated-lab/double_pendulum, design C.0 model 3.0, cf1/cf2); 0.1 N.m for the
    #: twin's AK80-9 (9:1). No encoder step here: the MIT reply's 16-bit position over ±12.5 rad (3.8e-4 rad)
    #: is coarser than the motor's encoder and is quantized on the wire already.
    mechanics = Mechanics(Friction(0.1), source="AK80-6 identification (dfki double_pendulum model 3.0: "
                                                "cf 0.078-0.093 N.m), AK80-9: 0.1 N.m")

    def start(self, ctx: TwinContext, params: dict[str, Any]) -> tuple[Any, dict[str, Any]]:
        from hil.mocks.cubemars_device import SimCubeMars

        ch, bus_kw = _can_params(ctx, params)
        _lockstep_kw: dict[str, Any] = {"sync": True, "bitrate": _bitrate(params, lb.CUBEMARS_DEFAULT_BITRATE),
                                        "tick_s": ctx.dt}
        if ctx.waits is not None:  # its silence after "set zero" passes on the host's (simulated) time
            _lockstep_kw["clock"] = ctx.waits.monotonic
        sim = SimCubeMars(ctx.point, ch, int(params.get("motor_id", 1)), ctx.can_interface,
                          model=params.get("model", "AK80-9"), faults=ctx.faults, seed=ctx.seed,
                          **(_lockstep_kw if ctx.lockstep else {}), **bus_kw)
        _lockstep_host_bus(ctx, sim, params)
        return sim, params



class CiA402Twin(CanTwin):
    """A canopen LocalNode on a private CAN channel."""

    udp_multicast = True  # served to a realtime run's adapters from another process, as the ODrive
    mechanics = Mechanics(source="a drive: no friction of its own; the position is quantized on the wire to "
                                 "counts_per_rev increments (0x608F)")

    def start(self, ctx: TwinContext, params: dict[str, Any]) -> tuple[Any, dict[str, Any]]:
        from hil.mocks.cia402_drive import SimCiA402

        ch, bus_kw = _can_params(ctx, params)
        kw = {k: params[k] for k in ("counts_per_rev", "rated_torque_mNm", "heartbeat_ms") if params.get(k) is not None}
        kw.update(bus_kw)
        if ctx.lockstep:
            kw["bitrate"] = _bitrate(params, lb.CIA402_DEFAULT_BITRATE)
        sim = SimCiA402(ctx.point, ch, int(params.get("node_id", 1)), ctx.can_interface,
                        gear_ratio=float(params.get("gear_ratio", 1.0)), faults=ctx.faults, seed=ctx.seed,
                        sync=ctx.lockstep, dt=ctx.dt, **kw)
        return sim, params


class StreamTwin(Twin):
    """A sensor streaming frames into a pty: one frame per lockstep period (``emit``); served in
    the host's thread on a lockstep bench (``serve_pending``: the host's commands answered, the
    frames made readable)."""

    def tick(self, sim: Any) -> None:
        sim.emit()

    def flush(self, sim: Any, adapters: Sequence[Any], timeout: float) -> None:
        if not sim.threaded:
            sim.serve_pending()


class BotaTwin(StreamTwin):
    def start(self, ctx: TwinContext, params: dict[str, Any]) -> tuple[Any, dict[str, Any]]:
        from hil.mocks.serial_devices import SimBota
        from hil.protocols.link_budget import BOTA_DEFAULT_BAUD, bota_sinc_length

        # the sensor samples at 51200 / sinc_length Hz on the simulated clock (not once per tick)
        # and its line carries baud/10 bytes per simulated second; the adapter configures it
        sinc = bota_sinc_length(params)
        sim = SimBota(ctx.point, sinc_length=sinc, tick_s=ctx.dt, faults=ctx.faults, seed=ctx.seed,
                      axes=tuple(ctx.cfg.wrench_axes), baudrate=int(params.get("baudrate", BOTA_DEFAULT_BAUD)),
                      threaded=not ctx.lockstep)
        params.pop("period_s", None)
        params.update(url=sim.path, sinc_length=sinc, clock=ctx.clock, timeout=ctx.timeout)
        _lockstep_waits(ctx, params)
        return sim, params

    def run_free(self, sim: Any, rate_hz: float, stream_rate_hz: float) -> None:
        sim.start(rate_hz)


def _wrench_fn(ctx: TwinContext) -> Callable[[], np.ndarray]:
    axes = ctx.cfg.wrench_axes
    point = ctx.point

    def wrench() -> np.ndarray:
        w = np.zeros(6)
        w[axes] = point.measured_force()
        return w

    return wrench


class FT300StreamTwin(StreamTwin):
    def start(self, ctx: TwinContext, params: dict[str, Any]) -> tuple[Any, dict[str, Any]]:
        from hil.mocks.ft300_stream import SimFT300Stream

        kw: dict[str, Any] = {"threaded": not ctx.lockstep}
        if ctx.waits is not None:  # the RTU inter-frame silence on the host's (simulated) time
            kw["clock"] = ctx.waits.monotonic
        sim = SimFT300Stream(_wrench_fn(ctx), faults=ctx.faults, seed=ctx.seed, slave=int(params.get("slave", 9)),
                             tick_s=ctx.dt, **kw)  # 100 Hz frames on the simulated clock
        params.update(url=sim.path, clock=ctx.clock, timeout=ctx.timeout)
        _lockstep_waits(ctx, params)
        return sim, params

    def run_free(self, sim: Any, rate_hz: float, stream_rate_hz: float) -> None:
        sim.start(stream_rate_hz)


class FT300ModbusTwin(Twin):
    """A pymodbus server on a free loopback port; registers refreshed once per lockstep period
    (free-running: on every request). On a lockstep bench the adapter gets its own link
    (``waits.link()``) and the barrier waits until the server has answered every request it
    counted (:meth:`hil.mocks.modbus_devices.SimulatedFT300.settle`)."""

    def start(self, ctx: TwinContext, params: dict[str, Any]) -> tuple[Any, dict[str, Any]]:
        from hil.mocks.modbus_devices import SimulatedFT300

        sim = SimulatedFT300(_wrench_fn(ctx), framing=ctx.cfg.sim.framing, port=0, faults=ctx.faults,
                             seed=ctx.seed, auto_update=not ctx.lockstep, slave=int(params.get("slave", 9)),
                             start_timeout=None if ctx.lockstep else 5.0)  # lockstep: however long it takes
        params.update(url=sim.url, clock=ctx.clock, timeout=ctx.timeout)
        if ctx.waits is not None:  # this device's link: its requests and answers are counted
            sim.link = params["waits"] = ctx.waits
        return sim, params

    def tick(self, sim: Any) -> None:
        sim.update()

    def flush(self, sim: Any, adapters: Sequence[Any], timeout: float) -> None:
        sim.settle()


class Concat:
    """Several SimulatedJoints seen as one (a bus serving several devices, e.g. a DYNAMIXEL chain)."""

    def __init__(self, points: list[Any]) -> None:
        self.points = points
        self.dof = sum(p.dof for p in points)
        self._split = np.cumsum([p.dof for p in points])[:-1]

    def apply_effort(self, effort: np.ndarray) -> None:
        for p, e in zip(self.points, np.split(np.asarray(effort, dtype=float).reshape(self.dof), self._split),
                        strict=True):
            p.apply_effort(e)

    def position(self) -> np.ndarray:
        return np.concatenate([p.position() for p in self.points])

    def velocity(self) -> np.ndarray:
        return np.concatenate([p.velocity() for p in self.points])

    def measured_force(self) -> np.ndarray:
        return np.concatenate([p.measured_force() for p in self.points])


class DynamixelTwin(Twin):
    """A DYNAMIXEL chain on a pty: the scene devices with the same ``params.port`` share one
    chain (one bus), each servo id driving its device's DOFs."""

    #: XM430-W350 (353.5:1 metal gears, stall 4.1 N.m at 12 V): Stribeck friction scaled from the MX-64
    #: (stall 6.0 N.m) identification of Duclusaud et al. 2024 (Rhoban/bam params/mx64 m4: 0.062 N.m
    #: Coulomb + 0.024 N.m Stribeck bump, v_s 1.52 rad/s) by 4.1/6.0; the 12-bit encoder (4096 pulse/rev,
    #: ROBOTIS e-Manual), the grid the protocol's Present Position already uses
    mechanics = Mechanics(Friction(0.04, 0.06, 1.5), encoder_step=2 * math.pi / 4096,
                          source="MX-64 identification (Rhoban/bam m4) scaled by stall torque 4.1/6.0; "
                                 "4096 pulse/rev encoder")

    def start(self, ctx: TwinContext, params: dict[str, Any]) -> tuple[Any, dict[str, Any]]:
        from hil.mocks.dynamixel_devices import DynamixelChain

        me = ctx.devices[ctx.index]
        key = str(ctx.cfg.params.get("port", f"#{ctx.index}"))
        group = [x for x in ctx.devices if x.cfg.driver == ctx.cfg.driver and
                 str(x.cfg.params.get("port", "")) == key] or [me]
        chain = next((x.host for x in group if x.host is not None), None)
        sim = None
        if chain is None:
            ids: list[int] = []
            for x in group:
                xi = [int(v) for v in x.cfg.params.get("ids", [1])]
                if len(xi) != x.cfg.dof:
                    j = list(ctx.devices).index(x)
                    raise SceneError(f"{ctx.label}: devices[{j}].params.ids: {len(xi)} servo ids for dof {x.cfg.dof}")
                ids += xi
            if len(set(ids)) != len(ids):
                raise SceneError(f"{ctx.label}: devices[{ctx.index}].params.ids: servo ids on port {key!r} must be "
                                 f"unique, got {ids}")
            points = [x.point for x in group]
            joints = points[0] if len(points) == 1 else Concat(points)
            # the servos run at the scene's baudrate (configured servos; a factory one is at 57 600)
            baud = int(group[0].cfg.params.get("baudrate", 57_600))
            chain = sim = DynamixelChain(joints, ids, faults=ctx.faults, seed=ctx.seed, clock=ctx.clock,
                                         baudrate=baud, link_budget=ctx.lockstep, threaded=not ctx.lockstep)
            # owned (closed, ticked) by the first device of the group; in lockstep the line carries baud/10 B/s
            # and the chain is served in the host's thread by the bench's barrier (flush)
        me.host = chain
        params.update(port=chain.port, clock=ctx.clock, timeout=ctx.timeout)
        _lockstep_waits(ctx, params)
        return sim, params

    def host(self, ctx: TwinContext, sim: Any) -> Any:
        return ctx.devices[ctx.index].host

    def publish(self, sim: Any) -> None:
        """The servos answer requests; nothing to publish."""

    def tick(self, sim: Any) -> None:
        sim.check_watchdog()  # Bus Watchdog(98) on the simulated clock

    def flush(self, sim: Any, adapters: Sequence[Any], timeout: float) -> None:
        """Every byte the adapters wrote processed and answered (sync writes get no reply): in the
        host's thread (lockstep), else waiting for the chain's thread."""
        if not sim.threaded:
            sim.serve_pending()
        elif adapters:
            sim.sync(sum(int(a.tx_bytes) for a in adapters), timeout=timeout)

    def address(self, driver: str, params: dict[str, Any]) -> tuple[str, bool]:
        return f"{params['port']} ids {list(params.get('ids', [1]))}", True


ODRIVE = ODriveTwin()
CUBEMARS = CubeMarsTwin()
CIA402 = CiA402Twin()
BOTA = BotaTwin()
FT300 = FT300ModbusTwin()
FT300_STREAM = FT300StreamTwin()
DYNAMIXEL = DynamixelTwin()
