"""CiA 402 servo drive over CANopen (the :mod:`canopen` package), torque modes, as an
:class:`~hil.protocols.base.Actuator`.

Standards: CiA 301 (CANopen application layer: NMT, SDO, PDO, SYNC, EMCY, heartbeat) and CiA 402 /
IEC 61800-7-201 (drive profile: state machine, modes, objects). SDO, PDO, NMT and EMCY are
canopen's (:class:`canopen.RemoteNode`); the state names and controlword codes are canopen's
:class:`canopen.profiles.p402.State402`. The default object dictionary is the shipped
``hil/protocols/data/cia402.eds`` (pass ``eds=`` for a vendor's EDS).

Open sequence (``enable=True``):

1. NMT Enter pre-operational; identity 0x1018 (vendor id; product code, revision and serial number
   when the drive has them: CiA 301 makes only sub-index 1 mandatory), device type 0x1000 (must be
   profile 402), name 0x1008, software version 0x100A; encoder resolution 0x608F and motor rated
   torque 0x6076 unless given.
2. Heartbeat producer time 0x1017 := ``heartbeat_ms``; the adapter is the heartbeat *consumer*:
   no heartbeat for ``heartbeat_timeout_ms`` (default 3 x ``heartbeat_ms``) or one reporting an NMT
   state other than OPERATIONAL is a :class:`~hil.errors.DeviceFault`.
3. PDO mapping by SDO (canopen ``PdoMap.save``): RPDO1 = controlword 0x6040 + target torque
   0x6071 (transmission type 255: applied on reception; ``sync_rpdo=True``: type 1, applied at the
   next SYNC, the usual choice in cyclic synchronous torque); TPDO1 = statusword 0x6041 + position
   actual 0x6064 + torque actual 0x6077, TPDO2 = velocity actual 0x606C + modes display 0x6061,
   both transmission type 1 (sent on every SYNC). Every other PDO the *drive* has is made invalid
   (COB-ID bit 31, CiA 301 §7.5.2.35/36), whatever the adapter's dictionary lists: the drive is asked
   by SDO for the communication parameters 0x1400 + k / 0x1800 + k, k = 0, 1, ... (the four of the
   predefined connection set always, further ones while they exist), so a PDO a vendor
   configuration left valid at power-on (a TPDO3 on every SYNC, an RPDO2 writing 0x6060) is off;
   ``pdos_disabled`` lists them.
4. Modes of operation 0x6060 := 4 (profile torque) or 10 (cyclic synchronous torque), then 0x6061
   (modes of operation display) polled until it shows the mode, within ``state_timeout`` (default
   0.5 s, canopen's ``BaseNode402.TIMEOUT_SWITCH_OP_MODE``): a drive shows the new mode on one of
   its next cycles, not in the SDO answer; target torque := 0; NMT Start (OPERATIONAL).
5. State machine to Operation enabled: Fault reset (0x80, if in Fault), Shutdown 0x06, Switch on
   0x07, Enable operation 0x0F, each confirmed in the statusword (SDO) within ``state_timeout``
   (default 0.4 s per transition, canopen's ``BaseNode402.TIMEOUT_SWITCH_STATE_SINGLE``: a drive
   releasing a holding brake reports Operation enabled only once the brake is open, 100-200 ms on
   common motors). CiA 402 has no object for the brake's release time (vendors keep it in their
   own objects), so the bound is this scene parameter; the error names the wait that ran out.

Objects the adapter needs (:data:`NEEDED_OBJECTS`, with what each is for) are checked in its object
dictionary when it opens: a missing one is one :class:`~hil.errors.ProtocolError` line naming the
objects and their use, before anything is sent; 0x608F and 0x6076 are needed only when
``counts_per_rev`` / ``rated_torque_mNm`` are not given (the documented fallback: give them), 0x1017
only with heartbeat supervision (``heartbeat_ms=0``: none). An object the dictionary lists but the
drive lacks (SDO abort 0x06020000 / 0x06090011) is the same one-line error, with the abort code.

Per tick: :meth:`CiA402Drive.read` sends one SYNC and waits for TPDO1 and TPDO2 (the drive
samples them at the SYNC); :meth:`CiA402Drive.command_effort` sends RPDO1 (controlword 0x0F,
target torque).

Non-blocking reads (``read(timeout=0)``, the realtime loop): PDOs with SYNC are already
asynchronous on the host side (canopen's notifier thread receives the TPDOs), but the blocking read
waits for the TPDOs answering its own SYNC: a bus round trip plus the drive's processing inside the
tick. A non-blocking read instead takes the newest complete TPDO1 + TPDO2 pair received since the
previous read (the answer to the SYNC that read sent; a TPDO2 completes the TPDO1 received before
it, so a sample never mixes two SYNCs), then sends the next SYNC (one SYNC per read: the cyclic
synchronous modes need it every cycle). ``produced_at`` is the pair's arrival (adapter clock, in
the notifier thread), one SYNC period older than a blocking read's. No new pair (partial, lost,
never sent): the previous sample again (stale: same ``seq`` and ``produced_at``,
``counters()["stale"]``), whose growing age the runner's watchdog judges; EMCY, heartbeat and
statusword checks are those of the blocking read. A frame destroyed by a CRC error is an error
frame (``error_frames``): its TPDO is missing and the read stale. The first non-blocking read
(nothing outstanding) reads once with ``timeout``.

Units (SI at this boundary; rotary joints only): ``q [rad] = 2 pi counts / (cpr * gear_ratio)``,
``qd [rad/s]`` the same scale applied to 0x606C in counts/s (the drive's velocity unit must be
encoder increments per second: factor group 0x6091/0x6092/0x6096 at identity), torque ``[N.m at
the joint] = gear_ratio * per_mille / 1000 * rated_torque_mNm / 1000`` (0x6071/0x6077 are per
mille of the motor rated torque 0x6076, CiA 402 §6.5.1). Commands are rounded to the nearest per
mille (resolution ``gear_ratio * rated / 1e6`` N.m) and clamped to int16. Positive effort drives
the joint positive (the drive's polarity 0x607E is left as configured).

Errors: an SDO that gets no answer in ``timeout`` (the SDO response time, 0.1 s by default) is a
:class:`~hil.errors.DeviceTimeout` (canopen ``SdoCommunicationError``), an SDO abort a
:class:`~hil.errors.ProtocolError` naming the abort code; no TPDO answer to a SYNC within
``timeout`` is a DeviceTimeout; the statusword Fault bit, an EMCY (``code`` = the EMCY error code,
else 0x603F) or leaving Operation enabled is a :class:`~hil.errors.DeviceFault`, and so is a state
transition not confirmed within ``state_timeout``; a modes of operation display that does not
follow within it is a :class:`~hil.errors.ProtocolError`; bus errors are
:class:`~hil.errors.DeviceDisconnected`.

Freshness: ``produced_at`` is the adapter ``clock`` when the TPDOs answering the read's SYNC
arrived (the drive samples at the SYNC), ``seq`` counts those answers.

Safe stop (:meth:`CiA402Drive.safe_stop`, also on :meth:`close`): RPDO with target torque 0, then
by SDO target torque 0 and controlword Quick stop 0x02 (the drive follows quick stop option code
0x605A), then Disable voltage 0x00 if the drive stays in Quick stop active; the final state and
torque actual are kept in ``last_stop``. Never raises.

Counters: ``error_frames``, ``timeouts`` (SYNCs or SDOs without an answer), ``emcy`` (EMCY frames
with a non-zero code); heartbeats received are in ``heartbeats`` (not a fault).
"""

