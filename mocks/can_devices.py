"""Simulated CAN devices (ODrive CANSimple axis, CubeMars AK "MIT mode" motor) on a python-can bus.

The simulated node is a *separate* bus connection on the same channel as the adapter (normally
``interface="virtual"``; ``"udp_multicast"`` or a ``vcan`` socketcan channel also work across
processes). It never integrates physics: it applies effort to, and reads state from, a
:class:`hil.mocks.interfaces.SimulatedJoints` handle that somebody else steps.

Three ways to run a node:

* **explicit lockstep** - call :meth:`SimCanNode.tick` once per control period (after the
  adapter sent its commands/requests): it handles every frame received so far, replying to each
  synchronously from the current joint state, advances the node's tick counter, delivers late
  frames that are due and publishes the cyclic frames due at this tick (ODrive heartbeat /
  encoder estimates). :meth:`SimCanNode.process_pending` does the first part only.
* **synchronous replies** (``sync=True``, virtual bus only) - every frame is handled at the moment
  it is delivered to the node, in the sender's thread, so a polling adapter gets its answer
  before ``bus.send`` returns. Fully deterministic, no threads. Call :meth:`tick` per period for
  cyclic frames and fault schedules.
* **free running** - :meth:`SimCanNode.start` runs ``tick`` in a background thread at
  ``rate_hz`` while answering requests as they arrive (for ``hil mock serve`` and manual tests;
  not deterministic).

Fault injection (:mod:`hil.mocks.faults`) applies to every frame the node sends: drop,
corruption (the frame is replaced by a CAN error frame, as the controllers' CRC check would do),
late delivery (``late_ticks`` ticks later in lockstep), stale data (the previous payload of that
message is repeated; for the ODrive's encoder estimates: no new estimate frame at all, heartbeats
go on), device error codes and disconnects (node silent and deaf) scheduled by the node's tick
counter.

Memory stays flat over any run length: the command logs (``commands``) keep only the newest
:data:`LOG_LEN` entries (``commands_total`` counts them all), late frames are bounded by
``late_ticks``.
"""

from __future__ import annotations

import logging
import math
import queue
import struct
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import can
import numpy as np
from can.interfaces import virtual as _virtual

from hil.mocks.faults import FaultInjector, FaultPlan
from hil.mocks.interfaces import SimulatedJoints
from hil.protocols.codecs import cubemars as cm
from hil.protocols.codecs import odrive as od
from hil.protocols.link_budget import can_frame_bits

logger = logging.getLogger(__name__)

AXIS_ERROR_WATCHDOG_TIMER_EXPIRED = od.AXIS_ERROR_WATCHDOG_TIMER_EXPIRED

#: RxSdo endpoint ids the simulated ODrive answers for its watchdog configuration (a real drive's
#: ids come from its firmware's flat_endpoints.json; these are the simulator's own).
SIM_WATCHDOG_ENDPOINTS = {"watchdog_timeout": 0x0101, "enable_watchdog": 0x0102}

#: Entries kept in a simulated node's command log (``commands``); older ones are discarded.
LOG_LEN = 1024


class _SyncQueue(queue.Queue):
    """Receive queue of a virtual bus that hands every delivered frame to the node immediately."""

    def __init__(self, node: SimCanNode) -> None:
        super().__init__()
        self._node = node

    def put(self, item: can.Message, block: bool = True, timeout: float | None = None) -> None:
        self._node._deliver_sync(item)


def _frame_copy(msg: can.Message, timestamp: float, channel: Any, is_rx: bool) -> can.Message:
    """What ``deepcopy(msg)`` followed by python-can's VirtualBus.send field updates gives (a new
    Message, its own ``bytearray`` of data; a remote frame carries none), built field by field:
    ``copy.deepcopy`` of a Message costs 5-10 µs through the generic copy machinery."""
    c = _NEW_MESSAGE(can.Message)
    c.timestamp = timestamp
    c.arbitration_id = msg.arbitration_id
    c.is_extended_id = msg.is_extended_id
    c.is_remote_frame = remote = msg.is_remote_frame
    c.is_error_frame = msg.is_error_frame
    c.channel = channel
    data = msg.data
    c.data = bytearray() if remote or data is None else bytearray(data)
    c.dlc = msg.dlc
    c.is_fd = msg.is_fd
    c.is_rx = is_rx
    c.bitrate_switch = msg.bitrate_switch
    c.error_state_indicator = msg.error_state_indicator
    return c


_NEW_MESSAGE = can.Message.__new__


