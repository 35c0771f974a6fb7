"""Simulated chain of DYNAMIXEL X-series servos (e.g. XM430-W350) behind a pseudo-terminal.

The simulated bus holds the *master* side of a pty (``os.openpty``); the adapter under test - or
the unmodified ``dynamixel_sdk`` - opens the slave path (:attr:`DynamixelChain.port`) exactly as
it would open ``/dev/ttyUSB0``. A background thread parses DYNAMIXEL Protocol 2.0 instruction
packets and answers with status packets.

Protocol 2.0 (ROBOTIS e-manual, "DYNAMIXEL Protocol 2.0"):

* instruction packet ``FF FF FD 00 ID LEN_L LEN_H INST PARAM... CRC_L CRC_H``;
  ``LEN`` = number of parameters + 3; status packet: ``INST = 0x55`` followed by an ``ERR`` byte
  (bit 7 = alert: see Hardware Error Status(70); bits 0-6 = error number: 1 result fail,
  2 instruction, 3 CRC, 4 data range, 5 data length, 6 data limit, 7 access);
* byte stuffing: inside INST..PARAM, ``FF FF FD`` is sent as ``FF FF FD FD``; LEN and CRC are
  computed over the stuffed packet;
* CRC-16 polynomial 0x8005, init 0, not reflected (``hil.protocols.crc.crc16_dynamixel``).

Implemented instructions: ping (0x01, unicast and broadcast), read (0x02), write (0x03),
reboot (0x08, answers only), sync read (0x82), sync write (0x83), bulk read (0x92),
bulk write (0x93). Others get error 2 (instruction error).

Control table (XM430-W350 e-manual; sizes in bytes): model number(0,2)=1020,
firmware version(6,1), ID(7,1), operating mode(11,1), current limit(38,2)=1193, torque enable(64,1),
hardware error status(70,1), goal current(102,2, signed, 2.69 mA), present current(126,2, signed),
present velocity(128,4, signed, 0.229 rev/min), present position(132,4, signed, 4096 ticks/rev).
Writes to the EEPROM area (< 64) while torque is on fail with error 7 (access), as on the servo.

**Factory defaults** (XM430-W350 e-manual, control table "Initial Value" column): Baud Rate(8) = 1
(57 600 bps), Return Delay Time(9) = 250 (x 2 us = 500 us), ID(7) = 1, Operating Mode(11) = 3.
A chain can be built with other values (``baud_index``, ``return_delay``: a bench whose servos were
configured). The servo only understands the host at its own baud rate: the chain reads the line
speed the host set on the pty (termios of the slave end; pyserial sets it) and ignores packets sent
at another standard rate (counted in ``baud_mismatch``; a custom rate it cannot read is accepted).
Writing Baud Rate(8) takes effect at once, as on the servo.
**Link budget** (``link_budget=True``, as a lockstep bench builds it): the half-duplex line carries
``baud / 10`` bytes per ``clock`` second (8N1), instruction and status packets together
(:class:`hil.mocks.pty.LinkBudget`, the budget :mod:`hil.protocols.link_budget` checks at load
time); a status packet the line has no room left for is not sent (``link_dropped``): the host
times out, as with a real line that cannot carry the traffic. Not enforced until the clock first
moves (the adapter's open sequence paces itself on the wall clock, which lockstep does not model).
Each status packet is sent after the
servo's Return Delay Time (wall clock in a threaded chain: a host that cares for speed writes 0
there, as the adapter does by default; simulated in a chain served in lockstep).

**Served in lockstep** (``threaded=False``, what a lockstep bench builds): no thread; the host's
barrier (:meth:`DynamixelChain.serve_pending`) processes what the host wrote and answers it in the
host's thread, so an answer never depends on how fast the machine schedules a device thread.

**Physics (lockstep).** Servo ``ids[i]`` is joint ``i`` of the :class:`SimulatedJoints` handle.
Whenever a goal current or the torque enable changes, the chain applies
``effort_i = goal_current_i * 2.69 mA * torque_constant`` (N.m) to the plant (0 when torque is
off or the mode is not current control, 0); present position/velocity are computed from the plant
state when a read is answered. Present current echoes the goal current (ideal current loop).
Replies depend only on this state. Because a sync write gets no reply, a lockstep runner calls
:meth:`DynamixelChain.sync` with the number of bytes the host has written before stepping the plant.

**Faults** (:mod:`hil.mocks.faults`); the chain's *tick* is the index of the instruction packet
being processed (0, 1, ...); decisions are drawn per status packet:

* drop / disconnect: the status packet is not sent (host times out); while disconnected the
  chain also ignores writes;
* corrupt: one byte from the ERR byte on is flipped, so the CRC no longer matches;
* garbage: random bytes are sent before the status packet (host must resynchronise);
* stale: present values are repeated from the previous reply of that servo;
* device error: Hardware Error Status(70) holds ``error_code`` and every status packet has the
  alert bit (0x80) set, while the error is scheduled.

**Bus Watchdog(98)** (e-manual, X series RAM area, 1 byte): 0 = off (writing 0 also clears the
error), 1..127 = armed, unit 20 ms; while Torque Enable is 1 and no instruction packet arrived for
longer than that, the servo stops (Goal Current := 0, no effort) and Bus Watchdog reads -1 (0xFF,
Bus Watchdog Error); writing a goal value is then refused with error 4 (data range) until 0 is
written to 98. Time is the chain's ``clock`` (the simulated clock in lockstep): the watchdog is
checked on every instruction packet and by :meth:`DynamixelChain.check_watchdog` (the lockstep
bench calls it once per tick, so a silent host is caught without any packet).
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from hil.mocks.faults import FaultInjector, FaultPlan
from hil.mocks.interfaces import SimulatedJoints
from hil.mocks.pty import LinkBudget, close_fds, host_writes, open_raw_pty, pending_host_bytes, push_to_host
from hil.protocols.codecs.crc import crc16_dynamixel
from hil.protocols.codecs.dynamixel import BAUD_RATES as _BAUD_RATES

logger = logging.getLogger(__name__)

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
INST_PING = 0x01
INST_READ = 0x02
INST_WRITE = 0x03
INST_REBOOT = 0x08
INST_STATUS = 0x55
INST_SYNC_READ = 0x82
INST_SYNC_WRITE = 0x83
INST_BULK_READ = 0x92
INST_BULK_WRITE = 0x93

ERR_RESULT_FAIL = 0x01
ERR_INSTRUCTION = 0x02
ERR_CRC = 0x03
ERR_DATA_RANGE = 0x04
ERR_DATA_LENGTH = 0x05
ERR_DATA_LIMIT = 0x06
ERR_ACCESS = 0x07
ERR_ALERT = 0x80

# control table addresses (XM430-W350)
ADDR_MODEL_NUMBER = 0
ADDR_FIRMWARE_VERSION = 6
ADDR_ID = 7
ADDR_BAUD_RATE = 8
ADDR_RETURN_DELAY = 9
ADDR_OPERATING_MODE = 11
ADDR_CURRENT_LIMIT = 38
ADDR_TORQUE_ENABLE = 64
ADDR_STATUS_RETURN_LEVEL = 68
ADDR_HARDWARE_ERROR = 70
ADDR_BUS_WATCHDOG = 98
BUS_WATCHDOG_UNIT_S = 0.020
BUS_WATCHDOG_ERROR = 0xFF
ADDR_GOAL_CURRENT = 102
ADDR_PRESENT_CURRENT = 126
ADDR_PRESENT_VELOCITY = 128
ADDR_PRESENT_POSITION = 132
TABLE_SIZE = 662
EEPROM_END = 64
READ_ONLY = {*range(0, 7), 69, 70, *range(120, 148)}

CURRENT_UNIT_A = 0.00269
VELOCITY_UNIT_RPM = 0.229
TICKS_PER_REV = 4096

BAUD_RATES = _BAUD_RATES  # Baud Rate(8) index -> bps (X-series e-manual), shared with the adapter
FACTORY_BAUD_INDEX = 1
FACTORY_RETURN_DELAY = 250  # x 2 us
RETURN_DELAY_UNIT_S = 2e-6


def baud_index(bps: int) -> int:
    """Baud Rate(8) index of a line speed (ValueError if the X series has no such rate)."""
    for k, v in BAUD_RATES.items():
        if v == int(bps):
            return k
    raise ValueError(f"DYNAMIXEL X has no baud rate {bps}; choose one of {sorted(BAUD_RATES.values())}")


def _termios_bps(fd: int) -> int | None:
    """Line speed (bps) set on a tty, or None when unknown (custom speed, closed fd)."""
    import termios

    try:
        speed = termios.tcgetattr(fd)[5]
    except (termios.error, OSError):
        return None
    for bps in BAUD_RATES.values():
        if getattr(termios, f"B{bps}", None) == speed:
            return bps
    return None


# ------------------------------------------------------------------------------------------------
# packet codec (pure)
# ------------------------------------------------------------------------------------------------
def stuff(body: bytes) -> bytes:
    """Byte stuffing of the INST..PARAM field: after every ``FF FF FD`` of the original bytes an
    extra ``FD`` is inserted (the header's reserved 0x00 precedes INST, so it never triggers)."""
    out = bytearray()
    for i, b in enumerate(body):
        out.append(b)
        if b == 0xFD and i >= 2 and body[i - 2] == 0xFF and body[i - 1] == 0xFF:
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes) -> bytes:
    """Inverse of :func:`stuff`: drop the ``FD`` that follows each ``FF FF FD``."""
    out = bytearray()
    i = 0
    while i < len(body):
        b = body[i]
        out.append(b)
        stuffed = b == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF
        if stuffed and i + 1 < len(body) and body[i + 1] == 0xFD:
            i += 1
        i += 1
    return bytes(out)


