"""CubeMars AK "MIT mode" wire format: per-model ranges, special frames, command/reply bit packing
(pure; no CAN library). See :mod:`hil.protocols.can_cubemars` for the protocol and sources."""

from __future__ import annotations

from dataclasses import dataclass

from hil.errors import ProtocolError


@dataclass(frozen=True)
class MitLimits:
    """Mapping ranges of one AK model: P [rad], V [rad/s], T [N.m], KP [N.m/rad], KD [N.m.s/rad]."""

    p_min: float
    p_max: float
    v_min: float
    v_max: float
    t_min: float
    t_max: float
    kp_min: float = 0.0
    kp_max: float = 500.0
    kd_min: float = 0.0
    kd_max: float = 5.0


#: Per-model ranges. P is +-12.5 rad for all, KP 0..500 N.m/rad, KD 0..5 N.m.s/rad. The V and T
#: ranges depend on model *and firmware* (the driver table is compiled into each firmware); the
#: source of each row is in :data:`MODEL_SOURCES`. A motor whose firmware uses other ranges needs
#: ``model=MitLimits(...)`` with its own values (they are printed in CubeMars' upper computer).
MODEL_LIMITS: dict[str, MitLimits] = {
    #            P            V            T
    "AK10-9": MitLimits(-12.5, 12.5, -50.0, 50.0, -65.0, 65.0),
    "AK60-6": MitLimits(-12.5, 12.5, -45.0, 45.0, -15.0, 15.0),
    "AK70-10": MitLimits(-12.5, 12.5, -50.0, 50.0, -25.0, 25.0),
    "AK80-6": MitLimits(-12.5, 12.5, -76.0, 76.0, -12.0, 12.0),
    "AK80-9": MitLimits(-12.5, 12.5, -50.0, 50.0, -18.0, 18.0),
    "AK80-64": MitLimits(-12.5, 12.5, -8.0, 8.0, -144.0, 144.0),
}

_MANUAL = "CubeMars AK Series Module Driver User Manual, 5.3 MIT mode, range table"
_TMCC = "neurobionics/TMotorCANControl mit_can.py MIT_Params"
#: Where each row of :data:`MODEL_LIMITS` comes from.
MODEL_SOURCES: dict[str, str] = {
    "AK10-9": f"{_TMCC} (= {_MANUAL})",
    "AK60-6": f"{_MANUAL}: V +-45 rad/s (TMotorCANControl lists +-50, an older firmware's table)",
    "AK70-10": f"{_TMCC} (= {_MANUAL})",
    "AK80-6": f"{_TMCC} (= {_MANUAL})",
    "AK80-9": f"{_TMCC} (= {_MANUAL})",
    "AK80-64": f"{_TMCC} (= {_MANUAL})",
}

#: Silence of the motor after "set zero" (s, manual: about 1 s while the origin is stored).
ZERO_SILENCE_S = 1.0

#: MIT-mode error codes (byte 7 of the reply).
ERROR_CODES: dict[int, str] = {
    0: "no error",
    1: "over temperature",
    2: "over current",
    3: "over voltage",
    4: "under voltage",
    5: "encoder fault",
    6: "phase current unbalance (hardware may be damaged)",
}

_FF7 = b"\xff" * 7
SPECIAL_FRAMES: dict[str, bytes] = {"enter": _FF7 + b"\xfc", "exit": _FF7 + b"\xfd", "zero": _FF7 + b"\xfe"}
SPECIAL_FRAMES_INV: dict[bytes, str] = {v: k for k, v in SPECIAL_FRAMES.items()}


def model_limits(model: str | MitLimits) -> MitLimits:
    if isinstance(model, MitLimits):
        return model
    try:
        return MODEL_LIMITS[model]
    except KeyError:
        raise ValueError(f"unknown CubeMars model {model!r}; known: {sorted(MODEL_LIMITS)}") from None


