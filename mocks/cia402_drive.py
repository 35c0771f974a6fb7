"""Simulated CiA 402 servo drive: a :class:`canopen.LocalNode` with the shipped object dictionary
(``hil/protocols/data/cia402.eds``) answering on a python-can bus.

It is a :class:`hil.mocks.can_devices.SimCanNode` (same three ways to run: explicit lockstep
:meth:`~hil.mocks.can_devices.SimCanNode.tick`, synchronous replies ``sync=True`` on the virtual
bus, free running :meth:`~hil.mocks.can_devices.SimCanNode.start`; same fault injection on every
frame it sends), whose frames are fed to a :mod:`canopen` network: canopen's own SDO server, NMT
slave, PDO maps and EMCY producer do the protocol; this module adds what a drive does:

* **NMT** (CiA 301 §7.2.8): boot-up message ``0x700+id [00]`` on creation and after an NMT reset,
  then PRE-OPERATIONAL. Services by state (CiA 301 §7.3.2.2, Table 41): PRE-OPERATIONAL: SDO,
  SYNC, EMCY, NMT, heartbeat; OPERATIONAL: these and PDOs; STOPPED: NMT and heartbeat only (no SDO
  answer, no SYNC, no PDO, no EMCY). Reset communication restores every communication object
  (0x1000-0x1FFF: heartbeat time, PDO parameters, ...) to its power-on value; reset node restores
  every object and the drive's state machine (CiA 301 §7.2.8.3.2.2). The heartbeat producer
  (0x1017, factory default 100 ms, writable by SDO) is timed on the node's tick counter (``dt`` s
  per tick), so lockstep runs stay deterministic.
* **SDO**: canopen's server (expedited and segmented) plus block upload and block download
  (:class:`hil.mocks.canopen_server.BlockSdoServer`, CRC-16 when the client asks for it).
* **PDOs**: the host maps them over SDO (0x1400/0x1600 RPDO, 0x1800/0x1A00 TPDO, CiA 301 §7.4.8)
  and gets the aborts a device gives for a mapping it cannot take
  (:func:`hil.mocks.canopen_server.check_pdo_parameter_write`: 0x06040041 an object that cannot be
  mapped such as 0x1000, 0x06040042 more than 64 bits, 0x06010000 a mapping changed while the PDO
  is valid); the drive reloads its maps from its dictionary when they change. RPDOs with
  transmission type 254/255 are applied on reception, 0..240 at the next SYNC; TPDOs with type
  1..240 go out on every n-th SYNC (``0x80``), sampled at the SYNC; TPDOs with type 254/255 and an
  event timer (sub-index 5, ms; not shorter than the inhibit time, sub-index 3, 100 us) every
  event-timer period, on the tick counter (event-driven ones without a timer: not sent, the
  drive defines no change-of-state events).
* **NMT and the power stage are not coupled** (CiA 402 ties none of its states to NMT): the drive
  enabled by SDO in PRE-OPERATIONAL applies its target torque, and dropping from OPERATIONAL to
  PRE-OPERATIONAL leaves it enabled. What the drive does when the connection is lost is its abort
  connection option code 0x6007 (CiA 402 §6.3.1; events used here: NMT STOPPED entered, reset
  communication): 0 nothing, 1 fault signal (state FAULT, 0x603F = 0x8100 communication), 2
  disable voltage, 3 quick stop (then as 0x605A); the shipped dictionary's 1.
* **CiA 402 state machine** (IEC 61800-7-201 §5.3, the states and codes of
  :class:`canopen.profiles.p402.State402`): controlword 0x6040 Shutdown 0x06, Switch on 0x07,
  Enable operation 0x0F, Disable voltage 0x00, Quick stop 0x02, Fault reset (rising edge of bit
  7); statusword 0x6041 with bit 4 (voltage enabled), bit 5 (quick stop *not* active) and bit 9
  (remote). Quick stop option code 0x605A: 0 -> Switch on disabled at once; 1..3 -> stop, then
  Switch on disabled on the next tick; 5..7 -> stop and stay in Quick stop active (Enable
  operation returns to Operation enabled, transition 16). Torque is zero in Quick stop active.
* **Modes** 0x6060 / 0x6061: profile torque (4) and cyclic synchronous torque (10) (0x6502 =
  0x208); any other value is refused with SDO abort 0x06090030 (value range exceeded).
* **Physics**: in Operation enabled with mode 4 or 10 (in any NMT state) the drive applies target
  torque 0x6071 [per mille of motor rated torque 0x6076, mN.m], clamped to max torque 0x6072, as
  joint effort ``gear_ratio * 0x6071/1000 * 0x6076/1000`` N.m; torque actual 0x6077 reports the
  applied per mille. Position actual 0x6064 = round(q * gear_ratio * cpr / 2 pi) counts (int32,
  wrapping), velocity actual 0x606C the same scale in counts/s, ``cpr`` = encoder increments per
  motor revolution (0x608F). Not modelled: torque slope 0x6087 (the target applies at once, as
  with an unlimited slope), homing, position/velocity modes.
* **Faults**: an injected ``error_code`` (:class:`hil.mocks.faults.FaultPlan`) is a drive fault:
  EMCY ``0x80+id`` (code = error_code & 0xFFFF, error register 0x1001 per CiA 301 §7.5.2.2), state
  Fault, 0x603F = the code, zero torque; it stays latched until a Fault reset after the injected
  error ended, which sends the EMCY "error reset" (code 0). A disconnect makes the node silent and
  deaf (no heartbeat, no SDO answer).
"""