def build_packet(dxl_id: int, instruction: int, params: bytes = b"") -> bytes:
    """A complete Protocol 2.0 packet (instruction, or status when ``instruction`` is 0x55 and
    ``params`` starts with the error byte), stuffed, with length and CRC."""
    body = stuff(bytes([instruction]) + bytes(params))
    length = len(body) + 2
    pkt = HEADER + bytes([dxl_id & 0xFF, length & 0xFF, length >> 8]) + body
    return pkt + crc16_dynamixel(pkt).to_bytes(2, "little")


def build_status(dxl_id: int, error: int, params: bytes = b"") -> bytes:
    return build_packet(dxl_id, INST_STATUS, bytes([error & 0xFF]) + bytes(params))


@dataclass(frozen=True)
class Packet:
    """A decoded packet: ``params`` already unstuffed (for status packets ``params[0]`` is ERR)."""

    dxl_id: int
    instruction: int
    params: bytes
    raw: bytes = b""  # the frame as received (stuffed, with CRC)


class PacketDecodeError(ValueError):
    """A complete frame was found but its CRC does not match (``dxl_id`` of the frame kept)."""

    def __init__(self, message: str, dxl_id: int, instruction: int) -> None:
        super().__init__(message)
        self.dxl_id = dxl_id
        self.instruction = instruction


