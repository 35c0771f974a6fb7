"""Simulated ODrive axis speaking CANSimple, firmware 0.6 or 0.5.x, on a python-can bus.

A :class:`hil.mocks.can_devices.SimCanNode` (lockstep ``tick``, synchronous replies, free running,
fault injection on every frame it sends). What it sends follows ODrive's own CAN databases
(``odrive-cansimple-0.6.10.dbc``, ``odrive-cansimple-0.5.6.dbc``) and firmware
(``Firmware/communication/can/can_simple.cpp`` of the 0.5 branch; the 0.6 "CAN Protocol" docs):

* **Every Get_* message of the line** is answered to an RTR request (or an empty data frame):
  0.6: Get_Version, Heartbeat, Get_Error, Get_Encoder_Estimates, Get_Iq, Get_Temperature,
  Get_Bus_Voltage_Current, Get_Torques, Get_Powers (and Address); 0.5.x: Heartbeat,
  Get_Motor_Error, Get_Encoder_Error, Get_Sensorless_Error, Get_Encoder_Estimates,
  Get_Encoder_Count, Get_Iq, Get_Sensorless_Estimates, Get_Bus_Voltage_Current,
  Get_Controller_Error, and Get_ADC_Voltage to a *data* frame carrying the GPIO number (the firmware
  reads byte 0 and answers 8 bytes). Every answer has the DBC's 8 bytes. A 0.5.x drive has no
  Get_Version (id 0 is the CANopen NMT command there): it does not answer it.
* **Cyclic messages** at the factory periods of the DBC (``GenMsgCycleTime``): 0.6: Heartbeat
  100 ms, Get_Encoder_Estimates 10 ms, Get_Version 100 ms; 0.5.x: Heartbeat 100 ms,
  Get_Encoder_Estimates 10 ms (``axis.config.can.heartbeat_rate_ms`` / ``encoder_rate_ms``).
  A bench sets them (``cyclic_ms`` by message name, or ``heartbeat_every`` / ``encoder_every`` in
  ticks); on 0.6 the host sets them over CAN too, as RxSdo writes of the
  ``axis.config.can.*_msg_rate_ms`` endpoints (:data:`RATE_SETTINGS`; uint32 ms, 0 = off) at the
  simulator's own endpoint ids (:data:`SIM_ENDPOINTS`; a real drive's come from its
  ``flat_endpoints.json``); an RxSdo read is answered with TxSdo.
* **Axis errors of the line** (:data:`hil.protocols.codecs.odrive.AXIS_ERRORS`): Estop latches
  ESTOP_REQUESTED (0.6: 0x02000000, 0.5: 0x4000), a watchdog expiry WATCHDOG_TIMER_EXPIRED (0.6:
  0x01000000, 0.5: 0x800). Injected error codes are OR-ed into ``axis_error`` and disarm the axis
  while active; the error that disarmed the axis is the ``disarm_reason`` of Get_Error (0.6).
* **Torque**: applied only in CLOSED_LOOP_CONTROL with TORQUE_CONTROL and no axis error; the motor
  torque ``input_torque`` (N.m) becomes joint effort through ``gear_ratio`` / ``linear_scale``
  (which must match the adapter's).
* **Watchdog** (``axis.config.enable_watchdog`` = False, ``watchdog_timeout`` = 0 by default):
  ``watchdog_ticks`` = 0 means off. When on, every CAN message addressed to the node feeds it
  (``can_simple.cpp`` calls ``axis.watchdog_feed()`` before dispatching); when nothing arrives for
  ``watchdog_ticks`` ticks in CLOSED_LOOP_CONTROL the axis latches WATCHDOG_TIMER_EXPIRED and drops
  to IDLE with zero torque (``axis.cpp``); Clear_Errors clears it. On 0.6 the host arms it with
  RxSdo writes of ``watchdog_timeout`` (float32 s) and ``enable_watchdog`` (0/1); 0.5.x has no
  RxSdo (set over USB: constructor parameters).

Telemetry (a lossless drive; motor-side quantities, ``omega`` = motor velocity in rad/s, ``tau``
= applied motor torque): Iq measured = ``tau / torque_constant`` (A), Iq setpoint = ``input_torque
/ torque_constant`` when armed, mechanical power = electrical power = ``tau * omega`` (W), bus
current = power / ``bus_voltage`` (A), temperatures ``fet_temperature`` / ``motor_temperature``
(degC), encoder count ``round(turns * encoder_cpr)`` (0.5.x), motor, encoder, sensorless and
controller errors 0 (0.5.x), ADC voltage ``adc_voltage`` for every GPIO (0.5.x).
"""

