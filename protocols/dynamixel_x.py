"""DYNAMIXEL X-series servos (e.g. XM430-W350) in current control, over Protocol 2.0 with the
official ``dynamixel_sdk``.

Role: :class:`hil.protocols.base.Actuator`, rotary, ``dof`` = number of servo ids (a leader or
follower arm is one adapter with several ids on one bus). Joint ``i`` is servo ``ids[i]``.

Per tick the adapter sends one *sync write* of Goal Current and one *sync read* of the contiguous
block Present Current .. Present Position (addresses 126..135, 10 bytes).

Control table (ROBOTIS e-manual, XM430-W350 page, Protocol 2.0 control table):

============================ ======= ====== ===================================================
item                         address bytes  unit / meaning
============================ ======= ====== ===================================================
Model Number                 0       2      1020 for XM430-W350
Firmware Version             6       1
Operating Mode               11      1      0 = current control (EEPROM: torque must be off)
Current Limit                38      2      2.69 mA, initial 1193 (~3.2 A)
Torque Enable                64      1      0 / 1
Hardware Error Status        70      1      bit field (input voltage, overheating, encoder,
                                            electrical shock, overload)
Goal Current                 102     2      signed, 2.69 mA, -limit..+limit
Present Current              126     2      signed, 2.69 mA
Present Velocity             128     4      signed, 0.229 rev/min
Present Position             132     4      signed, 4096 ticks per revolution
============================ ======= ====== ===================================================

Factory-new servos (e-manual "Initial Value"): Baud Rate(8) = 1, i.e. **57 600 bps**, Return
Delay Time(9) = 250 (500 us), ID 1. The adapter's default ``baudrate`` is that 57 600 bps; when the
first id does not answer a ping at ``baudrate`` and ``scan_baudrates`` is on (default), it pings
it at every other X-series rate (9 600 ... 4.5 Mbps, :data:`BAUD_RATES`) and continues at the rate
that answers, with a warning naming it (set ``baudrate`` in the scene to skip the scan). A fast
loop needs a faster bus than 57 600 bps (see the link budget in ``hil.scene.spec``): configure the
servos (e.g. with DYNAMIXEL Wizard) and give their rate as ``baudrate``. On open the adapter writes
Return Delay Time(9) = ``return_delay`` (default 0, in 2 us units; ``None`` leaves it): a factory
servo otherwise waits 0.5 ms before every status packet.

Conversions (SI, per joint, ``d = directions[i]`` = +1 or -1):

* ``position [rad] = d * (ticks - zero_ticks) * 2 pi / 4096``
* ``velocity [rad/s] = d * raw * 0.229 * 2 pi / 60``
* ``effort [N.m] = d * raw_current * 2.69e-3 * kt`` (measured through the current)
* command: ``raw_current = round(d * effort / kt / 2.69e-3)`` clamped to +-Current Limit(38)

``kt`` is the output torque per motor current (N.m/A). The default for the XM430-W350,
1.78 N.m/A, is the e-manual's stall point at 12 V (4.1 N.m at 2.3 A); the real torque/current
curve is not linear (friction, saturation), so identify it on the bench and pass
``torque_constant=``.

Status packets carry an error byte: bit 7 (alert) means a hardware error; the adapter then reads
Hardware Error Status(70) and raises :class:`DeviceFault` with that code. Error numbers 1..7
(result fail, instruction, CRC, range, length, limit, access) raise :class:`DeviceFault` with
``code = 0x100 | number``. No status packet within the timeout raises :class:`DeviceTimeout`;
a status packet with a bad CRC raises :class:`ChecksumError`.

Timeouts: the SDK's own packet timeout (based on a 16 ms USB latency timer) is replaced by the
call's ``timeout``; its polling loop is made to wait for input instead of spinning. Every deadline
and wait goes through ``waits`` (:mod:`hil.protocols.waits`): the host's clock at a bench, simulated
time on a lockstep bench (a status packet the simulated chain did not send times out at once,
without wall time; one it sent is always there).

Freshness: status packets carry no timestamp; ``JointSample.produced_at`` is the arrival of the
sync read's status packets (adapter clock) and ``seq`` advances with each complete set. A missing
status packet raises DeviceTimeout (counted in ``counters()["timeouts"]``), a corrupt one
ChecksumError (``crc_errors``).

Non-blocking reads (``read(timeout=0)``, what the realtime loop does: take the newest sample
that has arrived, never wait): the sync read is split into its request and its status packets.
A read collects the status packets that arrived since the sync read sent ahead (a packet split
over several reads is kept until complete, :class:`~hil.protocols.codecs.dynamixel.StatusParser`):
all servos answered -> a fresh sample (``produced_at`` = the read that completed the set, adapter
clock: at most one read period after the data left the servos); otherwise the previous sample
again (stale: same ``seq`` and ``produced_at``, ``counters()["stale"]``). The next sync read is
sent right after the next Goal Current sync write (:meth:`DynamixelX.command_effort`), so that on
the half-duplex line the host never transmits over the servos' status packets (the sync write
gets no reply); a read with nothing outstanding and no command since the previous read sends it
itself. A status packet failing its CRC is dropped and counted (``crc_errors``), its set given up
(stale) and asked again once its status packets are over on the line (their duration at
``baudrate``); a set incomplete after ``timeout`` (host clock) is given up (``timeouts``) and asked
again: the samples' age grows meanwhile, and the runner's watchdog (``watchdog_ms``) stops the run.
Status packets of a given-up request are ``late`` (dropped). With the Bus Watchdog armed every
``watchdog_check_every``-th request reads 98 instead (that read is stale). A non-blocking read with
nothing requested ahead (the first one, or the first after blocking reads) reads once with
``timeout``; a blocking read (timeout > 0) after non-blocking
ones first lets the outstanding sync read finish (at most its time on the line) and then works as
the request/answer exchange above. :meth:`close` with a request outstanding does the same before
the zero current and torque off. Non-blocking reads need the adapter to own its port: two
adapters open on one port (one bus; the lockstep scene ``dynamixel_leader_follower`` does this)
would take each other's status packets and transmit over each other's replies, so their reads
stay blocking (with a warning); one adapter with all the ids of the bus reads without waiting.

Bus Watchdog(98) (e-manual: 1 byte, RAM; 0 = off and clears the error, 1..127 = armed in units of
20 ms, -1 = Bus Watchdog Error): with ``bus_watchdog_s`` the adapter arms it on open (rounded up
to 20 ms, at most 2.54 s; the bench passes the scene's ``watchdog_ms``), after clearing it. While
the torque is on and no instruction packet arrives for that long, the servo stops by itself and
98 reads -1; goal values are then refused. The adapter reads 98 of every servo every
``watchdog_check_every`` reads (default 100: one extra 1-byte sync read) and in
:meth:`bus_watchdog_expired`, and raises :class:`DeviceFault` (``code = 0x200``) naming the servos
whose watchdog expired. Counters: ``crc_errors``, ``timeouts``, ``bus_watchdog_errors``,
``resync_bytes`` (bytes before a status packet's header, skipped: line noise; on blocking reads
the bytes the SDK read are parsed again with :class:`~hil.protocols.codecs.dynamixel.StatusParser`
to count what it skipped), ``frozen`` (sets of present blocks byte for byte equal to the
previous set although another Goal Current was sent in between: Present Current follows Goal
Current in current control, so those servos answer without refreshing their values; servos at
rest under a constant command are not counted; issue 27).
"""

