"""Simulated CubeMars / T-Motor AK actuator in MIT mode on a python-can bus (see
:mod:`hil.protocols.can_cubemars` for the protocol and its sources).

The MIT impedance law ``tau = kp (p_des - q) + kd (v_des - qd) + t_ff`` runs inside the motor's
driver, in front of its current loop (AK Series Actuator Driver Manual, 5.3 "MIT power mode" block
diagram): a command sets the five parameters and the driver keeps re-evaluating the law from the
state it measures, at its loop rate, until the next command. The twin does the same at the finest
rate its lockstep plant resolves: the law is re-evaluated from the current (wrapped) position and
velocity on every tick (``tick_s``, the scene's control period) and on every command, and the
torque is held over the tick (zero-order hold). With the gains of a stiff impedance (K = 200 N.m/rad,
B = 2 N.m.s/rad) and commands at 40 Hz this settles as the motor does; the law evaluated once per
command and held for 25 ms (what the twin did before issue 29) diverges. What remains of the
motor's faster loop is the tick's hold: a delay of half a tick in the law's feedback.
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from typing import Any

import can
import numpy as np

from hil.mocks.can_devices import LOG_LEN, SimCanNode
from hil.mocks.interfaces import SimulatedJoints
from hil.protocols.codecs import cubemars as cm

logger = logging.getLogger(__name__)


class SimCubeMars(SimCanNode):
    """Simulated CubeMars / T-Motor AK actuator in MIT mode (see :mod:`hil.protocols.can_cubemars`).

    Commands arrive on id ``motor_id``; every command (and each special frame) is answered with a
    state frame on id ``reply_id`` whose first byte is ``motor_id``. The impedance law
    ``tau = kp*(p_des - q) + kd*(v_des - qd) + t_ff`` of the newest command is evaluated from the
    current state (``q`` in the motor's wrapped frame) on the command and again on every tick, as
    the motor's driver keeps evaluating it (module docstring; torque-only control with kp = kd = 0
    is the same either way). Torque is clamped to the model's T range. ``temperature`` is reported in byte 6, injected
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
        self.command: cm.MitCommand | None = None  # the law in force (newest command in motor mode)
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
            self.command = None
        elif special == "zero":
            self.zero_offset = float(self.joints.position()[0])
            self._silent_until = self._clock() + self.zero_silence_s
            return
        else:
            c = cm.unpack_command(data, self.limits)
            self.commands.append((self.tick_count, c))
            self.commands_total += 1
            if self.enabled:
                self.command = c
                self._law()
            else:
                self.ignored_in_rest += 1
        self._apply()
        self._send_state()

    def _law(self) -> None:
        """The MIT law of the command in force, from the state now, clamped to the T range."""
        c = self.command
        if c is None or not self.enabled:
            return
        q = self.wrapped_position()
        v = float(self.joints.velocity()[0])
        tau = c.kp * (c.p_des - q) + c.kd * (c.v_des - v) + c.t_ff
        self.torque = min(max(tau, self.limits.t_min), self.limits.t_max)

    def on_tick(self) -> None:
        self._law()  # the driver keeps evaluating the law between commands
        self._apply()


__all__ = ["SimCubeMars"]
