"""ODrive over CAN ("CANSimple"), torque control, as an :class:`~hil.protocols.base.Actuator`.

Wire format (sources: ODrive docs "CAN Protocol", https://docs.odriverobotics.com/v/latest/
can-protocol.html, and the odrive-cansimple DBC tables as rendered by the ``odrive_can`` project
and the ``odrive-messages`` crate, all consulted through the search tool):

* 11-bit standard id ``node_id << 5 | cmd_id`` (node 0..63, cmd 0..31); little-endian payloads.
* Messages used here:

  ====  =====================  ========  =========================================================
  cmd   name                   dir       payload
  ====  =====================  ========  =========================================================
  0x01  Heartbeat              drive->   axis_error u32, axis_state u8, procedure_result u8,
                                         trajectory_done u8, reserved u8 (cyclic)
  0x02  Estop                  ->drive   empty
  0x07  Set_Axis_State         ->drive   axis_requested_state u32 (IDLE=1, CLOSED_LOOP_CONTROL=8)
  0x09  Get_Encoder_Estimates  drive->   pos_estimate f32 [turns], vel_estimate f32 [turns/s]
                                         (cyclic, or answer to an RTR frame with this id)
  0x0B  Set_Controller_Mode    ->drive   control_mode u32 (TORQUE_CONTROL=1), input_mode u32
                                         (PASSTHROUGH=1)
  0x0E  Set_Input_Torque       ->drive   input_torque f32 [N.m at the motor]
  0x18  Clear_Errors           ->drive   identify u8 (firmware 0.6; older firmware: empty)
  0x1C  Get_Torques            drive->   torque_target f32, torque_estimate f32 [N.m] (firmware
                                         0.6 only; on 0.5.x 0x1C is Get_ADC_Voltage, float32 V)
  ====  =====================  ========  =========================================================

  Firmware: the two lines speak different tables (ODrive's CAN databases
  ``odrive-cansimple-0.5.6.dbc`` and ``-0.6.10.dbc``): ``"0.6"`` (ODrive Pro / S1 and 0.6 on v3.6)
  or ``"0.5"`` (0.5.x on ODrive v3.x, ``Firmware/communication/can/can_simple.hpp`` of the 0.5
  branch: ``MSG_GET_ADC_VOLTAGE = 0x1C``, no Get_Torques; Clear_Errors without payload) and, above
  all, different axis_error bits (0.5: ESTOP_REQUESTED 0x4000, WATCHDOG_TIMER_EXPIRED 0x800; 0.6:
  0x4000 is INVERTER_OVER_TEMP, 0x800 DC_BUS_OVER_REGEN_CURRENT). By default (``firmware=None``)
  the adapter asks the drive on open: an RTR Get_Version (cmd 0x00, firmware 0.6 answers with its
  version, :attr:`ODriveCAN.firmware_version`); no answer within ``timeout`` means 0.5.x (id 0 is
  the CANopen NMT command there, ignored). The line found selects the error table, the torque
  message and the frame lengths; ``firmware="0.6"`` / ``"0.5"`` (a scene parameter) skips the
  question. ``read_torque`` needs 0.6: on 0.5 it is refused instead of decoding a voltage as torque.

  Frames carry the data length the DBC of the line defines (:data:`DLC`): Set_Input_Torque,
  Set_Axis_State, Set_Controller_Mode and RxSdo are 8 bytes (the 4-byte float or integer, then
  zeros), Clear_Errors 1 byte on 0.6 (identify) and none on 0.5, Estop none.

  Example (conformance vector): Set_Input_Torque to node 3 with 1.5 N.m is id 0x6E, data
  ``00 00 C0 3F 00 00 00 00``.

Units and scaling: the drive works in motor turns and motor N.m. This adapter reports SI joint
units. Rotary (default): ``q [rad] = 2*pi*turns / gear_ratio``, ``tau_joint = gear_ratio *
tau_motor``. Linear (``linear_scale`` = metres per motor turn, e.g. a ball screw lead): ``x [m] =
linear_scale * turns``, ``F [N] = 2*pi * tau_motor / linear_scale`` (ideal, lossless
transmission). Sign: positive effort drives the joint in its positive direction (the drive's
positive direction; flip it on the drive or with a negative ``gear_ratio``).

Feedback: ``feedback="poll"`` sends an RTR frame for Get_Encoder_Estimates on every
:meth:`ODriveCAN.read` and waits for the answer (stale answers queued before the request are
discarded); ``feedback="cyclic"`` uses the frames the drive broadcasts at its configured
``encoder_msg_rate_ms`` and returns the newest one received since the previous read. Heartbeats
are processed whenever frames are read; a non-zero ``axis_error`` raises
:class:`hil.errors.DeviceFault` (``code`` = axis_error) on every read until cleared.

Freshness (``JointSample.produced_at``, ``seq``): CANSimple estimates carry no timestamp or
counter, so the data is dated by the *arrival* of its Get_Encoder_Estimates frame (the adapter's
``clock`` when the frame was taken off the bus; at most one read period late). ``seq`` advances
only with a new frame. Cyclic mode: a read that finds no new estimate frame waits for one until
the newest estimate is ``timeout`` old (host clock), then returns the previous estimate again
(same ``seq`` and ``produced_at``: a stale sample, counted in ``counters()["stale"]``); the
runner's watchdog stops the run when its age exceeds ``watchdog_ms``. Only the very first read
raises DeviceTimeout. Poll mode: each answer to the RTR request is a new frame; a request that
gets no answer is sent again (``retries``, within the same ``timeout``), then DeviceTimeout.
Non-blocking poll (``read(timeout=0)``, what the realtime loop does): the read takes the answer
to the request the previous read sent, if it has arrived (otherwise a stale sample), and sends
the next request (send timeout 1 ms), so the round trip overlaps the loop's wait for its next tick;
the first such read after a blocking one (nothing requested ahead) polls once, with ``timeout``.
A frozen estimator that keeps answering with the same payload cannot be told from a joint at rest
by the host: the drive itself reports that (axis_error MISSING_ESTIMATE).

Counters (:meth:`ODriveCAN.counters`): ``error_frames`` (CAN error frames: a frame destroyed by a
CRC/stuffing error), ``stale`` (reads without a new estimate), ``late`` (poll answers that arrived
after their request had been given up, discarded), ``retries``, ``timeouts``.

Closed loop is checked, not assumed: after requesting CLOSED_LOOP_CONTROL on open the adapter
waits (``state_timeout``, default 0.5 s: longer than the default 100 ms heartbeat period) for a
heartbeat sent after the request (it also asks for one with an RTR frame, which firmware 0.6
answers; 0.5.x sends its cyclic one) and raises :class:`hil.errors.DeviceFault` when the heartbeat
carries an axis_error (code = axis_error; the drive refuses to arm in error, call
:meth:`ODriveCAN.clear_errors`) or the axis did not enter CLOSED_LOOP_CONTROL, and
:class:`hil.errors.DeviceTimeout` when no heartbeat arrives at all. Later, a heartbeat showing the
axis out of CLOSED_LOOP_CONTROL (it fell to IDLE: watchdog, estop, a fault) makes every
:meth:`ODriveCAN.read` raise DeviceFault: efforts would silently not be applied.

Drive watchdog (firmware 0.6 ``axis.config.watchdog_timeout`` / ``enable_watchdog``): CANSimple
has no dedicated message for it, but firmware 0.6 has generic endpoint access (RxSdo 0x04 ->
TxSdo 0x05: ``opcode u8 (0 read, 1 write), endpoint_id u16, reserved u8, value``). Endpoint ids
are *not* stable: they come from the ``flat_endpoints.json`` of the exact firmware build on the
drive, so the adapter arms the watchdog only when given them: ``watchdog_s`` (s) together with
``watchdog_endpoints={"watchdog_timeout": id, "enable_watchdog": id}``. It then writes
watchdog_timeout (float32) and enable_watchdog = 1 on open. Without the ids the drive's own
watchdog is left as configured (a warning is logged; a factory drive has it off). The drive feeds
the watchdog on every CAN message addressed to the node (``can_simple.cpp``; what the simulator
does), and on expiry latches WATCHDOG_TIMER_EXPIRED (0x01000000) and goes IDLE: the next heartbeat
makes :meth:`ODriveCAN.read` raise DeviceFault.
"""