from __future__ import annotations

import functools
import logging
import os
import time
from collections.abc import Callable, Sequence
from typing import Any, ClassVar

import numpy as np

from hil.errors import ChecksumError, DeviceDisconnected, DeviceError, DeviceFault, DeviceTimeout, ProtocolError
from hil.protocols.base import Actuator, DeviceInfo, JointSample, StopStep
from hil.protocols.codecs import dynamixel as _wire
from hil.protocols.codecs import forwarder
from hil.protocols.codecs.dynamixel import (
    ADDR_BUS_WATCHDOG,
    ADDR_CURRENT_LIMIT,
    ADDR_FIRMWARE_VERSION,
    ADDR_GOAL_CURRENT,
    ADDR_HARDWARE_ERROR,
    ADDR_OPERATING_MODE,
    ADDR_PRESENT_CURRENT,
    ADDR_RETURN_DELAY,
    ADDR_TORQUE_ENABLE,
    BAUD_RATES,
    BUS_WATCHDOG_ERROR,
    CURRENT_UNIT_A,
    ERRBIT_ALERT,
    FAULT_BUS_WATCHDOG,
    MODE_CURRENT,
    MODELS,
    PRESENT_BLOCK_LEN,
    RAD_PER_TICK,
    STATUS_OVERHEAD,
    VELOCITY_UNIT_RAD_S,
    StatusParser,
    XModel,
    bus_watchdog_units,
    decode_present_block,
    effort_to_current_raw,
    to_unsigned,
)
from hil.protocols.waits import WALL, Waits

logger = logging.getLogger(__name__)

#: write timeout (s) of a sync read sent ahead (non-blocking reads)
POLL_AHEAD_SEND_TIMEOUT_S = 0.001


