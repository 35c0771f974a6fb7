"""FT-300 data-stream mode: wire-format vectors, and the stream adapter against the simulated
streaming sensor over a real pty (and over ``socket://`` through a TCP relay).

Except where a test is about the sensor's own free-running threads (or a relay thread), the sensor
is served in the test's thread and the adapter waits on simulated time (``tests/simtime``): what a
test sees never depends on how fast the machine runs, and "promptly" is the simulated time a wait
took."""

from __future__ import annotations

import math
import os
import select
import socket
import struct
import threading
import time

import numpy as np
import pytest
from simtime import served

from hil.errors import ChecksumError, DeviceDisconnected, DeviceFault, DeviceTimeout
from hil.mocks.faults import FaultPlan
from hil.mocks.ft300_stream import SimFT300Stream
from hil.protocols.modbus_robotiq import (
    STREAM_FRAME_LEN,
    RobotiqFT300,
    RobotiqFT300Stream,
    StreamParser,
    decode_stream_frame,
    encode_stream_frame,
    rtu_frame,
    stream_start_request,
)
from hil.protocols.registry import open_device

pytestmark = pytest.mark.timeout(120)


# ------------------------------------------------------------------------------------------------
# conformance vectors
# ------------------------------------------------------------------------------------------------
def crc16_modbus_bitwise(data: bytes) -> int:
    """Independent CRC-16/MODBUS: init 0xFFFF, reflected poly 0xA001, bit by bit (as the
    ``rq_com_compute_crc`` of Robotiq's reference driver)."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


@pytest.mark.parametrize(
    "frame_hex",
    [
        "09 03 00 B4 00 06 84 A6",  # FT-300 manual: read registers 180..185 (Fx..Mz)
        "09 10 03 E8 00 03 01 30",  # Robotiq manuals: echo of an FC16 write (same RTU layer)
        "09 03 07 D0 00 01 85 CF",  # Robotiq manuals: read one holding register
    ],
)
def test_bitwise_crc_matches_manual_rtu_frames(frame_hex):
    frame = bytes.fromhex(frame_hex)
    assert crc16_modbus_bitwise(frame[:-2]) == int.from_bytes(frame[-2:], "little")
    assert rtu_frame(frame[0], frame[1:-2]) == frame


def test_bitwise_crc_check_value():
    assert crc16_modbus_bitwise(b"123456789") == 0x4B37  # CRC catalogue check value


def test_stream_start_request_layout():
    # slave 9, FC16, register 410 (0x019A), 1 register, 2 bytes, value 0x0200, CRC low byte first
    body = bytes.fromhex("09 10 01 9A 00 01 02 02 00")
    expected = body + crc16_modbus_bitwise(body).to_bytes(2, "little")
    assert stream_start_request(9) == expected
    assert expected.hex(" ") == "09 10 01 9a 00 01 02 02 00 cd ca"


# (wrench in N / N.m, the six int16 counts the manual's scaling gives: F * 100, M * 1000)
FRAME_CASES = [
    ((0.0, 0.0, 0.0, 0.0, 0.0, 0.0), (0, 0, 0, 0, 0, 0)),
    ((1.0, 2.5, 10.0, 0.1, 0.25, 1.0), (100, 250, 1000, 100, 250, 1000)),
    ((-12.34, -0.01, -300.0, -1.234, -0.001, -32.0), (-1234, -1, -30000, -1234, -1, -32000)),
    ((327.67, -327.68, 0.5, 32.767, -32.768, -0.5), (32767, -32768, 50, 32767, -32768, -500)),
    ((500.0, -500.0, 0.0, 40.0, -40.0, 0.0), (32767, -32768, 0, 32767, -32768, 0)),  # saturated
]


@pytest.mark.parametrize(("wrench", "counts"), FRAME_CASES)
def test_stream_frame_from_documented_layout(wrench, counts):
    # <0x20><0x4e><LSB_data1><MSB_data1> ... <LSB_data6><MSB_data6><LSB_crc><MSB_crc>,
    # CRC over the first 14 bytes (header included)
    body = b"\x20\x4e" + b"".join(int(c).to_bytes(2, "little", signed=True) for c in counts)
    expected = body + crc16_modbus_bitwise(body).to_bytes(2, "little")
    assert len(expected) == STREAM_FRAME_LEN == 16
    assert encode_stream_frame(np.array(wrench)) == expected
    decoded = decode_stream_frame(expected)
    np.testing.assert_allclose(decoded, np.array(counts) / np.array([100.0] * 3 + [1000.0] * 3), rtol=0, atol=0)


def test_parser_resync_and_crc_count_on_raw_bytes():
    a = encode_stream_frame(np.array([1, 2, 3, 0.1, 0.2, 0.3]))
    b = bytearray(encode_stream_frame(np.array([4, 5, 6, 0.4, 0.5, 0.6])))
    b[5] ^= 0x40
    c = encode_stream_frame(np.array([-7, -8, -9, -0.7, -0.8, -0.9]))
    p = StreamParser()
    out = p.feed(b"\x20\x00\xff\x4e\x20" + a + bytes(b) + b"junk" + c[:9])
    assert len(out) == 1 and p.crc_errors == 1
    out = p.feed(c[9:])
    np.testing.assert_allclose(out[0], [-7, -8, -9, -0.7, -0.8, -0.9])
    assert p.frames == 2 and p.skipped_bytes > 0


# ------------------------------------------------------------------------------------------------
# adapter against the simulated sensor on a pty
# ------------------------------------------------------------------------------------------------
class Box:
    """A settable wrench source."""

    def __init__(self) -> None:
        self.w = np.zeros(6)

    def __call__(self) -> np.ndarray:
        return self.w


@pytest.fixture
def rig():
    box = Box()
    sim = SimFT300Stream(box, threaded=False, seed=3)
    dev = RobotiqFT300Stream(sim.path, waits=served(sim), timeout=0.5)
    yield box, sim, dev
    dev.close()
    sim.close()


def test_handshake_fc16_then_stream(rig):
    _box, sim, dev = rig
    assert sim.written == [(16, 410, [0x0200])]
    assert sim.streaming and dev.streaming
    assert dev.info.extra["start"] == "handshake"
    assert dev.info.firmware == "FTS-1.0.3" and dev.info.serial == "SIM-0001"
    assert dev.info.extra["production_year"] == 2024


@pytest.mark.parametrize(("wrench", "counts"), FRAME_CASES)
def test_scaling_all_axes(rig, wrench, counts):
    box, sim, dev = rig
    box.w = np.array(wrench)
    assert sim.emit()
    s = dev.read()
    np.testing.assert_allclose(s.wrench, np.array(counts) / np.array([100.0] * 3 + [1000.0] * 3), rtol=0, atol=1e-12)
    assert s.seq == 1


def test_newest_frame_wins_and_seq_counts(rig):
    box, sim, dev = rig
    for k in range(1, 4):
        box.w = np.full(6, float(k))
        sim.emit()
    assert dev.wait_rx(sim.tx_bytes, 1.0)  # the barrier: all three frames are there (simulated time)
    s = dev.read()
    assert s.wrench[0] == 3.0 and s.seq == 1
    assert dev.stats["frames"] == 3 and dev.stats["skipped_frames"] == 2
    box.w = np.full(6, 4.0)
    sim.emit()
    assert dev.read().seq == 2


def test_resync_after_garbage(rig):
    box, sim, dev = rig
    box.w = np.array([1.25, -2.5, 3.75, -0.125, 0.25, -0.375])
    sim.write_raw(b"\x00\x20\x20\x4e\x13\x37garbage\xff\x20")
    sim.emit()
    np.testing.assert_allclose(dev.read().wrench, box.w)
    assert dev.stats["skipped_bytes"] >= 10
    assert dev.stats["crc_errors"] >= 1  # the fake header "20 4E 13 37 ..." failed its CRC


def test_garbage_fault_every_frame():
    box = Box()
    with SimFT300Stream(box, threaded=False, faults=FaultPlan(garbage_prob=1.0, garbage_len=20), seed=1) as sim:
        dev = RobotiqFT300Stream(sim.path, waits=served(sim), timeout=0.5)
        try:
            for k in range(1, 21):
                box.w = np.array([k, -k, 2 * k, 0.01 * k, -0.01 * k, 0.001 * k], dtype=float)
                sim.emit()
                np.testing.assert_allclose(dev.read().wrench, box.w, atol=1e-12)
            assert sim.stats["garbage"] == 20 and dev.stats["skipped_bytes"] >= 20
        finally:
            dev.close()


def _lockstep_read(dev: RobotiqFT300Stream, sim: SimFT300Stream):
    """Wait for every byte the sensor wrote (a byte-count barrier), then read without waiting:
    the new wrench[0], or None when the read found no new frame (a stale sample)."""
    assert dev.wait_rx(sim.tx_bytes, timeout=30.0)
    before = dev._seq
    s = dev.read(timeout=0.0)
    return s.wrench[0] if s.seq > before else None


def test_crc_failures_are_counted_gaps():
    box = Box()
    with SimFT300Stream(box, threaded=False, faults=FaultPlan(corrupt_ticks=frozenset({2, 4})), seed=2) as sim:
        dev = RobotiqFT300Stream(sim.path, waits=served(sim), timeout=0.5)
        try:
            got = []
            for k in range(1, 6):
                box.w = np.array([k, 0, 0, 0, 0, 0], dtype=float)
                sim.emit()
                got.append(_lockstep_read(dev, sim))
            assert got == [1.0, None, 3.0, None, 5.0]
            assert dev.stats["crc_errors"] == 2 and dev.stats["gaps"] == 2 and dev.stats["frames"] == 3
            assert dev.counters()["crc_errors"] == 2 and dev.counters()["stale"] == 2
        finally:
            dev.close()


def test_crc_failure_raises_when_asked():
    box = Box()
    with SimFT300Stream(box, threaded=False, faults=FaultPlan(corrupt_ticks=frozenset({1})), seed=2) as sim:
        dev = RobotiqFT300Stream(sim.path, waits=served(sim), timeout=0.5, on_crc_error="raise")
        try:
            sim.emit()
            with pytest.raises(ChecksumError):
                dev.read(timeout=0.1)
            sim.emit()
            assert dev.read().seq == 1
        finally:
            dev.close()


def test_dropped_frame_and_silence_time_out_promptly(rig):
    _box, sim, dev = rig
    w0 = dev._waits.waited
    with pytest.raises(DeviceTimeout):
        dev.read(timeout=0.05)
    assert dev._waits.waited - w0 == pytest.approx(0.05, abs=1e-6)  # its timeout of simulated time
    sim.emit()
    first = dev.read()
    w0 = dev._waits.waited
    again = dev.read(timeout=0.02)  # no new frame: the previous data, not fresh
    assert dev._waits.waited - w0 == pytest.approx(0.02, abs=1e-6)
    assert again.seq == first.seq and again.produced_at == first.produced_at
    assert dev.counters() == {"crc_errors": 0, "resync_bytes": 0, "skipped": 0, "stale": 1, "timeouts": 1}


def test_max_age_returns_previous_sample():
    box = Box()
    with SimFT300Stream(box, threaded=False) as sim:
        dev = RobotiqFT300Stream(sim.path, waits=served(sim), max_age=5.0)
        try:
            sim.emit()
            a = dev.read()
            b = dev.read(timeout=0.0)
            assert b.seq == a.seq == 1 and b.produced_at == a.produced_at
        finally:
            dev.close()


def test_tare_offsets_later_readings(rig):
    box, sim, dev = rig
    box.w = np.array([1.0, 2.0, 3.0, 0.1, 0.2, 0.3])
    sim.emit()
    dev.tare()
    box.w = np.array([1.5, 2.0, 3.0, 0.1, 0.2, 0.0])
    sim.emit()
    np.testing.assert_allclose(dev.read().wrench, [0.5, 0, 0, 0, 0, -0.3], atol=1e-12)


def test_close_stops_stream_and_is_idempotent():
    box = Box()
    with SimFT300Stream(box, rate_hz=200.0) as sim:  # free running (its own threads, wall clock):
        sim.start()                                    # the waits below are bounds, never a pace
        dev = RobotiqFT300Stream(sim.path, timeout=10.0, stop_timeout=10.0)
        assert dev.read().seq == 1  # free-running frames arrive
        dev.close()
        assert dev.stream_stopped is True
        assert sim.wait_streaming(False, 10.0) and sim.stats["jams"] == 1
        n = sim.tick_count
        time.sleep(0.05)
        assert sim.tick_count == n  # silent after the jam
        dev.close()
        with pytest.raises(DeviceDisconnected):
            dev.read()
        # back in Modbus mode: a new adapter starts the stream again
        dev2 = RobotiqFT300Stream(sim.path, timeout=10.0, read_info=False, stop_timeout=10.0)
        assert dev2.info.extra["start"] == "handshake" and dev2.read().seq == 1
        dev2.close()
        assert len(sim.written) == 2


def test_already_streaming_sensor_is_used_as_is():
    box = Box()
    box.w = np.array([0, 0, 9.81, 0, 0, 0])
    with SimFT300Stream(box, rate_hz=200.0, streaming=True) as sim:  # free running: bounds, not a pace
        sim.start()
        dev = RobotiqFT300Stream(sim.path, timeout=10.0, probe_s=10.0, stop_timeout=10.0)
        try:
            assert dev.info.extra["start"] == "already-streaming" and sim.written == []
            assert dev.read().wrench[2] == pytest.approx(9.81)
        finally:
            dev.close()
        assert sim.wait_streaming(False, 10.0)


def test_silent_port_times_out_on_open():
    master, slave = os.openpty()
    try:
        waits = served()  # nobody on the line: simulated time, nothing to serve
        with pytest.raises(DeviceTimeout):
            RobotiqFT300Stream(os.ttyname(slave), timeout=0.1, read_info=False, stop_timeout=0.1, waits=waits)
        assert waits.waited < 1.0  # the probe, the request's timeout and the jam: no hang
    finally:
        os.close(master)
        os.close(slave)


def test_exception_reply_raises_device_fault():
    master, slave = os.openpty()

    def responder() -> None:
        buf = b""
        while len(buf) < 11:
            if select.select([master], [], [], 30.0)[0]:  # a bound, not a pace
                buf += os.read(master, 64)
            else:
                return
        os.write(master, rtu_frame(9, bytes([0x90, 0x04])))  # SERVER DEVICE FAILURE

    th = threading.Thread(target=responder, daemon=True)
    th.start()
    try:
        with pytest.raises(DeviceFault) as ei:
            RobotiqFT300Stream(os.ttyname(slave), timeout=30.0, read_info=False, probe_s=0.0, stop_timeout=0.1)
        assert ei.value.code == 4
    finally:
        th.join(30.0)
        os.close(master)
        os.close(slave)


def test_unplugged_port_is_device_disconnected():
    box = Box()
    sim = SimFT300Stream(box, threaded=False)
    dev = RobotiqFT300Stream(sim.path, waits=served(sim), timeout=0.2)
    try:
        sim.hangup()
        with pytest.raises(DeviceDisconnected):
            dev.read(timeout=0.2)
    finally:
        dev.close()
        sim.close()


def test_determinism_with_faults():
    def run() -> tuple[list, dict]:
        box = Box()
        plan = FaultPlan(drop_prob=0.2, corrupt_prob=0.2, garbage_prob=0.3, stale_prob=0.1)
        with SimFT300Stream(box, threaded=False, faults=plan, seed=11) as sim:
            dev = RobotiqFT300Stream(sim.path, waits=served(sim), timeout=0.5, read_info=False)
            out = []
            try:
                for k in range(40):
                    box.w = np.array([k, -k, 0.5 * k, 0.01 * k, 0, -0.01 * k], dtype=float)
                    sim.emit()
                    try:
                        out.append(_lockstep_read(dev, sim))
                    except DeviceTimeout:  # no frame at all yet
                        out.append("timeout")
                return out, dict(dev.stats)
            finally:
                dev.close()

    a, b = run(), run()
    assert a == b
    assert a[1]["crc_errors"] > 0 and any(x is None for x in a[0])


def test_registry_and_rtu_url():
    box = Box()
    box.w = np.array([-1.0, 2.0, -3.0, 0.4, -0.5, 0.6])
    with SimFT300Stream(box, threaded=False) as sim:
        dev = open_device("robotiq_ft300_stream", url=f"rtu://{sim.path}?baudrate=19200", timeout=0.5,
                          waits=served(sim))
        try:
            assert isinstance(dev, RobotiqFT300Stream)
            sim.emit()
            np.testing.assert_allclose(dev.read().wrench, box.w)
        finally:
            dev.close()
        with pytest.raises(ValueError):
            RobotiqFT300Stream("tcp://127.0.0.1:502")


def test_polled_adapter_over_serial_rtu_on_the_same_device():
    """Registers 180-185 over a real serial line (pty), through pymodbus's serial client."""
    box = Box()
    box.w = np.array([12.34, -5.67, -300.0, 1.234, -0.567, -32.0])
    with SimFT300Stream(box, threaded=False) as sim:
        dev = RobotiqFT300(f"rtu://{sim.path}", timeout=0.5, waits=served(sim))
        try:
            np.testing.assert_allclose(dev.read().wrench, box.w, atol=1e-12)
            assert dev.info.serial == "SIM-0001"
        finally:
            dev.close()