from __future__ import annotations

import contextlib
import functools
import logging
import math
import threading
import time
from collections.abc import Callable
from importlib import resources
from typing import Any

import can
import canopen
import numpy as np
from canopen.profiles.p402 import State402

from hil.errors import DeviceDisconnected, DeviceFault, DeviceTimeout, ProtocolError
from hil.protocols.base import Actuator, DeviceInfo, JointSample
from hil.protocols.waits import WALL, Waits

logger = logging.getLogger(__name__)

#: modes of operation (0x6060) the adapter drives, by name
MODES = {"profile_torque": 4, "pt": 4, "cyclic_synchronous_torque": 10, "cst": 10}
PROFILE_402 = 0x192
#: seconds a state transition / a mode switch may take by default: canopen's BaseNode402 bounds
#: (TIMEOUT_SWITCH_STATE_SINGLE, TIMEOUT_SWITCH_OP_MODE)
STATE_TIMEOUT_S = 0.4
MODE_TIMEOUT_S = 0.5
#: PDO communication parameter bases (CiA 301: RPDO k+1 at 0x1400 + k, TPDO k+1 at 0x1800 + k)
RPDO_COMM, TPDO_COMM = 0x1400, 0x1800
PDO_NOT_VALID = 0x80000000
#: SDO aborts meaning "the drive has no such object / sub-index" (CiA 301 Table 22)
ABORTS_ABSENT = (0x06020000, 0x06090011)
#: objects the adapter uses: index -> (CiA name, what the adapter needs it for)
NEEDED_OBJECTS: dict[int, tuple[str, str]] = {
    0x1000: ("device type", "checks that the node is a CiA 402 drive"),
    0x1017: ("producer heartbeat time", "heartbeat supervision; heartbeat_ms=0 runs without it"),
    0x1018: ("identity", "names the drive (vendor id)"),
    0x1400: ("RPDO1 communication parameter", "sends controlword and target torque each tick"),
    0x1600: ("RPDO1 mapping", "sends controlword and target torque each tick"),
    0x1800: ("TPDO1 communication parameter", "reads statusword, position and torque each tick"),
    0x1801: ("TPDO2 communication parameter", "reads velocity and mode display each tick"),
    0x1A00: ("TPDO1 mapping", "reads statusword, position and torque each tick"),
    0x1A01: ("TPDO2 mapping", "reads velocity and mode display each tick"),
    0x6040: ("controlword", "drives the state machine"),
    0x6041: ("statusword", "confirms the state machine and faults"),
    0x6060: ("modes of operation", "selects the torque mode"),
    0x6061: ("modes of operation display", "confirms the torque mode"),
    0x6064: ("position actual value", "the joint position"),
    0x606C: ("velocity actual value", "the joint velocity"),
    0x6071: ("target torque", "the torque command"),
    0x6077: ("torque actual value", "the joint torque"),
    0x608F: ("position encoder resolution", "converts encoder counts to rad; give counts_per_rev instead"),
    0x6076: ("motor rated torque", "scales the per-mille torques to N.m; give rated_torque_mNm instead"),
}
EMCY_DESCRIPTIONS = {0x2310: "continuous over current", 0x3210: "DC link over voltage",
                     0x4310: "drive over temperature", 0x7305: "incremental encoder", 0x8611: "following error"}


def default_eds() -> str:
    """Path of the shipped object dictionary (``hil/protocols/data/cia402.eds``)."""
    return str(resources.files("hil.protocols").joinpath("data", "cia402.eds"))


def state_of(statusword: int) -> str:
    """CiA 402 state name of a statusword (canopen's State402 masks), ``"UNKNOWN"`` otherwise."""
    for name, (mask, value) in State402.SW_MASK.items():
        if statusword & mask == value:
            return name
    return "UNKNOWN"


