"""A CiA 402 drive that is *not* the project's twin: canopen's own :class:`canopen.LocalNode` built
from a vendor EDS (Technosoft iPOS), free running on a python-can virtual channel with canopen's
network thread and heartbeat producer, as a drive on a real bus is.

It behaves as the drive behind the issue-29 findings, in the ways real drives do and the project's
twin does not:

* **delayed mode display**: 0x6061 follows a write of 0x6060 one drive cycle later; the drive's
  cycle here is one SDO exchange (so the first read of 0x6061 after the write still shows the old
  mode, every later one the new: deterministic, whatever the machine's load);
* **holding brake**: Enable operation (transition 4) reaches OPERATION ENABLED only once the brake
  has released, ``brake_release_s`` after the controlword (wall clock, as on a bench); ``None``:
  the brake never releases (the statusword stays SWITCHED ON);
* **leftover PDOs**: its power-on PDO configuration is the EDS's (RPDO1..4 valid) plus TPDO3 valid
  (``tpdo_on``, a configuration stored by a previous application); every valid synchronous TPDO
  goes out on each SYNC in NMT OPERATIONAL (``tpdo_frames`` counts them per COB-ID);
* **missing objects**: whatever the EDS lacks (this one has no 0x608F encoder resolution and no
  0x6076 rated torque) is answered with SDO abort 0x06020000 by canopen's SDO server.

The state machine is CiA 402's (transitions 2, 3, 4, 5, 6, 7, 9, 10, 11, 12, 15 on the controlword
bits of IEC 61800-7-201 Table 28); actual values are constants set by the test
(``position``, ``velocity``, ``torque`` in drive units).
"""

from __future__ import annotations

import struct
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

import canopen
from canopen.profiles.p402 import State402


class VendorDrive:
    """canopen LocalNode drive from ``eds`` on virtual ``channel`` (see the module docstring)."""

    def __init__(self, channel: str, eds: Path | str, node_id: int = 5, *, brake_release_s: float | None = 0.15,
                 tpdo_on: tuple[int, ...] = (3,), position: int = 4096, velocity: int = -2048,
                 torque: int = 125) -> None:
        self.node_id = node_id
        self.brake_release_s = brake_release_s
        self.state = "SWITCH ON DISABLED"
        self.position, self.velocity, self.torque = position, velocity, torque
        self.mode = 0  # modes of operation display 0x6061
        self._pending_mode: int | None = None
        self._mode_reads = 0
        self._enable_at: float | None = None
        self.tpdo_frames: Counter[int] = Counter()
        self.syncs = 0
        self.sdo_requests = 0
        self._lock = threading.RLock()
        self.network = canopen.Network()
        self.network.NOTIFIER_CYCLE = 0.05
        self.network.connect(interface="virtual", channel=channel)
        self.node = canopen.LocalNode(node_id, canopen.import_od(str(eds), node_id))
        self.network.add_node(self.node)
        store = self.node.data_store
        # what the drive's firmware holds and the EDS leaves empty (values of this test drive)
        for sub, value in ((2, 0x0000_2A01), (3, 0x0001_0004), (4, 0x0000_1234)):
            store.setdefault(0x1018, {})[sub] = struct.pack("<I", value)
        store.setdefault(0x100A, {})[0] = b"F000H"
        for k in tpdo_on:  # a stored configuration: this TPDO valid at power-on
            cob = int(self.node.object_dictionary[0x1800 + k - 1][1].default) & 0x7FF
            store.setdefault(0x1800 + k - 1, {})[1] = struct.pack("<I", cob)
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)
        self.network.subscribe(0x80, self._on_sync)
        self.network.subscribe(0x600 + node_id, self._count_sdo)
        nmt = self.node.nmt
        nmt._state = 0
        self.network.send_message(0x700 + node_id, [0])  # boot-up
        nmt._state = 127
        nmt.start_heartbeat(int(self.node.sdo[0x1017].raw))

    # -- object dictionary ------------------------------------------------------------------------
    def _count_sdo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        self.sdo_requests += 1

    def statusword(self) -> int:
        with self._lock:
            if (self.state == "SWITCHED ON" and self._enable_at is not None and self.brake_release_s is not None
                    and time.monotonic() - self._enable_at >= self.brake_release_s):
                self.state, self._enable_at = "OPERATION ENABLED", None  # brake released: transition 4 done
            base = State402.SW_MASK[self.state][1]
            if self.state in ("READY TO SWITCH ON", "SWITCHED ON", "OPERATION ENABLED", "QUICK STOP ACTIVE"):
                base |= 0x10
            return base | 0x0200

    def _on_read(self, index: int, subindex: int, od: Any) -> int | None:
        if index == 0x6041:
            return self.statusword()
        if index == 0x6061:
            with self._lock:
                if self._pending_mode is not None:
                    self._mode_reads += 1
                    if self._mode_reads > 1:  # the drive's next cycle: the display follows
                        self.mode, self._pending_mode = self._pending_mode, None
                return self.mode
        if index == 0x6064:
            return self.position
        if index == 0x606C:
            return self.velocity
        if index == 0x6077:
            return self.torque
        return None

    def _on_write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        if index == 0x6060:
            with self._lock:
                self._pending_mode, self._mode_reads = struct.unpack("<b", bytes(data))[0], 0
        elif index == 0x6040:
            self._controlword(struct.unpack("<H", bytes(data))[0])

    def _controlword(self, cw: int) -> None:
        with self._lock:
            s = self.state
            if s == "FAULT":
                if cw & 0x80:
                    self.state = "SWITCH ON DISABLED"
                return
            if not cw & 0x02:
                self.state = "SWITCH ON DISABLED"
            elif not cw & 0x04:
                self.state = "QUICK STOP ACTIVE" if s == "OPERATION ENABLED" else "SWITCH ON DISABLED"
            elif not cw & 0x01:
                if s in ("SWITCH ON DISABLED", "SWITCHED ON", "OPERATION ENABLED"):
                    self.state = "READY TO SWITCH ON"
            elif not cw & 0x08:
                if s in ("READY TO SWITCH ON", "OPERATION ENABLED"):
                    self.state = "SWITCHED ON"
            elif s in ("READY TO SWITCH ON", "SWITCHED ON"):
                self.state = "SWITCHED ON"  # transition 4 waits for the brake
                self._enable_at = time.monotonic()
            if self.state != "SWITCHED ON":
                self._enable_at = None

    # -- SYNC: the valid synchronous TPDOs, read from the drive's own dictionary -------------------
    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self.node.nmt.state != "OPERATIONAL":
            return
        with self._lock:
            self.syncs += 1
            self.node.tpdo.read()
            for pdo in self.node.tpdo.map.values():
                if not pdo.enabled or pdo.trans_type is None or not 1 <= pdo.trans_type <= 240:
                    continue
                for var in pdo:
                    var.set_data(self.node.get_data(var.index, var.subindex))
                pdo.transmit()
                self.tpdo_frames[pdo.cob_id] += 1

    def close(self) -> None:
        self.node.nmt.stop_heartbeat()
        self.network.disconnect()