from __future__ import annotations

import logging
import math
import struct
from collections import deque
from copy import deepcopy
from importlib import resources
from typing import Any

import can
import canopen
import numpy as np
from canopen.nmt import NmtSlave
from canopen.profiles.p402 import State402
from canopen.sdo import SdoAbortedError

from hil.mocks.can_devices import LOG_LEN, SimCanNode
from hil.mocks.canopen_server import BlockSdoServer, check_pdo_parameter_write
from hil.mocks.interfaces import SimulatedJoints

logger = logging.getLogger(__name__)

#: Modes of operation the simulated drive supports (0x6060): profile torque, cyclic synchronous torque
SUPPORTED_MODES = (4, 10)
ABORT_VALUE_RANGE = 0x06090030  # CiA 301 SDO abort: value range of parameter exceeded
#: EMCY / 0x603F code of a fault raised by the abort connection option code (CiA 301: communication)
CONNECTION_FAULT = 0x8100


def eds_path() -> str:
    """Path of the shipped object dictionary (package data ``hil.protocols/data/cia402.eds``)."""
    return str(resources.files("hil.protocols").joinpath("data", "cia402.eds"))


def load_od(node_id: int) -> canopen.ObjectDictionary:
    """The shipped object dictionary with ``$NODEID`` resolved for ``node_id``."""
    return canopen.import_od(eds_path(), node_id)


def _wrap_i32(x: int) -> int:
    return ((int(x) + (1 << 31)) % (1 << 32)) - (1 << 31)


def _error_register(code: int) -> int:
    """CiA 301 §7.5.2.2 error register bits for an EMCY code: bit 0 generic (always), 1 current
    (0x2xxx), 2 voltage (0x3xxx), 3 temperature (0x4xxx), 4 communication (0x81xx)."""
    reg = 0x01
    top = (code >> 12) & 0xF
    reg |= {2: 0x02, 3: 0x04, 4: 0x08}.get(top, 0)
    if code & 0xFF00 == 0x8100:
        reg |= 0x10
    return reg


class _TickNmt(NmtSlave):
    """canopen's NMT slave with the heartbeat timed by the simulated node's ticks, not a thread."""

    drive: SimCiA402

    def start_heartbeat(self, heartbeat_time_ms: int) -> None:
        self._heartbeat_time_ms = int(heartbeat_time_ms)

    def stop_heartbeat(self) -> None:
        self._heartbeat_time_ms = 0

    def update_heartbeat(self) -> None:
        pass