from __future__ import annotations

import logging
import math
import struct
from collections import deque
from collections.abc import Callable, Mapping
from typing import Any

import can
import numpy as np

from hil.mocks.can_devices import LOG_LEN, SimCanNode
from hil.mocks.interfaces import SimulatedJoints
from hil.protocols.codecs import odrive as od

logger = logging.getLogger(__name__)

AXIS_ERROR_WATCHDOG_TIMER_EXPIRED = od.AXIS_ERROR_WATCHDOG_TIMER_EXPIRED

#: RxSdo endpoint ids the simulated ODrive answers (a real drive's ids come from its firmware's
#: flat_endpoints.json; these are the simulator's own): watchdog and cyclic message rates
SIM_ENDPOINTS: dict[str, int] = {
    "watchdog_timeout": 0x0101, "enable_watchdog": 0x0102,
    "version_msg_rate_ms": 0x0110, "heartbeat_msg_rate_ms": 0x0111, "encoder_msg_rate_ms": 0x0112,
    "iq_msg_rate_ms": 0x0113, "error_msg_rate_ms": 0x0114, "temperature_msg_rate_ms": 0x0115,
    "bus_voltage_msg_rate_ms": 0x0116, "torques_msg_rate_ms": 0x0117, "powers_msg_rate_ms": 0x0118,
}
#: the watchdog's two endpoints (what the adapter's ``watchdog_endpoints`` names)
SIM_WATCHDOG_ENDPOINTS = {k: SIM_ENDPOINTS[k] for k in ("watchdog_timeout", "enable_watchdog")}
#: firmware 0.6 ``axis.config.can`` rate settings -> the message each one times
RATE_SETTINGS: dict[str, str] = {
    "version_msg_rate_ms": "Get_Version", "heartbeat_msg_rate_ms": "Heartbeat",
    "encoder_msg_rate_ms": "Get_Encoder_Estimates", "iq_msg_rate_ms": "Get_Iq", "error_msg_rate_ms": "Get_Error",
    "temperature_msg_rate_ms": "Get_Temperature", "bus_voltage_msg_rate_ms": "Get_Bus_Voltage_Current",
    "torques_msg_rate_ms": "Get_Torques", "powers_msg_rate_ms": "Get_Powers",
}
#: factory cyclic messages (ms) by line: ODrive's DBCs, GenMsgCycleTime
FACTORY_CYCLIC_MS: dict[str, dict[str, int]] = {
    "0.6": {"Heartbeat": 100, "Get_Encoder_Estimates": 10, "Get_Version": 100},
    "0.5": {"Heartbeat": 100, "Get_Encoder_Estimates": 10},
}