def describe_emcy(code: int) -> str:
    """A short description of an EMCY error code (CiA 301 Table 21 classes, a few CiA 402 codes)."""
    if code in EMCY_DESCRIPTIONS:
        return EMCY_DESCRIPTIONS[code]
    return canopen.emcy.EmcyError(code, 0, b"", 0.0).get_desc() or "unknown"


def parse_mode(mode: int | str) -> int:
    """4 / 10 from ``4``, ``10``, ``"profile_torque"``, ``"pt"``, ``"cyclic_synchronous_torque"``, ``"cst"``."""
    if isinstance(mode, str):
        if mode.lower() not in MODES:
            raise ValueError(f"mode must be one of {sorted(MODES)} or 4/10, got {mode!r}")
        return MODES[mode.lower()]
    if int(mode) not in (4, 10):
        raise ValueError(f"mode must be 4 (profile torque) or 10 (cyclic synchronous torque), got {mode!r}")
    return int(mode)


class _ErrorFrames(can.Listener):
    def __init__(self) -> None:
        self.count = 0

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            self.count += 1


class CiA402Drive(Actuator):
    """One CiA 402 drive axis in a torque mode; ``dof`` = 1, rotary.

    Parameters
    ----------
    node_id: CANopen node id (1..127).
    channel, interface, bitrate, bus_kwargs: python-can bus; ``bus``: an open bus (not shut down
        by :meth:`close`).
    mode: 4 / ``"profile_torque"`` or 10 / ``"cyclic_synchronous_torque"``.
    gear_ratio: motor turns per joint turn.
    counts_per_rev, rated_torque_mNm: encoder increments per motor revolution and motor rated torque
        (mN.m); ``None``: read from the drive (0x608F, 0x6076).
    effort_limit: symmetric clamp of the commanded joint torque (N.m), ``None``: none.
    heartbeat_ms, heartbeat_timeout_ms: producer time written to 0x1017 and consumer timeout
        (default 3 x heartbeat_ms); ``heartbeat_ms=0``: no heartbeat supervision.
    sync_rpdo: RPDO1 transmission type 1 (applied at the next SYNC) instead of 255 (default: True
        in cyclic synchronous torque, False in profile torque).
    enable: run the open sequence (module docstring); on close, safe stop and NMT pre-operational.
    clock: time source of ``JointSample.t`` / ``produced_at``.
    timeout: SDO response timeout (s) and the wait for the TPDOs answering a read's SYNC.
    state_timeout: bound (s) of each state transition's confirmation and of the modes of operation
        display following 0x6060; ``None``: 0.4 s per transition and 0.5 s for the mode (canopen's
        BaseNode402). Raise it for a drive whose holding brake takes longer to release.
    eds: object dictionary (path or :class:`canopen.ObjectDictionary`); default: the shipped one.
    """

    dof = 1
    units = "rotary"

    def __init__(self, node_id: int = 1, channel: str = "can0", interface: str = "socketcan",
                 bitrate: int | None = None, *, bus: can.BusABC | None = None, mode: int | str = 4,
                 gear_ratio: float = 1.0, counts_per_rev: int | None = None, rated_torque_mNm: int | None = None,
                 effort_limit: float | None = None, heartbeat_ms: int = 100, heartbeat_timeout_ms: float | None = None,
                 sync_rpdo: bool | None = None, enable: bool = True, clock: Callable[[], float] = time.monotonic,
                 timeout: float = 0.1, eds: Any = None, state_timeout: float | None = None,
                 waits: Waits = WALL, **bus_kwargs: Any) -> None:
        if not 1 <= int(node_id) <= 127:
            raise ValueError(f"CANopen node id must be 1..127, got {node_id}")
        if gear_ratio == 0 or not math.isfinite(gear_ratio):
            raise ValueError("gear_ratio must be finite and non-zero")
        self.node_id = int(node_id)
        self.mode = parse_mode(mode)
        self.gear_ratio = float(gear_ratio)
        self.effort_limit = effort_limit
        self.heartbeat_ms = int(heartbeat_ms)
        self.heartbeat_timeout_s = (3.0 * self.heartbeat_ms if heartbeat_timeout_ms is None
                                    else float(heartbeat_timeout_ms)) / 1000.0
        self.sync_rpdo = (self.mode == 10) if sync_rpdo is None else bool(sync_rpdo)
        self.clock = clock
        self._waits = waits
        self.timeout = float(timeout)
        if state_timeout is not None and not (math.isfinite(state_timeout) and state_timeout > 0):
            raise ValueError(f"state_timeout must be > 0 s, got {state_timeout!r}")
        self.state_timeout = STATE_TIMEOUT_S if state_timeout is None else float(state_timeout)
        self.mode_timeout = MODE_TIMEOUT_S if state_timeout is None else float(state_timeout)
        #: PDOs of the drive made invalid on open (they are not the adapter's), e.g. ["TPDO3"]
        self.pdos_disabled: list[str] = []
        self._eds_name = "the shipped cia402.eds" if eds is None else (
            str(eds).rsplit("/", 1)[-1] if isinstance(eds, str) else "the given object dictionary")
        self._enable = enable
        self.label = f"CiA 402 node {self.node_id}"
        self._timeouts = 0
        self._emcy_count = 0
        self._hb_count = 0
        self._cond = threading.Condition()
        self._rx = [0, 0]  # TPDO1, TPDO2 receptions
        self._rx_at = [math.nan, math.nan]
        # non-blocking reads (timeout 0): the newest complete TPDO1 + TPDO2 pair (notifier thread)
        self._t1: tuple[int, int, int] | None = None  # statusword, position, torque of the newest TPDO1
        self._pair: tuple[int, int, int, int, float] | None = None  # + velocity, arrival (clock)
        self._pairs = 0  # complete pairs received
        self._pairs_taken = 0
        self._ahead = False  # a SYNC sent by a non-blocking read is outstanding
        self._nb_reads = 0
        self._last: JointSample | None = None
        self._stale_reads = 0
        self._emcy: Any = None
        self._hb_state: int | None = None
        self._last_hb = clock()
        self.last_stop: dict[str, Any] = {}
        self.counts_per_rev = counts_per_rev
        self.rated_torque_mNm = rated_torque_mNm
        self._errors = _ErrorFrames()
        od = canopen.import_od(default_eds() if eds is None else eds, self.node_id)
        self._check_dictionary(od, enable)  # before the bus is opened: nothing to release
        if bus is None:
            from hil.protocols.can_odrive import open_can_bus

            self._bus = open_can_bus(interface, channel, bitrate, None, **bus_kwargs)
            self._own_bus = True
        else:
            self._bus, self._own_bus = bus, False
        self.network = canopen.Network(self._bus)
        self.network.NOTIFIER_CYCLE = 0.05  # receive-thread poll period: bounds how long close() waits
        self.network.listeners.append(self._errors)  # type: ignore[arg-type]  # canopen types these as its own MessageListener; a can.Listener is what python-can's Notifier calls
        self.node = canopen.RemoteNode(self.node_id, od)
        self.node.sdo.RESPONSE_TIMEOUT = self.timeout
        self.network.add_node(self.node)
        self._dispatching = bool(waits.lockstep)
        if self._dispatching:  # no receive thread (connect() would start canopen's notifier): what
            self.node.sdo.__class__ = _WaitingSdoClient  # arrives is dispatched when the adapter waits
            self.node.sdo.adapter = self
        else:
            self.network.connect()
        self.node.emcy.add_callback(self._on_emcy)
        self.node.nmt.add_heartbeat_callback(self._on_heartbeat)
        self.info = DeviceInfo(driver="cia402", transport=f"can:{interface}:{channel}" if bus is None
                               else f"can:{bus.channel_info}", vendor="", model="CiA 402 drive",
                               extra={"node_id": self.node_id, "mode": self.mode, "gear_ratio": self.gear_ratio})
        try:
            if enable:
                self._open_sequence()
        except BaseException:
            self.close()
            raise

    # -- SDO with the package's errors ----------------------------------------------------------
    def _check_dictionary(self, od: Any, enable: bool) -> None:
        """ProtocolError (one line) naming every object of :data:`NEEDED_OBJECTS` that ``od`` lacks and
        what it is needed for (0x608F / 0x6076 only when not given, 0x1017 only with heartbeat
        supervision; nothing is checked with ``enable=False``)."""
        if not enable:
            return
        skip = {0x608F} if self.counts_per_rev is not None else set()
        skip |= {0x6076} if self.rated_torque_mNm is not None else set()
        skip |= {0x1017} if self.heartbeat_ms <= 0 else set()
        missing = [i for i in NEEDED_OBJECTS if i not in skip and i not in od]
        if missing:
            raise ProtocolError(f"CiA 402 node {self.node_id}: {self._eds_name} has no "
                                + "; no ".join(self._describe(i) for i in missing))

    @staticmethod
    def _describe(index: int, sub: int | None = None) -> str:
        """``0x608F:1 (position encoder resolution: converts ...)``: an object and what it is for."""
        name, use = NEEDED_OBJECTS.get(index, ("", ""))
        return f"0x{index:04X}" + (f":{sub}" if sub is not None else "") + (f" ({name}: {use})" if name else "")

    def _var(self, index: int, sub: int | None = None) -> Any:
        try:
            v = self.node.sdo[index]
            return v if sub is None else v[sub]
        except KeyError:
            raise ProtocolError(f"CiA 402 node {self.node_id}: {self._eds_name} has no "
                                f"{self._describe(index, sub)}") from None

    def _sdo(self, fn: Callable[[], Any], what: str, index: int | None = None) -> Any:
        self._check_open()
        try:
            return fn()
        except canopen.SdoAbortedError as exc:
            absent = ""
            if exc.code in ABORTS_ABSENT and index is not None:
                absent = f": the drive has no {self._describe(index)}"
            raise ProtocolError(f"CiA 402 node {self.node_id}: {what}: SDO abort 0x{exc.code:08X} ({exc})"
                                f"{absent}") from exc
        except canopen.SdoCommunicationError as exc:
            self._timeouts += 1
            raise DeviceTimeout(f"CiA 402 node {self.node_id}: {what}: no SDO answer within "
                                f"{self.timeout:.3f} s ({exc})") from exc
        except can.CanError as exc:
            raise DeviceDisconnected(f"CiA 402 node {self.node_id}: bus error during {what}: {exc}") from exc

    def sdo_read(self, index: int, sub: int | None = None) -> Any:
        """Read an object by SDO (decoded with the object dictionary)."""
        return self._sdo(lambda: self._var(index, sub).raw, f"SDO read 0x{index:04X}" + (f":{sub}" if sub else ""),
                         index)

    def sdo_write(self, index: int, value: Any, sub: int | None = None) -> None:
        """Write an object by SDO (encoded with the object dictionary)."""
        def w() -> None:
            self._var(index, sub).raw = value
        self._sdo(w, f"SDO write 0x{index:04X}" + (f":{sub}" if sub else ""), index)

    def _send(self, fn: Callable[[], None], what: str) -> None:
        self._check_open()
        try:
            fn()
        except can.CanOperationError as exc:
            raise DeviceTimeout(f"CiA 402 node {self.node_id}: {what} failed: {exc}") from exc
        except can.CanError as exc:
            raise DeviceDisconnected(f"CiA 402 node {self.node_id}: bus error during {what}: {exc}") from exc

    # -- open ---------------------------------------------------------------------------------
    def _open_sequence(self) -> None:
        node = self.node
        self._send(lambda: setattr(node.nmt, "state", "PRE-OPERATIONAL"), "NMT enter pre-operational")
        dtype = int(self.sdo_read(0x1000))
        if dtype & 0xFFFF != PROFILE_402:
            raise ProtocolError(f"CiA 402 node {self.node_id}: device type 0x{dtype:08X} is not a CiA 402 drive")
        ident = {"vendor_id": int(self.sdo_read(0x1018, 1))}
        for sub, key in ((2, "product_code"), (3, "revision"), (4, "serial")):  # optional (CiA 301 §7.5.2.22)
            with contextlib.suppress(ProtocolError):
                ident[key] = int(self.sdo_read(0x1018, sub))
        name = firmware = ""
        with contextlib.suppress(ProtocolError):
            name = str(self.sdo_read(0x1008))
        with contextlib.suppress(ProtocolError):
            firmware = str(self.sdo_read(0x100A))
        if self.counts_per_rev is None:
            inc, rev = int(self.sdo_read(0x608F, 1)), int(self.sdo_read(0x608F, 2))
            self.counts_per_rev = inc // max(rev, 1)
        if self.rated_torque_mNm is None:
            self.rated_torque_mNm = int(self.sdo_read(0x6076))
        if self.counts_per_rev <= 0 or self.rated_torque_mNm <= 0:
            raise ProtocolError(f"CiA 402 node {self.node_id}: encoder resolution {self.counts_per_rev} "
                                f"counts/rev and rated torque {self.rated_torque_mNm} mN.m must be > 0")
        self.info.vendor = f"0x{ident['vendor_id']:08X}"
        self.info.model = name or (f"product 0x{ident['product_code']:08X}" if "product_code" in ident else "")
        self.info.serial = str(ident.get("serial", ""))
        self.info.firmware = firmware or (f"rev 0x{ident['revision']:08X}" if "revision" in ident else "")
        self.info.extra.update(ident, counts_per_rev=self.counts_per_rev, rated_torque_mNm=self.rated_torque_mNm)
        if self.heartbeat_ms > 0 or 0x1017 in self.node.object_dictionary:
            self.sdo_write(0x1017, self.heartbeat_ms)
        self._map_pdos()
        self.sdo_write(0x6060, self.mode)
        shown = self._poll_sdo(0x6061, lambda v: v == self.mode, self.mode_timeout)
        if shown != self.mode:
            raise ProtocolError(f"CiA 402 node {self.node_id}: modes of operation display 0x6061 still {shown} "
                                f"{self.mode_timeout:.3f} s after modes of operation 0x6060 := {self.mode} "
                                f"(state_timeout)")
        self.sdo_write(0x6071, 0)
        self._send(lambda: setattr(node.nmt, "state", "OPERATIONAL"), "NMT start")
        self._last_hb = self.clock()
        self.enable_operation()
        # A heartbeat the drive sent before it processed the NMT start (still PRE-OPERATIONAL) may
        # have arrived after that command went out; the drive's SDO answers since then prove it
        # processed the start (one producer: its frames arrive in order), so only heartbeats from
        # now on tell its NMT state.
        with self._cond:
            self._hb_state = None

    def _map_pdos(self) -> None:
        """Every PDO of the drive but the adapter's made invalid (:meth:`_disable_other_pdos`), then
        RPDO1, TPDO1 and TPDO2 mapped by SDO (canopen ``PdoMap.save``: COB-ID invalid, transmission
        type, sub-index 0 := 0, entries, sub-index 0 := n, COB-ID valid)."""
        node = self.node
        self.pdos_disabled = self._disable_other_pdos()
        if self.pdos_disabled:
            logger.info("CiA 402 node %d: PDOs left valid by the drive made invalid: %s", self.node_id,
                        ", ".join(self.pdos_disabled))
        r1, t1, t2 = node.rpdo[1], node.tpdo[1], node.tpdo[2]

        def configure() -> None:
            for m, cob, trans, objs in ((r1, 0x200, 1 if self.sync_rpdo else 255, (0x6040, 0x6071)),
                                        (t1, 0x180, 1, (0x6041, 0x6064, 0x6077)), (t2, 0x280, 1, (0x606C, 0x6061))):
                m.read()
                m.clear()
                for index in objs:
                    if index not in node.object_dictionary:  # canopen's add_variable would skip it silently
                        raise ProtocolError(f"CiA 402 node {self.node_id}: {self._eds_name} has no "
                                            f"{self._describe(index)}")
                    m.add_variable(index)
                m.cob_id, m.trans_type, m.enabled = cob + self.node_id, trans, True
                m.save()

        self._sdo(configure, "PDO mapping")
        t1.add_callback(lambda m: self._on_tpdo(0, m))
        t2.add_callback(lambda m: self._on_tpdo(1, m))

    def _disable_other_pdos(self) -> list[str]:
        """Make every PDO of the drive except RPDO1, TPDO1 and TPDO2 invalid (COB-ID bit 31 set by SDO):
        the communication parameters 0x1400 + k (RPDO k+1) and 0x1800 + k (TPDO k+1) are read for
        k = 0..3 (the predefined connection set) and on while the drive has them (an SDO abort
        "object does not exist" ends the search), by raw SDO, so PDOs the adapter's dictionary
        does not list are found too. Returns the ones it made invalid (e.g. ``["TPDO3"]``)."""
        sdo = self.node.sdo
        off: list[str] = []
        for base, kind, ours in ((RPDO_COMM, "RPDO", (0,)), (TPDO_COMM, "TPDO", (0, 1))):
            for k in range(512):
                index = base + k
                try:
                    raw = self._sdo(functools.partial(sdo.upload, index, 1), f"SDO read 0x{index:04X}:1")
                except ProtocolError as exc:
                    if isinstance(exc.__cause__, canopen.SdoAbortedError) and exc.__cause__.code in ABORTS_ABSENT:
                        if k >= 3:
                            break
                        continue
                    raise
                cob = int.from_bytes(bytes(raw)[:4].ljust(4, b"\0"), "little")
                if k in ours or cob & PDO_NOT_VALID:
                    continue
                value = (cob | PDO_NOT_VALID).to_bytes(4, "little")
                self._sdo(functools.partial(sdo.download, index, 1, value), f"SDO write 0x{index:04X}:1 (invalidate)")
                off.append(f"{kind}{k + 1}")
        return off

    def _poll_sdo(self, index: int, done: Callable[[int], bool], bound: float) -> int:
        """Read ``index`` by SDO until ``done(value)`` or ``bound`` seconds have passed; the last value."""
        waits = self._waits
        deadline = waits.monotonic() + bound
        while True:
            value = int(self.sdo_read(index))
            if done(value) or waits.monotonic() >= deadline:
                return value
            waits.sleep(0.001)

    def _await_state(self, target: str, deadline: float) -> int:
        return self._poll_sdo(0x6041, lambda sw: state_of(sw) == target, deadline - self._waits.monotonic())

    def _pump(self) -> None:
        """Lockstep (no receive thread): hand every frame the bus has queued to canopen's listeners,
        in order, in this thread (what canopen's notifier thread does at a bench). Nothing else."""
        if not self._dispatching:
            return
        listeners = self.network.listeners
        bus = self._bus
        while (msg := bus.recv(0.0)) is not None:
            for listener in listeners:
                listener(msg)  # can.Listener.__call__ = on_message_received

    def _wait(self, ready: Callable[[], bool], timeout: float) -> bool:
        """Wait up to ``timeout`` s (``waits``) until ``ready()`` (checked under ``_cond``), which the
        frames dispatched meanwhile make true: by canopen's notifier thread at a bench, by
        :meth:`_pump` on a lockstep bench."""
        def poll(t: float) -> bool | None:
            self._pump()
            with self._cond:
                return True if self._cond.wait_for(ready, t) else None

        return self._waits.receive(poll, timeout) is not None

    def enable_operation(self) -> None:
        """State machine to Operation enabled (fault reset if needed, Shutdown, Switch on, Enable
        operation, each confirmed within ``state_timeout``); DeviceFault if a step is not reached,
        naming the transition and the bound."""
        sw = int(self.sdo_read(0x6041))
        bound = self.state_timeout
        if state_of(sw) in ("FAULT", "FAULT REACTION ACTIVE"):
            self.sdo_write(0x6040, 0x00)
            self.sdo_write(0x6040, 0x80)  # rising edge of bit 7: fault reset (transition 15)
            sw = self._await_state("SWITCH ON DISABLED", self._waits.monotonic() + bound)
            if state_of(sw) != "SWITCH ON DISABLED":
                code = int(self.sdo_read(0x603F))
                raise DeviceFault(f"CiA 402 node {self.node_id}: fault reset refused within {bound:.3f} s "
                                  f"(state_timeout; error code 0x{code:04X}, {describe_emcy(code)})", code=code)
            self._emcy = None
        for cw, what, target in ((State402.CW_SHUTDOWN, "Shutdown", "READY TO SWITCH ON"),
                                 (State402.CW_SWITCH_ON, "Switch on", "SWITCHED ON"),
                                 (State402.CW_OPERATION_ENABLED, "Enable operation", "OPERATION ENABLED")):
            self.sdo_write(0x6040, cw)
            sw = self._await_state(target, self._waits.monotonic() + bound)
            if state_of(sw) != target:
                brake = ("; a drive releasing a holding brake may need a longer state_timeout"
                         if target == "OPERATION ENABLED" else "")
                raise DeviceFault(f"CiA 402 node {self.node_id}: controlword 0x{cw:04X} ({what}) did not reach "
                                  f"{target} within {bound:.3f} s (state_timeout; statusword 0x{sw:04X}: "
                                  f"{state_of(sw)}){brake}", code=sw)
        logger.info("CiA 402 node %d: operation enabled, mode %d", self.node_id, self.mode)

    # -- callbacks (canopen's notifier thread) -------------------------------------------------
    def _on_tpdo(self, k: int, pdo: Any = None) -> None:
        with self._cond:
            self._rx[k] += 1
            self._rx_at[k] = self.clock()
            if pdo is not None:  # pairing for the non-blocking read: TPDO2 completes the TPDO1 before it
                if k == 0:
                    self._t1 = (int(pdo[0x6041].raw), int(pdo[0x6064].raw), int(pdo[0x6077].raw))
                elif self._t1 is not None:
                    self._pair = (*self._t1, int(pdo[0x606C].raw), self._rx_at[1])
                    self._t1 = None
                    self._pairs += 1
            self._cond.notify_all()

    def _on_emcy(self, entry: Any) -> None:
        if entry.code & 0xFF00 == 0:
            self._emcy = None
            return
        self._emcy_count += 1
        self._emcy = entry
        logger.warning("CiA 402 node %d: EMCY 0x%04X (%s), error register 0x%02X", self.node_id, entry.code,
                    describe_emcy(entry.code), entry.register)

    def _on_heartbeat(self, state: int) -> None:
        self._hb_count += 1
        self._hb_state = state
        self._last_hb = self.clock()

    # -- role API -----------------------------------------------------------------------------
    def counters(self) -> dict[str, int]:
        """error_frames, timeouts, emcy (module docstring), and once a non-blocking read ran
        ``stale`` (reads without a new TPDO pair); heartbeats received: ``heartbeats``."""
        out = {"error_frames": self._errors.count, "timeouts": self._timeouts, "emcy": self._emcy_count}
        if self._nb_reads:
            out["stale"] = self._stale_reads
        return out

    @property
    def heartbeats(self) -> int:
        """Heartbeats received since open (not a fault counter)."""
        return self._hb_count

    def _known(self, value: int | None, what: str) -> int:
        """A drive constant read at open (or given); ProtocolError if neither happened."""
        if value is None:
            raise ProtocolError(f"CiA 402 node {self.node_id}: {what} unknown (give it, or open with enable=True "
                                f"to read it from the drive)")
        return value

    def joint_torque_to_per_mille(self, effort: float) -> int:
        """Joint torque (N.m) -> target torque 0x6071 (per mille of rated torque, int16)."""
        rated = self._known(self.rated_torque_mNm, "rated torque 0x6076")
        pm = round(effort / self.gear_ratio / (rated / 1000.0) * 1000.0)
        return max(-32768, min(32767, pm))

    def per_mille_to_joint_torque(self, pm: int) -> float:
        return self.gear_ratio * pm / 1000.0 * self._known(self.rated_torque_mNm, "rated torque 0x6076") / 1000.0

    def counts_to_rad(self, counts: float) -> float:
        cpr = self._known(self.counts_per_rev, "encoder resolution 0x608F")
        return 2.0 * math.pi * counts / (cpr * self.gear_ratio)

    def _encode_effort(self, effort: np.ndarray) -> int:
        """Joint torque (N.m, dof 1) -> the target torque 0x6071 sent (clamped, per mille, int16)."""
        u = float(np.asarray(effort, dtype=float).reshape(-1)[0])
        if not math.isfinite(u):
            raise ValueError(f"non-finite effort {u!r}")
        if self.effort_limit is not None:
            u = min(max(u, -self.effort_limit), self.effort_limit)
        return self.joint_torque_to_per_mille(u)

    def effort_on_wire(self, effort: np.ndarray) -> np.ndarray:
        """The joint torque (N.m) that :meth:`command_effort` would send for ``effort``: clamped to
        ``effort_limit``, rounded to the per mille of rated torque 0x6071 carries (CiA 402 §6.5.1;
        resolution ``gear_ratio * rated_torque_mNm / 1e6`` N.m) and clamped to int16, decoded back.
        The drive applies exactly this (the record's ``effort_cmd``, hil.run.runner)."""
        return np.array([self.per_mille_to_joint_torque(self._encode_effort(effort))])

    def _send_effort(self, effort: np.ndarray, timeout: float) -> None:
        """Joint torque (N.m) as target torque in RPDO1 (controlword Enable operation)."""
        self._rpdo(State402.CW_OPERATION_ENABLED, self._encode_effort(effort))

    def _rpdo(self, controlword: int, per_mille: int) -> None:
        r1 = self.node.rpdo[1]
        r1[0x6040].raw = controlword
        r1[0x6071].raw = per_mille
        self._send(r1.transmit, "RPDO1")

    def _raise_if_fault(self, statusword: int | None = None) -> None:
        self._pump()
        if self._emcy is not None:
            e = self._emcy
            raise DeviceFault(f"CiA 402 node {self.node_id}: EMCY 0x{e.code:04X} ({describe_emcy(e.code)}), "
                              f"error register 0x{e.register:02X}", code=e.code)
        if self.heartbeat_ms > 0:
            age = self.clock() - self._last_hb
            if age > self.heartbeat_timeout_s:
                raise DeviceFault(f"CiA 402 node {self.node_id}: heartbeat lost ({age * 1000:.0f} ms without one, "
                                  f"consumer time {self.heartbeat_timeout_s * 1000:.0f} ms)", code=None)
            if self._hb_state is not None and self._hb_state != 5:
                st = canopen.nmt.NMT_STATES.get(self._hb_state, str(self._hb_state))
                raise DeviceFault(f"CiA 402 node {self.node_id}: heartbeat reports NMT state {st}, not OPERATIONAL",
                                  code=self._hb_state)
        if statusword is not None:
            st = state_of(statusword)
            if st in ("FAULT", "FAULT REACTION ACTIVE"):
                code = None
                with contextlib.suppress(Exception):
                    code = int(self.sdo_read(0x603F))
                what = f"error code 0x{code:04X} ({describe_emcy(code)})" if code is not None else "error code unread"
                raise DeviceFault(f"CiA 402 node {self.node_id}: drive in {st}, {what}", code=code)
            if st != "OPERATION ENABLED":
                raise DeviceFault(f"CiA 402 node {self.node_id}: drive left OPERATION ENABLED (statusword "
                                  f"0x{statusword:04X}: {st}): torque commands are not applied", code=statusword)

    def _read_sample(self, timeout: float) -> JointSample:
        """SYNC, then TPDO1 + TPDO2 as a JointSample (rad, rad/s, N.m). DeviceTimeout when they do
        not arrive within ``timeout``; DeviceFault on EMCY, Fault, lost heartbeat or a state other
        than Operation enabled. ``timeout`` 0: the non-blocking read (module docstring)."""
        if timeout == 0.0:
            return self._read_ahead()
        self._ahead = False
        self._raise_if_fault()
        with self._cond:
            before = list(self._rx)
        self._send(self.network.sync.transmit, "SYNC")
        if not self._wait(lambda: self._rx[0] > before[0] and self._rx[1] > before[1], timeout):
            self._timeouts += 1
            raise DeviceTimeout(f"CiA 402 node {self.node_id}: no TPDO answer to SYNC within {timeout:.3f} s")
        with self._cond:
            produced = max(self._rx_at)
            t1, t2 = self.node.tpdo[1], self.node.tpdo[2]
            sw = int(t1[0x6041].raw)
            pos, tq = int(t1[0x6064].raw), int(t1[0x6077].raw)
            vel = int(t2[0x606C].raw)
        self._raise_if_fault(sw)
        self._seq += 1
        self._last = JointSample(t=self.clock(), seq=self._seq, position=np.array([self.counts_to_rad(pos)]),
                                 velocity=np.array([self.counts_to_rad(vel)]),
                                 effort=np.array([self.per_mille_to_joint_torque(tq)]), fault=0, produced_at=produced)
        return self._last

    def _read_ahead(self) -> JointSample:
        """The non-blocking read: the newest complete TPDO1 + TPDO2 pair received since the previous
        read (the answer to the SYNC that read sent) as a fresh sample, else the previous sample
        again (stale); then the next SYNC. The first one, with no SYNC outstanding, reads once with
        the adapter's ``timeout``."""
        self._nb_reads += 1
        if not self._ahead:
            self._read_sample(self.timeout)
            with self._cond:
                self._pairs_taken = self._pairs  # that SYNC's pair is in the sample just read
            sample = self._last
            assert sample is not None
        else:
            self._raise_if_fault()
            with self._cond:
                pair = self._pair if self._pairs > self._pairs_taken else None
                self._pairs_taken = self._pairs
            if pair is None:
                sample = self._stale(self._last, self.clock(), f"CiA 402 node {self.node_id}: no TPDO answer yet")
            else:
                sw, pos, tq, vel, produced = pair
                self._raise_if_fault(sw)
                self._seq += 1
                sample = self._last = JointSample(
                    t=self.clock(), seq=self._seq, position=np.array([self.counts_to_rad(pos)]),
                    velocity=np.array([self.counts_to_rad(vel)]), effort=np.array([self.per_mille_to_joint_torque(tq)]),
                    fault=0, produced_at=produced)
        self._send(self.network.sync.transmit, "SYNC")
        self._ahead = True
        return sample

    def quick_stop(self, timeout: float = 0.05) -> str:
        """Controlword Quick stop (0x02) by SDO; returns the state reached (statusword)."""
        self.sdo_write(0x6040, State402.CW_QUICK_STOP)
        sw = self._await_state("QUICK STOP ACTIVE", self._waits.monotonic() + timeout)
        st = state_of(sw)
        if st != "QUICK STOP ACTIVE":
            sw = int(self.sdo_read(0x6041))
            st = state_of(sw)
        return st

    def _stop_steps(self) -> tuple[Callable[[], object], ...]:
        return (self._stop_sequence,)

    def _stop_sequence(self) -> None:
        """The safe stop: zero torque, Quick stop, then Disable voltage if still in Quick stop active (module
        docstring). Never raises; ``last_stop`` records what was reached."""
        rec: dict[str, Any] = {}
        old = self.node.sdo.RESPONSE_TIMEOUT
        self.node.sdo.RESPONSE_TIMEOUT = min(old, 0.05)
        try:
            with contextlib.suppress(Exception):
                self._rpdo(State402.CW_OPERATION_ENABLED, 0)
                rec["rpdo_zero"] = True
            with contextlib.suppress(Exception):
                self.sdo_write(0x6071, 0)
            try:
                rec["state"] = self.quick_stop()
                if rec["state"] == "QUICK STOP ACTIVE":
                    self.sdo_write(0x6040, State402.CW_DISABLE_VOLTAGE)
                    rec["state"] = state_of(int(self.sdo_read(0x6041)))
                rec["torque_actual"] = int(self.sdo_read(0x6077))
            except Exception as exc:
                rec["error"] = f"{type(exc).__name__}: {exc}"
        finally:
            self.node.sdo.RESPONSE_TIMEOUT = old
        self.last_stop = rec
        logger.info("CiA 402 node %d: safe stop %s", self.node_id, rec)

    def _armed(self) -> bool:
        return bool(self._enable)

    def _close_steps(self) -> tuple[Callable[[], object], ...]:
        """After the safe stop on close: NMT pre-operational (then the receive thread stops and the
        bus is released, :meth:`_release`)."""
        return (lambda: setattr(self.node.nmt, "state", "PRE-OPERATIONAL"),)

    def _release(self) -> None:
        with contextlib.suppress(Exception):
            if self.network.notifier is not None:
                self.network.notifier.stop(1.0)
        if self._own_bus:
            with contextlib.suppress(Exception):
                self._bus.shutdown()


class _WaitingSdoClient(canopen.sdo.SdoClient):
    """canopen's SDO client on a lockstep bench (the class of the adapter's ``node.sdo``, swapped in
    place, so canopen's wiring of that object is unchanged): the wait for a response goes through
    the adapter's ``waits`` and dispatches what arrived in the waiting thread (there is no receive
    thread); a response the simulated drive did not send times out in simulated time."""

    adapter: CiA402Drive

    def read_response(self) -> bytes:
        adapter = self.adapter

        def poll(t: float) -> bool | None:
            adapter._pump()
            return None if self.responses.empty() else True

        if adapter._waits.receive(poll, self.RESPONSE_TIMEOUT) is None:
            raise canopen.SdoCommunicationError("No SDO response received")
        response: bytes = super().read_response()  # type: ignore[no-untyped-call]  # queued: returns at once
        return response


__all__ = ["MODES", "CiA402Drive", "default_eds", "describe_emcy", "parse_mode", "state_of"]