def find_packet(buf: bytearray) -> tuple[Packet | None, int, PacketDecodeError | None]:
    """Look for one packet at the start of ``buf``.

    Returns ``(packet, consumed, error)``: ``consumed`` bytes may be dropped from ``buf`` (junk
    before a header, or a whole frame); ``packet`` is None if more bytes are needed or the frame
    was bad (``error`` then says why, for a CRC failure).
    """
    i = 0
    n = len(buf)
    while True:
        j = buf.find(b"\xff\xff\xfd", i)
        if j < 0:
            return None, max(0, n - 2), None  # keep a possible partial header
        if j + 3 < n and buf[j + 3] == 0xFD:  # stuffed pattern, not a header
            i = j + 1
            continue
        if n - j < 10:
            return None, j, None
        if buf[j + 3] != 0x00:
            i = j + 1
            continue
        length = buf[j + 5] | (buf[j + 6] << 8)
        total = 7 + length
        if length < 3 or length > 1024:
            i = j + 1
            continue
        if n - j < total:
            return None, j, None
        frame = bytes(buf[j : j + total])
        crc = int.from_bytes(frame[-2:], "little")
        if crc16_dynamixel(frame[:-2]) != crc:
            err = PacketDecodeError("CRC mismatch", frame[4], frame[7])
            return None, j + total, err
        body = unstuff(frame[7:-2])
        return Packet(frame[4], body[0], bytes(body[1:]), frame), j + total, None