class LockstepVirtualBus(_virtual.VirtualBus):
    """python-can's in-process ``virtual`` bus (same channels, queues and delivery order, the
    same Message each receiver gets) without the per-receiver ``deepcopy`` of every frame sent.

    Used by the simulated CAN nodes of a lockstep bench and for the adapters' buses there (given
    to the adapter as its ``bus``): a :class:`python-can VirtualBus <can.interfaces.virtual.VirtualBus>`
    subclass, so it shares channels with plain virtual buses and the adapters talk to it through
    python-can's ``BusABC.send`` / ``recv`` (filters included) exactly as before. ``send`` gives
    every other connection of the channel its own copy (:func:`_frame_copy`: timestamp = the
    send's wall time unless ``preserve_timestamps``, ``channel``, ``is_rx``), as VirtualBus does;
    a receive that must not wait returns at once when the queue is empty (no ``queue.Empty``
    raised and caught). ``channel_info`` reads ``virtual:CHANNEL`` (what an adapter that opened
    ``interface="virtual"`` itself reports as its transport, ``can:virtual:CHANNEL``).
    """

    def __init__(self, channel: Any = "channel-0", **kwargs: Any) -> None:
        super().__init__(channel=channel, **kwargs)
        self.channel_info = f"virtual:{channel}"

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if timeout is not None and timeout <= 0.0:
            self._check_if_open()
            q = self.queue
            if not q.qsize():
                return None, False
            try:
                return q.get_nowait(), False
            except queue.Empty:  # emptied by another thread meanwhile
                return None, False
        return super()._recv_internal(timeout)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._check_if_open()
        timestamp = msg.timestamp if self.preserve_timestamps else time.time()
        own = self.queue
        ch = self.channel_id
        all_sent = True
        for bus_queue in self.channel:
            if bus_queue is own and not self.receive_own_messages:
                continue
            try:
                bus_queue.put(_frame_copy(msg, timestamp, ch, bus_queue is not own), block=True, timeout=timeout)
            except queue.Full:
                all_sent = False
        if not all_sent:
            raise can.CanOperationError("Could not send message to one or more recipients")


#: Frames one sender may have waiting for the bus (Linux SocketCAN's default ``txqueuelen`` of a
#: CAN interface is 10, ``drivers/net/can/dev/dev.c``); a frame beyond it is refused (ENOBUFS) and lost.
CAN_TX_QUEUE_LEN = 10


#: can_frame_bits(n) for n = 0..8 payload bytes (worst case, standard identifier), computed once
_FRAME_BITS = tuple(can_frame_bits(n) for n in range(9))


def frame_bits(msg: can.Message) -> int:
    """Worst-case bits of ``msg`` on the wire (:func:`hil.protocols.link_budget.can_frame_bits`; a
    remote frame carries no data; an error frame stands for the 8-byte frame it destroyed)."""
    if msg.is_error_frame:
        return _FRAME_BITS[8]
    return _FRAME_BITS[0 if msg.is_remote_frame else min(len(msg.data), 8)]


@dataclass
class _Pending:
    prio: int  # arbitration id: the lower wins arbitration
    seq: int
    sender: str  # "host" or the node's kind/id
    bits: int
    action: Callable[[], None] | None = None  # a node frame: transmit it
    copies: list[tuple[SimCanNode, can.Message]] = field(default_factory=list)  # a host frame: deliver these