from __future__ import annotations

import contextlib
import logging
import math
import time
from collections.abc import Callable
from typing import Any, Literal

import can
import numpy as np

from hil.errors import DeviceFault, DeviceTimeout, ProtocolError
from hil.protocols.base import DeviceInfo, JointSample, StopStep
from hil.protocols.can_common import CanActuator
from hil.protocols.can_common import open_can_bus as open_can_bus  # re-export (old path)
from hil.protocols.codecs import forwarder
from hil.protocols.codecs import odrive as _wire
from hil.protocols.codecs.odrive import (
    CMD_CLEAR_ERRORS,
    CMD_ESTOP,
    CMD_GET_ENCODER_ESTIMATES,
    CMD_GET_TORQUES,
    CMD_GET_VERSION,
    CMD_HEARTBEAT,
    CMD_RX_SDO,
    CMD_SET_AXIS_STATE,
    CMD_SET_CONTROLLER_MODE,
    CMD_SET_INPUT_TORQUE,
    CMD_TX_SDO,
    DLC,
    FIRMWARES,
    AxisState,
    ControlMode,
    InputMode,
    _state_name,
    arbitration_id,
    decode_f32x2,
    decode_heartbeat,
    decode_version,
    describe_axis_error,
    encode_controller_mode,
    encode_f32,
    encode_input_torque,
    encode_sdo_write,
    encode_u32,
    firmware_line,
    split_id,
)
from hil.protocols.waits import WALL, Waits

