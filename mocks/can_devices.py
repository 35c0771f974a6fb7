"""Simulated CAN devices on a python-can bus: the common node machinery (:class:`SimCanNode`, the
lockstep virtual bus, the bus budget). The devices are :mod:`hil.mocks.odrive_device` (ODrive
CANSimple axis) and :mod:`hil.mocks.cubemars_device` (CubeMars AK "MIT mode" motor), both still
importable from here.

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
import queue
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import can
from can.interfaces import virtual as _virtual

from hil.mocks.faults import FaultInjector, FaultPlan
from hil.mocks.interfaces import SimulatedJoints
from hil.protocols.link_budget import can_frame_bits

logger = logging.getLogger(__name__)

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
        if bitrate is not None and not sync:  # refused before the bus exists: nothing to shut down
            raise ValueError("a bus budget (bitrate=) needs sync=True: lockstep on the simulated clock")
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


#: names that moved to the device modules (issue 29), still importable from here
_MOVED = {"SimODrive": "hil.mocks.odrive_device", "SIM_WATCHDOG_ENDPOINTS": "hil.mocks.odrive_device",
          "SIM_ENDPOINTS": "hil.mocks.odrive_device", "AXIS_ERROR_WATCHDOG_TIMER_EXPIRED": "hil.mocks.odrive_device",
          "SimCubeMars": "hil.mocks.cubemars_device"}


def __getattr__(name: str) -> Any:
    if name in _MOVED:  # imported on first use: the device modules import this one
        import importlib

        return getattr(importlib.import_module(_MOVED[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["LOG_LEN", "SimCanNode"]
