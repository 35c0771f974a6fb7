"""Simulated Robotiq FT-300 force/torque sensor: a real pymodbus server on loopback.

The adapter under test (:class:`hil.protocols.modbus_robotiq.RobotiqFT300`) talks to this device
over a real TCP socket, either with Modbus/TCP (MBAP) framing or with Modbus RTU framing carried
over TCP (``rtu-over-tcp://``: the bytes a USB-RS485 converter would carry, CRC included). Any
plain Modbus client can read the same registers.

Register map (FT-300 manual, "Modbus RTU" section; firmware/serial layout as decoded by
Robotiq's own ``rq_sensor_com.c``), all 16-bit registers, slave id 9:

======== ============================================ =========================================
register content                                      encoding
======== ============================================ =========================================
180..182 Fx, Fy, Fz                                    int16, value = N * 100
183..185 Mx, My, Mz                                    int16, value = N.m * 1000
190..192 accel X, Y, Z                                 int16, value = g * 1000 (0 here)
410      output select                                 write 0x0200 = start data stream
500..502 firmware version                              "FTS" + major, minor, patch bytes
510..513 serial number                                 3 ASCII chars + uint32 (513:512)
514      production year                               uint16
======== ============================================ =========================================

The registers are readable both as holding (FC03, what Robotiq documents) and input registers
(FC04): one shared block.

**Lockstep.** Registers 180-185 are refreshed from the wrench source *when a request arrives*
(``auto_update=True``) or only by an explicit :meth:`SimulatedFT300.update` call
(``auto_update=False``). Either way a reply depends only on the simulated state, never on wall
time. The wrench source is ``SimulatedJoints.measured_force()`` or any callable returning up to 6
values (N, N.m); shorter vectors fill Fx, Fy, ... in order, the rest reads 0. Values are clipped to
the int16 range (+-327.67 N, +-32.767 N.m) like a saturated sensor.

**Faults** (:mod:`hil.mocks.faults`); the device's *tick* is the index of the Modbus request
addressed to its slave id (0, 1, 2, ...; requests for other ids are ignored, as on an RS-485 bus):

* drop / disconnect: no reply at all -> the client times out;
* corrupt: with RTU framing one byte of the reply is flipped and the CRC catches it. With
  Modbus/TCP framing (``tcp_corrupt``): ``"gateway"`` (default) is what a real Modbus/TCP
  installation shows: the TCP/Ethernet checksums protect the wire, the damage happens on the
  gateway's serial side, whose CRC check fails, and the gateway answers exception 11 (gateway
  target device failed to respond); ``"payload"`` flips one byte after the MBAP header (a
  faulty gateway: function code, byte count or a register value may be damaged; only the
  adapter's validation can catch it, and not a low-byte flip that stays in range);
* stale: the registers are not refreshed for this request (previous values repeated);
* device error: the device answers with a Modbus exception response, exception code 4
  (SERVER DEVICE FAILURE); ``error_code`` of the plan is recorded in :attr:`last_error_code`.

``late`` and ``garbage`` are not used by this device (request/response over TCP).

**Lockstep barrier.** The server runs in its own thread (pymodbus' asyncio server) and TCP
delivers bytes asynchronously, so a lockstep bench counts: the adapter's requests (its ``waits``
link, :meth:`hil.protocols.waits.LockstepWaits.link`) against the server's answers
(:attr:`SimulatedFT300.answered`, counted after pymodbus wrote each one, :meth:`SimulatedFT300.settle`),
and the answer bytes written (``link.device_tx``) against those the adapter has taken: no
deadline, however long the machine takes to run the server thread.
"""

from __future__ import annotations

import asyncio
import logging
import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from hil.mocks.faults import BoundedLog, FaultInjector, FaultPlan
from hil.mocks.interfaces import SimulatedJoints

logger = logging.getLogger(__name__)

WrenchSource = Callable[[], np.ndarray]


def wrench_source(source: SimulatedJoints | WrenchSource | None) -> WrenchSource:
    """Callable returning the simulated wrench [Fx, Fy, Fz, Mx, My, Mz] (N, N·m).

    ``None`` gives zeros; a :class:`SimulatedJoints` gives its measured force.
    """
    if source is None:
        return lambda: np.zeros(6)
    if hasattr(source, "measured_force"):
        return source.measured_force  # type: ignore[union-attr]
    if callable(source):
        return source
    raise TypeError("source must be a SimulatedJoints, a callable or None")