def to_signed(value: int, nbytes: int) -> int:
    bits = 8 * nbytes
    value &= (1 << bits) - 1
    return value - (1 << bits) if value >= 1 << (bits - 1) else value


def to_unsigned(value: int, nbytes: int) -> int:
    bits = 8 * nbytes
    lo, hi = -(1 << (bits - 1)), (1 << bits) - 1
    if not lo <= value <= hi:
        raise OverflowError(f"{value} does not fit in {nbytes} bytes")
    return value & ((1 << bits) - 1)


# ------------------------------------------------------------------------------------------------
# simulated servos
# ------------------------------------------------------------------------------------------------
@dataclass
class ServoModel:
    """Per-model constants of the simulation (defaults: XM430-W350 at 12 V)."""

    name: str = "XM430-W350"
    model_number: int = 1020
    firmware_version: int = 45
    current_limit: int = 1193  # Current Limit(38) initial value, units of 2.69 mA
    torque_constant: float = 4.1 / 2.3  # N.m per A at the output: stall 4.1 N.m at 2.3 A (12 V)


class SimulatedServo:
    """Control-table memory of one servo."""

    def __init__(self, dxl_id: int, model: ServoModel, baud: int = FACTORY_BAUD_INDEX,
                 return_delay: int = FACTORY_RETURN_DELAY) -> None:
        self.table = bytearray(TABLE_SIZE)
        self.model = model
        self._set(ADDR_MODEL_NUMBER, 2, model.model_number)
        self._set(ADDR_FIRMWARE_VERSION, 1, model.firmware_version)
        self._set(ADDR_ID, 1, dxl_id)
        self._set(ADDR_BAUD_RATE, 1, baud)  # factory: 1 = 57 600 bps
        self._set(ADDR_RETURN_DELAY, 1, return_delay)  # factory: 250 x 2 us
        self._set(ADDR_OPERATING_MODE, 1, 3)  # position control (factory default)
        self._set(13, 1, 2)  # protocol version
        self._set(ADDR_CURRENT_LIMIT, 2, model.current_limit)
        self._set(ADDR_STATUS_RETURN_LEVEL, 1, 2)
        self.last_present: bytes | None = None

    @property
    def dxl_id(self) -> int:
        return self.table[ADDR_ID]

    def _set(self, addr: int, size: int, value: int) -> None:
        self.table[addr : addr + size] = (value & ((1 << (8 * size)) - 1)).to_bytes(size, "little")

    def get(self, addr: int, size: int, signed: bool = False) -> int:
        v = int.from_bytes(self.table[addr : addr + size], "little")
        return to_signed(v, size) if signed else v

    @property
    def torque_on(self) -> bool:
        return self.table[ADDR_TORQUE_ENABLE] == 1

    def check_write(self, addr: int, data: bytes) -> int:
        """Error number (0 = ok) for writing ``data`` at ``addr``."""
        end = addr + len(data)
        if addr < 0 or end > TABLE_SIZE:
            return ERR_ACCESS
        if any(a in READ_ONLY for a in range(addr, end)):
            return ERR_ACCESS
        if addr < EEPROM_END and self.torque_on:
            return ERR_ACCESS  # EEPROM is locked while torque is enabled
        if addr <= ADDR_BUS_WATCHDOG < end and data[ADDR_BUS_WATCHDOG - addr] > 127:
            return ERR_DATA_RANGE  # -1 is a status, not a value to write
        if addr <= ADDR_GOAL_CURRENT < end or addr <= ADDR_GOAL_CURRENT + 1 < end:
            if self.table[ADDR_BUS_WATCHDOG] == BUS_WATCHDOG_ERROR:
                return ERR_DATA_RANGE  # goal values are read-only after a Bus Watchdog Error
            if not (addr <= ADDR_GOAL_CURRENT and end >= ADDR_GOAL_CURRENT + 2):
                return ERR_DATA_LENGTH
            off = ADDR_GOAL_CURRENT - addr
            goal = to_signed(int.from_bytes(data[off : off + 2], "little"), 2)
            if abs(goal) > self.get(ADDR_CURRENT_LIMIT, 2):
                return ERR_DATA_LIMIT
        return 0

    def write(self, addr: int, data: bytes) -> None:
        self.table[addr : addr + len(data)] = data