def test_socket_url_through_tcp_relay():
    """``socket://`` (a transparent serial device server): a TCP relay in front of the pty."""
    box = Box()
    box.w = np.array([3.0, -4.0, 5.0, -0.3, 0.4, -0.5])
    with SimFT300Stream(box) as sim:
        srv = socket.create_server(("127.0.0.1", 0))
        port = srv.getsockname()[1]
        stop = threading.Event()

        def relay() -> None:
            conn, _ = srv.accept()
            fd = os.open(sim.path, os.O_RDWR | os.O_NOCTTY)
            try:
                while not stop.is_set():
                    ready, _, _ = select.select([conn, fd], [], [], 0.02)
                    if conn in ready:
                        data = conn.recv(4096)
                        if not data:
                            return
                        os.write(fd, data)
                    if fd in ready:
                        conn.sendall(os.read(fd, 4096))
            finally:
                os.close(fd)
                conn.close()

        th = threading.Thread(target=relay, daemon=True)
        th.start()
        dev = RobotiqFT300Stream(f"socket://127.0.0.1:{port}", timeout=10.0, stop_timeout=10.0)  # bounds
        try:
            assert sim.wait_streaming(True, 10.0)
            sim.emit()
            np.testing.assert_allclose(dev.read().wrench, box.w)
        finally:
            dev.close()
            assert sim.wait_streaming(False, 10.0)
            stop.set()
            th.join(2.0)
            srv.close()


