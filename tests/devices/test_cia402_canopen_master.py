"""The simulated CiA 402 drive (hil.mocks.cia402_drive) driven by an independent CiA 301/402 master:
the ``canopen`` package's Network, RemoteNode, NMT master, SDO client (expedited, segmented, block),
PDO maps saved by SDO, SYNC producer, heartbeat and EMCY consumers (issue 29, item 6).

Expectations are CiA 301 / CiA 402 rules, stated at each test: services by NMT state (CiA 301
§7.3.2.2), reset communication / reset node (§7.2.8.3.2.2), the PDO mapping procedure and its
aborts (§7.4.8; 0x06040041, 0x06040042, 0x06010000), event-timer TPDOs (§7.5.2.36), the abort
connection option code 0x6007 (CiA 402 §6.3.1), and no coupling of the power stage to NMT."""

from __future__ import annotations

import itertools
import struct

import numpy as np
import pytest

can = pytest.importorskip("can")
canopen = pytest.importorskip("canopen")

from hil.mocks.cia402_drive import SimCiA402, eds_path  # noqa: E402
from hil.mocks.faults import FaultPlan  # noqa: E402
from hil.mocks.interfaces import FreeJoints  # noqa: E402

pytestmark = pytest.mark.timeout(60)
_chan = itertools.count()
NODE = 9
WAIT = 2.0  # s: how long the master waits for a frame the drive already sent (a bound, not a measure)


class Rig:
    def __init__(self, faults: FaultPlan | None = None) -> None:
        self.ch = f"canopen-master-{next(_chan)}"
        self.spy = can.Bus(interface="virtual", channel=self.ch)  # sees the boot-up too
        self.joints = FreeJoints(1, 0.01)
        self.drive = SimCiA402(self.joints, self.ch, NODE, sync=True, dt=0.001, heartbeat_ms=0, faults=faults)
        self.net = canopen.Network()
        self.net.NOTIFIER_CYCLE = 0.05
        self.net.connect(interface="virtual", channel=self.ch)
        self.node = canopen.RemoteNode(NODE, eds_path())
        self.node.sdo.RESPONSE_TIMEOUT = 0.3
        self.net.add_node(self.node)

    def tick(self, n: int = 1) -> None:
        for _ in range(n):
            self.joints.step(0.001)
            self.drive.tick()

    def frames(self) -> list[can.Message]:
        return list(iter(lambda: self.spy.recv(0.0), None))

    def u(self, index: int, sub: int = 0, fmt: str = "<I") -> int:
        return struct.unpack(fmt, self.node.sdo.upload(index, sub))[0]

    def enable_by_sdo(self, per_mille: int, mode: int = 4) -> None:
        self.node.sdo.download(0x6060, 0, struct.pack("<b", mode))
        for cw in (0x06, 0x07, 0x0F):
            self.node.sdo.download(0x6040, 0, struct.pack("<H", cw))
        self.node.sdo.download(0x6071, 0, struct.pack("<h", per_mille))

    def close(self) -> None:
        self.net.disconnect()
        self.drive.close()
        self.spy.shutdown()


@pytest.fixture
def rig():
    r = Rig()
    yield r
    r.close()


def test_nmt_bootup_states_and_heartbeat(rig):
    """Boot-up 0x700+id [00]; heartbeat every 0x1017 ms carrying the NMT state (0x7F pre-op,
    0x05 operational, 0x04 stopped); NMT commands from canopen's master."""
    boot = [m for m in rig.frames() if m.arbitration_id == 0x700 + NODE]
    assert [bytes(m.data) for m in boot] == [b"\x00"]
    rig.node.sdo["Producer heartbeat time"].raw = 20  # 0x1017 := 20 ms
    seen = []
    for state, code in (("PRE-OPERATIONAL", 0x7F), ("OPERATIONAL", 0x05), ("STOPPED", 0x04)):
        rig.node.nmt.state = state
        rig.frames()
        rig.tick(40)
        hb = [m.data[0] for m in rig.frames() if m.arbitration_id == 0x700 + NODE]
        seen.append((state, hb))
        assert hb == [code, code], (state, hb)  # 40 ticks of 1 ms at 20 ms: two heartbeats
        assert rig.node.nmt.wait_for_heartbeat(WAIT) == state  # canopen's heartbeat consumer


