"""RobotiqFT300 adapter against the simulated FT-300 over real loopback sockets, plus wire vectors."""

from __future__ import annotations

import struct

import numpy as np
import pytest

pytest.importorskip("pymodbus")

from simtime import served_modbus

from hil.errors import (
    ChecksumError,
    DeviceDisconnected,
    DeviceFault,
    DeviceTimeout,
    ProtocolError,
)
from hil.mocks.faults import FaultInjector, FaultPlan
from hil.mocks.interfaces import FreeJoints
from hil.mocks.modbus_devices import SimulatedFT300, wrench_to_registers
from hil.protocols.base import ForceSensor
from hil.protocols.modbus_robotiq import (
    STREAM_FRAME_LEN,
    GatewayError,
    ModbusEndpoint,
    RobotiqFT300,
    StreamParser,
    decode_firmware,
    decode_serial,
    decode_stream_frame,
    encode_stream_frame,
    registers_to_wrench,
)

pytestmark = pytest.mark.timeout(120)

# Manual scaling: Fx,Fy,Fz = register / 100 N; Mx,My,Mz = register / 1000 N.m (signed 16 bit).
SCALING = [
    # registers 180..185                       -> expected wrench
    ([100, 0, 0, 0, 0, 0], [1.0, 0, 0, 0, 0, 0]),
    ([0xFF9C, 0, 0, 0, 0, 0], [-1.0, 0, 0, 0, 0, 0]),
    ([0, 30000, 0, 0, 0, 0], [0, 300.0, 0, 0, 0, 0]),
    ([0, 0, 0x8000, 0, 0, 0], [0, 0, -327.68, 0, 0, 0]),
    ([0, 0, 0, 1000, 0, 0], [0, 0, 0, 1.0, 0, 0]),
    ([0, 0, 0, 0, 0xFFFF, 0], [0, 0, 0, 0, -0.001, 0]),
    ([0, 0, 0, 0, 0, 30000], [0, 0, 0, 0, 0, 30.0]),
]


@pytest.mark.parametrize(("regs", "expected"), SCALING)
def test_register_scaling(regs: list[int], expected: list[float]) -> None:
    np.testing.assert_allclose(registers_to_wrench(regs), expected, atol=1e-12)


def test_info_decoding() -> None:
    assert decode_firmware([0x4654, 0x5301, 0x0003]) == "FTS-1.0.3"
    assert decode_serial([0x4654, 0x5300, 42, 0]) == "FTS-0042"
    assert decode_serial([0, 0, 0, 0]) == "UNKNOWN"


URLS = [
    ("tcp://127.0.0.1:5020", ModbusEndpoint("tcp", host="127.0.0.1", port=5020)),
    ("rtu-over-tcp://10.0.0.2:4001", ModbusEndpoint("rtu-over-tcp", host="10.0.0.2", port=4001)),
    ("rtu:///dev/ttyUSB0?baudrate=115200", ModbusEndpoint("rtu", device="/dev/ttyUSB0", baudrate=115200)),
    ("/dev/ttyUSB1", ModbusEndpoint("rtu", device="/dev/ttyUSB1", baudrate=19200)),
]


@pytest.mark.parametrize(("url", "endpoint"), URLS)
def test_url_scheme(url: str, endpoint: ModbusEndpoint) -> None:
    assert ModbusEndpoint.parse(url) == endpoint


def test_bad_url_scheme() -> None:
    with pytest.raises(ValueError):
        ModbusEndpoint.parse("http://x:1")


# ---- stream frames ----------------------------------------------------------------------------
def _ref_crc(data: bytes) -> int:
    """Bitwise CRC-16/MODBUS as in Robotiq's rq_com_compute_crc (independent oracle)."""
    crc = 0xFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


STREAM_VECTORS = [
    # wrench (N, N.m)                              int16 payload
    ([0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0, 0]),
    ([1.0, -1.0, 10.0, 0.5, -0.25, 0.001], [100, -100, 1000, 500, -250, 1]),
    ([-300.0, 300.0, -0.01, -30.0, 30.0, -0.001], [-30000, 30000, -1, -30000, 30000, -1]),
]


@pytest.mark.parametrize(("wrench", "counts"), STREAM_VECTORS)
def test_stream_frame_vectors(wrench: list[float], counts: list[int]) -> None:
    body = b"\x20\x4e" + struct.pack("<6h", *counts)
    expected = body + struct.pack("<H", _ref_crc(body))
    frame = encode_stream_frame(np.array(wrench))
    assert frame == expected and len(frame) == STREAM_FRAME_LEN
    np.testing.assert_allclose(decode_stream_frame(frame), wrench, atol=1e-12)


def test_stream_frame_errors() -> None:
    frame = bytearray(encode_stream_frame(np.array([1.0, 2, 3, 0.1, 0.2, 0.3])))
    frame[5] ^= 0x10
    with pytest.raises(ChecksumError):
        decode_stream_frame(bytes(frame))
    with pytest.raises(ProtocolError):
        decode_stream_frame(b"\x21" + bytes(frame[1:]))
    with pytest.raises(ProtocolError):
        decode_stream_frame(bytes(frame[:10]))


