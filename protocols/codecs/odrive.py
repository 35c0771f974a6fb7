"""ODrive CANSimple wire format: command ids, axis states and errors, frame payload codecs (pure; no
CAN library). See :mod:`hil.protocols.can_odrive` for the protocol description and sources.

Two firmware lines speak different tables (ODrive's CAN databases ``odrive-cansimple-0.5.6.dbc`` and
``odrive-cansimple-0.6.10.dbc``; firmware sources ``Firmware/communication/can/can_simple.cpp`` of
the 0.5 branch): the same command id means different messages (0x03 Get_Motor_Error on 0.5.x,
Get_Error on 0.6; 0x1C Get_ADC_Voltage / Get_Torques; ...) and the axis error bits differ
(:data:`AXIS_ERRORS`). Every frame is sent with the data length its DBC gives (:data:`DLC`)."""

from __future__ import annotations

import struct
from enum import IntEnum

from hil.errors import ProtocolError

# -- command ids ----------------------------------------------------------------------------
CMD_GET_VERSION = 0x00  # firmware 0.6; on 0.5.x id 0 is the (ignored) CANopen NMT command
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
CMD_GET_ERROR = 0x03  # firmware 0.6 (Active_Errors, Disarm_Reason); 0.5.x: Get_Motor_Error
CMD_ADDRESS = 0x06  # firmware 0.6 (Node_ID, Serial_Number); 0.5.x: Set_Axis_Node_ID
CMD_GET_IQ = 0x14
CMD_GET_TEMPERATURE = 0x15  # firmware 0.6; 0.5.x: Get_Sensorless_Estimates
CMD_GET_BUS_VOLTAGE_CURRENT = 0x17
CMD_GET_POWERS = 0x1D  # firmware 0.6; 0.5.x: Get_Controller_Error
CMD_GET_MOTOR_ERROR_05 = 0x03
CMD_GET_ENCODER_ERROR_05 = 0x04
CMD_GET_SENSORLESS_ERROR_05 = 0x05
CMD_GET_ENCODER_COUNT_05 = 0x0A
CMD_GET_SENSORLESS_ESTIMATES_05 = 0x15
CMD_GET_CONTROLLER_ERROR_05 = 0x1D

#: The messages a drive sends (cyclic or on request), by firmware line: cmd id -> DBC name (ODrive's
#: odrive-cansimple-0.5.6.dbc / -0.6.10.dbc; Heartbeat is cyclic only)
GET_MESSAGES: dict[str, dict[int, str]] = {
    "0.6": {0x00: "Get_Version", 0x01: "Heartbeat", 0x03: "Get_Error", 0x09: "Get_Encoder_Estimates",
            0x14: "Get_Iq", 0x15: "Get_Temperature", 0x17: "Get_Bus_Voltage_Current", 0x1C: "Get_Torques",
            0x1D: "Get_Powers"},
    "0.5": {0x01: "Heartbeat", 0x03: "Get_Motor_Error", 0x04: "Get_Encoder_Error", 0x05: "Get_Sensorless_Error",
            0x09: "Get_Encoder_Estimates", 0x0A: "Get_Encoder_Count", 0x14: "Get_Iq",
            0x15: "Get_Sensorless_Estimates", 0x17: "Get_Bus_Voltage_Current", 0x1C: "Get_ADC_Voltage",
            0x1D: "Get_Controller_Error"},
}
#: Data length (bytes) of the host's commands, by firmware line, as the DBCs define them (0 for the
#: empty ones; 8 where a 4-byte signal sits in an 8-byte frame, e.g. Set_Input_Torque)
DLC: dict[str, dict[int, int]] = {
    "0.6": {0x02: 0, 0x04: 8, 0x06: 8, 0x07: 8, 0x0B: 8, 0x0C: 8, 0x0D: 8, 0x0E: 8, 0x0F: 8, 0x11: 8, 0x12: 8,
            0x13: 8, 0x16: 1, 0x18: 1, 0x19: 8, 0x1A: 8, 0x1B: 8, 0x1F: 0},
    "0.5": {0x06: 8, 0x07: 8, 0x0B: 8, 0x0C: 8, 0x0D: 8, 0x0E: 8, 0x0F: 8, 0x10: 0, 0x11: 8, 0x12: 8, 0x13: 8,
            0x16: 0, 0x18: 0, 0x19: 8, 0x1A: 8, 0x1B: 8},
}

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
#: firmware 0.6 axis_error bits (odrive-cansimple-0.6.10.dbc, Axis_Error)
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
#: firmware 0.5.x axis_error bits (odrive-cansimple-0.5.6.dbc, Axis_Error; ``Axis::Error`` of 0.5.6)
AXIS_ERROR_NAMES_05 = {
    0x1: "INVALID_STATE",
    0x40: "MOTOR_FAILED",
    0x80: "SENSORLESS_ESTIMATOR_FAILED",
    0x100: "ENCODER_FAILED",
    0x200: "CONTROLLER_FAILED",
    0x800: "WATCHDOG_TIMER_EXPIRED",
    0x1000: "MIN_ENDSTOP_PRESSED",
    0x2000: "MAX_ENDSTOP_PRESSED",
    0x4000: "ESTOP_REQUESTED",
    0x20000: "HOMING_WITHOUT_ENDSTOP",
    0x40000: "OVER_TEMP",
    0x80000: "UNKNOWN_POSITION",
}
#: axis_error names by firmware line
AXIS_ERRORS: dict[str, dict[int, str]] = {"0.6": AXIS_ERROR_NAMES, "0.5": AXIS_ERROR_NAMES_05}