def test_stream_frame_struct_matches_manual_table():
    """data1..data6 = Fx*100, Fy*100, Fz*100, Mx*1000, My*1000, Mz*1000 (int16 little-endian)."""
    f = encode_stream_frame(np.array([1.0, 2.0, 3.0, 0.004, 0.005, 0.006]))
    assert struct.unpack_from("<6h", f, 2) == (100, 200, 300, 4, 5, 6)


def test_lockstep_bench_with_streaming_ft300_is_deterministic():
    """A simulated bench with the stream driver: frames at the sensor's fixed 100 Hz on the
    simulated clock (manual, "Data stream"; not one per 0.5 ms control period), reproducible."""
    import yaml

    from hil.bench.runtime import Bench
    from hil.scene.spec import load_scene, scene_from_dict

    data = yaml.safe_load(load_scene("sdea_bench").source_text)
    data["devices"][1].update(driver="robotiq_ft300_stream", params={"url": "/dev/ttyUSB0"})
    scene = scene_from_dict(data, label="sdea_ft300_stream")

    def run() -> list[tuple[float, int, float]]:
        out = []
        with Bench(scene, variant="locked") as bench:
            for _ in range(30):
                m = bench.read()
                bench.command({"motor": [0.2]})
                s = m["spring_ft"]
                out.append((s.t, s.seq, float(s.wrench[5])))
                bench.advance()
        return out

    a = run()
    assert a == run()
    # frame n is sampled at n / 100 s: tick k (t = k dt) reads frame floor(100 k dt) + 1
    assert [x[1] for x in a] == [math.floor(100 * k * scene.dt + 1e-9) + 1 for k in range(30)]
    assert a[5][0] == pytest.approx(5 * scene.dt)
    assert a[-1][2] > a[0][2]  # the spring torque builds up under the 0.2 N.m step