def test_stream_parser_resynchronises() -> None:
    w1 = np.array([1.0, -2.0, 3.0, 0.1, -0.2, 0.3])
    w2 = np.array([-5.0, 0.0, 7.5, 0.0, 0.0, -1.0])
    bad = bytearray(encode_stream_frame(w1))
    bad[9] ^= 0xFF
    data = b"\xff\x00\x20" + encode_stream_frame(w1) + bytes(bad) + b"\x13" + encode_stream_frame(w2)
    parser = StreamParser()
    out: list[np.ndarray] = []
    for i in range(0, len(data), 5):  # arbitrary chunking
        out += parser.feed(data[i : i + 5])
    assert len(out) == 2 and parser.frames == 2 and parser.crc_errors == 1
    np.testing.assert_allclose(out[0], w1)
    np.testing.assert_allclose(out[1], w2)


# ---- adapter against the simulated device over real sockets ----------------------------------
@pytest.fixture(params=["tcp", "rtu"])
def framing(request: pytest.FixtureRequest) -> str:
    return request.param


def test_adapter_reads_scaled_signed_wrench(framing: str) -> None:
    plant = FreeJoints(dof=6)
    with (
        SimulatedFT300(plant, framing=framing) as sim,
        RobotiqFT300(sim.url, waits=served_modbus(sim), timeout=0.5) as ft,
    ):
        assert isinstance(ft, ForceSensor) and ft.axes == 6
        assert ft.info.firmware == "FTS-1.0.3" and ft.info.serial == "SIM-0001"
        assert ft.info.extra["production_year"] == 2024
        seqs = []
        for w in ([1.5, -2.25, 300.0, -0.5, 0.125, -30.0], [-0.01, 0.01, -120.0, 0.001, -0.001, 2.5]):
            plant.apply_effort(np.array(w))
            s = ft.read()
            np.testing.assert_allclose(s.wrench, w, atol=1e-9)
            seqs.append(s.seq)
        assert seqs == [1, 2]


def test_adapter_tare(framing: str) -> None:
    plant = FreeJoints(dof=3)
    plant.apply_effort(np.array([1.0, 2.0, -3.0]))
    with (
        SimulatedFT300(plant, framing=framing) as sim,
        RobotiqFT300(sim.url, waits=served_modbus(sim), read_info=False) as ft,
    ):
        ft.tare()
        plant.apply_effort(np.array([1.5, 2.0, -3.0]))
        np.testing.assert_allclose(ft.read().wrench, [0.5, 0, 0, 0, 0, 0], atol=1e-9)


def test_adapter_start_stream_writes_register_410(framing: str) -> None:
    with (
        SimulatedFT300(framing=framing) as sim,
        RobotiqFT300(sim.url, waits=served_modbus(sim), read_info=False) as ft,
    ):
        ft.start_stream()
        assert sim.written == [(410, [0x0200])]


def test_dropped_reply_raises_timeout_quickly(framing: str) -> None:
    with (
        SimulatedFT300(framing=framing, faults=FaultPlan(drop_ticks=[0])) as sim,
        RobotiqFT300(sim.url, waits=served_modbus(sim), read_info=False, timeout=0.1) as ft,
    ):
        with pytest.raises(DeviceTimeout):
            ft.read()
        assert ft._waits.waited == pytest.approx(0.1, abs=1e-6)  # one timeout of simulated time: quickly
        ft.read()  # the next request is answered again
        assert sim.replies_dropped == 1


def test_corrupted_rtu_reply_raises_checksum_error() -> None:
    with (
        SimulatedFT300(framing="rtu", faults=FaultPlan(corrupt_ticks=[0])) as sim,
        RobotiqFT300(sim.url, waits=served_modbus(sim), read_info=False, timeout=0.1, retries=0) as ft,
    ):
        with pytest.raises(ChecksumError):
            ft.read()
        ft.read()
        assert ft.counters()["crc_errors"] == 1


def test_corrupted_rtu_reply_is_asked_again_and_counted() -> None:
    plant = FreeJoints(dof=1)
    plant.apply_effort(np.array([12.5]))
    with (
        SimulatedFT300(plant, framing="rtu", faults=FaultPlan(corrupt_ticks=[0])) as sim,
        RobotiqFT300(sim.url, waits=served_modbus(sim), read_info=False, timeout=0.1) as ft,
    ):
        s = ft.read()
        assert s.wrench[0] == pytest.approx(12.5) and s.seq == 1
        assert ft.counters()["crc_errors"] == 1 and ft.counters()["retries"] == 1 and sim.requests == 2


