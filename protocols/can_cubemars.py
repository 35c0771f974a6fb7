"""CubeMars / T-Motor AK series in "MIT mode" over CAN, as an :class:`~hil.protocols.base.Actuator`.

Wire format (sources, consulted through the search tool: CubeMars "AK Series Module Driver User
Manual", section 5.3 *MIT Mode Communication Protocol* as quoted in public drivers; the
``neurobionics/TMotorCANControl`` python driver ``mit_can.py`` for the per-model ranges, the reply
layout and the error codes; the MIT mini-cheetah ``pack_cmd``/``unpack_reply`` convention):

* Host -> motor, standard id = motor id, 8 bytes, big-endian bit packing::

      byte0..1  p_des  16 bit          byte3[3:0]..4  kp  12 bit
      byte2..3  v_des  12 bit (byte3[7:4])   byte5..6   kd  12 bit (byte6[7:4])
                                         byte6[3:0]..7  t_ff 12 bit

  Each field is an unsigned int mapped linearly from ``[min, max]`` of the model
  (``x_uint = (x - min) * (2**bits - 1) / (max - min)``, clamped).
* Special frames: ``FF FF FF FF FF FF FF FC`` enter motor mode, ``... FD`` exit motor mode,
  ``... FE`` set current position as zero. Every frame is answered with a state reply.
* Motor -> host reply (id ``reply_id``, 0x000 on the firmware the sources describe, driver id in
  byte 0)::

      byte0 motor id | byte1..2 position 16 bit | byte3..4[7:4] velocity 12 bit |
      byte4[3:0]..5 torque 12 bit | byte6 temperature [deg C] | byte7 error code

  Older firmware sends 6 bytes (no temperature/error). The 12-bit "current" field is scaled with
  the torque range T and is reported here as effort [N.m]. Error codes: see :data:`ERROR_CODES`.

Conversion: as in the reference C code, :func:`float_to_uint` truncates (so a zero torque is sent
as 0x7FF = -0.0044 N.m on an AK80-9: zero is not representable with an even number of codes).

Units: position rad, velocity rad/s, torque N.m, all at the output shaft (the motor reports output
quantities). Positive torque accelerates towards positive position.

Position range and unwrapping: the 16-bit position field covers ``[p_min, p_max]`` = +-12.5 rad
(4 output turns), and the motor's position *wraps* in that field (it counts modulo the span, it does
not stop at the end: the reply after +12.5 rad reads -12.5 rad). The adapter unwraps it (``unwrap``,
default on): a jump between consecutive replies larger than half the span (12.5 rad; at the
velocity limit of <= 76 rad/s that would take > 160 ms between replies) is taken as one wrap, so
``JointSample.position`` is continuous beyond two output turns. ``command_mit``'s ``p_des`` is in the
motor's own wrapped frame.

Rest mode and set-zero (manual, 5.3 "MIT mode": enter motor mode before control; "set zero" stores
the current position as the origin): the motor ignores control commands until "enter motor mode";
after "set zero" it is silent for about 1 s (it writes the origin to flash) and answers no frame.
:meth:`CubeMarsMIT.set_zero` therefore waits up to ``zero_timeout`` (default 1.5 s) re-sending
"enter motor mode" (idempotent) every 0.1 s until the motor answers again; the unwrap count is
reset there.

Freshness: a reply carries no timestamp or counter; ``JointSample.produced_at`` is the arrival
of the state reply (adapter clock, when it was taken off the bus) and ``seq`` advances with each
new reply. :meth:`CubeMarsMIT.read` uses the reply to the latest command if one arrived since the
previous read, else re-sends the last command to get one; no reply within ``timeout`` raises
DeviceTimeout. A non-blocking read (``timeout`` 0, the realtime loop) that finds no new reply
returns the previous sample again (stale: same ``seq`` and ``produced_at``; the runner's watchdog
judges its age) instead of re-sending. Counters (:meth:`CubeMarsMIT.counters`): ``error_frames`` (CAN error frames: a
destroyed reply), ``decode_errors``, ``skipped`` (replies superseded before a read), ``timeouts``,
and, since every frame but "exit motor mode" is answered exactly once (issue 27): ``dropped``
(blocking reads that found the reply to the command sent since the previous read missing; the
command is sent again), ``late`` (replies arriving when no frame is waiting for one: a reply
given up for and re-sent, arriving after all; not used, older than the re-sent one's),
``frozen`` (replies byte for byte equal to the previous one although another command was sent in
between: the reply's torque field follows the commanded torque, so such a motor answers without
refreshing its state; a motor at rest under a constant command is not counted).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable
from typing import Any

import can
import numpy as np

from hil.errors import DeviceFault, DeviceTimeout, ProtocolError
from hil.protocols.base import DeviceInfo, JointSample, StopStep
from hil.protocols.can_common import CanActuator
from hil.protocols.codecs import cubemars as _wire
from hil.protocols.codecs import forwarder
from hil.protocols.codecs.cubemars import (
    ERROR_CODES,
    SPECIAL_FRAMES,
    ZERO_SILENCE_S,
    MitCommand,
    MitLimits,
    MitReply,
    float_to_uint,
    model_limits,
    pack_command,
    uint_to_float,
    unpack_reply,
)
from hil.protocols.waits import WALL, Waits

logger = logging.getLogger(__name__)


class CubeMarsMIT(CanActuator):
    """One AK actuator in MIT mode; ``dof`` = 1, rotary, output-shaft rad / rad/s / N.m.

    Parameters
    ----------
    motor_id: CAN id of the motor (commands are sent on this id).
    model: key of :data:`MODEL_LIMITS` or a :class:`MitLimits`.
    reply_id: arbitration id of the replies (``None``: accept any id and match byte 0).
    channel, interface, bitrate, bus, clock: as for :class:`hil.protocols.can_odrive.ODriveCAN`.
    enable: send "enter motor mode" on open and "exit motor mode" on close.
    zero_on_open: send "set zero" after entering motor mode (waits for the motor's ~1 s silence).
    unwrap: unwrap the +-12.5 rad position field across wraps (see the module docstring).
    zero_timeout: how long :meth:`set_zero` waits for the motor to answer again (s).

    :meth:`command_effort` sends a torque-only command (kp = kd = 0, t_ff = effort);
    :meth:`command_mit` exposes the full impedance command. Each command is answered by the motor;
    :meth:`read` returns the newest reply received since the previous read, or re-sends the last
    command (idempotent) to elicit one. A non-zero error byte raises :class:`DeviceFault`.
    """

    dof = 1
    units = "rotary"

    def __init__(
        self,
        motor_id: int = 1,
        channel: str = "can0",
        interface: str = "socketcan",
        bitrate: int | None = None,
        *,
        model: str | MitLimits = "AK80-9",
        reply_id: int | None = None,
        bus: can.BusABC | None = None,
        enable: bool = True,
        zero_on_open: bool = False,
        clock: Callable[[], float] = time.monotonic,
        waits: Waits = WALL,
        timeout: float = 0.1,
        unwrap: bool = True,
        zero_timeout: float = ZERO_SILENCE_S + 0.5,
        **bus_kwargs: Any,
    ) -> None:
        self.motor_id = int(motor_id)
        self.unwrap = bool(unwrap)
        self.zero_timeout = float(zero_timeout)
        self._wraps = 0
        self._prev_raw: float | None = None
        self.limits = model_limits(model)
        self.reply_id = reply_id
        self.clock = clock
        self._waits = waits
        self.timeout = timeout
        self._enable = enable
        self.label = f"CubeMars {self.motor_id}"
        self._fresh: MitReply | None = None
        self._last_cmd: bytes = pack_command(MitCommand(0.0, 0.0, 0.0, 0.0, 0.0), self.limits)
        self.temperature: int | None = None
        self.decode_errors = 0
        self.error_frames = 0  # CAN error frames seen (e.g. a corrupted reply)
        self._fresh_at = math.nan  # adapter clock when self._fresh arrived
        self._last_sample: JointSample | None = None  # the newest sample read (non-blocking reads repeat it)
        self._skipped = 0
        self._timeouts = 0
        # issue 27: replies are matched to the frames sent (each is answered once)
        self._outstanding = 0  # frames sent whose reply has not arrived
        self._dropped = 0  # reads that found the command sent since the previous read unanswered
        self._late = 0  # replies that came when none was outstanding (after their re-send)
        self._frozen = 0  # replies byte for byte equal to the previous one after another command
        self._prev_reply: bytes | None = None
        self._cmd_changed = False  # another command was sent since the previous reply
        # no acceptance filter: error frames must reach us; reply filtering is done in _handle
        self._open_bus(interface, channel, bitrate, bus, bus_kwargs)
        name = model if isinstance(model, str) else "custom"
        self.info = DeviceInfo(
            driver="cubemars_mit",
            transport=f"can:{interface}:{channel}",
            vendor="CubeMars",
            model=name,
            extra={"motor_id": self.motor_id, "limits": self.limits.__dict__},
        )
        if enable:
            try:
                self.enter_motor_mode(timeout)
                if zero_on_open:
                    self.set_zero()
            except Exception:
                self.close()
                raise

    # -- low level ----------------------------------------------------------------------------
    def _send(self, data: bytes, timeout: float) -> None:
        self._send_frame(can.Message(arbitration_id=self.motor_id, data=data, is_extended_id=False), timeout)
        if data != SPECIAL_FRAMES["exit"]:  # every frame but "exit motor mode" is answered
            self._outstanding += 1

    def _handle(self, msg: can.Message) -> bool:
        if msg.is_error_frame:
            self.error_frames += 1
            return False
        if msg.is_remote_frame or msg.is_extended_id:
            return False
        if msg.arbitration_id == self.motor_id:  # a command (ours or another master's)
            return False
        if self.reply_id is not None and msg.arbitration_id != self.reply_id:
            return False
        data = bytes(msg.data)
        if len(data) not in (6, 8) or data[0] != self.motor_id:
            return False
        if self._outstanding <= 0:  # more replies than frames sent: one came after its re-send
            self._late += 1
            return False
        self._outstanding -= 1
        if self._cmd_changed and data == self._prev_reply:  # a new command, the same bytes: frozen
            self._frozen += 1
        self._prev_reply = data
        self._cmd_changed = False
        try:
            reply = unpack_reply(data, self.limits)
        except ProtocolError:
            self.decode_errors += 1
            return False
        if self.unwrap:
            reply = dataclasses.replace(reply, position=self._unwrapped(reply.position))
        if self._fresh is not None:
            self._skipped += 1
        self._fresh, self._fresh_at = reply, self.clock()
        return True

    def _unwrapped(self, raw: float) -> float:
        """Continuous position from the wrapped field: a step larger than half the span between
        consecutive replies is one wrap of ``p_max - p_min``."""
        span = self.limits.p_max - self.limits.p_min
        if self._prev_raw is not None:
            step = raw - self._prev_raw
            if step > span / 2:
                self._wraps -= 1
            elif step < -span / 2:
                self._wraps += 1
        self._prev_raw = raw
        return raw + self._wraps * span

    def counters(self) -> dict[str, int]:
        """error_frames, decode_errors, skipped, timeouts, and, each listed once there is one,
        dropped, late, frozen and ``stale`` (non-blocking reads without a new reply) (see the
        module docstring)."""
        out = {"error_frames": self.error_frames, "decode_errors": self.decode_errors, "skipped": self._skipped,
               "timeouts": self._timeouts}
        for k, v in (("dropped", self._dropped), ("late", self._late), ("frozen", self._frozen)):
            if v:  # listed once there is one (records of fault-free runs keep their counters)
                out[k] = v
        if self._stale_reads:
            out["stale"] = self._stale_reads
        return out

    def _await_reply(self, deadline: float) -> MitReply:
        while self._fresh is None:
            remaining = deadline - self._waits.monotonic()
            msg = self._recv(remaining if remaining > 0 else 0.0)
            if msg is None:
                self._timeouts += 1
                raise DeviceTimeout(f"CubeMars {self.motor_id}: no reply within timeout")
            self._handle(msg)
        return self._fresh

    def _transact(self, data: bytes, timeout: float) -> MitReply:
        self._drain()
        self._fresh = None
        self._outstanding = 0  # a new exchange: anything still unanswered is given up
        self._send(data, timeout)
        reply = self._await_reply(self._waits.monotonic() + timeout)
        self._fresh = None  # consumed: read() must not return it as a new sample
        return reply

    # -- commands -----------------------------------------------------------------------------
    def enter_motor_mode(self, timeout: float = 0.1) -> MitReply:
        return self._transact(SPECIAL_FRAMES["enter"], timeout)

    def exit_motor_mode(self, timeout: float = 0.1) -> None:
        self._send(SPECIAL_FRAMES["exit"], timeout)

    def set_zero(self, timeout: float | None = None) -> MitReply:
        """Send "set zero", then wait up to ``timeout`` (default ``zero_timeout``) s for the motor
        to answer again after its ~1 s silence, re-sending "enter motor mode" every 0.1 s. Returns
        the first reply (position ~0); DeviceTimeout if the motor stays silent."""
        limit = self.zero_timeout if timeout is None else float(timeout)
        deadline = self._waits.monotonic() + limit
        self._drain()
        self._fresh = None
        self._wraps, self._prev_raw = 0, None
        self._send(SPECIAL_FRAMES["zero"], min(0.1, limit))
        while True:
            until = min(deadline, self._waits.monotonic() + 0.1)
            while self._fresh is None and (remaining := until - self._waits.monotonic()) > 0:
                msg = self._recv(remaining)
                if msg is not None:
                    self._handle(msg)
            if self._fresh is not None:
                reply, self._fresh = self._fresh, None
                self._outstanding = 0  # the frames sent into the silence are never answered
                return reply
            if self._waits.monotonic() >= deadline:
                self._timeouts += 1
                raise DeviceTimeout(f"CubeMars {self.motor_id}: no reply within {limit:.2f} s after set zero (the "
                                    f"motor is silent ~{ZERO_SILENCE_S:.0f} s while it stores the origin)")
            self._send(SPECIAL_FRAMES["enter"], 0.1)  # idempotent: elicits a reply once the motor is back

    def command_mit(
        self, p_des: float, v_des: float, kp: float, kd: float, t_ff: float, timeout: float = 0.1
    ) -> None:
        """Impedance command: tau = kp*(p_des - q) + kd*(v_des - qd) + t_ff (all clamped to range)."""
        data = pack_command(MitCommand(p_des, v_des, kp, kd, t_ff), self.limits)
        self._send(data, timeout)
        if data != self._last_cmd:
            self._cmd_changed = True
        self._last_cmd = data

    def effort_on_wire(self, effort: np.ndarray) -> np.ndarray:
        """The torque (N.m) :meth:`command_effort` sends for ``effort``: the 12-bit t_ff field over the
        model's [T_min, T_max] (manual 5.3, MIT mode; truncated as :func:`float_to_uint`), decoded
        back (what hil.run.runner records as ``effort_cmd``; resolution (T_max - T_min) / 4095)."""
        u = float(self._checked_effort(effort)[0])  # the same effort_limit clamp as command_effort
        lim = self.limits
        return np.array([uint_to_float(float_to_uint(u, lim.t_min, lim.t_max, 12), lim.t_min, lim.t_max, 12)])

    def _send_effort(self, effort: np.ndarray, timeout: float) -> None:
        """Torque-only command in N.m at the output (kp = kd = 0), clamped to the model's T range."""
        self.command_mit(0.0, 0.0, 0.0, 0.0, float(effort[0]), timeout)

    # -- feedback -----------------------------------------------------------------------------
    def _read_sample(self, timeout: float) -> JointSample:
        """The newest reply since the previous read, else the reply to the last command sent again."""
        deadline = self._waits.monotonic() + timeout
        self._drain()
        if self._fresh is None and timeout == 0.0 and self._last_sample is not None:
            # non-blocking read (realtime loop): the previous reply again; the next command's reply
            # arrives while the loop waits for its next tick
            self._last_sample = self._stale(self._last_sample, self.clock(), "")
            return self._last_sample
        if self._fresh is None:
            if self._outstanding > 0:  # the reply to the command sent since the last read is missing
                self._dropped += 1
                self._outstanding = 0  # given up: if it comes after all, it is late
            self._send(self._last_cmd, timeout)
            self._await_reply(deadline)
            self._drain()
        r, produced = self._fresh, self._fresh_at
        assert r is not None
        self._fresh = None
        self.temperature = r.temperature
        err = r.error or 0
        if err:
            what = ERROR_CODES.get(err, "unknown")
            raise DeviceFault(f"CubeMars {self.motor_id}: error {err} ({what})", code=err)
        self._last_sample = JointSample(
            t=self.clock(),
            seq=self._next_seq(),
            position=np.array([r.position]),
            velocity=np.array([r.velocity]),
            effort=np.array([r.torque]),
            fault=err,
            produced_at=produced,
        )
        return self._last_sample

    def _close_steps(self) -> tuple[StopStep, ...]:
        """After the safe stop (zero torque) on close: leave motor mode."""
        return (lambda: self.exit_motor_mode(0.05),)

    def _armed(self) -> bool:
        return bool(self._enable)


#: the wire-format names (:mod:`hil.protocols.codecs`) stay importable from this module
__getattr__ = forwarder(_wire, __name__)