logger = logging.getLogger(__name__)


#: send timeout (s) of the non-blocking poll's request frames: a full transmit queue is a fault
POLL_AHEAD_SEND_TIMEOUT_S = 0.001


class ODriveCAN(CanActuator):
    """One ODrive axis (one CANSimple node) in torque control; ``dof`` = 1.

    Parameters
    ----------
    node_id: CANSimple node id of the axis (0..63).
    channel, interface, bitrate: python-can bus (e.g. ``"can0"``/``"socketcan"`` on a bench,
        ``"hil0"``/``"virtual"`` against the simulator). Extra ``bus_kwargs`` go to ``can.Bus``.
    bus: use an already open bus instead (not shut down by :meth:`close`).
    gear_ratio: motor turns per joint turn (rotary).
    linear_scale: metres of joint travel per motor turn; makes the joint linear (units "linear").
    feedback: ``"poll"`` (RTR request per read) or ``"cyclic"`` (drive broadcasts estimates).
    read_torque: also poll Get_Torques (0x1C) and report ``effort`` = torque estimate (joint units);
        firmware 0.6 only.
    firmware: ``None`` (default: asked with Get_Version on open), ``"0.6"`` or ``"0.5"``: which
        CANSimple table the drive speaks (error bits, messages, frame lengths).
    state_timeout: how long (s) open waits for a heartbeat confirming CLOSED_LOOP_CONTROL; ``None``:
        do not wait (a node stepped by hand that answers only on its next tick), :meth:`read`
        checks the state from the next heartbeat on.
    effort_limit: symmetric clamp on commanded joint effort (N or N.m), ``None`` = no clamp.
    enable: on open, set TORQUE_CONTROL/PASSTHROUGH and request CLOSED_LOOP_CONTROL; on close,
        command zero torque and request IDLE.
    clock: time source for ``JointSample.t`` (pass the simulator clock in lockstep runs).
    """

    dof = 1

    def __init__(
        self,
        node_id: int = 0,
        channel: str = "can0",
        interface: str = "socketcan",
        bitrate: int | None = None,
        *,
        bus: can.BusABC | None = None,
        gear_ratio: float = 1.0,
        linear_scale: float | None = None,
        feedback: Literal["poll", "cyclic"] = "poll",
        read_torque: bool = False,
        effort_limit: float | None = None,
        enable: bool = True,
        clock: Callable[[], float] = time.monotonic,
        waits: Waits = WALL,
        timeout: float = 0.1,
        retries: int = 1,
        watchdog_s: float | None = None,
        watchdog_endpoints: dict[str, int] | None = None,
        firmware: str | None = None,
        state_timeout: float | None = 0.5,
        **bus_kwargs: Any,
    ) -> None:
        if firmware is not None:
            firmware = str(firmware)
            if firmware not in FIRMWARES:
                raise ValueError(f"firmware must be one of {', '.join(FIRMWARES)}, got {firmware!r}")
        if read_torque and firmware == "0.5":
            raise ValueError("read_torque needs firmware 0.6: on 0.5.x cmd 0x1C is Get_ADC_Voltage, "
                             "not Get_Torques")
        #: the CANSimple line the drive speaks ("0.6" / "0.5"): given, or found on open (Get_Version)
        self.firmware = firmware or "0.6"
        #: (major, minor, revision) from the drive's Get_Version answer; None: not asked or no answer
        self.firmware_version: tuple[int, int, int] | None = None
        self.state_timeout = None if state_timeout is None else float(state_timeout)
        self._expect_closed_loop = False
        self._hb_count = 0
        if feedback not in ("poll", "cyclic"):
            raise ValueError(f"feedback must be 'poll' or 'cyclic', got {feedback!r}")
        if gear_ratio == 0 or (linear_scale is not None and linear_scale == 0):
            raise ValueError("gear_ratio and linear_scale must be non-zero")
        self.node_id = int(node_id)
        arbitration_id(self.node_id, 0)  # validates the node id
        self.gear_ratio = float(gear_ratio)
        self.linear_scale = None if linear_scale is None else float(linear_scale)
        self.units = "linear" if self.linear_scale is not None else "rotary"
        self.feedback = feedback
        self.read_torque = read_torque
        self.effort_limit = effort_limit
        self.clock = clock
        self._waits = waits
        self.timeout = timeout
        self._enable = enable
        self.label = f"ODrive node {self.node_id}"
        self._fault = 0
        self.axis_state: int | None = None
        self.retries = max(0, int(retries))
        self.error_frames = 0  # CAN error frames seen (e.g. a corrupted answer)
        self.stale_discarded = 0  # poll mode: late answers discarded before a new request
        self._ahead = False  # non-blocking poll: a request for the next read is outstanding
        self._stale_reads = 0
        self._retried = 0
        self._timeouts = 0
        self._estimate: tuple[float, float, float] | None = None  # newest unread (pos, vel) turns, arrival
        self._last: JointSample | None = None
        self._last_rx_wall = -math.inf  # host monotonic time of the newest estimate frame
        self._torques: tuple[float, float] | None = None
        # no acceptance filter: error frames (id 0) must reach us too; node filtering is done in _handle
        self._open_bus(interface, channel, bitrate, bus, bus_kwargs)
        self.info = DeviceInfo(
            driver="odrive_can",
            transport=f"can:{interface}:{channel}" if bus is None else f"can:{bus.channel_info}",
            vendor="ODrive Robotics",
            model="CANSimple axis",
            firmware=self.firmware,
            extra={"node_id": self.node_id, "gear_ratio": self.gear_ratio, "linear_scale": self.linear_scale},
        )
        self.watchdog_armed = False
        if firmware is None:
            try:
                self.detect_firmware(self.timeout)
            except Exception:
                self.close()
                raise
            if read_torque and self.firmware == "0.5":
                self.close()
                raise ProtocolError(f"ODrive node {self.node_id}: read_torque needs firmware 0.6 (Get_Torques); the "
                                    f"drive did not answer Get_Version: firmware 0.5.x, whose 0x1C is Get_ADC_Voltage")
        if enable:
            try:
                if watchdog_s is not None:
                    self.arm_watchdog(float(watchdog_s), watchdog_endpoints)
                self.set_controller_mode(ControlMode.TORQUE_CONTROL, InputMode.PASSTHROUGH)
                self.set_axis_state(AxisState.CLOSED_LOOP_CONTROL)
                if self.state_timeout is None:  # no wait at open: read() checks from the next heartbeat on
                    self._expect_closed_loop = True
                else:
                    self.confirm_closed_loop(self.state_timeout)
            except Exception:
                self.close()
                raise

    def counters(self) -> dict[str, int]:
        """error_frames, stale, late, retries, timeouts (see the module docstring)."""
        return {"error_frames": self.error_frames, "stale": self._stale_reads, "late": self.stale_discarded,
                "retries": self._retried, "timeouts": self._timeouts}

    def detect_firmware(self, timeout: float) -> str:
        """Ask the drive for its version (RTR Get_Version, cmd 0x00; sent again up to ``retries``
        times within ``timeout`` s): an answer sets :attr:`firmware_version` and the line from it,
        none means 0.5.x (the message exists from firmware 0.6 on). Sets and returns
        :attr:`firmware` (``info.firmware`` too)."""
        self._drain()
        now = self._waits.monotonic
        deadline = now() + timeout
        attempts = 1 + self.retries
        for k in range(attempts):
            self._send(CMD_GET_VERSION, remote=True, timeout=timeout)
            with contextlib.suppress(DeviceTimeout):
                self._wait_for(CMD_GET_VERSION, now() + (deadline - now()) / (attempts - k))
            if self.firmware_version is not None:
                break
        self.firmware = firmware_line(self.firmware_version)
        self.info.firmware = ("{}.{}.{}".format(*self.firmware_version) if self.firmware_version is not None
                              else "0.5 (no Get_Version answer)")
        logger.info("ODrive node %d: firmware %s: CANSimple %s table", self.node_id, self.info.firmware,
                    self.firmware)
        return self.firmware

    def arm_watchdog(self, timeout_s: float, endpoints: dict[str, int] | None, timeout: float = 0.1) -> bool:
        """Write ``axis.config.watchdog_timeout`` = ``timeout_s`` and ``enable_watchdog`` = 1 through
        RxSdo endpoint access (firmware 0.6). ``endpoints`` maps ``watchdog_timeout`` and
        ``enable_watchdog`` to the endpoint ids of the drive's firmware (its flat_endpoints.json);
        without them, or on firmware 0.5.x (no RxSdo), nothing is sent and False is returned."""
        if self.firmware == "0.5":
            logger.warning("ODrive node %d: drive watchdog not armed: firmware 0.5.x has no RxSdo over CAN "
                           "(set axis.config.watchdog_timeout and enable_watchdog with odrivetool)", self.node_id)
            return False
        if not endpoints or not {"watchdog_timeout", "enable_watchdog"} <= set(endpoints):
            logger.warning("ODrive node %d: drive watchdog not armed: endpoint ids of watchdog_timeout and "
                        "enable_watchdog not given (see the firmware's flat_endpoints.json)", self.node_id)
            return False
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f"watchdog timeout must be > 0 s, got {timeout_s!r}")
        self._send(CMD_RX_SDO, encode_sdo_write(int(endpoints["watchdog_timeout"]), encode_f32(timeout_s)),
                   timeout=timeout)
        self._send(CMD_RX_SDO, encode_sdo_write(int(endpoints["enable_watchdog"]), b"\x01"), timeout=timeout)
        self.watchdog_armed = True
        logger.info("ODrive node %d: drive watchdog armed (%.3f s)", self.node_id, timeout_s)
        return True

    # -- unit conversion --------------------------------------------------------------------
    def _turns_to_joint(self, turns: float) -> float:
        if self.linear_scale is not None:
            return turns * self.linear_scale
        return turns * 2.0 * math.pi / self.gear_ratio

    def _motor_torque_to_joint(self, tau: float) -> float:
        if self.linear_scale is not None:
            return tau * 2.0 * math.pi / self.linear_scale
        return tau * self.gear_ratio

    def joint_effort_to_motor_torque(self, effort: float) -> float:
        """Joint effort (N or N.m) -> motor torque (N.m) sent in Set_Input_Torque."""
        if self.linear_scale is not None:
            return effort * self.linear_scale / (2.0 * math.pi)
        return effort / self.gear_ratio

    # -- low level ----------------------------------------------------------------------------
    def _send(self, cmd: int, data: bytes = b"", remote: bool = False, timeout: float | None = None) -> None:
        """One frame to the node; a command's data padded to the length of its DBC (:data:`DLC`)."""
        if not remote:
            data = bytes(data).ljust(DLC[self.firmware].get(cmd, len(data)), b"\0")
        msg = can.Message(
            arbitration_id=arbitration_id(self.node_id, cmd),
            data=data,
            is_extended_id=False,
            is_remote_frame=remote,
            dlc=8 if remote else len(data),
        )
        self._send_frame(msg, self.timeout if timeout is None else timeout, f"send of cmd 0x{cmd:02X}")

    def _handle(self, msg: can.Message) -> int | None:
        """Digest one received frame; return its cmd id (None if not ours / a request)."""
        if msg.is_error_frame:
            self.error_frames += 1
            return None
        if msg.is_extended_id or msg.is_remote_frame:
            return None
        node, cmd = split_id(msg.arbitration_id)
        if node != self.node_id:
            return None
        if cmd == CMD_HEARTBEAT:
            err, state = decode_heartbeat(msg.data)
            if err != self._fault:
                if err:
                    logger.warning("ODrive node %d: axis_error 0x%X (%s)", node, err,
                                   describe_axis_error(err, self.firmware))
                else:
                    logger.info("ODrive node %d: axis_error cleared", node)
            self._fault, self.axis_state = err, state
            self._hb_count += 1
        elif cmd == CMD_GET_ENCODER_ESTIMATES:
            self._estimate = (*decode_f32x2(msg.data), self.clock())
            self._last_rx_wall = self._waits.monotonic()
        elif cmd == CMD_GET_TORQUES and self.firmware == "0.6":  # 0x1C is Get_ADC_Voltage on 0.5.x
            self._torques = decode_f32x2(msg.data)
        elif cmd == CMD_GET_VERSION and len(msg.data) == 8:  # firmware 0.6 (id 0 is NMT on 0.5.x)
            self.firmware_version = decode_version(msg.data)[2]
        return cmd

    def _raise_if_fault(self) -> None:
        if self._fault:
            raise DeviceFault(
                f"ODrive node {self.node_id}: axis_error 0x{self._fault:X} "
                f"({describe_axis_error(self._fault, self.firmware)}, firmware {self.firmware} table)",
                code=self._fault,
            )
        if (self._expect_closed_loop and self.axis_state is not None
                and self.axis_state != AxisState.CLOSED_LOOP_CONTROL):
            raise DeviceFault(f"ODrive node {self.node_id}: axis_state {_state_name(self.axis_state)}, not "
                              f"CLOSED_LOOP_CONTROL: efforts are not applied", code=self._fault)

    def confirm_closed_loop(self, timeout: float = 0.5) -> None:
        """Wait up to ``timeout`` s for a heartbeat, sent after this call, showing
        CLOSED_LOOP_CONTROL without axis_error (asks for one with an RTR frame: firmware 0.6 answers
        it, 0.5.x sends its cyclic one). DeviceFault on an axis_error or another state, DeviceTimeout
        when no heartbeat arrives; from then on :meth:`read` checks the state of every heartbeat."""
        self._drain()
        seen = self._hb_count
        with contextlib.suppress(DeviceTimeout):
            self._send(CMD_HEARTBEAT, remote=True, timeout=timeout)
        deadline = self._waits.monotonic() + timeout
        while True:
            if self._hb_count > seen and (self._fault or self.axis_state == AxisState.CLOSED_LOOP_CONTROL):
                break
            remaining = deadline - self._waits.monotonic()
            if remaining <= 0:
                break
            msg = self._recv(remaining)
            if msg is not None:
                self._handle(msg)
        if self._hb_count == seen:
            raise DeviceTimeout(f"ODrive node {self.node_id}: no heartbeat within {timeout:.3f} s after requesting "
                                f"CLOSED_LOOP_CONTROL")
        if self._fault:
            raise DeviceFault(f"ODrive node {self.node_id}: did not enter CLOSED_LOOP_CONTROL: axis_error "
                              f"0x{self._fault:X} ({describe_axis_error(self._fault, self.firmware)}); "
                              f"clear_errors() first",
                              code=self._fault)
        if self.axis_state != AxisState.CLOSED_LOOP_CONTROL:
            raise DeviceFault(f"ODrive node {self.node_id}: did not enter CLOSED_LOOP_CONTROL within {timeout:.3f} s "
                              f"(heartbeat axis_state {_state_name(self.axis_state)})", code=self._fault)
        self._expect_closed_loop = True

    def _wait_for(self, cmd: int, deadline: float) -> None:
        while True:
            remaining = deadline - self._waits.monotonic()
            msg = self._recv(remaining) if remaining > 0 else self._recv(0.0)
            if msg is None:
                raise DeviceTimeout(f"ODrive node {self.node_id}: no answer to cmd 0x{cmd:02X} in time")
            if self._handle(msg) == cmd:
                return

    # -- commands -----------------------------------------------------------------------------
    def set_axis_state(self, state: int, timeout: float = 0.1) -> None:
        """Set_Axis_State (0x07). Requesting any state but CLOSED_LOOP_CONTROL ends the closed-loop
        check of :meth:`read` (call :meth:`confirm_closed_loop` after re-arming)."""
        if int(state) != AxisState.CLOSED_LOOP_CONTROL:
            self._expect_closed_loop = False
        self._send(CMD_SET_AXIS_STATE, encode_u32(int(state)), timeout=timeout)

    def set_controller_mode(self, control_mode: int, input_mode: int, timeout: float = 0.1) -> None:
        data = encode_controller_mode(int(control_mode), int(input_mode))
        self._send(CMD_SET_CONTROLLER_MODE, data, timeout=timeout)

    def set_input_torque(self, motor_torque: float, timeout: float = 0.1) -> None:
        """Raw Set_Input_Torque in motor N.m (no gear/scale conversion), 8 data bytes as both DBCs define."""
        self._send(CMD_SET_INPUT_TORQUE, encode_input_torque(float(motor_torque)), timeout=timeout)

    def estop(self, timeout: float = 0.1) -> None:
        """Send Estop (0x02): the drive disarms and latches ESTOP_REQUESTED."""
        self._send(CMD_ESTOP, b"", timeout=timeout)

    def clear_errors(self, timeout: float = 0.1) -> None:
        """Clear_Errors (0x18): an ``identify`` byte (0) on firmware 0.6, no payload on 0.5.x."""
        self._send(CMD_CLEAR_ERRORS, b"\x00" if self.firmware == "0.6" else b"", timeout=timeout)
        self._fault = 0

    def _send_effort(self, effort: np.ndarray, timeout: float) -> None:
        """Joint effort (N.m rotary / N linear), converted to motor torque (see module doc)."""
        self.set_input_torque(self.joint_effort_to_motor_torque(float(effort[0])), timeout=timeout)

    # -- feedback -----------------------------------------------------------------------------
    def _read_sample(self, timeout: float) -> JointSample:
        """Newest encoder estimate as a JointSample (rad, rad/s or m, m/s); see "Freshness" in the
        module docstring for what a read without a new frame returns.

        Raises DeviceTimeout when no estimate arrives in ``timeout`` (poll mode, or the first read
        in cyclic mode) and DeviceFault when the latest heartbeat carries a non-zero axis_error.
        """
        if self.feedback == "poll" and timeout == 0.0:
            self._poll_ahead()
        elif self.feedback == "poll":
            self._poll(timeout)
        else:
            self._drain()
            if self._estimate is None:
                wait_until = self._waits.monotonic() + timeout
                if self._last is not None:  # wait only until the newest estimate is `timeout` old
                    wait_until = min(wait_until, self._last_rx_wall + timeout)
                with contextlib.suppress(DeviceTimeout):
                    self._wait_for(CMD_GET_ENCODER_ESTIMATES, wait_until)
                self._drain()
        self._raise_if_fault()
        est = self._estimate
        if est is None:
            return self._stale(self._last, self.clock(),
                               f"ODrive node {self.node_id}: no encoder estimate within {timeout:.3f} s")
        self._estimate = None
        effort = None
        if self._torques is not None:
            effort = np.array([self._motor_torque_to_joint(self._torques[1])])
        self._last = JointSample(
            t=self.clock(),
            seq=self._next_seq(),
            position=np.array([self._turns_to_joint(est[0])]),
            velocity=np.array([self._turns_to_joint(est[1])]),
            effort=effort,
            fault=self._fault,
            produced_at=est[2],
        )
        return self._last

    def _poll_ahead(self) -> None:
        """A non-blocking poll (``timeout`` 0, the realtime loop): take the answer to the request
        sent by the previous read if it has arrived (otherwise the read is stale), then send the
        next request, answered while the loop waits for its next tick. The first one after a
        blocking read (no request outstanding) polls once with the adapter's ``timeout``."""
        if not self._ahead:
            self._poll(self.timeout)
        else:
            self._drain()
        self._raise_if_fault()
        self._ahead = True
        self._send(CMD_GET_ENCODER_ESTIMATES, remote=True, timeout=POLL_AHEAD_SEND_TIMEOUT_S)
        if self.read_torque:
            self._send(CMD_GET_TORQUES, remote=True, timeout=POLL_AHEAD_SEND_TIMEOUT_S)

    def _poll(self, timeout: float) -> None:
        """Request the estimate (and torques) with RTR frames; resend up to ``retries`` times within
        ``timeout``; DeviceTimeout if no answer."""
        deadline = self._waits.monotonic() + timeout
        self._ahead = False  # a request sent ahead (non-blocking poll) is answered here, as a stale one
        self._drain()
        if self._estimate is not None:
            self.stale_discarded += 1
            self._estimate = None
        self._raise_if_fault()
        attempts = 1 + self.retries
        for k in range(attempts):
            self._send(CMD_GET_ENCODER_ESTIMATES, remote=True, timeout=timeout)
            until = self._waits.monotonic() + (deadline - self._waits.monotonic()) / (attempts - k)
            try:
                self._wait_for(CMD_GET_ENCODER_ESTIMATES, until)
                break
            except DeviceTimeout:
                if k == attempts - 1:
                    self._timeouts += 1
                    raise DeviceTimeout(f"ODrive node {self.node_id}: no answer to Get_Encoder_Estimates "
                                        f"within {timeout:.3f} s ({attempts} requests)") from None
                self._retried += 1
        if self.read_torque:
            self._torques = None
            self._send(CMD_GET_TORQUES, remote=True, timeout=timeout)
            try:
                self._wait_for(CMD_GET_TORQUES, max(deadline, self._waits.monotonic()))
            except DeviceTimeout:
                self._timeouts += 1
                raise

    def _stop_steps(self) -> tuple[StopStep, ...]:
        """Safe stop: zero torque, then request IDLE (the closed-loop check of :meth:`read` ends)."""
        return (lambda: setattr(self, "_expect_closed_loop", False),
                lambda: self.set_input_torque(0.0, 0.05),
                lambda: self.set_axis_state(AxisState.IDLE, 0.05))

    def _armed(self) -> bool:
        return bool(self._enable)


__all__ = [
    "CMD_ESTOP",
    "CMD_GET_ENCODER_ESTIMATES",
    "CMD_GET_TORQUES",
    "CMD_GET_VERSION",
    "CMD_HEARTBEAT",
    "CMD_RX_SDO",
    "CMD_SET_AXIS_STATE",
    "CMD_SET_CONTROLLER_MODE",
    "CMD_SET_INPUT_TORQUE",
    "CMD_TX_SDO",
    "AxisState",
    "ControlMode",
    "InputMode",
    "ODriveCAN",
    "arbitration_id",
    "split_id",
]


#: the wire-format names (:mod:`hil.protocols.codecs`) stay importable from this module
__getattr__ = forwarder(_wire, __name__)