def test_sdo_expedited_segmented_and_block_transfers(rig):
    """Expedited (<= 4 bytes), segmented (the 35-byte device name 0x1008; a 40-byte note into
    0x2000) and block transfers (canopen's BlockUploadStream / BlockDownloadStream, CRC on) give the
    same bytes; canopen's own server would answer the block upload with a plain upload reply."""
    name = rig.node.sdo.upload(0x1008, 0)  # segmented upload
    assert name == b"hil-certify simulated CiA 402 drive"
    with rig.node.sdo.open(0x1008, 0, "rb", block_transfer=True) as f:
        assert f.read() == name
    note = bytes(range(48, 48 + 40))
    rig.node.sdo.download(0x2000, 0, note)  # segmented download
    assert rig.node.sdo.upload(0x2000, 0) == note
    long_note = bytes(range(256)) * 4  # 1024 bytes: 147 segments, two blocks of up to 127
    with rig.node.sdo.open(0x2000, 0, "wb", block_transfer=True, size=len(long_note)) as f:
        f.write(long_note)
    with rig.node.sdo.open(0x2000, 0, "rb", block_transfer=True) as f:
        assert f.read() == long_note
    assert rig.drive.node.sdo.block_transfers == {"upload": 2, "download": 1}
    assert rig.u(0x1000) == 0x00020192  # expedited


def test_no_sdo_answer_in_stopped(rig):
    """CiA 301 §7.3.2.2: in STOPPED only NMT (and the heartbeat) are active."""
    rig.node.nmt.state = "STOPPED"
    with pytest.raises(canopen.SdoCommunicationError):
        rig.node.sdo.upload(0x1000, 0)
    rig.node.nmt.state = "PRE-OPERATIONAL"
    assert rig.u(0x1000) == 0x00020192


def test_pdo_mapping_by_sdo_with_the_required_aborts(rig):
    """canopen's PdoMap.save (CiA 301 §7.4.8 procedure). 0x1000 (device type, PDOMapping=0):
    0x06040041; 32 + 32 + 16 = 80 bits: 0x06040042; an entry written while the PDO is valid:
    0x06010000; a valid mapping is taken and sent on SYNC."""
    rig.node.tpdo.read()
    t2 = rig.node.tpdo[2]
    t2.clear()
    t2.add_variable(0x1000)
    with pytest.raises(canopen.SdoAbortedError) as e:
        t2.save()
    assert e.value.code == 0x06040041
    t2.clear()
    for index in (0x6064, 0x606C, 0x6077):
        t2.add_variable(index)
    with pytest.raises(canopen.SdoAbortedError) as e:
        t2.save()
    assert e.value.code == 0x06040042
    # a valid TPDO1: its mapping cannot be changed
    assert not rig.u(0x1800, 1) & 0x80000000
    with pytest.raises(canopen.SdoAbortedError) as e:
        rig.node.sdo.download(0x1A00, 1, struct.pack("<I", 0x60410010))
    assert e.value.code == 0x06010000
    # a good one: statusword + position actual on TPDO2, sent on every SYNC in OPERATIONAL
    t2.clear()
    t2.add_variable(0x6041)
    t2.add_variable(0x6064)
    t2.trans_type, t2.enabled = 1, True
    t2.save()
    rig.node.nmt.state = "OPERATIONAL"
    rig.frames()
    rig.net.sync.transmit()
    got = [m for m in rig.frames() if m.arbitration_id == 0x280 + NODE]
    assert len(got) == 1 and len(got[0].data) == 6
    assert struct.unpack_from("<H", got[0].data)[0] == rig.drive.statusword()


def test_event_timer_tpdo_is_sent_every_period(rig):
    """Transmission type 255 with event timer 5 ms: one TPDO every 5 ticks of 1 ms in OPERATIONAL,
    none in PRE-OPERATIONAL (CiA 301 §7.5.2.36)."""
    rig.node.tpdo.read()
    t1 = rig.node.tpdo[1]
    t1.trans_type, t1.event_timer, t1.enabled = 255, 5, True
    t1.save()
    rig.frames()
    rig.tick(20)
    assert not [m for m in rig.frames() if m.arbitration_id == 0x180 + NODE]
    rig.node.nmt.state = "OPERATIONAL"
    rig.tick(20)
    ticks = [m for m in rig.frames() if m.arbitration_id == 0x180 + NODE]
    assert len(ticks) == 4