REG_WRENCH = 180
REG_ACCEL = 190
REG_OUTPUT_SELECT = 410
REG_FIRMWARE = 500
REG_SERIAL = 510
REG_PRODUCTION_YEAR = 514
STREAM_START_VALUE = 0x0200
FORCE_SCALE = 100.0  # register = N * 100
TORQUE_SCALE = 1000.0  # register = N.m * 1000
WRENCH_SCALES = np.array([FORCE_SCALE] * 3 + [TORQUE_SCALE] * 3)
DEFAULT_SLAVE_ID = 9


def wrench_to_registers(wrench: np.ndarray) -> list[int]:
    """Encode (Fx, Fy, Fz, Mx, My, Mz) in N / N.m as six uint16 register values (int16 two's
    complement), rounding to the nearest count and saturating at the int16 range."""
    w = np.zeros(6)
    src = np.asarray(wrench, dtype=float).reshape(-1)[:6]
    w[: src.size] = src
    counts = np.clip(np.rint(w * WRENCH_SCALES), -32768, 32767).astype(np.int64)
    return [int(c) & 0xFFFF for c in counts]


def firmware_registers(version: tuple[int, int, int] = (1, 0, 3), prefix: str = "FTS") -> list[int]:
    """Registers 500..502 as Robotiq's driver decodes them ("%c%c%c-%u.%u.%u")."""
    p = prefix.encode("ascii")[:3].ljust(3, b" ")
    major, minor, patch = version
    return [(p[0] << 8) | p[1], (p[2] << 8) | (major & 0xFF), ((minor & 0xFF) << 8) | (patch & 0xFF)]


def serial_registers(prefix: str = "SIM", number: int = 1) -> list[int]:
    """Registers 510..513: three ASCII chars, then the number as uint32 with 513 the high word."""
    p = prefix.encode("ascii")[:3].ljust(3, b" ")
    return [(p[0] << 8) | p[1], p[2] << 8, number & 0xFFFF, (number >> 16) & 0xFFFF]