def axis_error_bit(name: str, firmware: str = "0.6") -> int:
    """The axis_error bit called ``name`` in ``firmware``'s table (KeyError if it has none)."""
    for bit, n in AXIS_ERRORS[firmware].items():
        if n == name:
            return bit
    raise KeyError(f"firmware {firmware} has no axis error {name!r}")


def _state_name(state: int | None) -> str:
    try:
        return AxisState(int(state)).name  # type: ignore[arg-type]
    except (ValueError, TypeError):
        return str(state)


def describe_axis_error(code: int, firmware: str = "0.6") -> str:
    """``A|B|0x..`` names of the bits of ``code`` in ``firmware``'s axis_error table (unknown bits in hex)."""
    table = AXIS_ERRORS[firmware]
    names = [n for bit, n in table.items() if code & bit]
    unknown = code & ~sum(table)
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


def pad(data: bytes, length: int = 8) -> bytes:
    """``data`` zero-padded to ``length`` bytes (the DBC's frame length)."""
    return bytes(data).ljust(length, b"\0")


def encode_input_torque(tau: float) -> bytes:
    """Set_Input_Torque payload: float32 N.m in an 8-byte frame (both DBCs: length 8)."""
    return pad(struct.pack("<f", tau))


def encode_version(protocol: int, hw: tuple[int, int, int], fw: tuple[int, int, int], unreleased: int = 0) -> bytes:
    """Get_Version payload (firmware 0.6): protocol version, hardware major/minor/variant, firmware
    major/minor/revision, unreleased flag, one byte each."""
    return bytes([protocol, *hw, *fw, unreleased])


def decode_version(data: bytes | bytearray) -> tuple[int, tuple[int, int, int], tuple[int, int, int], int]:
    """(protocol version, hardware (major, minor, variant), firmware (major, minor, revision),
    unreleased) of a Get_Version payload."""
    if len(data) < 8:
        raise ProtocolError(f"Get_Version needs 8 bytes, got {len(data)}")
    b = bytes(data)
    return b[0], (b[1], b[2], b[3]), (b[4], b[5], b[6]), b[7]


def firmware_line(fw: tuple[int, int, int] | None) -> str:
    """``"0.6"`` for firmware 0.6 and later, else ``"0.5"``; ``None`` (no Get_Version answer: the
    message exists from 0.6 on) is ``"0.5"``."""
    return "0.6" if fw is not None and (fw[0], fw[1]) >= (0, 6) else "0.5"


def encode_f32x2(a: float, b: float) -> bytes:
    return struct.pack("<ff", a, b)


def decode_f32x2(data: bytes | bytearray) -> tuple[float, float]:
    if len(data) < 8:
        raise ProtocolError(f"expected 8 data bytes, got {len(data)}")
    a, b = struct.unpack_from("<ff", bytes(data))
    return a, b


def encode_u32(x: int) -> bytes:
    return struct.pack("<I", x)


def encode_u32x2(a: int, b: int) -> bytes:
    """Two uint32 (Get_Error: active errors, disarm reason)."""
    return struct.pack("<II", a & 0xFFFFFFFF, b & 0xFFFFFFFF)


def encode_i32x2(a: int, b: int) -> bytes:
    """Two int32 (0.5.x Get_Encoder_Count: shadow count, count in CPR)."""
    return struct.pack("<ii", a, b)


def encode_address(node_id: int, serial_number: int) -> bytes:
    """Address payload (firmware 0.6): node id u8, 48-bit serial number, one reserved byte."""
    return bytes([node_id & 0xFF]) + (serial_number & 0xFFFFFFFFFFFF).to_bytes(6, "little") + b"\0"


SDO_READ = 0
SDO_WRITE = 1


def encode_sdo_read(endpoint_id: int) -> bytes:
    """RxSdo (0x04) payload reading ``endpoint_id`` (the drive answers with TxSdo 0x05)."""
    if not 0 <= endpoint_id <= 0xFFFF:
        raise ValueError(f"endpoint id 0..65535 required, got {endpoint_id}")
    return pad(struct.pack("<BHB", SDO_READ, endpoint_id, 0))


def encode_tx_sdo(endpoint_id: int, value: bytes) -> bytes:
    """TxSdo (0x05) payload: reserved u8, endpoint id u16, reserved u8, value (up to 4 bytes)."""
    return pad(struct.pack("<BHB", 0, endpoint_id, 0) + bytes(value)[:4])


def encode_sdo_write(endpoint_id: int, value: bytes) -> bytes:
    """RxSdo (0x04) payload writing ``value`` (1..4 bytes, little endian) to ``endpoint_id``."""
    if not 0 <= endpoint_id <= 0xFFFF or not 1 <= len(value) <= 4:
        raise ValueError(f"endpoint id 0..65535 and 1..4 value bytes required, got {endpoint_id}, {len(value)}")
    return pad(struct.pack("<BHB", SDO_WRITE, endpoint_id, 0) + bytes(value))


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