class CanBusBudget:
    """The capacity of one simulated CAN channel: ``bitrate`` bits per *simulated* second, shared
    by the host and every simulated node on the channel (the same budget the load-time check of
    :mod:`hil.protocols.link_budget` applies to a scene).

    Each frame costs its worst-case bits (:func:`frame_bits`). A frame that fits in the bits
    accumulated so far goes at once (as before: a compliant run is unchanged); one that does not
    waits for the bus, as a saturated bus delays a frame that keeps losing arbitration: at each
    tick the waiting frames go in arbitration order (lowest id first) as far as the tick's bits
    carry them. A sender holds at most :data:`CAN_TX_QUEUE_LEN` waiting frames, the ones of
    highest priority (a controller that transmits by identifier priority, as bxCAN's default):
    with its queue full, its lowest-priority frame is lost (``dropped``). Up to ``burst_s`` of
    unused capacity is kept (plus one 8-byte
    frame), so the tick discretization's bursts (all of a tick's frames at one instant) pass
    when the average fits. Simulated time advances with the nodes' ticks (:meth:`advance_to`), so
    the outcome does not depend on the machine. Counters: ``stats`` (``delayed``, ``dropped``,
    ``frames``, ``bits``).
    """

    def __init__(self, bitrate: float, *, burst_s: float = 0.02, queue_len: int = CAN_TX_QUEUE_LEN) -> None:
        if not bitrate > 0:
            raise ValueError(f"CAN bitrate must be > 0, got {bitrate!r}")
        self.bitrate = float(bitrate)
        self.cap = self.bitrate * float(burst_s) + can_frame_bits(8)
        self.credit = self.cap
        self.queue_len = int(queue_len)
        self.time = 0.0
        self.pending: list[_Pending] = []
        self.stats: Counter[str] = Counter()
        self.sending = 0  # > 0 while a simulated node transmits (its copies reach the other nodes)
        self._seq = 0
        self._last: tuple[tuple[Any, ...], _Pending | bool | None] | None = None
        self.users = 0

    def _queued(self, sender: str) -> int:
        return sum(1 for p in self.pending if p.sender == sender)

    def _fits(self, bits: int) -> bool:
        if not self.pending and bits <= self.credit:
            self.credit -= bits
            self.stats["frames"] += 1
            self.stats["bits"] += bits
            return True
        return False

    def _wait(self, sender: str, bits: int, prio: int) -> _Pending | None:
        if self._queued(sender) >= self.queue_len:
            worst = max((p for p in self.pending if p.sender == sender), key=lambda p: (p.prio, p.seq))
            self.stats["dropped"] += 1
            if worst.prio <= prio:  # the queue keeps its highest-priority frames: the new one is lost
                return None
            self.pending.remove(worst)  # ... or the lowest-priority one waiting makes room
            self.stats["delayed"] -= 1
        self._seq += 1
        p = _Pending(prio, self._seq, sender, bits)
        self.pending.append(p)
        self.stats["delayed"] += 1
        return p

    def host_frame(self, node: SimCanNode, msg: can.Message) -> None:
        """A frame from the host reaching ``node`` (one copy per node: the copies of one send share
        its timestamp and are decided together)."""
        key = (msg.timestamp, msg.arbitration_id, bytes(msg.data), msg.is_remote_frame, msg.is_error_frame)
        if self._last is not None and self._last[0] == key:
            decision = self._last[1]
        else:
            bits = frame_bits(msg)
            decision = True if self._fits(bits) else self._wait("host", bits, msg.arbitration_id)
            self._last = (key, decision)
        if decision is True:
            node._receive(msg)
        elif isinstance(decision, _Pending):
            decision.copies.append((node, msg))

    def node_frame(self, node: SimCanNode, msg: can.Message) -> None:
        """A frame ``node`` transmits: now if it fits, else when the bus carries it (or lost)."""
        bits = frame_bits(msg)
        if self._fits(bits):
            node._transmit(msg)
            return
        p = self._wait(f"{node.kind}@{id(node):x}", bits, msg.arbitration_id)
        if p is not None:
            p.action = lambda: node._transmit(msg)

    def advance_to(self, t: float) -> None:
        """Simulated time ``t`` (s) reached: add its bits, then send what waits, in arbitration order."""
        if t <= self.time:
            return
        self.credit = min(self.cap, self.credit + (t - self.time) * self.bitrate)
        self.time = t
        self._last = None
        self.pending.sort(key=lambda p: (p.prio, p.seq))
        while self.pending and self.pending[0].bits <= self.credit:
            p = self.pending.pop(0)
            self.credit -= p.bits
            self.stats["frames"] += 1
            self.stats["bits"] += p.bits
            if p.action is not None:
                p.action()
            for n, m in p.copies:
                with n._lock:
                    if not n._closed:
                        n._receive(m)


#: One budget per simulated channel name (shared by the nodes on it; removed with the last one)
_BUDGETS: dict[str, CanBusBudget] = {}
_BUDGETS_LOCK = threading.Lock()