class SimODrive(SimCanNode):
    """Simulated ODrive axis (see the module docstring) attached to ``joints``.

    Parameters: ``node_id`` 0..63; ``gear_ratio`` / ``linear_scale`` as the adapter's; ``firmware``
    ``"0.6"`` or ``"0.5"`` (``firmware_version``: what Get_Version reports, default 0.6.10);
    ``cyclic_ms``: message name -> period (ms, 0 = off) over the factory ones; ``heartbeat_every`` /
    ``encoder_every``: the same in ticks (``None``: as ``cyclic_ms`` / factory); ``dt`` seconds per
    tick; ``watchdog_ticks`` / ``watchdog_endpoints`` (see the module docstring); telemetry:
    ``bus_voltage`` (V), ``torque_constant`` (N.m/A), ``fet_temperature`` / ``motor_temperature``
    (degC), ``encoder_cpr``, ``adc_voltage`` (V), ``serial_number``; other keywords go to
    :class:`~hil.mocks.can_devices.SimCanNode`.
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
        encoder_every: int | None = None,
        cyclic_ms: Mapping[str, int] | None = None,
        watchdog_ticks: int = 0,
        dt: float = 0.001,
        watchdog_endpoints: dict[str, int] | None = None,
        firmware: str = "0.6",
        firmware_version: tuple[int, int, int] | None = None,
        adc_voltage: float = 0.0,
        bus_voltage: float = 24.0,
        torque_constant: float = 8.27 / 270.0,
        fet_temperature: float = 35.0,
        motor_temperature: float = 30.0,
        encoder_cpr: int = 8192,
        serial_number: int = 0x3942_3430_3433,
        **kw: Any,
    ) -> None:
        if firmware not in od.FIRMWARES:
            raise ValueError(f"firmware must be one of {list(od.FIRMWARES)}, got {firmware!r}")
        self.node_id = node_id
        self.firmware = firmware
        #: the version a 0.6 drive reports in Get_Version (a 0.5.x drive has no such message)
        self.firmware_version = tuple(firmware_version or ((0, 6, 10) if firmware == "0.6" else (0, 5, 6)))
        self.adc_voltage = float(adc_voltage)
        self.bus_voltage = float(bus_voltage)
        self.torque_constant = float(torque_constant)
        self.fet_temperature, self.motor_temperature = float(fet_temperature), float(motor_temperature)
        self.encoder_cpr = int(encoder_cpr)
        self.serial_number = int(serial_number)
        self.estop_bit = od.axis_error_bit("ESTOP_REQUESTED", firmware)
        self.watchdog_bit = od.axis_error_bit("WATCHDOG_TIMER_EXPIRED", firmware)
        self.watchdog_ticks = int(watchdog_ticks)
        self._last_torque_tick = 0
        self.gear_ratio = gear_ratio
        self.linear_scale = linear_scale
        self.dt = float(dt)
        self.axis_state = int(od.AxisState.IDLE)
        self.control_mode = int(od.ControlMode.VOLTAGE_CONTROL)
        self.input_mode = int(od.InputMode.INACTIVE)
        self.input_torque = 0.0  # motor N.m
        self.latched_error = 0
        self.disarm_reason = 0
        self.commands: deque[tuple[int, float]] = deque(maxlen=LOG_LEN)  # newest (tick, motor torque)
        self.endpoints = {**SIM_ENDPOINTS, **(watchdog_endpoints or {})}
        self._endpoint_names = {v: k for k, v in self.endpoints.items()}
        self.watchdog_enabled = watchdog_ticks > 0  # off by default (as shipped), or armed over RxSdo
        self.watchdog_expired = 0  # times the drive's own watchdog idled the axis
        self.watchdog_configured = False  # set by an RxSdo write from the host
        self.get_messages = od.GET_MESSAGES[firmware]
        self._cmd_of = {name: cmd for cmd, name in self.get_messages.items()}
        self._getters: dict[int, Callable[[], bytes]] = self._payloads()
        #: cyclic message id -> period in ticks (0 = off)
        self.periods: dict[int, int] = {}
        for name, ms in {**FACTORY_CYCLIC_MS[firmware], **(cyclic_ms or {})}.items():
            self.set_rate(name, ms)
        if heartbeat_every is not None:
            self.heartbeat_every = int(heartbeat_every)
        if encoder_every is not None:
            self.encoder_every = int(encoder_every)
        super().__init__(joints, channel, interface, **kw)

    # -- cyclic rates -----------------------------------------------------------------------------
    def set_rate(self, message: str, ms: float) -> None:
        """Period (ms, 0 = off) of cyclic ``message`` (a Get_* name of this line, or Heartbeat),
        in whole ticks (at least one)."""
        if message not in self._cmd_of:
            raise ValueError(f"firmware {self.firmware} has no message {message!r} "
                             f"(it has {', '.join(sorted(self._cmd_of))})")
        self.periods[self._cmd_of[message]] = 0 if ms <= 0 else max(1, round(ms / 1000.0 / self.dt))

    @property
    def heartbeat_every(self) -> int:
        """Heartbeat period in ticks (0 = off)."""
        return self.periods.get(od.CMD_HEARTBEAT, 0)

    @heartbeat_every.setter
    def heartbeat_every(self, ticks: int) -> None:
        self.periods[od.CMD_HEARTBEAT] = int(ticks)

    @property
    def encoder_every(self) -> int:
        """Get_Encoder_Estimates period in ticks (0 = off)."""
        return self.periods.get(od.CMD_GET_ENCODER_ESTIMATES, 0)

    @encoder_every.setter
    def encoder_every(self, ticks: int) -> None:
        self.periods[od.CMD_GET_ENCODER_ESTIMATES] = int(ticks)

    # -- state and conversions (inverse of the adapter's) -------------------------------------------
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
        uniform = getattr(self.joints, "apply_uniform", None)  # a bench's SimPoint: no array per tick
        if uniform is not None:
            uniform(effort)
        else:
            self.joints.apply_effort(np.full(self.joints.dof, effort))

    def _disarm(self, reason: int) -> None:
        if self.axis_state != od.AxisState.IDLE:
            self.disarm_reason = reason
        self.axis_state = int(od.AxisState.IDLE)

    def _turns(self) -> tuple[float, float]:
        """(position, velocity) of the motor in turns and turns/s."""
        return (self._joint_to_turns(float(self.joints.position()[0])),
                self._joint_to_turns(float(self.joints.velocity()[0])))

    # -- payloads of the Get_* messages ----------------------------------------------------------
    def _payloads(self) -> dict[int, Callable[[], bytes]]:
        """cmd -> payload of each Get_* message of the line (module docstring)."""
        kt = self.torque_constant

        def power() -> float:
            return self.applied_motor_torque() * 2.0 * math.pi * self._turns()[1]

        common: dict[int, Callable[[], bytes]] = {
            od.CMD_HEARTBEAT: lambda: od.encode_heartbeat(self.axis_error, self.axis_state),
            od.CMD_GET_ENCODER_ESTIMATES: lambda: od.encode_f32x2(*self._turns()),
            od.CMD_GET_IQ: lambda: od.encode_f32x2(self.input_torque / kt if self._armed() else 0.0,
                                                   self.applied_motor_torque() / kt),
            od.CMD_GET_BUS_VOLTAGE_CURRENT: lambda: od.encode_f32x2(self.bus_voltage, power() / self.bus_voltage),
        }
        if self.firmware == "0.6":
            fw = self.firmware_version
            return {**common,
                    od.CMD_GET_VERSION: lambda: od.encode_version(2, (4, 4, 58), (fw[0], fw[1], fw[2])),
                    od.CMD_GET_ERROR: lambda: od.encode_u32x2(self.axis_error, self.disarm_reason),
                    od.CMD_GET_TEMPERATURE: lambda: od.encode_f32x2(self.fet_temperature, self.motor_temperature),
                    od.CMD_GET_TORQUES: lambda: od.encode_f32x2(self.input_torque, self.applied_motor_torque()),
                    od.CMD_GET_POWERS: lambda: od.encode_f32x2(power(), power()),
                    od.CMD_ADDRESS: lambda: od.encode_address(self.node_id, self.serial_number)}
        zero = od.pad(b"")
        return {**common,
                od.CMD_GET_MOTOR_ERROR_05: lambda: zero, od.CMD_GET_ENCODER_ERROR_05: lambda: zero,
                od.CMD_GET_SENSORLESS_ERROR_05: lambda: zero, od.CMD_GET_CONTROLLER_ERROR_05: lambda: zero,
                od.CMD_GET_ENCODER_COUNT_05: self._encoder_count,
                od.CMD_GET_SENSORLESS_ESTIMATES_05: lambda: od.encode_f32x2(*self._turns())}

    def _encoder_count(self) -> bytes:
        shadow = round(self._turns()[0] * self.encoder_cpr)
        shadow = ((shadow + (1 << 31)) % (1 << 32)) - (1 << 31)
        return od.encode_i32x2(shadow, shadow % self.encoder_cpr)

    def _reply(self, cmd: int, data: bytes) -> None:
        self.send(od.arbitration_id(self.node_id, cmd), data)

    def _send_message(self, cmd: int) -> None:
        if cmd == od.CMD_GET_ENCODER_ESTIMATES:
            self._reply_estimate()
        else:
            self._reply(cmd, self._getters[cmd]())

    def publish_estimate(self) -> None:
        """Send one Get_Encoder_Estimates frame now (the first cyclic frame of a lockstep bench)."""
        with self._lock:
            self._reply_estimate()

    def _reply_estimate(self) -> None:
        # a stale estimator has no new estimate: no frame at all (heartbeats go on)
        self.send(od.arbitration_id(self.node_id, od.CMD_GET_ENCODER_ESTIMATES), od.encode_f32x2(*self._turns()),
                  stale="suppress")

    # -- host frames ---------------------------------------------------------------------------------
    def _sdo(self, data: bytes) -> None:
        op, ep, value = od.decode_sdo(data)
        name = self._endpoint_names.get(ep)
        if name is None:
            return
        if op == od.SDO_READ:
            if name == "watchdog_timeout":
                raw = od.encode_f32(self.watchdog_ticks * self.dt)
            elif name == "enable_watchdog":
                raw = bytes([int(self.watchdog_enabled)])
            else:
                ticks = self.periods.get(self._cmd_of[RATE_SETTINGS[name]], 0)
                raw = od.encode_u32(round(ticks * self.dt * 1000.0))
            self._reply(od.CMD_TX_SDO, od.encode_tx_sdo(ep, raw))
            return
        if op != od.SDO_WRITE:
            return
        if name == "watchdog_timeout" and len(value) >= 4:
            timeout_s = struct.unpack_from("<f", value)[0]
            self.watchdog_ticks = max(1, math.ceil(timeout_s / self.dt * (1 - 1e-6)))  # float32 on the wire
            self.watchdog_configured = True
        elif name == "enable_watchdog":
            self.watchdog_enabled = bool(value[0])
            self.watchdog_configured = True
            self._last_torque_tick = self.tick_count
        elif name in RATE_SETTINGS and len(value) >= 4:
            self.set_rate(RATE_SETTINGS[name], struct.unpack_from("<I", value)[0])

    def handle(self, msg: can.Message) -> None:
        if msg.is_extended_id or msg.is_error_frame:
            return
        node, cmd = od.split_id(msg.arbitration_id)
        if node != self.node_id:
            return
        data = bytes(msg.data)
        is_request = msg.is_remote_frame or len(data) == 0
        self._last_torque_tick = self.tick_count  # can_simple.cpp: every message of the node feeds the watchdog
        if self.firmware == "0.5" and cmd == od.CMD_GET_ADC_VOLTAGE_05:
            # can_simple.cpp (0.5): byte 0 is the GPIO number, whatever the frame; the answer is 8 bytes
            self._reply(cmd, od.pad(od.encode_f32(self.adc_voltage)))
        elif is_request and cmd in self._getters:
            self._send_message(cmd)
        elif cmd == od.CMD_SET_INPUT_TORQUE and len(data) >= 4:
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
            self.latched_error |= self.estop_bit
            self._disarm(self.estop_bit)
            self._apply()
        elif cmd == od.CMD_CLEAR_ERRORS:
            self.latched_error = 0
            self.disarm_reason = 0
        elif cmd == od.CMD_RX_SDO and self.firmware == "0.6" and len(data) >= 4:
            self._sdo(data)

    def on_tick(self) -> None:
        if self.axis_error and self.axis_state != od.AxisState.IDLE:
            self._disarm(self.axis_error)  # a fault disarms the axis
        if (self.watchdog_enabled and self.watchdog_ticks and self.axis_state == od.AxisState.CLOSED_LOOP_CONTROL
                and self.tick_count - self._last_torque_tick > self.watchdog_ticks):
            logger.warning("odrive node %d: CAN watchdog expired: WATCHDOG_TIMER_EXPIRED, axis idle", self.node_id)
            self.input_torque = 0.0
            self.latched_error |= self.watchdog_bit
            self._disarm(self.watchdog_bit)  # the drive's own watchdog (axis.cpp)
            self.watchdog_expired += 1
        self._apply()
        t = self.tick_count
        for cmd, every in self.periods.items():
            if every and t % every == 0:
                self._send_message(cmd)


__all__ = ["FACTORY_CYCLIC_MS", "RATE_SETTINGS", "SIM_ENDPOINTS", "SIM_WATCHDOG_ENDPOINTS", "SimODrive"]