class SimulatedFT300:
    """A simulated FT-300 behind a pymodbus server on ``127.0.0.1`` (background thread).

    ``framing`` is ``"tcp"`` (Modbus/TCP, MBAP header) or ``"rtu"`` (RTU frames over TCP).
    ``port=0`` picks a free port; the bound port is :attr:`port` and the adapter URL :attr:`url`.
    ``start_timeout`` (s, wall clock): how long to wait for the server to listen; None: as long as
    its thread lives (a lockstep bench: however long a loaded machine takes).
    Use as a context manager or call :meth:`close` (idempotent).
    """

    def __init__(
        self,
        source: SimulatedJoints | WrenchSource | None = None,
        *,
        framing: str = "tcp",
        host: str = "127.0.0.1",
        port: int = 0,
        slave: int = DEFAULT_SLAVE_ID,
        faults: FaultPlan | FaultInjector | None = None,
        seed: int | None = 0,
        auto_update: bool = True,
        firmware: tuple[int, int, int] = (1, 0, 3),
        serial: tuple[str, int] = ("SIM", 1),
        production_year: int = 2024,
        start_timeout: float | None = 5.0,
        tcp_corrupt: str = "gateway",
    ) -> None:
        # Imported here: pymodbus is an optional dependency (extra "modbus").
        from pymodbus import FramerType
        from pymodbus.simulator import DataType, SimData, SimDevice

        if framing not in ("tcp", "rtu"):
            raise ValueError(f"framing must be 'tcp' or 'rtu', got {framing!r}")
        if tcp_corrupt not in ("gateway", "payload"):
            raise ValueError(f"tcp_corrupt must be 'gateway' or 'payload', got {tcp_corrupt!r}")
        self.tcp_corrupt = tcp_corrupt
        self.framing = framing
        self.host = host
        self.slave = slave
        self.auto_update = auto_update
        self.injector = faults if isinstance(faults, FaultInjector) else FaultInjector(faults, seed)
        self._source = wrench_source(source)
        self._lock = threading.Lock()
        self._tick = -1  # index of the request being served
        self._registers: list[int] | None = None  # live register list inside the pymodbus runtime
        self._block_start = REG_WRENCH
        self._pending_wrench: list[int] = wrench_to_registers(np.zeros(6))
        self.requests = 0
        self.replies_dropped = 0
        self.stale_replies = 0
        self.corrupted_replies = 0
        self.exception_replies = 0
        self.last_error_code = 0
        self.streaming_requested = False
        self.written: BoundedLog = BoundedLog()  # newest (address, values)
        self.last_request = b""  # raw bytes of the last request frame received (diagnostics)
        #: requests answered so far (a suppressed reply counts) and the bytes written for them
        self.answered = 0
        self.answer_bytes = 0
        self._answered = threading.Condition()
        #: the adapter's lockstep link (:meth:`hil.protocols.waits.LockstepWaits.link`): its
        #: ``tx_units`` (requests sent) and ``device_tx`` (answer bytes written) make the barrier
        self.link: Any = None

        simdata = [
            SimData(address=REG_WRENCH, count=6, values=0, datatype=DataType.REGISTERS),
            SimData(address=REG_ACCEL, count=3, values=0, datatype=DataType.REGISTERS),
            SimData(address=REG_OUTPUT_SELECT, count=1, values=0, datatype=DataType.REGISTERS),
            SimData(address=REG_FIRMWARE, values=firmware_registers(firmware), datatype=DataType.REGISTERS),
            SimData(address=REG_SERIAL, values=serial_registers(*serial), datatype=DataType.REGISTERS),
            SimData(address=REG_PRODUCTION_YEAR, values=production_year, datatype=DataType.REGISTERS),
        ]
        # id 0 = "every other id": a placeholder so that pymodbus 3.16 (whose SimCore raises
        # KeyError for unknown ids) answers something, which _trace_packet then suppresses.
        self._devices = [
            SimDevice(id=slave, simdata=simdata, action=self._action),
            SimDevice(id=0, simdata=[SimData(address=0, count=1, datatype=DataType.REGISTERS)]),
        ]
        self._addressed = True
        self._framer = FramerType.RTU if framing == "rtu" else FramerType.SOCKET
        self._loop = asyncio.new_event_loop()
        self._server: Any = None
        self._ready = threading.Event()
        self._start_error: BaseException | None = None
        self._closed = False
        self._thread = threading.Thread(
            target=self._run, args=(port,), name=f"sim-ft300-{framing}", daemon=True
        )
        self._thread.start()
        while not self._ready.wait(start_timeout if start_timeout is not None else 1.0):
            if start_timeout is not None or not self._thread.is_alive():
                self.close()
                raise TimeoutError("simulated FT-300 server did not start")
        if self._start_error is not None:
            self.close()
            raise RuntimeError(f"simulated FT-300 server failed: {self._start_error}")
        server: Any = self._server  # set by the server thread before _ready
        self.port: int = server.transport.sockets[0].getsockname()[1]
        if not auto_update:
            self.update()
        logger.debug("simulated FT-300 (%s framing) on %s:%d", framing, host, self.port)

    # -- public -------------------------------------------------------------------------------
    @property
    def url(self) -> str:
        """URL for :class:`~hil.protocols.modbus_robotiq.RobotiqFT300`."""
        scheme = "rtu-over-tcp" if self.framing == "rtu" else "tcp"
        return f"{scheme}://{self.host}:{self.port}"

    def update(self) -> None:
        """Snapshot the wrench source for registers 180-185 (explicit lockstep update). The registers
        take it when the next request reads them, unless a stale fault keeps the previous values
        (writing them here at once would undo that fault: issue 27)."""
        values = wrench_to_registers(self._source())
        with self._lock:
            self._pending_wrench = values

    def close(self) -> None:
        """Stop the server and its thread. Idempotent."""
        if self._closed:
            return
        self._closed = True
        if self._server is not None and self._loop.is_running():
            fut = asyncio.run_coroutine_threadsafe(self._server.shutdown(), self._loop)
            try:
                fut.result(timeout=5.0)
            except Exception:
                logger.warning("simulated FT-300: server shutdown did not complete cleanly")
        self._thread.join(timeout=5.0)
        if not self._loop.is_closed() and not self._loop.is_running():
            self._loop.close()

    def __enter__(self) -> SimulatedFT300:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- internals ----------------------------------------------------------------------------
    def _run(self, port: int) -> None:
        from pymodbus.server import ModbusTcpServer

        asyncio.set_event_loop(self._loop)

        async def main() -> None:
            try:
                self._server = ModbusTcpServer(
                    self._devices,
                    framer=self._framer,
                    address=(self.host, port),
                    ignore_missing_devices=True,  # a real RTU slave ignores other ids
                    trace_packet=self._trace_packet,
                    trace_pdu=self._trace_pdu,
                )
                await self._server.listen()
            except BaseException as exc:
                self._start_error = exc
                self._ready.set()
                return
            self._ready.set()
            await self._server.serving

        try:
            self._loop.run_until_complete(main())
        finally:
            self._loop.close()

    def _write_wrench(self, values: list[int]) -> None:
        assert self._registers is not None
        off = REG_WRENCH - self._block_start
        self._registers[off : off + 6] = values

    def _trace_pdu(self, sending: bool, pdu: Any) -> Any:
        if not sending:
            with self._lock:
                self._addressed = getattr(pdu, "dev_id", self.slave) == self.slave
                if self._addressed:
                    self._tick += 1
                    self.requests += 1
        return pdu

    def _trace_packet(self, sending: bool, data: bytes) -> bytes:
        if not sending:
            self.last_request = bytes(data)
            return data
        out = self._reply_bytes(data)
        # pymodbus writes `out` right after this returns, in this loop callback: count it after that
        self._loop.call_soon(self._replied, len(out))
        return out

    def _reply_bytes(self, data: bytes) -> bytes:
        if not self._addressed:
            return b""  # a real RTU slave stays silent for other ids
        tick = self._tick
        inj = self.injector
        if inj.is_disconnected(tick) or inj.should_drop(tick):
            self.replies_dropped += 1
            return b""
        inj.hold_up()
        if inj.should_corrupt(tick):
            self.corrupted_replies += 1
            if self.framing == "tcp" and self.tcp_corrupt == "gateway" and len(data) >= 8:
                # MBAP (transaction, protocol, length = 3, unit) + fc | 0x80 + exception 11
                return data[:4] + (3).to_bytes(2, "big") + data[6:7] + bytes([data[7] | 0x80, 0x0B])
            # keep the RTU address byte / MBAP header intact so the damage lands in the PDU or CRC
            start = 1 if self.framing == "rtu" else 7
            return inj.corrupt(data, start=min(start, len(data) - 1))
        return data

    def _replied(self, nbytes: int) -> None:
        """One request answered (``nbytes`` written, 0 when the reply was suppressed)."""
        with self._answered:
            self.answered += 1
            self.answer_bytes += nbytes
            if self.link is not None:
                self.link.device_tx += nbytes
            self._answered.notify_all()

    def settle(self, requests: int | None = None) -> None:
        """Lockstep barrier (a bench in lockstep: :attr:`link` set): return once the server has
        answered (or deliberately not answered) ``requests`` requests, by default every request the
        adapter on :attr:`link` has sent. Waits as long as the server thread needs: no deadline
        (only a server thread that died ends it, with an error)."""
        if requests is None:
            if self.link is None:
                return
            requests = int(self.link.tx_units)
        with self._answered:
            while self.answered < requests:
                if not self._thread.is_alive():
                    raise RuntimeError(f"simulated FT-300 server stopped with {requests - self.answered} "
                                       "request(s) unanswered")
                self._answered.wait(1.0)  # a liveness check period, not a deadline

    async def _action(
        self,
        function_code: int,
        start_address: int,
        address: int,
        count: int,
        registers: list[int],
        set_values: list[int] | list[bool] | None,
    ) -> Any:
        from pymodbus.constants import ExcCodes

        with self._lock:
            self._registers = registers
            self._block_start = start_address
            tick = self._tick
            code = self.injector.error_code(tick)
            if code:
                self.last_error_code = code
                self.exception_replies += 1
                return ExcCodes.DEVICE_FAILURE
            if set_values:
                self.written.append((address, [int(v) for v in set_values]))
                if address == REG_OUTPUT_SELECT and int(set_values[0]) == STREAM_START_VALUE:
                    # On a serial line the sensor would now switch to its 100 Hz stream; over TCP
                    # there is no stream transport, so only the request is recorded.
                    self.streaming_requested = True
                return None
            touches_wrench = address < REG_WRENCH + 6 and address + count > REG_WRENCH
            if touches_wrench:
                if self.injector.should_repeat_stale(tick):
                    self.stale_replies += 1
                elif self.auto_update:
                    self._write_wrench(wrench_to_registers(self._source()))
                else:
                    self._write_wrench(self._pending_wrench)
        return None