def test_power_stage_is_not_coupled_to_nmt(rig):
    """Enabled by SDO in PRE-OPERATIONAL the drive applies its target torque; OPERATIONAL ->
    PRE-OPERATIONAL leaves it enabled; STOPPED applies 0x6007: 1 (power-on) faults it, 0 leaves it."""
    rig.enable_by_sdo(250)
    assert rig.drive.state == "OPERATION ENABLED" and rig.drive.applied_per_mille() == 250
    rig.node.nmt.state = "OPERATIONAL"
    rig.node.nmt.state = "PRE-OPERATIONAL"
    assert rig.drive.state == "OPERATION ENABLED" and rig.drive.applied_per_mille() == 250
    rig.node.sdo.download(0x6007, 0, struct.pack("<h", 0))
    rig.node.nmt.state = "STOPPED"
    assert rig.drive.state == "OPERATION ENABLED"
    rig.node.nmt.state = "PRE-OPERATIONAL"
    rig.node.sdo.download(0x6007, 0, struct.pack("<h", 1))
    rig.node.nmt.state = "STOPPED"
    assert rig.drive.state == "FAULT" and rig.drive.applied_per_mille() == 0
    rig.node.nmt.state = "PRE-OPERATIONAL"
    assert rig.u(0x603F, 0, "<H") == 0x8100


def test_reset_communication_and_reset_node_restore_power_on_values(rig):
    """Reset communication: 0x1017 and the PDO parameters back to their power-on values, the
    application objects kept; reset node: every object (0x2000, 0x605A) back, drive disabled."""
    def mapping() -> list[int]:
        return [rig.u(0x1A00, 0, "<B"), rig.u(0x1A00, 1), rig.u(0x1A00, 2)]

    before = mapping()
    rig.node.sdo.download(0x1017, 0, struct.pack("<H", 20))
    rig.node.sdo.download(0x1800, 1, struct.pack("<I", 0x80000180 + NODE))
    rig.node.sdo.download(0x1A00, 0, b"\x00")
    rig.node.sdo.download(0x2000, 0, b"kept by reset communication")
    rig.node.sdo.download(0x605A, 0, struct.pack("<h", 6))
    rig.frames()
    rig.node.nmt.send_command(0x82)
    assert [bytes(m.data) for m in rig.frames() if m.arbitration_id == 0x700 + NODE] == [b"\x00"]  # boot-up
    assert rig.u(0x1017, 0, "<H") == 0 and rig.u(0x1800, 1) == 0x180 + NODE
    assert mapping() == before
    assert rig.node.sdo.upload(0x2000, 0) == b"kept by reset communication" and rig.u(0x605A, 0, "<h") == 6
    rig.node.nmt.send_command(0x81)
    assert rig.u(0x605A, 0, "<h") == 2
    with pytest.raises(canopen.SdoAbortedError):
        rig.node.sdo.upload(0x2000, 0)  # empty again: nothing to upload


def test_emcy_and_error_register():
    """An injected drive fault: EMCY 0x80+id with the code and error register 0x1001 (CiA 301
    §7.2.7), read by canopen's EMCY consumer; in STOPPED the fault latches without an EMCY."""
    r = Rig(FaultPlan(error_code=0x4310, error_at_tick=5))
    try:
        r.tick(6)
        err = r.node.emcy.wait(0x4310, WAIT)
        assert err is not None and err.register == 0x09 and r.u(0x1001, 0, "<B") == 0x09
        assert r.drive.state == "FAULT" and r.u(0x603F, 0, "<H") == 0x4310
    finally:
        r.close()
    r = Rig(FaultPlan(error_code=0x2310, error_at_tick=5))
    try:
        r.node.nmt.state = "STOPPED"
        r.frames()
        r.tick(6)
        assert r.drive.state == "FAULT"
        assert not [m for m in r.frames() if m.arbitration_id == 0x80 + NODE]
    finally:
        r.close()


def test_sync_applies_a_cyclic_synchronous_torque_rpdo(rig):
    """RPDO1 with transmission type 1 is applied at the next SYNC (CiA 301 §7.2.2.2)."""
    rig.node.rpdo.read()
    r1 = rig.node.rpdo[1]
    r1.clear()
    r1.add_variable(0x6040)
    r1.add_variable(0x6071)
    r1.trans_type, r1.enabled = 1, True
    r1.save()
    rig.node.nmt.state = "OPERATIONAL"
    rig.enable_by_sdo(0, mode=10)
    r1[0x6040].raw, r1[0x6071].raw = 0x0F, 300
    r1.transmit()
    assert rig.drive.applied_per_mille() == 0  # held until the SYNC
    rig.net.sync.transmit()
    assert rig.drive.applied_per_mille() == 300
    rig.tick(2)
    assert np.sign(rig.joints.velocity()[0]) == 1.0