def test_tcp_gateway_exception_is_a_missed_reply_not_data() -> None:
    """Modbus/TCP: a reply damaged on the gateway's serial side comes back as exception 11."""
    plant = FreeJoints(dof=1)
    plant.apply_effort(np.array([7.0]))
    with (
        SimulatedFT300(plant, framing="tcp", faults=FaultPlan(corrupt_ticks=[1, 2])) as sim,
        RobotiqFT300(sim.url, waits=served_modbus(sim), read_info=False, timeout=0.1) as ft,
    ):
        ft.read()
        with pytest.raises(GatewayError):
            ft.read()  # ticks 1 and 2 (the retry) both damaged
        assert ft.read().wrench[0] == pytest.approx(7.0)
        assert ft.counters()["gateway_errors"] == 2 and ft.counters()["retries"] == 1
        assert sim.corrupted_replies == 2


def _damaged_reply(seed: int, reply: bytes) -> bytes:
    """The bytes the simulator sends for ``reply`` when it damages it (same seeded stream)."""
    inj = FaultInjector(FaultPlan(corrupt_ticks=[1]), seed)
    return inj.corrupt(reply, start=7)


def test_tcp_payload_damage_never_returned_as_data_unless_undetectable() -> None:
    """A faulty gateway flips one byte of the PDU: a damaged function code or byte count, or a
    value outside the rated range, raises ProtocolError; only an in-range value damage (no CRC on
    Modbus/TCP) can pass, and then the adapter returns exactly the damaged value."""
    truth = np.array([10.0, -5.0, 2.0, 0.1, 0.2, 0.3])
    regs = wrench_to_registers(truth)
    pdu = bytes([9, 3, 12]) + b"".join(int(r).to_bytes(2, "big") for r in regs)
    seen = {"fc_or_count": 0, "range": 0, "passed": 0}
    for seed in range(30):
        reply = b"\x00\x02\x00\x00\x00\x0f" + pdu  # MBAP of the 2nd request + unit, fc, count, data
        bad = _damaged_reply(seed, reply)
        i = next(k for k in range(len(reply)) if bad[k] != reply[k])
        damaged = registers_to_wrench([int.from_bytes(bad[9 + 2 * k: 11 + 2 * k], "big") for k in range(6)])
        with (
            SimulatedFT300(lambda: truth, framing="tcp", faults=FaultPlan(corrupt_ticks=[1]), seed=seed,
                           tcp_corrupt="payload") as sim,
            RobotiqFT300(sim.url, waits=served_modbus(sim), read_info=False, timeout=0.2, retries=0) as ft,
        ):
            ft.read()
            if i in (7, 8):
                with pytest.raises(ProtocolError):
                    ft.read()
                seen["fc_or_count"] += 1
            elif np.any(np.abs(damaged[:3]) > 300) or np.any(np.abs(damaged[3:]) > 30):
                with pytest.raises(ProtocolError):
                    ft.read()
                assert ft.counters()["out_of_range"] == 1
                seen["range"] += 1
            else:
                np.testing.assert_allclose(ft.read().wrench, damaged)
                seen["passed"] += 1
    assert seen["fc_or_count"] > 0 and seen["passed"] > 0


def test_device_error_raises_device_fault(framing: str) -> None:
    plan = FaultPlan(error_code=5, error_at_tick=1, error_until_tick=2)
    with (
        SimulatedFT300(framing=framing, faults=plan) as sim,
        RobotiqFT300(sim.url, waits=served_modbus(sim), read_info=False) as ft,
    ):
        ft.read()
        with pytest.raises(DeviceFault) as exc:
            ft.read()
        assert exc.value.code == 4  # Modbus SERVER DEVICE FAILURE
        ft.read()


def test_disconnected_device_times_out() -> None:
    with (
        SimulatedFT300(faults=FaultPlan(disconnect_at_tick=1)) as sim,
        RobotiqFT300(sim.url, waits=served_modbus(sim), read_info=False, timeout=0.1) as ft,
    ):
        ft.read()
        for _ in range(2):
            with pytest.raises(DeviceTimeout):
                ft.read()


def test_stale_fault_repeats_previous_value() -> None:
    plant = FreeJoints(dof=1)
    with (
        SimulatedFT300(plant, faults=FaultPlan(stale_prob=0.5), seed=1) as sim,
        RobotiqFT300(sim.url, waits=served_modbus(sim), read_info=False) as ft,
    ):
        values = []
        for k in range(10):
            plant.apply_effort(np.array([float(k + 1)]))
            values.append(ft.read().wrench[0])
        fresh = [v == k + 1 for k, v in enumerate(values)]
        assert sum(not f for f in fresh) == sim.stale_replies > 0


def test_server_gone_raises_disconnected_or_timeout() -> None:
    sim = SimulatedFT300()
    ft = RobotiqFT300(sim.url, read_info=False, timeout=0.1)
    ft.read()
    sim.close()
    with pytest.raises((DeviceDisconnected, DeviceTimeout)):
        ft.read()
    ft.close()
    ft.close()  # idempotent
    with pytest.raises(DeviceDisconnected):
        ft.read()


def test_connect_refused_raises_disconnected() -> None:
    sim = SimulatedFT300()
    url = sim.url
    sim.close()
    with pytest.raises(DeviceDisconnected):
        RobotiqFT300(url, timeout=0.1)