class _SimNetwork(canopen.Network):
    """A canopen network fed by the simulated node (no notifier thread) whose frames go out
    through the node's fault injector."""

    def __init__(self, drive: SimCiA402) -> None:
        super().__init__(drive.bus)
        self._drive = drive

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        self._drive.send(int(can_id), bytes(data))


class SimCiA402(SimCanNode):
    """Simulated CiA 402 drive (see the module docstring) attached to ``joints``.

    Parameters: ``node_id`` 1..127; ``gear_ratio`` motor turns per joint turn (must match the
    adapter's); ``counts_per_rev`` encoder increments per motor revolution (0x608F:1);
    ``rated_torque_mNm`` motor rated torque (0x6076); ``heartbeat_ms`` producer heartbeat time
    (0x1017); ``dt`` seconds per tick (heartbeat timing); ``identity``: 0x1018 vendor id,
    product code, revision, serial number; other keywords go to
    :class:`~hil.mocks.can_devices.SimCanNode` (``faults``, ``seed``, ``sync``, bus keywords).
    """

    kind = "cia402"

    def __init__(self, joints: SimulatedJoints, channel: str, node_id: int = 1, interface: str = "virtual", *,
                 gear_ratio: float = 1.0, counts_per_rev: int = 131072, rated_torque_mNm: int = 1000,
                 heartbeat_ms: int = 100, dt: float = 0.001, identity: dict[str, int] | None = None,
                 quick_stop_option: int = 2, **kw: Any) -> None:
        if not 1 <= int(node_id) <= 127:
            raise ValueError(f"CANopen node id must be 1..127, got {node_id}")
        self.node_id = int(node_id)
        self.gear_ratio = float(gear_ratio)
        self.dt = float(dt)
        self.state = "SWITCH ON DISABLED"
        self.fault_code = 0
        self._last_cw = 0
        self._pdo_dirty = True
        self._sync_count = 0
        self._pending_sync_rpdo: list[Any] = []
        self._hb_due = 0
        self.commands: deque[tuple[int, int]] = deque(maxlen=LOG_LEN)  # (tick, target torque per mille)
        self.emcy_sent: list[int] = []
        super().__init__(joints, channel, interface, **kw)
        od = load_od(self.node_id)
        self.node = canopen.LocalNode(self.node_id, od)
        self.node.sdo = BlockSdoServer(0x600 + self.node_id, 0x580 + self.node_id, self.node)
        self.node.nmt.__class__ = _TickNmt  # heartbeat on ticks (the write callback stays registered)
        self.network = _SimNetwork(self)
        self.network.add_node(self.node)
        self.network.subscribe(0, self._on_nmt)  # after the NMT slave's own handler
        self.network.subscribe(0x80, self._on_sync)
        store = self.node.data_store
        ident = {"vendor_id": 0x00000A1C, "product_code": 0x00000402, "revision": 0x00010000, "serial": 1,
                 **(identity or {})}
        for sub, key in enumerate(("vendor_id", "product_code", "revision", "serial"), start=1):
            store.setdefault(0x1018, {})[sub] = struct.pack("<I", int(ident[key]) & 0xFFFFFFFF)
        store.setdefault(0x608F, {})[1] = struct.pack("<I", int(counts_per_rev))
        store.setdefault(0x6076, {})[0] = struct.pack("<I", int(rated_torque_mNm))
        store.setdefault(0x1017, {})[0] = struct.pack("<H", int(heartbeat_ms))
        store.setdefault(0x605A, {})[0] = struct.pack("<h", int(quick_stop_option))
        #: every object's value at power-on (what reset node / reset communication restore)
        self._power_on = deepcopy(store)
        self._event_due: dict[int, int] = {}  # TPDO COB-ID -> tick its event timer sends it next
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)
        for m in list((self.node.rpdo.map or {}).values()):
            m.add_callback(self._on_rpdo)
        self._boot()

    # -- helpers ------------------------------------------------------------------------------
    def _u(self, index: int, sub: int = 0) -> int:
        od = self.node.object_dictionary[index]
        var = od if isinstance(od, canopen.objectdictionary.ODVariable) else od[sub]
        return int(var.decode_raw(self.node.get_data(index, sub)))

    @property
    def counts_per_rev(self) -> int:
        return self._u(0x608F, 1) // max(1, self._u(0x608F, 2))

    @property
    def nmt_state(self) -> str:
        return self.node.nmt.state

    @property
    def mode(self) -> int:
        return self._u(0x6060)

    @property
    def target_torque(self) -> int:
        """Target torque 0x6071 (per mille of rated torque)."""
        return self._u(0x6071)

    def applied_per_mille(self) -> int:
        """The torque the drive applies now (per mille of rated torque; 0 unless enabled). The NMT
        state plays no part (CiA 402 does not couple the power stage to NMT)."""
        if (self.state != "OPERATION ENABLED" or self.mode not in SUPPORTED_MODES
                or self.injector.error_code(self.tick_count)):
            return 0
        lim = self._u(0x6072)
        return max(-lim, min(lim, self.target_torque))

    def applied_joint_torque(self) -> float:
        """Applied joint torque (N.m): gear_ratio * per mille / 1000 * rated torque (mN.m) / 1000."""
        return self.gear_ratio * self.applied_per_mille() / 1000.0 * self._u(0x6076) / 1000.0

    def _apply(self) -> None:
        self.joints.apply_effort(np.full(self.joints.dof, self.applied_joint_torque()))

    def statusword(self) -> int:
        base = State402.SW_MASK[self.state][1]
        if self.state in ("READY TO SWITCH ON", "SWITCHED ON", "OPERATION ENABLED", "QUICK STOP ACTIVE"):
            base |= 0x10  # voltage enabled
        return base | 0x0200  # remote

    def _counts(self, x: float) -> int:
        return _wrap_i32(round(x * self.gear_ratio * self.counts_per_rev / (2.0 * math.pi)))

    # -- NMT ----------------------------------------------------------------------------------
    def _boot(self) -> None:
        """Boot-up: message 0x700+id [00], then PRE-OPERATIONAL with the 0x1017 heartbeat."""
        nmt = self.node.nmt
        nmt._state = 0
        self.send(0x700 + self.node_id, b"\x00")
        nmt._state = 127
        nmt.start_heartbeat(self._u(0x1017))
        self._hb_due = self.tick_count
        self._pdo_dirty = True

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if len(data) < 2 or data[1] not in (0, self.node_id):
            return
        cmd = data[0]
        if cmd == 0x81:  # reset node: every object and the application to their power-on state
            self._restore(0x0000, 0xFFFF)
            self.state, self.fault_code, self._last_cw = "SWITCH ON DISABLED", 0, 0
            self._boot()
        elif cmd == 0x82:  # reset communication: the communication objects only
            self._restore(0x1000, 0x1FFF)
            self._boot()
            self._connection_lost("reset communication")
        elif cmd == 0x02:
            self._connection_lost("NMT stopped")
        self._apply()

    def _restore(self, lo: int, hi: int) -> None:
        """Objects lo..hi back to their power-on values (CiA 301 §7.2.8.3.2.2)."""
        store = self.node.data_store
        for index in [i for i in store if lo <= i <= hi]:
            del store[index]
        store.update({i: dict(subs) for i, subs in deepcopy(self._power_on).items() if lo <= i <= hi})
        self._pdo_dirty = True
        self._event_due.clear()

    def _connection_lost(self, why: str) -> None:
        """The abort connection option code 0x6007 (CiA 402 §6.3.1): 0 nothing, 1 fault signal,
        2 disable voltage command, 3 quick stop command."""
        option = self._u(0x6007) if 0x6007 in self.node.object_dictionary else 0
        s = self.state
        if option == 1 and s != "FAULT":
            logger.warning("cia402 node %d: %s: fault (abort connection option 1)", self.node_id, why)
            self.state, self.fault_code = "FAULT", CONNECTION_FAULT
            if self.nmt_state != "STOPPED":
                self.node.emcy.send(CONNECTION_FAULT, _error_register(CONNECTION_FAULT))
                self.emcy_sent.append(CONNECTION_FAULT)
        elif option == 2 and s != "FAULT":
            self.state = "SWITCH ON DISABLED"
        elif option == 3 and s == "OPERATION ENABLED":
            self.state = "QUICK STOP ACTIVE" if self._u(0x605A) != 0 else "SWITCH ON DISABLED"

    # -- object dictionary hooks ----------------------------------------------------------------
    def _on_read(self, index: int, subindex: int, od: Any) -> int | None:
        if index == 0x6041:
            return self.statusword()
        if index == 0x6061:
            return self.mode
        if index == 0x6064:
            return self._counts(float(self.joints.position()[0]))
        if index == 0x606C:
            return self._counts(float(self.joints.velocity()[0]))
        if index in (0x6077, 0x6074):
            return self.applied_per_mille()
        if index == 0x603F:
            return self.fault_code & 0xFFFF
        if index == 0x1001:
            return _error_register(self.fault_code) if self.state == "FAULT" else 0
        return None

    def _on_write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        if index == 0x6060:
            mode = struct.unpack("<b", bytes(data))[0]
            if mode not in SUPPORTED_MODES:
                raise SdoAbortedError(ABORT_VALUE_RANGE)
        elif index == 0x6040:
            self._controlword(struct.unpack("<H", bytes(data))[0])
        elif index == 0x6071:
            self.commands.append((self.tick_count, struct.unpack("<h", bytes(data))[0]))
            self.commands_total += 1
        elif check_pdo_parameter_write(self.node, index, subindex, bytes(data)):
            self._pdo_dirty = True
            self._event_due.clear()

    def _controlword(self, cw: int) -> None:
        """CiA 402 transitions (IEC 61800-7-201 Fig. 14) for controlword ``cw``."""
        rising_reset = bool(cw & 0x80) and not self._last_cw & 0x80
        self._last_cw = cw
        s = self.state
        if s == "FAULT":
            if rising_reset and not self.injector.error_code(self.tick_count):
                self.state = "SWITCH ON DISABLED"  # transition 15
                self.fault_code = 0
                self.node.emcy.reset()
            return
        if not cw & 0x02:  # disable voltage: 7, 9, 10, 12
            self.state = "SWITCH ON DISABLED"
        elif not cw & 0x04:  # quick stop: 7, 10 (to SOD), 11 (OE -> QSA)
            if s == "OPERATION ENABLED":
                self.state = "QUICK STOP ACTIVE" if self._u(0x605A) != 0 else "SWITCH ON DISABLED"
            elif s in ("READY TO SWITCH ON", "SWITCHED ON"):
                self.state = "SWITCH ON DISABLED"
        elif not cw & 0x01:  # shutdown: 2, 6, 8
            if s in ("SWITCH ON DISABLED", "SWITCHED ON", "OPERATION ENABLED"):
                self.state = "READY TO SWITCH ON"
        elif not cw & 0x08:  # switch on (3) / disable operation (5)
            if s in ("READY TO SWITCH ON", "OPERATION ENABLED"):
                self.state = "SWITCHED ON"
        else:  # enable operation: 3+4, 4, 16
            back = s == "QUICK STOP ACTIVE" and self._u(0x605A) in (5, 6, 7, 8)  # transition 16
            if s in ("READY TO SWITCH ON", "SWITCHED ON") or back:
                self.state = "OPERATION ENABLED"
        if self.state != s:
            logger.debug("cia402 node %d: %s -> %s (controlword 0x%04X)", self.node_id, s, self.state, cw)
        self._apply()

    # -- PDOs ----------------------------------------------------------------------------------
    def _reload_pdos(self) -> None:
        if self._pdo_dirty:
            self.node.rpdo.read()
            self.node.tpdo.read()
            self._pdo_dirty = False

    def _on_rpdo(self, pdo: Any) -> None:
        if self.nmt_state != "OPERATIONAL":
            return
        if pdo.trans_type is not None and pdo.trans_type <= 240:
            self._pending_sync_rpdo.append((pdo, bytes(pdo.data)))
            return
        self._write_rpdo(pdo, bytes(pdo.data))

    def _write_rpdo(self, pdo: Any, data: bytes) -> None:
        pdo.data = bytearray(data)
        for var in pdo:
            try:
                self.node.set_data(var.index, var.subindex, var.get_data())
            except SdoAbortedError as exc:
                logger.warning("cia402 node %d: RPDO write of 0x%04X refused: %s", self.node_id, var.index, exc)
        self._apply()

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self.nmt_state != "OPERATIONAL":
            return
        self._reload_pdos()
        self._sync_count += 1
        pending, self._pending_sync_rpdo = self._pending_sync_rpdo, []
        for pdo, payload in pending:
            self._write_rpdo(pdo, payload)
        for pdo in (self.node.tpdo.map or {}).values():
            tt = pdo.trans_type
            if not pdo.enabled or tt is None or tt > 240 or (tt and self._sync_count % tt):
                continue
            for var in pdo:
                var.set_data(self.node.get_data(var.index, var.subindex))
            pdo.transmit()

    def _event_tpdos(self) -> None:
        """TPDOs of transmission type 254/255 with an event timer: sent every event-timer period (ms,
        at least the inhibit time, 100 us units), the first one on the tick the timer is seen."""
        self._reload_pdos()
        for pdo in (self.node.tpdo.map or {}).values():
            tt, timer = pdo.trans_type, pdo.event_timer or 0
            if not pdo.enabled or tt is None or tt < 254 or timer <= 0:
                continue
            period_s = max(timer / 1000.0, (pdo.inhibit_time or 0) / 10000.0)
            due = self._event_due.setdefault(pdo.cob_id, self.tick_count)
            if self.tick_count >= due:
                for var in pdo:
                    var.set_data(self.node.get_data(var.index, var.subindex))
                pdo.transmit()
                self._event_due[pdo.cob_id] = self.tick_count + max(1, round(period_s / self.dt))

    def handle(self, msg: can.Message) -> None:
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            return
        if self.nmt_state == "STOPPED" and msg.arbitration_id != 0:
            return  # STOPPED: NMT only (CiA 301 §7.3.2.2); no SDO answer, no SYNC, no PDO
        if 0x200 <= msg.arbitration_id < 0x580 and self._pdo_dirty and self.nmt_state == "OPERATIONAL":
            self._reload_pdos()  # a PDO for a map configured since the last frame
        self.network.notify(msg.arbitration_id, bytearray(msg.data), msg.timestamp)

    # -- ticks ---------------------------------------------------------------------------------
    def on_tick(self) -> None:
        code = self.injector.error_code(self.tick_count) & 0xFFFF
        if code and self.state != "FAULT":
            logger.warning("cia402 node %d: fault 0x%04X", self.node_id, code)
            self.state = "FAULT"
            self.fault_code = code
            if self.nmt_state != "STOPPED":  # no EMCY in STOPPED (the fault is latched all the same)
                self.emcy_sent.append(code)
                self.node.emcy.send(code, _error_register(code))
        if self.state == "QUICK STOP ACTIVE" and self._u(0x605A) in (1, 2, 3):
            self.state = "SWITCH ON DISABLED"  # quick stop completed (torque is zero at once)
        self._apply()
        if self.nmt_state == "OPERATIONAL":
            self._event_tpdos()
        hb_ms = self.node.nmt._heartbeat_time_ms
        if hb_ms and self.tick_count >= self._hb_due:
            self.send(0x700 + self.node_id, bytes([self.node.nmt._state & 0x7F]))
            self._hb_due = self.tick_count + max(1, round(hb_ms / 1000.0 / self.dt))


__all__ = ["SUPPORTED_MODES", "SimCiA402", "eds_path", "load_od"]
