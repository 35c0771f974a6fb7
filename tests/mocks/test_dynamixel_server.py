"""Simulated DYNAMIXEL chain: Protocol 2.0 conformance vectors and the unmodified dynamixel_sdk.

The SDK talks to a chain served in the test's thread: ``simtime.served_sdk_port`` is the SDK's stock
``PortHandler`` whose read first lets the chain answer (the lockstep barrier) and whose packet
timeout runs on simulated time (a read that finds nothing moves the clock by 1 ms), so no answer
depends on how fast the machine runs a thread."""

from __future__ import annotations

import dynamixel_sdk as sdk
import numpy as np
import pytest
from simtime import served_sdk_port

from hil.mocks.dynamixel_devices import (
    DynamixelChain,
    PacketDecodeError,
    build_packet,
    build_status,
    find_packet,
    stuff,
    unstuff,
)
from hil.mocks.faults import FaultPlan
from hil.mocks.interfaces import FreeJoints

pytestmark = pytest.mark.timeout(20)

H = bytes.fromhex  # whitespace between bytes is ignored

# (id, instruction, params, expected bytes) - examples of the ROBOTIS e-manual, Protocol 2.0 page
INSTRUCTION_VECTORS = [
    ("ping id 1", 0x01, 0x01, b"", H("FF FF FD 00 01 03 00 01 19 4E")),
    ("broadcast ping", 0xFE, 0x01, b"", H("FF FF FD 00 FE 03 00 01 31 42")),
    ("read 132 x4 id 1", 0x01, 0x02, H("84000400"), H("FF FF FD 00 01 07 00 02 84 00 04 00 1D 15")),
    ("write 512 to 116", 0x01, 0x03, H("74 00 00 02 00 00"), H("FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89")),
    ("reg write 200 to 104", 0x01, 0x04, H("68 00 C8 00 00 00"), H("FF FF FD 00 01 09 00 04 68 00 C8 00 00 00 AE 8E")),
    ("action", 0x01, 0x05, b"", H("FF FF FD 00 01 03 00 05 02 CE")),
    ("factory reset", 0x01, 0x06, H("01"), H("FF FF FD 00 01 04 00 06 01 A1 E6")),
    ("reboot", 0x01, 0x08, b"", H("FF FF FD 00 01 03 00 08 2F 4E")),
    ("clear multi-turn", 0x01, 0x10, H("01 44 58 4C 22"), H("FF FF FD 00 01 08 00 10 01 44 58 4C 22 B1 DC")),
    (
        "sync read 132 x4 ids 1,2",
        0xFE,
        0x82,
        H("84 00 04 00 01 02"),
        H("FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA"),
    ),
    (
        "sync write 116 x4 (150, 170)",
        0xFE,
        0x83,
        H("74000400" "0196000000" "02AA000000"),
        H("FF FF FD 00 FE 11 00 83 74 00 04 00 01 96 00 00 00 02 AA 00 00 00 82 87"),
    ),
    (
        "bulk read voltage(144) of 1, temperature(146) of 2",
        0xFE,
        0x92,
        H("01 90 00 02 00  02 92 00 01 00"),
        H("FF FF FD 00 FE 0D 00 92 01 90 00 02 00 02 92 00 01 00 1A 05"),
    ),
]

STATUS_VECTORS = [
    ("ping status id 1", 0x01, 0x00, H("060426"), H("FF FF FD 00 01 07 00 55 00 06 04 26 65 5D")),
    ("ping status id 2", 0x02, 0x00, H("060426"), H("FF FF FD 00 02 07 00 55 00 06 04 26 6F 6D")),
    ("read status 166", 0x01, 0x00, H("A6000000"), H("FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0")),
    ("sync read status 2079", 0x02, 0x00, H("1F080000"), H("FF FF FD 00 02 08 00 55 00 1F 08 00 00 BA BE")),
    ("write status", 0x01, 0x00, b"", H("FF FF FD 00 01 04 00 55 00 A1 0C")),
    ("bulk read status voltage", 0x01, 0x00, H("7700"), H("FF FF FD 00 01 06 00 55 00 77 00 C3 69")),
    ("bulk read status temperature", 0x02, 0x00, H("24"), H("FF FF FD 00 02 05 00 55 00 24 8B A9")),
]


@pytest.mark.parametrize(("name", "dxl_id", "inst", "params", "expected"), INSTRUCTION_VECTORS)
def test_instruction_packet_vectors(name: str, dxl_id: int, inst: int, params: bytes, expected: bytes) -> None:
    assert build_packet(dxl_id, inst, params) == expected, name
    pkt, consumed, err = find_packet(bytearray(expected))
    assert err is None and consumed == len(expected)
    assert (pkt.dxl_id, pkt.instruction, pkt.params) == (dxl_id, inst, params)