class SimCanNode:
    """Common machinery of a simulated CAN node (see module docstring)."""

    kind = "can-node"

    def __init__(
        self,
        joints: SimulatedJoints,
        channel: str,
        interface: str = "virtual",
        *,
        faults: FaultPlan | FaultInjector | None = None,
        seed: int | None = 0,
        sync: bool = False,
        bitrate: float | None = None,
        tick_s: float | None = None,
        **bus_kwargs: Any,
    ) -> None:
        self.joints = joints
        self.channel = channel
        self.interface = interface
        self.injector = faults if isinstance(faults, FaultInjector) else FaultInjector(faults, seed)
        self.tick_count = 0
        self.frames_in = 0
        self.frames_out = 0
        self.frames_suppressed = 0  # frames not sent because the device had no new data (stale)
        self.commands_total = 0
        self._late: list[tuple[int, can.Message]] = []
        self._last_payload: dict[int, bytes] = {}
        self._lock = threading.RLock()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._closed = False
        self.bus: can.BusABC = (LockstepVirtualBus(channel, **bus_kwargs) if interface == "virtual"
                                else can.Bus(interface=interface, channel=channel, **bus_kwargs))
        self._host_buses: list[can.BusABC] = []  # buses opened for adapters (host_bus), closed with the node
        self.sync = sync
        if sync:
            self._install_sync_queue()
        #: simulated seconds per :meth:`tick` (the bus budget's clock): ``tick_s``, else the node's ``dt``
        self.tick_s = float(tick_s if tick_s is not None else getattr(self, "dt", 0.001))
        self.budget: CanBusBudget | None = None
        if bitrate is not None:
            if not sync:
                raise ValueError("a bus budget (bitrate=) needs sync=True: lockstep on the simulated clock")
            with _BUDGETS_LOCK:
                self.budget = _BUDGETS.get(channel)
                if self.budget is None:
                    self.budget = _BUDGETS[channel] = CanBusBudget(bitrate)
                self.budget.users += 1

    # -- transport ----------------------------------------------------------------------------
    def host_bus(self) -> can.BusABC:
        """A new connection to this node's virtual channel for an adapter (its ``bus`` parameter):
        a :class:`LockstepVirtualBus`, shut down when the node closes (the adapter does not own it)."""
        if self.interface != "virtual":
            raise ValueError("host_bus() needs interface='virtual'")
        bus = LockstepVirtualBus(self.channel)
        self._host_buses.append(bus)
        return bus

    def _install_sync_queue(self) -> None:
        from can.interfaces import virtual

        bus = self.bus
        if not isinstance(bus, virtual.VirtualBus):
            raise ValueError("sync=True needs interface='virtual' (use tick()/process_pending() otherwise)")
        with virtual.channels_lock:
            q = _SyncQueue(self)
            idx = next(i for i, x in enumerate(bus.channel) if x is bus.queue)
            bus.channel[idx] = q
            bus.queue = q

    def _deliver_sync(self, msg: can.Message) -> None:
        with self._lock:
            if self._closed:
                return
            b = self.budget
            # no budget before the first tick: the open sequence's request/answer traffic paces
            # itself on the wall clock, which lockstep does not model
            if b is None or b.sending or self.tick_count == 0:
                self._receive(msg)
            else:
                b.host_frame(self, msg)

    def _receive(self, msg: can.Message) -> None:
        inj = self.injector
        if not inj.inactive and inj.is_disconnected(self.tick_count):
            return
        self.frames_in += 1
        try:
            self.handle(msg)
        except Exception:  # a malformed frame must not kill the simulated device
            logger.exception("%s: error handling %s", self.kind, msg)

    def send(self, arb_id: int, data: bytes, *, stale_key: int | None = None, stale: str = "repeat") -> None:
        """Send one frame through the fault injector (drop / stale / corrupt / late). ``stale``:
        what a stale fault does to this frame: ``"repeat"`` the previous payload, or ``"suppress"``
        (no new data, so no frame)."""
        inj = self.injector
        key = arb_id if stale_key is None else stale_key
        if inj.inactive:  # no fault can apply: what the steps below do then, without their calls
            if self._closed:
                return
            self._last_payload[key] = data
            self._send_now(can.Message(arbitration_id=arb_id, data=data, is_extended_id=False))
            return
        t = self.tick_count
        if inj.is_disconnected(t) or self._closed:
            return
        inj.hold_up()
        if inj.should_drop(t):
            return
        if key in self._last_payload and inj.should_repeat_stale(t):
            if stale == "suppress":
                self.frames_suppressed += 1
                return
            data = self._last_payload[key]
        else:
            self._last_payload[key] = data
        if inj.should_corrupt(t):
            # A corrupted CAN frame fails the controllers' CRC check and is destroyed by an error
            # frame: the host never sees the payload, only the error frame.
            msg = can.Message(arbitration_id=0, is_error_frame=True, is_extended_id=False)
        else:
            msg = can.Message(arbitration_id=arb_id, data=data, is_extended_id=False)
        if inj.is_late():
            self._late.append((t + inj.plan.late_ticks, msg))
            return
        self._send_now(msg)

    def _send_now(self, msg: can.Message) -> None:
        if self.budget is not None and self.tick_count > 0:
            self.budget.node_frame(self, msg)
        else:
            self._transmit(msg)

    def _transmit(self, msg: can.Message) -> None:
        b = self.budget
        if b is not None:
            b.sending += 1  # the other nodes on the channel receive this copy at once
        try:
            self.bus.send(msg, timeout=0.1)
            self.frames_out += 1
        except can.CanError as exc:  # pragma: no cover
            logger.warning("%s: send failed: %s", self.kind, exc)
        finally:
            if b is not None:
                b.sending -= 1

    # -- lockstep -----------------------------------------------------------------------------
    def process_pending(self) -> int:
        """Handle (and answer) every frame received so far. Returns the number of frames."""
        n = 0
        with self._lock:
            if self.sync:
                return 0
            while (msg := self.bus.recv(timeout=0.0)) is not None:
                self._receive(msg)
                n += 1
        return n

    def tick(self) -> None:
        """One control period: process pending frames, advance, send late and cyclic frames."""
        with self._lock:
            self.process_pending()
            self.tick_count += 1
            if self.budget is not None:
                self.budget.advance_to(self.tick_count * self.tick_s)
            if self._late:
                due = [m for d, m in self._late if d <= self.tick_count]
                self._late = [(d, m) for d, m in self._late if d > self.tick_count]
                for m in due:
                    if not self.injector.is_disconnected(self.tick_count):
                        self._send_now(m)
            self.on_tick()

    # -- free running -------------------------------------------------------------------------
    def start(self, rate_hz: float = 1000.0) -> None:
        """Run ticks at ``rate_hz`` in a daemon thread, answering requests as they arrive."""
        if self._thread is not None:
            return
        if self.sync:
            raise ValueError("free-running mode needs sync=False")
        period = 1.0 / rate_hz
        self._stop.clear()

        def run() -> None:
            next_t = time.monotonic() + period
            while not self._stop.is_set():
                remaining = next_t - time.monotonic()
                if remaining > 0:
                    msg = self.bus.recv(timeout=remaining)
                    if msg is not None:
                        with self._lock:
                            self._receive(msg)
                    continue
                self.tick()
                next_t += period
                if next_t < time.monotonic() - 10 * period:  # fell far behind: resynchronise
                    next_t = time.monotonic() + period

        self._thread = threading.Thread(target=run, name=f"{self.kind}-{self.channel}", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        if self._thread is not None:
            self._stop.set()
            self._thread.join(timeout=2.0)
            self._thread = None

    def close(self) -> None:
        if self._closed:
            return
        self.stop()
        with self._lock:
            self._closed = True
            self.bus.shutdown()
            for bus in self._host_buses:
                bus.shutdown()
            self._host_buses.clear()
        if self.budget is not None:
            with _BUDGETS_LOCK:
                self.budget.users -= 1
                if self.budget.users <= 0 and _BUDGETS.get(self.channel) is self.budget:
                    del _BUDGETS[self.channel]

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- to override --------------------------------------------------------------------------
    def handle(self, msg: can.Message) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def on_tick(self) -> None:
        """Called after each tick (cyclic frames)."""


class SimODrive(SimCanNode):
    """Simulated ODrive axis speaking CANSimple (see :mod:`hil.protocols.can_odrive`).

    ``gear_ratio`` / ``linear_scale`` must match the adapter's: the node converts the joint state
    to motor turns and the motor torque to joint effort with them. The drive applies torque only
    in CLOSED_LOOP_CONTROL with TORQUE_CONTROL and no (injected or latched) axis error.
    Injected error codes are OR-ed into ``axis_error`` and disarm the axis while active.

    Defaults are a factory ODrive's (firmware 0.6 docs, "CAN Protocol" and ``odrive-interface``
    ``config.can``; ODrive firmware sources ``Firmware/communication/can/can_simple.cpp`` and
    ``Firmware/MotorControl/axis.cpp``); a bench or scene may override them:

    * ``heartbeat_every`` (ticks, 0 = off; ``None`` = the default ``heartbeat_msg_rate_ms`` = 100 ms,
      i.e. ``round(0.1 / dt)`` ticks); ``encoder_every`` (ticks, 0 = off: a factory drive's
      ``encoder_msg_rate_ms`` is 10 ms on 0.6, 0 on 0.5.x; the adapter polls by default).
    * watchdog (``axis.config.enable_watchdog`` = False, ``watchdog_timeout`` = 0 by default):
      ``watchdog_ticks`` = 0 means off. When on, *every* CAN message addressed to this node feeds
      it (``can_simple.cpp`` calls ``axis.watchdog_feed()`` for each message of the node before
      dispatching the command); when no message arrives for ``watchdog_ticks`` ticks in
      CLOSED_LOOP_CONTROL the axis latches WATCHDOG_TIMER_EXPIRED (0x01000000) in ``axis_error``
      and drops to IDLE with zero torque (``axis.cpp``: ``if (!watchdog_check()) error |=
      ERROR_WATCHDOG_TIMER_EXPIRED``); Clear_Errors clears it. The host configures it through
      RxSdo endpoint writes (firmware 0.6) to the ids in ``watchdog_endpoints`` (default
      :data:`SIM_WATCHDOG_ENDPOINTS`): ``watchdog_timeout`` (float32 s, converted with ``dt`` s per
      tick) and ``enable_watchdog`` (0/1).
    * ``firmware``: ``"0.6"`` (default: cmd 0x1C is Get_Torques, Clear_Errors carries an identify
      byte) or ``"0.5"`` (0x1C is Get_ADC_Voltage: float32 volts; there is no Get_Torques).
    """

    kind = "odrive"

    def __init__(
        self,
        joints: SimulatedJoints,
        channel: str,
        node_id: int = 0,
        interface: str = "virtual",
        *,
        gear_ratio: float = 1.0,
        linear_scale: float | None = None,
        heartbeat_every: int | None = None,
        encoder_every: int = 0,
        watchdog_ticks: int = 0,
        dt: float = 0.001,
        watchdog_endpoints: dict[str, int] | None = None,
        firmware: str = "0.6",
        adc_voltage: float = 0.0,
        **kw: Any,
    ) -> None:
        if firmware not in od.FIRMWARES:
            raise ValueError(f"firmware must be one of {list(od.FIRMWARES)}, got {firmware!r}")
        self.node_id = node_id
        self.firmware = firmware
        self.adc_voltage = float(adc_voltage)
        self.watchdog_ticks = int(watchdog_ticks)
        self._last_torque_tick = 0
        self.gear_ratio = gear_ratio
        self.linear_scale = linear_scale
        if heartbeat_every is None:  # factory heartbeat_msg_rate_ms = 100
            heartbeat_every = max(1, round(od.DEFAULT_HEARTBEAT_S / float(dt)))
        self.heartbeat_every = int(heartbeat_every)
        self.encoder_every = encoder_every
        self.axis_state = int(od.AxisState.IDLE)
        self.control_mode = int(od.ControlMode.VOLTAGE_CONTROL)
        self.input_mode = int(od.InputMode.INACTIVE)
        self.input_torque = 0.0  # motor N.m
        self.latched_error = 0
        self.commands: deque[tuple[int, float]] = deque(maxlen=LOG_LEN)  # newest (tick, motor torque)
        self.dt = float(dt)
        self.watchdog_endpoints = dict(watchdog_endpoints or SIM_WATCHDOG_ENDPOINTS)
        self.watchdog_enabled = watchdog_ticks > 0  # off by default (as shipped), or armed over RxSdo
        self.watchdog_expired = 0  # times the drive's own watchdog idled the axis
        self.watchdog_configured = False  # set by an RxSdo write from the host
        super().__init__(joints, channel, interface, **kw)

    # conversions (inverse of the adapter's)
    def _joint_to_turns(self, q: float) -> float:
        if self.linear_scale is not None:
            return q / self.linear_scale
        return q * self.gear_ratio / (2.0 * math.pi)

    def _motor_torque_to_joint(self, tau: float) -> float:
        if self.linear_scale is not None:
            return tau * 2.0 * math.pi / self.linear_scale
        return tau * self.gear_ratio

    @property
    def axis_error(self) -> int:
        return self.latched_error | self.injector.error_code(self.tick_count)

    def _armed(self) -> bool:
        return (
            self.axis_state == od.AxisState.CLOSED_LOOP_CONTROL
            and self.control_mode == od.ControlMode.TORQUE_CONTROL
            and self.axis_error == 0
        )

    def applied_motor_torque(self) -> float:
        return self.input_torque if self._armed() else 0.0

    def _apply(self) -> None:
        effort = self._motor_torque_to_joint(self.applied_motor_torque())
        self.joints.apply_effort(np.full(self.joints.dof, effort))

    def _reply(self, cmd: int, data: bytes) -> None:
        self.send(od.arbitration_id(self.node_id, cmd), data)

    def publish_estimate(self) -> None:
        """Send one Get_Encoder_Estimates frame now (the first cyclic frame of a lockstep bench)."""
        with self._lock:
            self._reply_estimate()

    def _reply_estimate(self) -> None:
        # a stale estimator has no new estimate: no frame at all (heartbeats go on)
        self.send(od.arbitration_id(self.node_id, od.CMD_GET_ENCODER_ESTIMATES), self._encoder_payload(),
                  stale="suppress")

    def _sdo(self, data: bytes) -> None:
        op, ep, value = od.decode_sdo(data)
        if op != od.SDO_WRITE:
            return
        if ep == self.watchdog_endpoints.get("watchdog_timeout") and len(value) >= 4:
            timeout_s = struct.unpack_from("<f", value)[0]
            self.watchdog_ticks = max(1, math.ceil(timeout_s / self.dt * (1 - 1e-6)))  # float32 on the wire
            self.watchdog_configured = True
        elif ep == self.watchdog_endpoints.get("enable_watchdog"):
            self.watchdog_enabled = bool(value[0])
            self.watchdog_configured = True
            self._last_torque_tick = self.tick_count

    def _encoder_payload(self) -> bytes:
        q = float(self.joints.position()[0])
        v = float(self.joints.velocity()[0])
        return od.encode_f32x2(self._joint_to_turns(q), self._joint_to_turns(v))

    def handle(self, msg: can.Message) -> None:
        if msg.is_extended_id or msg.is_error_frame:
            return
        node, cmd = od.split_id(msg.arbitration_id)
        if node != self.node_id:
            return
        data = bytes(msg.data)
        is_request = msg.is_remote_frame or len(data) == 0
        self._last_torque_tick = self.tick_count  # can_simple.cpp: every message of the node feeds the watchdog
        if cmd == od.CMD_SET_INPUT_TORQUE and len(data) >= 4:
            self.input_torque = struct.unpack_from("<f", data)[0]
            self.commands.append((self.tick_count, self.input_torque))
            self.commands_total += 1
            self._apply()
        elif cmd == od.CMD_SET_AXIS_STATE and len(data) >= 4:
            req = struct.unpack_from("<I", data)[0]
            if req == od.AxisState.CLOSED_LOOP_CONTROL and self.axis_error:
                req = od.AxisState.IDLE  # refuses to arm while in error
            self.axis_state = int(req)
            self._apply()
        elif cmd == od.CMD_SET_CONTROLLER_MODE and len(data) >= 8:
            self.control_mode, self.input_mode = struct.unpack_from("<II", data)
            self._apply()
        elif cmd == od.CMD_ESTOP:
            self.latched_error |= od.AXIS_ERROR_ESTOP_REQUESTED
            self.axis_state = int(od.AxisState.IDLE)
            self._apply()
        elif cmd == od.CMD_CLEAR_ERRORS:
            self.latched_error = 0
        elif cmd == od.CMD_RX_SDO and len(data) >= 5:
            self._sdo(data)
        elif cmd == od.CMD_GET_ENCODER_ESTIMATES and is_request:
            self._reply_estimate()
        elif cmd == od.CMD_GET_TORQUES and is_request:  # 0x1C: Get_Torques (0.6) / Get_ADC_Voltage (0.5.x)
            if self.firmware == "0.5":
                self._reply(cmd, od.encode_f32(self.adc_voltage))
            else:
                self._reply(cmd, od.encode_f32x2(self.input_torque, self.applied_motor_torque()))
        elif cmd == od.CMD_HEARTBEAT and is_request:
            self._reply(cmd, od.encode_heartbeat(self.axis_error, self.axis_state))

    def on_tick(self) -> None:
        if self.axis_error and self.axis_state != od.AxisState.IDLE:
            self.axis_state = int(od.AxisState.IDLE)  # a fault disarms the axis
        if (self.watchdog_enabled and self.watchdog_ticks and self.axis_state == od.AxisState.CLOSED_LOOP_CONTROL
                and self.tick_count - self._last_torque_tick > self.watchdog_ticks):
            logger.warning("odrive node %d: CAN watchdog expired: WATCHDOG_TIMER_EXPIRED, axis idle", self.node_id)
            self.axis_state = int(od.AxisState.IDLE)  # the drive's own watchdog (axis.cpp)
            self.input_torque = 0.0
            self.latched_error |= AXIS_ERROR_WATCHDOG_TIMER_EXPIRED
            self.watchdog_expired += 1
        self._apply()
        t = self.tick_count
        if self.heartbeat_every and t % self.heartbeat_every == 0:
            self._reply(od.CMD_HEARTBEAT, od.encode_heartbeat(self.axis_error, self.axis_state))
        if self.encoder_every and t % self.encoder_every == 0:
            self._reply_estimate()


class SimCubeMars(SimCanNode):
    """Simulated CubeMars / T-Motor AK actuator in MIT mode (see :mod:`hil.protocols.can_cubemars`).

    Commands arrive on id ``motor_id``; every command (and each special frame) is answered with a
    state frame on id ``reply_id`` whose first byte is ``motor_id``. The impedance law
    ``tau = kp*(p_des - q) + kd*(v_des - qd) + t_ff`` is evaluated once per command from the
    current state (``q`` in the motor's wrapped frame) and held until the next command (the real
    drive re-evaluates it at its own loop rate; torque-only control with kp = kd = 0 is exact).
    Torque is clamped to the model's T range. ``temperature`` is reported in byte 6, injected
    error codes in byte 7 (and disable torque).

    As the real motor (AK manual, 5.3 MIT mode; see the adapter's docstring): control commands
    received before "enter motor mode" (rest mode) are ignored (answered with the state, no
    torque: enabling later does not apply a stale command); the reported position wraps modulo
    the P span (``p_max - p_min`` = 25 rad) instead of saturating; after "set zero" the motor
    answers nothing for ``zero_silence_s`` (default 1 s, on ``clock``: wall time by default, the
    firmware's flash write does not follow a simulated clock).
    """

    kind = "cubemars"

    def __init__(
        self,
        joints: SimulatedJoints,
        channel: str,
        motor_id: int = 1,
        interface: str = "virtual",
        *,
        model: str | cm.MitLimits = "AK80-9",
        reply_id: int = 0,
        temperature: int = 30,
        short_reply: bool = False,
        zero_silence_s: float = cm.ZERO_SILENCE_S,
        clock: Any = time.monotonic,
        **kw: Any,
    ) -> None:
        self.motor_id = motor_id
        self.limits = cm.model_limits(model)
        self.reply_id = reply_id
        self.temperature = temperature
        self.short_reply = short_reply  # old firmware: 6-byte reply without temperature/error
        self.enabled = False
        self.zero_offset = 0.0
        self.torque = 0.0
        self.zero_silence_s = float(zero_silence_s)
        self._clock = clock
        self._silent_until = -math.inf
        self.ignored_in_rest = 0  # control commands received before enter-motor-mode
        self.commands: deque[tuple[int, cm.MitCommand]] = deque(maxlen=LOG_LEN)
        super().__init__(joints, channel, interface, **kw)

    def _error(self) -> int:
        return self.injector.error_code(self.tick_count)

    def _apply(self) -> None:
        tau = self.torque if (self.enabled and not self._error()) else 0.0
        self.joints.apply_effort(np.full(self.joints.dof, tau))

    def wrapped_position(self) -> float:
        """Output position relative to the zero, wrapped into [p_min, p_max) as the motor reports it."""
        lim = self.limits
        q = float(self.joints.position()[0]) - self.zero_offset
        return (q - lim.p_min) % (lim.p_max - lim.p_min) + lim.p_min

    def _send_state(self) -> None:
        v = float(self.joints.velocity()[0])
        tau = self.torque if (self.enabled and not self._error()) else 0.0
        reply = cm.MitReply(self.motor_id, self.wrapped_position(), v, tau, self.temperature, self._error())
        data = cm.pack_reply(reply, self.limits, short=self.short_reply)
        self.send(self.reply_id, data, stale_key=0x10000 + self.motor_id)

    def handle(self, msg: can.Message) -> None:
        if msg.is_extended_id or msg.is_remote_frame or msg.arbitration_id != self.motor_id:
            return
        data = bytes(msg.data)
        if len(data) != 8:
            return
        if self._clock() < self._silent_until:
            return  # storing the new origin: deaf and silent
        special = cm.SPECIAL_FRAMES_INV.get(data)
        if special == "enter":
            self.enabled = True
        elif special == "exit":
            self.enabled = False
            self.torque = 0.0
        elif special == "zero":
            self.zero_offset = float(self.joints.position()[0])
            self._silent_until = self._clock() + self.zero_silence_s
            return
        else:
            c = cm.unpack_command(data, self.limits)
            self.commands.append((self.tick_count, c))
            self.commands_total += 1
            if self.enabled:
                q = self.wrapped_position()
                v = float(self.joints.velocity()[0])
                tau = c.kp * (c.p_des - q) + c.kd * (c.v_des - v) + c.t_ff
                self.torque = min(max(tau, self.limits.t_min), self.limits.t_max)
            else:
                self.ignored_in_rest += 1
        self._apply()
        self._send_state()

    def on_tick(self) -> None:
        self._apply()


__all__ = ["LOG_LEN", "SIM_WATCHDOG_ENDPOINTS", "SimCanNode", "SimCubeMars", "SimODrive"]
