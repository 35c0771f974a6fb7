"""An independent client of the simulated CiA 402 drive: raw python-can frames and canopen's SDO
client with an *empty* object dictionary (nothing from hil's EDS or adapter), decoding by hand what
CiA 301 / CiA 402 specify: boot-up 0x700+id [00], heartbeat, SDO expedited transfers of identity
0x1018 and device type 0x1000, the PDO mapping procedure (CiA 301 §7.4.8: COB-ID bit 31 invalid ->
sub0 = 0 -> entries -> sub0 = n -> valid), NMT start, the state machine by statusword values
(0x21 ready to switch on, 0x23 switched on, 0x27 operation enabled, masks 0x6F) and EMCY frames
(error code u16 LE, error register u8, 5 vendor bytes)."""

from __future__ import annotations

import itertools
import struct

import numpy as np
import pytest

can = pytest.importorskip("can")
canopen = pytest.importorskip("canopen")

from hil.mocks.cia402_drive import SimCiA402  # noqa: E402
from hil.mocks.faults import FaultPlan  # noqa: E402
from hil.mocks.interfaces import FreeJoints  # noqa: E402

pytestmark = pytest.mark.timeout(30)
_chan = itertools.count()
NODE = 12


def _frames(bus: can.BusABC, timeout: float = 0.05) -> list[can.Message]:
    out = []
    while (m := bus.recv(timeout)) is not None:
        out.append(m)
    return out


@pytest.fixture
def raw():
    ch = f"test-cia402-raw-{next(_chan)}"
    spy = can.Bus(interface="virtual", channel=ch)  # listens before the drive boots
    joints = FreeJoints(1, 0.01)
    plan = FaultPlan(error_code=0x4310, error_at_tick=500)
    sim = SimCiA402(joints, ch, NODE, sync=True, dt=0.001, faults=plan, heartbeat_ms=20)
    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.05  # quick disconnect
    net.connect(interface="virtual", channel=ch)
    node = net.add_node(NODE, canopen.ObjectDictionary())  # raw SDO only
    # canopen's notifier thread hands the answers over: on a loaded machine it may run late, so the
    # SDO wait is a bound (the answer is queued by the drive before the request's send returns)
    node.sdo.RESPONSE_TIMEOUT = 10.0
    yield spy, sim, node, net, joints
    net.disconnect()
    sim.close()
    spy.shutdown()


def _u(node, index: int, sub: int = 0, fmt: str = "<I") -> int:
    return struct.unpack(fmt, node.sdo.upload(index, sub))[0]


def _w(node, index: int, sub: int, fmt: str, value: int) -> None:
    node.sdo.download(index, sub, struct.pack(fmt, value))


def test_bootup_heartbeat_and_identity(raw):
    spy, sim, node, _, _ = raw
    first = spy.recv(1.0)
    assert first.arbitration_id == 0x700 + NODE and bytes(first.data) == b"\x00"  # boot-up
    for _ in range(60):
        sim.tick()
    hb = [m for m in _frames(spy) if m.arbitration_id == 0x700 + NODE]
    # 0x1017 = 20 ms at 1 ms per tick: ticks 1, 21, 41 in 60 ticks; state byte 0x7F = pre-operational
    assert [bytes(m.data) for m in hb] == [b"\x7f"] * 3
    assert _u(node, 0x1000) & 0xFFFF == 402  # device profile number (CiA 301 §7.5.2.1)
    assert _u(node, 0x1018, 0, "<B") >= 4
    assert _u(node, 0x1018, 1) == 0x0A1C and _u(node, 0x1018, 2) == 0x402
    assert node.sdo.upload(0x1008, 0).decode() == "hil-certify simulated CiA 402 drive"


def test_raw_pdo_mapping_state_machine_torque_and_emcy(raw):
    spy, sim, node, _, joints = raw
    # TPDO1 = statusword (16 bit) + position actual (32 bit), sent on every SYNC
    _w(node, 0x1800, 1, "<I", 0x80000000 | (0x180 + NODE))
    _w(node, 0x1A00, 0, "<B", 0)
    _w(node, 0x1A00, 1, "<I", 0x60410010)
    _w(node, 0x1A00, 2, "<I", 0x60640020)
    _w(node, 0x1A00, 0, "<B", 2)
    _w(node, 0x1800, 2, "<B", 1)
    _w(node, 0x1800, 1, "<I", 0x180 + NODE)
    # RPDO1 = target torque (16 bit), applied on reception (type 255)
    _w(node, 0x1400, 1, "<I", 0x80000000 | (0x200 + NODE))
    _w(node, 0x1600, 0, "<B", 0)
    _w(node, 0x1600, 1, "<I", 0x60710010)
    _w(node, 0x1600, 0, "<B", 1)
    _w(node, 0x1400, 2, "<B", 255)
    _w(node, 0x1400, 1, "<I", 0x200 + NODE)
    _w(node, 0x6060, 0, "<b", 4)  # profile torque
    assert _u(node, 0x6061, 0, "<b") == 4
    spy.send(can.Message(arbitration_id=0, data=[0x01, NODE], is_extended_id=False))  # NMT start
    states = []
    for cw in (0x06, 0x07, 0x0F):
        _w(node, 0x6040, 0, "<H", cw)
        states.append(_u(node, 0x6041, 0, "<H") & 0x6F)
    assert states == [0x21, 0x23, 0x27]
    joints._x[:] = 1.0  # rad; default 131072 counts/rev, gear 1
    _frames(spy)
    spy.send(can.Message(arbitration_id=0x200 + NODE, data=struct.pack("<h", 250), is_extended_id=False))
    spy.send(can.Message(arbitration_id=0x80, data=b"", is_extended_id=False))  # SYNC
    tpdo = [m for m in _frames(spy) if m.arbitration_id == 0x180 + NODE]
    assert len(tpdo) == 1
    sw, pos = struct.unpack("<Hi", bytes(tpdo[0].data))
    assert sw & 0x6F == 0x27 and pos == round(131072 / (2 * np.pi))
    assert joints._u[0] == pytest.approx(0.250 * 1.0)  # 250 per mille of the 1 N.m rated torque
    for _ in range(500):  # the injected fault (drive over temperature 0x4310) starts at tick 500
        sim.tick()
    emcy = [m for m in _frames(spy) if m.arbitration_id == 0x80 + NODE]
    assert len(emcy) == 1
    code, register = struct.unpack_from("<HB", bytes(emcy[0].data))
    assert code == 0x4310 and register == 0x09  # generic + temperature (CiA 301 §7.5.2.2)
    assert _u(node, 0x6041, 0, "<H") & 0x4F == 0x08 and _u(node, 0x603F, 0, "<H") == 0x4310
    assert joints._u[0] == 0.0


def test_raw_sdo_abort_for_unsupported_mode(raw):
    _, _, node, _, _ = raw
    with pytest.raises(canopen.SdoAbortedError) as exc:
        _w(node, 0x6060, 0, "<b", 8)  # cyclic synchronous position: not in 0x6502
    assert exc.value.code == 0x06090030