@pytest.mark.parametrize(("name", "dxl_id", "error", "params", "expected"), STATUS_VECTORS)
def test_status_packet_vectors(name: str, dxl_id: int, error: int, params: bytes, expected: bytes) -> None:
    assert build_status(dxl_id, error, params) == expected, name


STUFFING = [
    (H("03FFFFFD00"), H("03 FF FF FD FD 00")),
    (H("FFFFFDFF"), H("FFFFFDFDFF")),
    (H("FFFFFDFD"), H("FFFFFDFDFD")),
    (H("FFFD"), H("FFFD")),
    (H("0102"), H("0102")),
]


@pytest.mark.parametrize(("raw", "stuffed"), STUFFING)
def test_byte_stuffing(raw: bytes, stuffed: bytes) -> None:
    assert stuff(raw) == stuffed
    assert unstuff(stuffed) == raw


def test_stuffed_packet_roundtrip_and_length() -> None:
    # writing FF FF FD to address 0x0074: the length counts the extra FD, the CRC covers it
    pkt = build_packet(1, 0x03, H("7400FFFFFD"))
    assert pkt[5] == 3 + 5 + 1 and H("FFFFFDFD") in pkt
    parsed, _, err = find_packet(bytearray(pkt))
    assert err is None and parsed.params == H("7400FFFFFD")


def test_parser_skips_junk_and_reports_crc_errors() -> None:
    good = build_packet(1, 0x01)
    bad = bytearray(good)
    bad[-1] ^= 1
    buf = bytearray(H("00FFFF") + bytes(bad) + good)
    pkt, consumed, err = find_packet(buf)
    assert pkt is None and isinstance(err, PacketDecodeError) and err.dxl_id == 1
    del buf[:consumed]
    pkt, consumed, err = find_packet(buf)
    assert pkt is not None and pkt.instruction == 0x01 and consumed == len(good)


# ---- the unmodified SDK against the simulated chain ----------------------------------------------
def Chain(*args, **kw) -> DynamixelChain:
    return DynamixelChain(*args, threaded=False, **kw)


@pytest.fixture
def chain_and_port():
    plant = FreeJoints(dof=2)
    with Chain(plant, ids=[1, 2]) as chain:
        port = served_sdk_port(chain)
        assert port.openPort() and port.setBaudRate(57_600)  # a factory servo's rate
        try:
            yield plant, chain, port, sdk.PacketHandler(2.0)
        finally:
            port.closePort()


def test_sdk_ping_read_write(chain_and_port) -> None:
    plant, chain, port, ph = chain_and_port
    assert ph.ping(port, 1) == (1020, sdk.COMM_SUCCESS, 0)
    assert chain.rx_frames[-1] == H("FF FF FD 00 01 03 00 01 19 4E")  # e-manual ping vector, sent by the SDK
    assert ph.ping(port, 7)[1] == sdk.COMM_RX_TIMEOUT  # nobody with id 7
    found, result = ph.broadcastPing(port)
    assert result == sdk.COMM_SUCCESS and found == {1: [1020, 45], 2: [1020, 45]}
    assert ph.read2ByteTxRx(port, 2, 38) == (1193, sdk.COMM_SUCCESS, 0)  # Current Limit
    assert ph.write1ByteTxRx(port, 1, 11, 0) == (sdk.COMM_SUCCESS, 0)  # Operating Mode = current
    assert ph.read1ByteTxRx(port, 1, 11)[0] == 0
    assert ph.write1ByteTxRx(port, 1, 64, 1) == (sdk.COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 1, 11, 3) == (sdk.COMM_SUCCESS, 7)  # EEPROM locked: access error
    assert ph.write2ByteTxRx(port, 1, 102, 1194) == (sdk.COMM_SUCCESS, 6)  # beyond Current Limit
    assert ph.write1ByteTxRx(port, 1, 0, 5) == (sdk.COMM_SUCCESS, 7)  # read-only model number
    plant.step(0.1)
    value, result, _ = ph.read4ByteTxRx(port, 1, 132)
    assert result == sdk.COMM_SUCCESS and value == 0
    assert chain.rx_frames[-1] == H("FF FF FD 00 01 07 00 02 84 00 04 00 1D 15")  # e-manual read vector