# ------------------------------------------------------------------------------------------------
# SDK port with real timeouts
# ------------------------------------------------------------------------------------------------
def _make_port_handler(port_name: str, waits: Waits = WALL) -> Any:
    from dynamixel_sdk import PortHandler

    class TimedPortHandler(PortHandler):  # type: ignore[misc]  # dynamixel_sdk has no type hints (Any)
        """``PortHandler`` whose packet timeout is the adapter's call timeout, measured on the
        adapter's ``waits`` (the host's clock at a bench, simulated time in lockstep), and whose read
        waits for input through ``waits`` (the stock one polls a non-blocking port in a busy loop)."""

        def __init__(self, name: str) -> None:
            super().__init__(name)
            self.waits = waits
            self.call_timeout_ms = 100.0
            self.tx_bytes = 0
            #: a sync read is outstanding (non-blocking read): the SDK's flush of the input before
            #: every packet it sends would throw its status packets away
            self.hold_input = False
            #: every byte read while not None (the adapter counts what the SDK skipped: garbage)
            self.capture: bytearray | None = None

        def clearPort(self) -> None:
            if not self.hold_input:
                super().clearPort()

        def setPacketTimeout(self, packet_length: int) -> None:
            self.packet_start_time = self.getCurrentTime()
            self.packet_timeout = self.call_timeout_ms

        def getCurrentTime(self) -> float:
            return 1000.0 * self.waits.monotonic()  # ms, as the SDK's own (time.time based)

        def readPort(self, length: int) -> bytes:
            if self.ser.in_waiting == 0 and self.packet_timeout > 0:
                left = self.packet_timeout - self.getTimeSinceStart()
                if left > 0:
                    self.waits.readable(self.ser.fileno(), min(left, 5.0) / 1000.0)
            data: bytes = self.ser.read(length)
            if self.capture is not None:
                self.capture += data
            return data

        def writePort(self, packet: Any) -> int:
            n: int = self.ser.write(packet) or 0
            self.tx_bytes += n
            return n

    return TimedPortHandler(port_name)