def float_to_uint(x: float, x_min: float, x_max: float, bits: int) -> int:
    """Clamp ``x`` to [x_min, x_max] and map it to 0 .. 2**bits - 1 (truncated, like the firmware)."""
    top = (1 << bits) - 1
    x = min(max(float(x), x_min), x_max)
    return min(top, max(0, int((x - x_min) * top / (x_max - x_min))))


def uint_to_float(u: int, x_min: float, x_max: float, bits: int) -> float:
    return u * (x_max - x_min) / ((1 << bits) - 1) + x_min


@dataclass(frozen=True)
class MitCommand:
    p_des: float
    v_des: float
    kp: float
    kd: float
    t_ff: float


@dataclass(frozen=True)
class MitReply:
    motor_id: int
    position: float
    velocity: float
    torque: float
    temperature: int | None = None
    error: int | None = None


def pack_command(c: MitCommand, lim: MitLimits) -> bytes:
    p = float_to_uint(c.p_des, lim.p_min, lim.p_max, 16)
    v = float_to_uint(c.v_des, lim.v_min, lim.v_max, 12)
    kp = float_to_uint(c.kp, lim.kp_min, lim.kp_max, 12)
    kd = float_to_uint(c.kd, lim.kd_min, lim.kd_max, 12)
    t = float_to_uint(c.t_ff, lim.t_min, lim.t_max, 12)
    b3 = ((v & 0xF) << 4) | (kp >> 8)
    b6 = ((kd & 0xF) << 4) | (t >> 8)
    return bytes((p >> 8, p & 0xFF, v >> 4, b3, kp & 0xFF, kd >> 4, b6, t & 0xFF))


def unpack_command(data: bytes, lim: MitLimits) -> MitCommand:
    if len(data) != 8:
        raise ProtocolError(f"MIT command needs 8 bytes, got {len(data)}")
    d = data
    p = (d[0] << 8) | d[1]
    v = (d[2] << 4) | (d[3] >> 4)
    kp = ((d[3] & 0xF) << 8) | d[4]
    kd = (d[5] << 4) | (d[6] >> 4)
    t = ((d[6] & 0xF) << 8) | d[7]
    return MitCommand(
        uint_to_float(p, lim.p_min, lim.p_max, 16),
        uint_to_float(v, lim.v_min, lim.v_max, 12),
        uint_to_float(kp, lim.kp_min, lim.kp_max, 12),
        uint_to_float(kd, lim.kd_min, lim.kd_max, 12),
        uint_to_float(t, lim.t_min, lim.t_max, 12),
    )


def pack_reply(r: MitReply, lim: MitLimits, short: bool = False) -> bytes:
    p = float_to_uint(r.position, lim.p_min, lim.p_max, 16)
    v = float_to_uint(r.velocity, lim.v_min, lim.v_max, 12)
    t = float_to_uint(r.torque, lim.t_min, lim.t_max, 12)
    head = bytes((r.motor_id & 0xFF, p >> 8, p & 0xFF, v >> 4, ((v & 0xF) << 4) | (t >> 8), t & 0xFF))
    if short:
        return head
    return head + bytes(((r.temperature or 0) & 0xFF, (r.error or 0) & 0xFF))


def unpack_reply(data: bytes, lim: MitLimits) -> MitReply:
    if len(data) not in (6, 8):
        raise ProtocolError(f"MIT reply needs 6 or 8 bytes, got {len(data)}")
    d = data
    p = (d[1] << 8) | d[2]
    v = (d[3] << 4) | (d[4] >> 4)
    t = ((d[4] & 0xF) << 8) | d[5]
    temp = d[6] if len(d) == 8 else None
    err = d[7] if len(d) == 8 else None
    return MitReply(
        d[0],
        uint_to_float(p, lim.p_min, lim.p_max, 16),
        uint_to_float(v, lim.v_min, lim.v_max, 12),
        uint_to_float(t, lim.t_min, lim.t_max, 12),
        temp,
        err,
    )