def test_sdk_group_sync_write_and_read(chain_and_port) -> None:
    plant, chain, port, ph = chain_and_port
    for i in (1, 2):
        assert ph.write1ByteTxRx(port, i, 11, 0) == (sdk.COMM_SUCCESS, 0)
        assert ph.write1ByteTxRx(port, i, 64, 1) == (sdk.COMM_SUCCESS, 0)
    gsw = sdk.GroupSyncWrite(port, ph, 102, 2)
    gsw.addParam(1, [200, 0])  # +200 x 2.69 mA
    gsw.addParam(2, [0x38, 0xFF])  # -200 (two's complement)
    assert gsw.txPacket() == sdk.COMM_SUCCESS
    gsr = sdk.GroupSyncRead(port, ph, 126, 10)
    gsr.addParam(1)
    gsr.addParam(2)
    assert gsr.txRxPacket() == sdk.COMM_SUCCESS  # pty is FIFO: the sync write was processed first
    assert gsr.getData(1, 126, 2) == 200 and gsr.getData(2, 126, 2) == 0xFF38
    kt = chain.model.torque_constant
    np.testing.assert_allclose(chain.effort(), [200 * 2.69e-3 * kt, -200 * 2.69e-3 * kt])
    plant.step(0.5)
    assert gsr.txRxPacket() == sdk.COMM_SUCCESS
    assert gsr.getData(2, 132, 4) > 2**31  # negative position, two's complement on the wire
    assert gsr.getData(1, 128, 4) > 0


def test_sdk_bulk_read(chain_and_port) -> None:
    _, _, port, ph = chain_and_port
    gbr = sdk.GroupBulkRead(port, ph)
    assert gbr.addParam(1, 0, 2) and gbr.addParam(2, 6, 1)
    assert gbr.txRxPacket() == sdk.COMM_SUCCESS
    assert gbr.getData(1, 0, 2) == 1020 and gbr.getData(2, 6, 1) == 45


def test_bad_crc_instruction_gets_crc_error_status(chain_and_port) -> None:
    _, chain, port, ph = chain_and_port
    bad = bytearray(build_packet(1, 0x01))
    bad[-2] ^= 0xFF
    port.writePort(bytes(bad))
    port.setPacketTimeout(11)
    rx, result = ph.rxPacket(port, False)
    assert result == sdk.COMM_SUCCESS and rx[8] == 0x03 and chain.crc_errors == 1


# ---- faults through the SDK -------------------------------------------------------------------
def _sdk(chain: DynamixelChain):
    port = served_sdk_port(chain)
    assert port.openPort() and port.setBaudRate(57_600)  # the SDK opens at 1 Mbps; a factory servo is at 57 600
    return port, sdk.PacketHandler(2.0)


def test_faults_seen_by_the_sdk() -> None:
    plan = FaultPlan(drop_ticks=[0], corrupt_ticks=[1], error_code=0x04, error_at_tick=3, error_until_tick=5)
    with Chain(FreeJoints(1), ids=[1], faults=plan) as chain:
        port, ph = _sdk(chain)
        try:
            assert ph.ping(port, 1)[1] == sdk.COMM_RX_TIMEOUT  # tick 0: dropped
            assert ph.ping(port, 1)[1] == sdk.COMM_RX_CORRUPT  # tick 1: CRC broken
            assert ph.ping(port, 1) == (1020, sdk.COMM_SUCCESS, 0)
            _, result, error = ph.ping(port, 1)  # tick 3: hardware error -> alert bit
            assert result == sdk.COMM_SUCCESS and error & 0x80
            assert ph.read1ByteTxRx(port, 1, 70) == (0x04, sdk.COMM_SUCCESS, 0x80)  # tick 4
            assert ph.ping(port, 1) == (1020, sdk.COMM_SUCCESS, 0)  # tick 5: cleared
        finally:
            port.closePort()


def test_garbage_before_status_is_skipped() -> None:
    with Chain(FreeJoints(1), ids=[1], faults=FaultPlan(garbage_prob=1.0), seed=2) as chain:
        port, ph = _sdk(chain)
        try:
            for _ in range(5):
                assert ph.ping(port, 1) == (1020, sdk.COMM_SUCCESS, 0)
            assert chain.injector.injected["garbage"] == 5
        finally:
            port.closePort()


def _fault_sequence(seed: int) -> list[int]:
    with Chain(FreeJoints(1), ids=[1], faults=FaultPlan(drop_prob=0.3, corrupt_prob=0.2), seed=seed) as c:
        port, ph = _sdk(c)
        try:
            return [ph.ping(port, 1)[1] for _ in range(12)]
        finally:
            port.closePort()


def test_faults_are_deterministic_for_a_seed() -> None:
    a = _fault_sequence(11)
    assert a == _fault_sequence(11)
    assert len(set(a)) > 1