class DynamixelX(Actuator):
    """X-series servos on one Protocol 2.0 bus, in current (torque) control.

    ``port`` is the serial device (``/dev/ttyUSB0``, a U2D2, or the pty of a simulated chain).
    ``current_limit`` (raw units) further restricts commands below each servo's Current Limit(38).
    ``zero_ticks`` (per joint) is the raw position reported as 0 rad. ``clock`` gives ``t``;
    ``waits`` measures every timeout (:mod:`hil.protocols.waits`).
    On open: ping every id, read Current Limit, torque off, Operating Mode = current, torque on
    (unless ``enable=False``). :meth:`close` commands zero current and turns torque off.
    """

    units = "rotary"
    #: open adapters per serial port (os.path.realpath): non-blocking reads need the port to themselves
    _port_users: ClassVar[dict[str, int]] = {}
    _port_key = ""

    def __init__(
        self,
        port: str,
        ids: Sequence[int] = (1,),
        *,
        baudrate: int = 57_600,
        scan_baudrates: bool = True,
        return_delay: int | None = 0,
        model: str | XModel = "XM430-W350",
        torque_constant: float | Sequence[float] | None = None,
        current_limit: int | Sequence[int] | None = None,
        directions: Sequence[int] | None = None,
        zero_ticks: Sequence[int] | None = None,
        timeout: float = 0.1,
        enable: bool = True,
        clock: Callable[[], float] = time.monotonic,
        bus_watchdog_s: float | None = None,
        watchdog_check_every: int = 100,
        waits: Waits = WALL,
    ) -> None:
        from dynamixel_sdk import GroupSyncRead, GroupSyncWrite, PacketHandler

        self.ids = [int(i) for i in ids]
        if not self.ids or len(set(self.ids)) != len(self.ids):
            raise ValueError(f"ids must be non-empty and unique, got {ids}")
        self.dof = len(self.ids)
        self.model = MODELS[model] if isinstance(model, str) else model
        n = self.dof
        kt = self.model.torque_constant if torque_constant is None else torque_constant
        self.torque_constant = np.broadcast_to(np.asarray(kt, dtype=float), (n,)).copy()
        self.directions = np.ones(n) if directions is None else np.asarray(directions, dtype=float)
        if self.directions.shape != (n,) or not np.all(np.abs(self.directions) == 1):
            raise ValueError("directions must be +1/-1 per joint")
        self.zero_ticks = np.zeros(n) if zero_ticks is None else np.asarray(zero_ticks, dtype=float)
        self._user_limit = None if current_limit is None else np.broadcast_to(
            np.asarray(current_limit, dtype=np.int64), (n,)
        )
        self.timeout = float(timeout)
        self._clock = clock
        self.bus_watchdog_units = bus_watchdog_units(bus_watchdog_s) if bus_watchdog_s is not None else 0
        self.watchdog_check_every = max(1, int(watchdog_check_every))
        self._counts = {"crc_errors": 0, "timeouts": 0, "bus_watchdog_errors": 0}
        self._prev_blocks: list[bytes] | None = None
        self._prev_raw: np.ndarray | None = None  # the Goal Currents sent last
        self._cmd_changed = False  # another Goal Current was sent since the last present blocks
        self._reads = 0
        self._requests = 0  # sync reads sent ahead (non-blocking reads)
        self._enabled = False
        # non-blocking reads (timeout 0): the sync read sent ahead and what came back of it
        self._status = StatusParser()
        self._ahead: str | None = None  # "present" / "watchdog": the request outstanding
        self._ahead_at = 0.0  # host monotonic time it was sent
        self._due = False  # a request is to be sent after the next sync write (or by the next read)
        self._due_reads = 0  # reads since it became due without a command sending it
        self._quiet_until = 0.0  # host monotonic: the status packets of a dropped request are over
        self._got: dict[int, tuple[int, bytes]] = {}
        self._last: JointSample | None = None
        self._stale_reads = 0
        self.port_name = port
        self.label = f"DYNAMIXEL ids {self.ids} on {port}"
        self.info = DeviceInfo(
            driver="dynamixel_x", transport="dynamixel2-serial", vendor="ROBOTIS", model=self.model.name,
            extra={"port": port, "ids": list(self.ids), "baudrate": baudrate},
        )
        self.baudrate = int(baudrate)
        self.scan_baudrates = bool(scan_baudrates)
        if return_delay is not None and not 0 <= int(return_delay) <= 254:
            raise ValueError(f"return_delay must be 0..254 (x 2 us) or None, got {return_delay}")
        self.return_delay = None if return_delay is None else int(return_delay)
        self._waits = waits
        self._port = _make_port_handler(port, waits)
        self._port.call_timeout_ms = 1000.0 * self.timeout  # the first ping's too (was a fixed 100 ms)
        self._ph = PacketHandler(2.0)
        try:
            ok = self._port.openPort() and self._port.setBaudRate(baudrate)
        except Exception as exc:  # pyserial raises SerialException (an OSError) on a bad path
            raise DeviceDisconnected(f"cannot open {port}: {exc}") from exc
        if not ok:
            raise DeviceError(f"cannot open {port} at {baudrate} bps")
        try:
            self._init_servos(enable)
        except BaseException:
            self._closed = True  # torque was never enabled: nothing to stop
            self._port.closePort()
            raise
        self._gsw = GroupSyncWrite(self._port, self._ph, ADDR_GOAL_CURRENT, 2)
        for i in self.ids:
            self._gsw.addParam(i, [0, 0])
        self._gsr = GroupSyncRead(self._port, self._ph, ADDR_PRESENT_CURRENT, PRESENT_BLOCK_LEN)
        for i in self.ids:
            self._gsr.addParam(i)
        self._gsr_wd = GroupSyncRead(self._port, self._ph, ADDR_BUS_WATCHDOG, 1)
        for i in self.ids:
            self._gsr_wd.addParam(i)
        self._port_key = os.path.realpath(port)
        DynamixelX._port_users[self._port_key] = DynamixelX._port_users.get(self._port_key, 0) + 1
        self._warned_shared = False
        logger.info("DYNAMIXEL %s ids %s on %s opened", self.model.name, self.ids, port)

    # -- Actuator ---------------------------------------------------------------------------------
    @property
    def tx_bytes(self) -> int:
        """Bytes written to the bus so far (for a simulated chain's lockstep ``sync``)."""
        return int(self._port.tx_bytes)

    def current_command(self, effort: np.ndarray) -> np.ndarray:
        """The Goal Current register values that :meth:`command_effort` would send."""
        e = np.asarray(effort, dtype=float).reshape(self.dof)
        return effort_to_current_raw(e, self.torque_constant, self.current_limit, self.directions)

    def effort_on_wire(self, effort: np.ndarray) -> np.ndarray:
        """The effort (N.m) :meth:`command_effort` sends for ``effort``: Goal Current(102) in units of
        2.69 mA, clamped to +-Current Limit(38) (XM430 e-Manual, control table), decoded back as
        ``d * raw * 2.69e-3 * kt`` (what hil.run.runner records as ``effort_cmd``), after the same
        ``effort_limit`` clamp as :meth:`command_effort`."""
        raw = self.current_command(self._checked_effort(effort)).astype(float)
        return np.asarray(self.directions * raw * CURRENT_UNIT_A * self.torque_constant, dtype=float)

    def _send_effort(self, effort: np.ndarray, timeout: float) -> None:
        """Sync-write Goal Current for every joint (no reply on the bus, so it never waits)."""
        raw = self.current_command(effort)
        if self._prev_raw is not None and not np.array_equal(raw, self._prev_raw):
            self._cmd_changed = True
        self._prev_raw = raw
        for i, r in zip(self.ids, raw, strict=True):
            u = to_unsigned(int(r), 2)
            self._gsw.changeParam(i, [u & 0xFF, u >> 8])
        self._port.call_timeout_ms = 1000.0 * timeout
        self._check_comm(self._gsw.txPacket(), "sync write Goal Current")
        if self._due and self._waits.monotonic() >= self._quiet_until:  # non-blocking reads: the next sync
            self._request()                                          # read follows the command

    def _read_sample(self, timeout: float) -> JointSample:
        """Sync-read Present Current/Velocity/Position of every joint; ``timeout`` 0: the
        non-blocking read of the module docstring ("Non-blocking reads")."""
        from dynamixel_sdk import COMM_SUCCESS

        if timeout == 0.0:
            if DynamixelX._port_users.get(self._port_key, 1) <= 1:
                return self._read_ahead()
            if not self._warned_shared:  # another adapter on this port would take our status packets
                self._warned_shared = True
                logger.warning("%s: the port is open in another adapter too: reads wait for their status "
                               "packets (timeout %.3f s); give one adapter all the ids of a bus for "
                               "non-blocking reads", self.label, self.timeout)
            timeout = self.timeout
        if self._ahead is not None or self._due:  # after non-blocking reads: back to request/answer
            self._settle(timeout)
        self._port.call_timeout_ms = 1000.0 * timeout
        self._check_comm(self._gsr.txPacket(), "sync read")
        blocks: list[bytes] = []
        errors: list[int] = []
        self._port.capture = bytearray()
        try:
            for i in self.ids:
                data, result, error = self._ph.readRx(self._port, i, PRESENT_BLOCK_LEN)
                if result != COMM_SUCCESS:
                    self._check_comm(result, f"sync read status of id {i}")
                blocks.append(bytes(data))
                errors.append(int(error))
        finally:  # what the SDK read, parsed again: the bytes it skipped before a header (garbage)
            got, self._port.capture = bytes(self._port.capture), None
            parser = StatusParser()
            parser.feed(got)
            if parser.skipped_bytes:
                self._counts["resync_bytes"] = self._counts.get("resync_bytes", 0) + parser.skipped_bytes
        self._count_repeated(blocks)
        for i, err in zip(self.ids, errors, strict=True):
            self._raise_for_error(i, err, timeout)
        cur, vel, pos = (np.array(v, dtype=float) for v in zip(*map(decode_present_block, blocks), strict=True))
        produced = self._clock()
        d = self.directions
        seq = self._next_seq()
        self._reads += 1
        if self.bus_watchdog_units and self._reads % self.watchdog_check_every == 0:
            self._raise_if_watchdog_expired(timeout)
        self._last = JointSample(
            t=produced,
            seq=seq,
            position=d * (pos - self.zero_ticks) * RAD_PER_TICK,
            velocity=d * vel * VELOCITY_UNIT_RAD_S,
            effort=d * cur * CURRENT_UNIT_A * self.torque_constant,
            produced_at=produced,
        )
        return self._last

    # -- non-blocking reads (timeout 0) ----------------------------------------------------------
    def _read_ahead(self) -> JointSample:
        """The non-blocking read: collect the status packets of the sync read sent ahead (fresh
        sample when every servo answered), else the previous sample again (stale); see the module
        docstring. One with nothing outstanding or due (the first, or the first after blocking
        reads) reads once with the adapter's ``timeout``."""
        if self._ahead is None and not self._due:
            sample = self._read_sample(self.timeout)
            self._due = True  # sent after the next sync write (half duplex: never over a reply)
            return sample
        fresh = self._collect()
        if self._ahead is None and self._due:
            self._due_reads += 1
            # a whole tick without a command to send it after: the bus is quiet, send it now
            if self._due_reads > 1 and self._waits.monotonic() >= self._quiet_until:
                self._request()
        if fresh is not None:
            return fresh
        return self._stale(self._last, self._clock(), f"{self.label}: no status packets yet")

    def _request(self) -> None:
        """Send the sync read ahead without waiting (every ``watchdog_check_every``-th one reads
        Bus Watchdog(98) instead when it is armed)."""
        self._requests += 1
        kind = "present"
        if self.bus_watchdog_units and self._requests % self.watchdog_check_every == 0:
            kind = "watchdog"
        self._status.clear()
        self._got.clear()
        self._port.hold_input = False
        self._port.clearPort()  # the bus is quiet: nothing outstanding is in flight
        self._port.call_timeout_ms = 1000.0 * POLL_AHEAD_SEND_TIMEOUT_S
        group = self._gsr if kind == "present" else self._gsr_wd
        result = group.txPacket()
        self._port.is_using = False  # the SDK's receive half, which would release the port, is ours
        self._check_comm(result, f"sync read ({kind}) sent ahead")
        self._port.hold_input = True
        self._ahead, self._ahead_at, self._due = kind, self._waits.monotonic(), False

    def _pump(self) -> None:
        ser = self._port.ser
        try:
            n = ser.in_waiting
            data = ser.read(n) if n else b""
        except OSError as exc:  # pyserial's SerialException is an OSError
            raise DeviceDisconnected(f"{self.label}: port lost: {exc}") from exc
        if not data:
            return
        crc0 = self._status.crc_errors
        for dxl_id, err, params in self._status.feed(data):
            if dxl_id in self.ids and self._ahead is not None:
                self._got[dxl_id] = (err, params)
            else:
                self._counts["late"] = self._counts.get("late", 0) + 1
        if self._status.crc_errors != crc0:
            self._counts["crc_errors"] += self._status.crc_errors - crc0

    def _collect(self) -> JointSample | None:
        """Take what arrived of the outstanding sync read; a fresh sample when it is complete."""
        if self._ahead is None:
            return None
        crc0 = self._counts["crc_errors"]
        self._pump()
        kind = self._ahead
        size = PRESENT_BLOCK_LEN if kind == "present" else 1
        if self._counts["crc_errors"] != crc0:  # a status packet was lost to its CRC: give the set up,
            self._quiet_until = self._ahead_at + 2.0 * self._reply_time_s()  # ask again once the line
            self._drop_request(due=True)                                      # is quiet
            return None
        if len(self._got) < len(self.ids):
            if self._waits.monotonic() - self._ahead_at > self.timeout:  # never came: ask again
                self._counts["timeouts"] += 1
                self._drop_request(due=True)
            return None
        got = [self._got[i] for i in self.ids]
        self._drop_request(due=True)
        for i, (err, params) in zip(self.ids, got, strict=True):
            if len(params) != size:
                raise ProtocolError(f"{self.label}: id {i} answered {len(params)} bytes, {size} asked")
            self._raise_for_error(i, err, self.timeout)
        if kind == "watchdog":
            expired = [i for i, (_e, p) in zip(self.ids, got, strict=True) if p[0] == BUS_WATCHDOG_ERROR]
            if expired:
                self._counts["bus_watchdog_errors"] += 1
                raise DeviceFault(f"DYNAMIXEL ids {expired}: Bus Watchdog expired (servo stopped by itself)",
                                  code=FAULT_BUS_WATCHDOG)
            return None
        self._count_repeated([bytes(p) for _e, p in got])
        cur, vel, pos = (np.array(v, dtype=float)
                         for v in zip(*(decode_present_block(p) for _e, p in got), strict=True))
        produced = self._clock()
        d = self.directions
        self._reads += 1
        self._last = JointSample(
            t=produced,
            seq=self._next_seq(),
            position=d * (pos - self.zero_ticks) * RAD_PER_TICK,
            velocity=d * vel * VELOCITY_UNIT_RAD_S,
            effort=d * cur * CURRENT_UNIT_A * self.torque_constant,
            produced_at=produced,
        )
        return self._last

    def _count_repeated(self, blocks: list[bytes]) -> None:
        """Count a set of present blocks byte for byte equal to the previous set although a different
        Goal Current was sent in between (``frozen``: Present Current follows Goal Current in current
        control, so servos that still answer but no longer move their values are frozen; servos at
        rest under a constant command are not counted)."""
        if self._cmd_changed and blocks == self._prev_blocks:
            self._counts["frozen"] = self._counts.get("frozen", 0) + 1
        self._prev_blocks = blocks
        self._cmd_changed = False

    def _drop_request(self, due: bool) -> None:
        self._ahead = None
        self._due, self._due_reads = due, 0
        self._got.clear()
        self._status.clear()
        self._port.hold_input = False

    def _reply_time_s(self) -> float:
        """How long the status packets of one sync read of the present block take on the line
        (8N1: 10 bits a byte) plus every servo's Return Delay Time, s."""
        nbytes = len(self.ids) * (STATUS_OVERHEAD + PRESENT_BLOCK_LEN)
        delay = 2e-6 * 254 if self.return_delay is None else 2e-6 * self.return_delay
        return 10.0 * nbytes / self.baudrate + len(self.ids) * delay

    def _settle(self, limit: float) -> None:
        """Before a request/answer exchange of the SDK: let the outstanding sync read finish (at
        most the time its status packets take on the line, and ``limit``), so that no instruction
        is sent over a reply on the half-duplex line and no late status packet is taken for an
        answer; then forget it and flush the input."""
        if self._ahead is not None:
            wait = min(limit, 2.0 * self._reply_time_s() + 0.001)
            waits = self._waits
            deadline = waits.monotonic() + wait
            while len(self._got) < len(self.ids) and waits.monotonic() < deadline:
                waits.readable(self._port.ser.fileno(), deadline - waits.monotonic())
                self._pump()
        self._drop_request(due=False)
        self._port.clearPort()

    def counters(self) -> dict[str, int]:
        """crc_errors, timeouts, bus_watchdog_errors; listed once non-zero resync_bytes (bytes skipped
        before a status packet's header: garbage on the line) and frozen (present blocks equal to the
        previous set after another Goal Current);
        once a non-blocking read ran also ``stale``
        (reads that returned the previous sample) and ``late`` (status packets of an abandoned
        sync read); see the module docstring."""
        out = dict(self._counts)
        if self._status.skipped_bytes:  # the non-blocking reads' own parser
            out["resync_bytes"] = out.get("resync_bytes", 0) + self._status.skipped_bytes
        if self._requests:
            out["stale"] = self._stale_reads
            out.setdefault("late", 0)
        return out

    def bus_watchdog_expired(self, timeout: float | None = None) -> list[int]:
        """Ids whose Bus Watchdog(98) reads -1 (Bus Watchdog Error), with one sync read."""
        from dynamixel_sdk import COMM_SUCCESS

        self._check_open()
        if self._ahead is not None:
            self._settle(self.timeout if timeout is None else timeout)
        self._with_timeout(timeout)
        self._check_comm(self._gsr_wd.txPacket(), "sync read Bus Watchdog")
        out = []
        for i in self.ids:
            data, result, _error = self._ph.readRx(self._port, i, 1)
            if result != COMM_SUCCESS:
                self._check_comm(result, f"sync read Bus Watchdog of id {i}")
            if data and data[0] == BUS_WATCHDOG_ERROR:
                out.append(i)
        return out

    def _raise_if_watchdog_expired(self, timeout: float | None) -> None:
        expired = self.bus_watchdog_expired(timeout)
        if expired:
            self._counts["bus_watchdog_errors"] += 1
            raise DeviceFault(f"DYNAMIXEL ids {expired}: Bus Watchdog expired (servo stopped by itself)",
                              code=FAULT_BUS_WATCHDOG)

    def enable(self, on: bool = True, timeout: float | None = None) -> None:
        """Torque Enable(64) on every servo."""
        self._check_open()
        for i in self.ids:
            self._write(i, ADDR_TORQUE_ENABLE, 1, int(on), timeout)
        self._enabled = on

    def _stop_steps(self) -> list[StopStep]:
        """Safe stop: zero current, then torque off on every servo (each attempted). A sync read
        outstanding (non-blocking reads) is let finish first (bounded by its time on the line and
        0.05 s) and not renewed."""
        steps: list[StopStep] = [lambda: self._settle(0.05),
                                 lambda: self.command_effort(np.zeros(self.dof), timeout=0.05)]
        steps += [functools.partial(self._write, i, ADDR_TORQUE_ENABLE, 1, 0, 0.05) for i in self.ids]
        steps.append(lambda: setattr(self, "_enabled", False))
        return steps

    def _armed(self) -> bool:
        return self._enabled

    def _release(self) -> None:
        if self._port_key:
            n = DynamixelX._port_users.get(self._port_key, 1) - 1
            if n > 0:
                DynamixelX._port_users[self._port_key] = n
            else:
                DynamixelX._port_users.pop(self._port_key, None)
        self._port.closePort()

    # -- internals --------------------------------------------------------------------------------
    def _find_baudrate(self) -> tuple[int, int, int]:
        """Ping the first id at ``baudrate``; if it does not answer and ``scan_baudrates`` is on,
        at every other X-series rate, and keep the first that answers. Returns the SDK's
        ``(model_number, result, error)`` of the last ping."""
        from dynamixel_sdk import COMM_SUCCESS

        first = self.ids[0]
        answer: tuple[int, int, int] = self._ph.ping(self._port, first)
        if answer[1] == COMM_SUCCESS or not self.scan_baudrates:
            return answer
        for bps in BAUD_RATES.values():
            if bps == self.baudrate:
                continue
            self._port.setBaudRate(bps)
            found: tuple[int, int, int] = self._ph.ping(self._port, first)
            if found[1] == COMM_SUCCESS:
                logger.warning("DYNAMIXEL id %d answers at %d bps, not %d: continuing at %d bps (set baudrate: %d "
                            "in the scene)", first, bps, self.baudrate, bps, bps)
                self.baudrate = bps
                self.info.extra["baudrate"] = bps
                return found
        self._port.setBaudRate(self.baudrate)  # nobody answers: report the failure at the given rate
        return answer

    def _init_servos(self, enable: bool) -> None:
        limits = []
        first = self._find_baudrate()
        for i in self.ids:
            model_number, result, error = first if i == self.ids[0] else self._ph.ping(self._port, i)
            self._check_comm(result, f"ping id {i}")
            self._raise_for_error(i, error, None)
            if model_number != self.model.model_number:
                logger.warning("id %d reports model %d, expected %d (%s)", i, model_number,
                            self.model.model_number, self.model.name)
            limits.append(self._read(i, ADDR_CURRENT_LIMIT, 2, None))
            self.info.extra.setdefault("firmware", {})[i] = self._read(i, ADDR_FIRMWARE_VERSION, 1, None)
        device_limit = np.array(limits, dtype=np.int64)
        self.current_limit = device_limit if self._user_limit is None else np.minimum(device_limit, self._user_limit)
        fw = sorted(set(self.info.extra["firmware"].values()))
        self.info.firmware = ",".join(str(v) for v in fw)
        for i in self.ids:
            self._write(i, ADDR_TORQUE_ENABLE, 1, 0, None)
            if self.return_delay is not None and self._read(i, ADDR_RETURN_DELAY, 1, None) != self.return_delay:
                self._write(i, ADDR_RETURN_DELAY, 1, self.return_delay, None)  # EEPROM: torque is off
            self._write(i, ADDR_OPERATING_MODE, 1, MODE_CURRENT, None)
            self._write(i, ADDR_BUS_WATCHDOG, 1, 0, None)  # off; also clears a Bus Watchdog Error
            self._write(i, ADDR_GOAL_CURRENT, 2, 0, None)
        if enable:
            self.enable(True)
            if self.bus_watchdog_units:
                for i in self.ids:
                    self._write(i, ADDR_BUS_WATCHDOG, 1, self.bus_watchdog_units, None)
                logger.info("DYNAMIXEL ids %s: Bus Watchdog armed (%d ms)", self.ids, 20 * self.bus_watchdog_units)

    def _check_comm(self, result: int, what: str) -> None:
        from dynamixel_sdk import COMM_RX_CORRUPT, COMM_RX_TIMEOUT, COMM_SUCCESS, COMM_TX_FAIL

        if result == COMM_SUCCESS:
            return
        text = self._ph.getTxRxResult(result)
        if result == COMM_RX_TIMEOUT:
            self._counts["timeouts"] += 1
            raise DeviceTimeout(f"DYNAMIXEL {what}: no status packet ({text})")
        if result == COMM_RX_CORRUPT:
            self._counts["crc_errors"] += 1
            raise ChecksumError(f"DYNAMIXEL {what}: corrupt status packet ({text})")
        if result == COMM_TX_FAIL:
            raise DeviceDisconnected(f"DYNAMIXEL {what}: transmit failed ({text})")
        raise ProtocolError(f"DYNAMIXEL {what}: {text} ({result})")

    def _raise_for_error(self, dxl_id: int, error: int, timeout: float | None) -> None:
        if not error:
            return
        if error & ERRBIT_ALERT:
            hw = self._read(dxl_id, ADDR_HARDWARE_ERROR, 1, timeout, check_alert=False)
            raise DeviceFault(f"DYNAMIXEL id {dxl_id}: hardware error status 0x{hw:02x}", code=hw)
        num = error & 0x7F
        raise DeviceFault(
            f"DYNAMIXEL id {dxl_id}: {self._ph.getRxPacketError(error)} (error {num})", code=0x100 | num
        )

    def _with_timeout(self, timeout: float | None) -> None:
        self._port.call_timeout_ms = 1000.0 * (self.timeout if timeout is None else timeout)

    def _read(self, dxl_id: int, addr: int, size: int, timeout: float | None, check_alert: bool = True) -> int:
        if self._ahead is not None:
            self._settle(self.timeout if timeout is None else timeout)
        self._with_timeout(timeout)
        data, result, error = self._ph.readTxRx(self._port, dxl_id, addr, size)
        self._check_comm(result, f"read {addr} of id {dxl_id}")
        if check_alert:
            self._raise_for_error(dxl_id, error, timeout)
        elif error & 0x7F:
            self._raise_for_error(dxl_id, error & 0x7F, timeout)
        return int.from_bytes(bytes(data[:size]), "little")

    def _write(self, dxl_id: int, addr: int, size: int, value: int, timeout: float | None) -> None:
        if self._ahead is not None:
            self._settle(self.timeout if timeout is None else timeout)
        self._with_timeout(timeout)
        u = to_unsigned(int(value), size)
        result, error = self._ph.writeTxRx(self._port, dxl_id, addr, size, list(u.to_bytes(size, "little")))
        self._check_comm(result, f"write {addr} of id {dxl_id}")
        self._raise_for_error(dxl_id, error, timeout)


#: the wire-format names (:mod:`hil.protocols.codecs`) stay importable from this module
__getattr__ = forwarder(_wire, __name__)
