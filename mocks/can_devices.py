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
import threading
import time
from collections import deque
from typing import Any

import can
import numpy as np

from hil.mocks.faults import FaultInjector, FaultPlan
from hil.mocks.interfaces import SimulatedJoints
from hil.protocols.codecs import cubemars as cm
from hil.protocols.codecs import odrive as od

log = logging.getLogger(__name__)

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
        self.bus = can.Bus(interface=interface, channel=channel, **bus_kwargs)
        self.sync = sync
        if sync:
            self._install_sync_queue()

    # -- transport ----------------------------------------------------------------------------
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
            if not self._closed:
                self._receive(msg)

    def _receive(self, msg: can.Message) -> None:
        if self.injector.is_disconnected(self.tick_count):
            return
        self.frames_in += 1
        try:
            self.handle(msg)
        except Exception:  # a malformed frame must not kill the simulated device
            log.exception("%s: error handling %s", self.kind, msg)

    def send(self, arb_id: int, data: bytes, *, stale_key: int | None = None, stale: str = "repeat") -> None:
        """Send one frame through the fault injector (drop / stale / corrupt / late). ``stale``:
        what a stale fault does to this frame: ``"repeat"`` the previous payload, or ``"suppress"``
        (no new data, so no frame)."""
        inj = self.injector
        t = self.tick_count
        if inj.is_disconnected(t) or self._closed:
            return
        if inj.should_drop(t):
            return
        key = arb_id if stale_key is None else stale_key
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
        try:
            self.bus.send(msg, timeout=0.1)
            self.frames_out += 1
        except can.CanError as exc:  # pragma: no cover
            log.warning("%s: send failed: %s", self.kind, exc)

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
            timeout_s = od.struct.unpack_from("<f", value)[0]
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
            self.input_torque = od.struct.unpack_from("<f", data)[0]
            self.commands.append((self.tick_count, self.input_torque))
            self.commands_total += 1
            self._apply()
        elif cmd == od.CMD_SET_AXIS_STATE and len(data) >= 4:
            req = od.struct.unpack_from("<I", data)[0]
            if req == od.AxisState.CLOSED_LOOP_CONTROL and self.axis_error:
                req = od.AxisState.IDLE  # refuses to arm while in error
            self.axis_state = int(req)
            self._apply()
        elif cmd == od.CMD_SET_CONTROLLER_MODE and len(data) >= 8:
            self.control_mode, self.input_mode = od.struct.unpack_from("<II", data)
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
            log.warning("odrive node %d: CAN watchdog expired: WATCHDOG_TIMER_EXPIRED, axis idle", self.node_id)
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