class DynamixelChain:
    """A chain of simulated X-series servos on a pty (see the module docstring).

    ``joints.dof`` must equal ``len(ids)``. Use as a context manager or call :meth:`close`.
    """

    def __init__(
        self,
        joints: SimulatedJoints,
        ids: list[int] | tuple[int, ...] = (1,),
        *,
        model: ServoModel | None = None,
        faults: FaultPlan | FaultInjector | None = None,
        seed: int | None = 0,
        clock: Callable[[], float] = time.monotonic,
        baudrate: int = BAUD_RATES[FACTORY_BAUD_INDEX],
        return_delay: int = FACTORY_RETURN_DELAY,
        link_budget: bool = False,
        threaded: bool = True,
    ) -> None:
        if joints.dof != len(ids):
            raise ValueError(f"joints.dof={joints.dof} but {len(ids)} servo ids")
        if len(set(ids)) != len(ids) or any(not 0 <= i <= 252 for i in ids):
            raise ValueError(f"servo ids must be unique and in 0..252, got {ids}")
        self.joints = joints
        self.model = model or ServoModel()
        index = baud_index(baudrate)
        if not 0 <= int(return_delay) <= 254:
            raise ValueError(f"return_delay must be 0..254 (x 2 us), got {return_delay}")
        self.servos = {i: SimulatedServo(i, self.model, index, int(return_delay)) for i in ids}
        self.baud_mismatch = 0  # packets sent at another line speed than the servos' (ignored)
        self.ids = list(ids)
        self.injector = faults if isinstance(faults, FaultInjector) else FaultInjector(faults, seed)
        self._master, self._slave, self.port = open_raw_pty(nonblocking_master=False)
        self._buf = bytearray()
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._closed = False
        self.tick = -1
        self.rx_bytes = 0
        self.packets = 0
        self.crc_errors = 0
        self.replies_dropped = 0
        self.stale_replies = 0
        self.rx_frames: deque[bytes] = deque(maxlen=64)  # raw instruction frames, newest last
        self.clock = clock
        self._last_instruction = clock()
        #: baud/10 bytes per ``clock`` second on the half-duplex line, instructions and replies
        #: together (``link_budget=True``; meant for a simulated clock: a lockstep bench)
        self.link: LinkBudget | None = LinkBudget(baudrate) if link_budget else None
        self._link_t = self._link_t0 = clock()
        self.link_dropped = 0  # status packets the line could not carry (not sent: the host times out)
        self.watchdog_expired = 0  # Bus Watchdog Errors raised so far (all servos)
        self.threaded = bool(threaded)
        self._thread: threading.Thread | None = None
        if self.threaded:
            self._thread = threading.Thread(target=self._serve, name="sim-dynamixel", daemon=True)
            self._thread.start()
        logger.debug("simulated DYNAMIXEL chain %s on %s", self.ids, self.port)

    # -- public -------------------------------------------------------------------------------
    def serve_pending(self) -> int:
        """Lockstep barrier of a chain built with ``threaded=False`` (served in the host's thread):
        process every byte the host has written so far and answer it, so that every status packet
        can be read by the host when this returns. Never waits on a clock: Linux moves pty bytes to
        the other end in a worker, and a poll of a pty that finds no input first runs that worker
        (``n_tty_poll`` -> ``tty_buffer_flush_work``), so polling the master without waiting sees
        everything the host wrote, and polling the chain's own slave end after the answers makes
        them visible to the host's ``in_waiting`` (FIONREAD, which does not run the worker).
        Returns the number of bytes processed."""
        if self._closed:
            return 0
        n = 0
        wrote = False
        for data in pending_host_bytes(self._master):
            n += len(data)
            with self._cond:
                self._buf += data
                replies = self._process_buffer()
                self.rx_bytes += len(data)
            if replies:
                self._send(replies)
                wrote = True
        if wrote:
            push_to_host(self._slave)  # the answers into the host's input queue
        return n

    def sync(self, tx_bytes: int, timeout: float = 1.0) -> None:
        """Block until the chain has consumed and processed ``tx_bytes`` bytes in total from the
        host (e.g. the adapter's ``tx_bytes`` counter). Lockstep barrier for reply-less writes of a
        threaded chain (a chain served in the host's thread: :meth:`serve_pending`)."""
        if not self.threaded:
            self.serve_pending()
            if self.rx_bytes < tx_bytes:
                raise TimeoutError(f"chain consumed {self.rx_bytes} of {tx_bytes} bytes")
            return
        deadline = time.monotonic() + timeout
        with self._cond:
            while self.rx_bytes < tx_bytes:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"chain consumed {self.rx_bytes} of {tx_bytes} bytes")
                self._cond.wait(left)

    def check_watchdog(self) -> list[int]:
        """Apply the Bus Watchdog(98) of every servo at the current ``clock`` time; returns the ids
        that expired now (their goal current is zeroed, 98 reads 0xFF)."""
        with self._cond:
            return self._check_watchdog()

    def _check_watchdog(self) -> list[int]:
        silent = self.clock() - self._last_instruction
        expired = []
        for i, servo in self.servos.items():
            units = servo.table[ADDR_BUS_WATCHDOG]
            if servo.torque_on and 1 <= units <= 127 and silent > units * BUS_WATCHDOG_UNIT_S + 1e-9:
                servo.table[ADDR_BUS_WATCHDOG] = BUS_WATCHDOG_ERROR
                servo.write(ADDR_GOAL_CURRENT, b"\x00\x00")
                expired.append(i)
        if expired:
            self.watchdog_expired += len(expired)
            logger.warning("simulated DYNAMIXEL ids %s: Bus Watchdog expired after %.3f s without a packet",
                        expired, silent)
            self.joints.apply_effort(self.effort())
        return expired

    def effort(self) -> np.ndarray:
        """Effort (N.m) the chain currently applies to the plant."""
        return np.array([self._servo_effort(self.servos[i]) for i in self.ids])

    def close(self) -> None:
        """Stop the bus thread and close the pty. Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        close_fds(self._master, self._slave)

    def __enter__(self) -> DynamixelChain:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- bus thread ---------------------------------------------------------------------------
    def _serve(self) -> None:
        for data in host_writes(self._master, self._stop):
            with self._cond:
                self._buf += data
                replies = self._process_buffer()
                self.rx_bytes += len(data)
            if replies:
                self._send(replies)
            with self._cond:
                self._cond.notify_all()

    def _process_buffer(self) -> bytes:
        out = bytearray()
        while True:
            pkt, consumed, err = find_packet(self._buf)
            if consumed:
                del self._buf[:consumed]
            if err is not None:
                self.crc_errors += 1
                self.tick += 1
                if err.dxl_id in self.servos:
                    out += self._status(self.servos[err.dxl_id], ERR_CRC)
                continue
            if pkt is None:
                return bytes(out)
            host_bps = _termios_bps(self._slave)
            if host_bps is not None and all(BAUD_RATES.get(sv.table[ADDR_BAUD_RATE]) != host_bps
                                            for sv in self.servos.values()):
                self.baud_mismatch += 1  # framing errors on the servo's UART: nothing understood
                continue
            self._check_watchdog()  # the interval that ends with this packet
            self._last_instruction = self.clock()
            self.tick += 1
            self.packets += 1
            self.rx_frames.append(pkt.raw)
            code = self.injector.error_code(self.tick) & 0xFF
            for servo in self.servos.values():
                servo.table[ADDR_HARDWARE_ERROR] = code
            reply = self._handle(pkt)
            if self.link is not None and not self._carried(len(pkt.raw), len(reply)):
                continue
            out += reply

    def _carried(self, n_in: int, n_out: int) -> bool:
        """Link budget of one exchange: the instruction's bytes were on the line (the host sent
        them); the status packets go only if the bytes left since then carry them, else they are
        lost (``link_dropped``; the host times out, as on a line that cannot carry its traffic)."""
        link = self.link
        assert link is not None
        bps = BAUD_RATES.get(self.servos[self.ids[0]].table[ADDR_BAUD_RATE])
        if bps is not None and bps != link.baud:  # Baud Rate(8) written: the line's new speed
            link.baud, link.bytes_per_s = float(bps), bps / 10.0
        now = self.clock()
        if now <= self._link_t0:  # before the clock first moves (the adapter's open sequence: its
            return True           # request/answer traffic paces itself on the wall clock)
        link.advance(now - self._link_t)
        self._link_t = now
        link.credit -= n_in
        if n_out == 0 or link.take(n_out):
            return True
        self.link_dropped += 1
        return False

    def _send(self, data: bytes) -> None:
        try:
            os.write(self._master, data)
        except OSError:
            logger.debug("simulated DYNAMIXEL chain: host side closed, reply lost")

    # -- instruction handling -------------------------------------------------------------------
    def _status(self, servo: SimulatedServo, error: int, params: bytes = b"") -> bytes:
        inj = self.injector
        tick = self.tick
        if servo.table[ADDR_HARDWARE_ERROR]:
            error |= ERR_ALERT
        if inj.is_disconnected(tick) or inj.should_drop(tick):
            self.replies_dropped += 1
            return b""
        inj.hold_up()
        delay = servo.table[ADDR_RETURN_DELAY] * RETURN_DELAY_UNIT_S
        if delay > 0 and self.threaded:
            # Return Delay Time(9): the servo waits before its status packet. Served in lockstep the
            # wait is simulated (at most 0.5 ms, far inside any reply timeout: the answer arrives)
            time.sleep(delay)
        pkt = build_status(servo.dxl_id, error, params)
        if inj.should_corrupt(tick):
            pkt = inj.corrupt(pkt, start=8)
        return inj.garbage() + pkt

    def _read_bytes(self, servo: SimulatedServo, addr: int, size: int) -> tuple[int, bytes]:
        if addr < 0 or size < 0 or addr + size > TABLE_SIZE:
            return ERR_ACCESS, b""
        if addr < ADDR_PRESENT_POSITION + 4 and addr + size > ADDR_PRESENT_CURRENT:
            self._refresh_present(servo)
        return 0, bytes(servo.table[addr : addr + size])

    def _refresh_present(self, servo: SimulatedServo) -> None:
        if self.injector.should_repeat_stale(self.tick) and servo.last_present is not None:
            self.stale_replies += 1
            servo.table[ADDR_PRESENT_CURRENT : ADDR_PRESENT_POSITION + 4] = servo.last_present
            return
        k = self.ids.index(servo.dxl_id)
        pos = float(self.joints.position()[k])
        vel = float(self.joints.velocity()[k])
        current = servo.get(ADDR_GOAL_CURRENT, 2, signed=True) if self._drives(servo) else 0
        # the int32 range, clamped as integers (np.clip of a Python int: the same value, ~10x the cost)
        ticks = min(max(round(pos * TICKS_PER_REV / (2 * math.pi)), -(2**31)), 2**31 - 1)
        vraw = min(max(round(vel * 60.0 / (2 * math.pi * VELOCITY_UNIT_RPM)), -(2**31)), 2**31 - 1)
        servo.write(ADDR_PRESENT_CURRENT, to_unsigned(current, 2).to_bytes(2, "little"))
        servo.write(ADDR_PRESENT_VELOCITY, to_unsigned(vraw, 4).to_bytes(4, "little"))
        servo.write(ADDR_PRESENT_POSITION, to_unsigned(ticks, 4).to_bytes(4, "little"))
        servo.last_present = bytes(servo.table[ADDR_PRESENT_CURRENT : ADDR_PRESENT_POSITION + 4])

    @staticmethod
    def _drives(servo: SimulatedServo) -> bool:
        return servo.torque_on and servo.table[ADDR_OPERATING_MODE] == 0

    def _servo_effort(self, servo: SimulatedServo) -> float:
        if not self._drives(servo):
            return 0.0
        amps = servo.get(ADDR_GOAL_CURRENT, 2, signed=True) * CURRENT_UNIT_A
        return amps * self.model.torque_constant

    def _write(self, servo: SimulatedServo, addr: int, data: bytes) -> int:
        if self.injector.is_disconnected(self.tick):
            return 0
        err = servo.check_write(addr, data)
        if err:
            return err
        servo.write(addr, data)
        self.joints.apply_effort(self.effort())  # zero-order hold of the new goal / enable state
        return 0

    def _handle(self, pkt: Packet) -> bytes:
        inst, p, dxl_id = pkt.instruction, pkt.params, pkt.dxl_id
        if inst == INST_SYNC_READ and dxl_id == BROADCAST_ID and len(p) >= 4:
            addr, size = int.from_bytes(p[0:2], "little"), int.from_bytes(p[2:4], "little")
            out = b""
            for i in p[4:]:
                if i in self.servos:
                    err, data = self._read_bytes(self.servos[i], addr, size)
                    out += self._status(self.servos[i], err, data)
            return out
        if inst == INST_SYNC_WRITE and dxl_id == BROADCAST_ID and len(p) >= 4:
            addr, size = int.from_bytes(p[0:2], "little"), int.from_bytes(p[2:4], "little")
            rec = p[4:]
            for k in range(0, len(rec) - size, size + 1):
                if rec[k] in self.servos:
                    self._write(self.servos[rec[k]], addr, rec[k + 1 : k + 1 + size])
            return b""
        if inst == INST_BULK_READ and dxl_id == BROADCAST_ID:
            out = b""
            for k in range(0, len(p) - 4, 5):
                i = p[k]
                addr = int.from_bytes(p[k + 1 : k + 3], "little")
                size = int.from_bytes(p[k + 3 : k + 5], "little")
                if i in self.servos:
                    err, data = self._read_bytes(self.servos[i], addr, size)
                    out += self._status(self.servos[i], err, data)
            return out
        if inst == INST_BULK_WRITE and dxl_id == BROADCAST_ID:
            k = 0
            while k + 5 <= len(p):
                i = p[k]
                addr = int.from_bytes(p[k + 1 : k + 3], "little")
                size = int.from_bytes(p[k + 3 : k + 5], "little")
                if i in self.servos:
                    self._write(self.servos[i], addr, p[k + 5 : k + 5 + size])
                k += 5 + size
            return b""
        if inst == INST_PING and dxl_id == BROADCAST_ID:
            return b"".join(self._ping_reply(self.servos[i]) for i in self.ids)
        if inst == INST_WRITE and dxl_id == BROADCAST_ID and len(p) >= 3:
            for each in self.servos.values():
                self._write(each, int.from_bytes(p[0:2], "little"), p[2:])
            return b""
        servo = self.servos.get(dxl_id)
        if servo is None:
            return b""  # nobody with that id on the bus (or broadcast read/write: no status)
        if inst == INST_PING:
            return self._ping_reply(servo)
        if inst == INST_READ:
            if len(p) != 4:
                return self._status(servo, ERR_DATA_LENGTH)
            err, data = self._read_bytes(servo, int.from_bytes(p[0:2], "little"), int.from_bytes(p[2:4], "little"))
            return self._status(servo, err, data)
        if inst == INST_WRITE:
            if len(p) < 3:
                return self._status(servo, ERR_DATA_LENGTH)
            return self._status(servo, self._write(servo, int.from_bytes(p[0:2], "little"), p[2:]))
        if inst == INST_REBOOT:
            servo.table[ADDR_TORQUE_ENABLE] = 0
            self.joints.apply_effort(self.effort())
            return self._status(servo, 0)
        return self._status(servo, ERR_INSTRUCTION)

    def _ping_reply(self, servo: SimulatedServo) -> bytes:
        model = servo.get(ADDR_MODEL_NUMBER, 2)
        return self._status(servo, 0, bytes([model & 0xFF, model >> 8, servo.table[ADDR_FIRMWARE_VERSION]]))
