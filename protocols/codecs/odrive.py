"""ODrive CANSimple wire format: command ids, axis states and errors, frame payload codecs (pure; no
CAN library). See :mod:`hil.protocols.can_odrive` for the protocol description and sources."""

from __future__ import annotations

import struct
from enum import IntEnum

from hil.errors import ProtocolError

# -- command ids ----------------------------------------------------------------------------
CMD_HEARTBEAT = 0x01
CMD_ESTOP = 0x02
CMD_RX_SDO = 0x04
CMD_TX_SDO = 0x05
CMD_SET_AXIS_STATE = 0x07
CMD_GET_ENCODER_ESTIMATES = 0x09
CMD_SET_CONTROLLER_MODE = 0x0B
CMD_SET_INPUT_TORQUE = 0x0E
CMD_CLEAR_ERRORS = 0x18
CMD_GET_TORQUES = 0x1C  # firmware 0.6; the same id is Get_ADC_Voltage on 0.5.x
CMD_GET_ADC_VOLTAGE_05 = 0x1C

#: Firmware families with different CANSimple tables (see the module docstring).
FIRMWARES = ("0.6", "0.5")
#: Factory ``config.can.heartbeat_msg_rate_ms`` (100 ms) in seconds.
DEFAULT_HEARTBEAT_S = 0.100
AXIS_ERROR_WATCHDOG_TIMER_EXPIRED = 0x01000000


class AxisState(IntEnum):
    UNDEFINED = 0
    IDLE = 1
    CLOSED_LOOP_CONTROL = 8


class ControlMode(IntEnum):
    VOLTAGE_CONTROL = 0
    TORQUE_CONTROL = 1
    VELOCITY_CONTROL = 2
    POSITION_CONTROL = 3


class InputMode(IntEnum):
    INACTIVE = 0
    PASSTHROUGH = 1


# ODrive Pro / S1 (firmware 0.6) axis_error bits used by the simulator and in messages
AXIS_ERROR_ESTOP_REQUESTED = 0x02000000
AXIS_ERROR_NAMES = {
    0x1: "INITIALIZING",
    0x2: "SYSTEM_LEVEL",
    0x4: "TIMING_ERROR",
    0x8: "MISSING_ESTIMATE",
    0x10: "BAD_CONFIG",
    0x20: "DRV_FAULT",
    0x40: "MISSING_INPUT",
    0x100: "DC_BUS_OVER_VOLTAGE",
    0x200: "DC_BUS_UNDER_VOLTAGE",
    0x400: "DC_BUS_OVER_CURRENT",
    0x800: "DC_BUS_OVER_REGEN_CURRENT",
    0x1000: "CURRENT_LIMIT_VIOLATION",
    0x2000: "MOTOR_OVER_TEMP",
    0x4000: "INVERTER_OVER_TEMP",
    0x8000: "VELOCITY_LIMIT_VIOLATION",
    0x10000: "POSITION_LIMIT_VIOLATION",
    0x1000000: "WATCHDOG_TIMER_EXPIRED",
    0x2000000: "ESTOP_REQUESTED",
    0x4000000: "SPINOUT_DETECTED",
    0x8000000: "BRAKE_RESISTOR_DISARMED",
    0x10000000: "THERMISTOR_DISCONNECTED",
    0x40000000: "CALIBRATION_ERROR",
}


def _state_name(state: int | None) -> str:
    try:
        return AxisState(int(state)).name  # type: ignore[arg-type]
    except (ValueError, TypeError):
        return str(state)


def describe_axis_error(code: int) -> str:
    names = [n for bit, n in AXIS_ERROR_NAMES.items() if code & bit]
    unknown = code & ~sum(AXIS_ERROR_NAMES)
    if unknown:
        names.append(f"0x{unknown:X}")
    return "|".join(names) or "NONE"


# -- pure wire helpers (shared with the simulator) ------------------------------------------
def arbitration_id(node_id: int, cmd_id: int) -> int:
    """CANSimple id: upper 6 bits node id, lower 5 bits command id."""
    if not 0 <= node_id <= 0x3F or not 0 <= cmd_id <= 0x1F:
        raise ValueError(f"node_id 0..63 and cmd_id 0..31 required, got {node_id}, {cmd_id}")
    return (node_id << 5) | cmd_id


def split_id(arb_id: int) -> tuple[int, int]:
    """(node_id, cmd_id) of a CANSimple id."""
    return (arb_id >> 5) & 0x3F, arb_id & 0x1F


def encode_f32(x: float) -> bytes:
    return struct.pack("<f", x)


def encode_f32x2(a: float, b: float) -> bytes:
    return struct.pack("<ff", a, b)


def decode_f32x2(data: bytes | bytearray) -> tuple[float, float]:
    if len(data) < 8:
        raise ProtocolError(f"expected 8 data bytes, got {len(data)}")
    a, b = struct.unpack_from("<ff", bytes(data))
    return a, b


def encode_u32(x: int) -> bytes:
    return struct.pack("<I", x)


SDO_READ = 0
SDO_WRITE = 1


def encode_sdo_write(endpoint_id: int, value: bytes) -> bytes:
    """RxSdo (0x04) payload writing ``value`` (1..4 bytes, little endian) to ``endpoint_id``."""
    if not 0 <= endpoint_id <= 0xFFFF or not 1 <= len(value) <= 4:
        raise ValueError(f"endpoint id 0..65535 and 1..4 value bytes required, got {endpoint_id}, {len(value)}")
    return struct.pack("<BHB", SDO_WRITE, endpoint_id, 0) + bytes(value)


def decode_sdo(data: bytes | bytearray) -> tuple[int, int, bytes]:
    """(opcode, endpoint_id, value bytes) of an RxSdo/TxSdo payload."""
    if len(data) < 4:
        raise ProtocolError(f"SDO needs >= 4 bytes, got {len(data)}")
    op, ep, _ = struct.unpack_from("<BHB", bytes(data))
    return op, ep, bytes(data[4:])


def encode_controller_mode(control_mode: int, input_mode: int) -> bytes:
    return struct.pack("<II", control_mode, input_mode)


def encode_heartbeat(axis_error: int, axis_state: int, procedure: int = 0, traj_done: int = 0) -> bytes:
    return struct.pack("<IBBBx", axis_error, axis_state, procedure, traj_done)


def decode_heartbeat(data: bytes | bytearray) -> tuple[int, int]:
    """(axis_error, axis_state) of a Heartbeat payload (at least 5 bytes)."""
    if len(data) < 5:
        raise ProtocolError(f"heartbeat needs >= 5 bytes, got {len(data)}")
    err, state = struct.unpack_from("<IB", bytes(data))
    return err, state
