"""Robotiq FT-300: a stream left running is stopped before polling, as Robotiq's driver does
(issue 14, item 1), and raw-library clients against the simulated sensors.

Specs followed: Robotiq "FT 300 Force Torque Sensor - Instruction Manual", Modbus RTU (19 200 8N1,
slave 9, registers 180..185 = Fx Fy Fz x100, Mx My Mz x1000) and "Data stream" (write 0x0200 to
register 410; stop with ~0.5 s of 0xFF); Robotiq's ``rq_sensor_com.c``
(``rq_com_tentative_connexion``: listen, ``rq_com_stop_stream_after_boot``, 100 ms, then Modbus).
The sensor on a pty is served in the test's thread (``threaded=False``; the adapter's simulated-time
waits serve it, ``tests/simtime``; a raw client's test serves it after each write), so no answer
depends on how fast the machine runs a thread; a raw client's timeout is a bound, never reached.
"""

from __future__ import annotations

import struct

import numpy as np
import pytest
import serial
from simtime import served, served_streaming

from hil.mocks.ft300_stream import SimFT300Stream
from hil.protocols.modbus_robotiq import STREAM_STOP_S, RobotiqFT300, RobotiqFT300Stream

pytestmark = pytest.mark.timeout(30)
WRENCH = np.array([12.5, -3.25, 40.0, 0.125, -0.5, 1.0])


def _crc_modbus(data: bytes) -> int:
    """CRC-16/MODBUS (poly 0xA001 reflected, init 0xFFFF), bit by bit."""
    crc = 0xFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def test_crc_reference_value_and_the_manuals_request():
    assert _crc_modbus(b"123456789") == 0x4B37  # CRC catalogue check value
    req = bytes.fromhex("090300B40006")
    assert req + struct.pack("<H", _crc_modbus(req)) == bytes.fromhex("090300B4000684A6")  # manual's example


def test_stop_timeout_is_half_a_second():
    assert STREAM_STOP_S == 0.5
    import inspect

    assert inspect.signature(RobotiqFT300Stream).parameters["stop_timeout"].default == 0.5


def test_polled_adapter_stops_a_stream_left_running():
    """The sensor is streaming when the polled adapter opens the line: it jams the stream, then
    polls over Modbus RTU (pymodbus) and gets the wrench the sensor measures."""
    # streaming at 100 Hz on the simulated time of the adapter's waits (until jammed)
    with SimFT300Stream(lambda: WRENCH, streaming=True, threaded=False) as sim, \
            RobotiqFT300(sim.path, timeout=0.5, read_info=True, waits=served_streaming(sim)) as dev:
        assert dev.stream_stopped is True and not sim.streaming
        np.testing.assert_allclose(dev.read().wrench, WRENCH, atol=1e-9)
        assert dev.info.firmware.startswith("FTS")


def test_polled_adapter_on_a_quiet_line_does_not_jam():
    with SimFT300Stream(lambda: WRENCH, threaded=False) as sim, \
            RobotiqFT300(sim.path, timeout=0.5, waits=served(sim)) as dev:
        assert dev.stream_stopped is None
        np.testing.assert_allclose(dev.read().wrench, WRENCH, atol=1e-9)


def test_raw_pyserial_client_streams_and_jams_like_robotiqs_driver():
    """Independent client (pyserial + its own CRC): FC16 write 0x0200 to register 410, read the
    echo and 16-byte frames (0x20 0x4E, six int16 LE, CRC), then 0xFF for ~0.5 s: the line goes
    quiet and Modbus answers again (FC03 of registers 180..185)."""
    with SimFT300Stream(lambda: WRENCH, threaded=False) as sim, serial.Serial(sim.path, 19200, timeout=10.0) as port:
        req = bytes.fromhex("0910019A0001020200")
        port.write(req + struct.pack("<H", _crc_modbus(req)))
        sim.serve_pending()  # the sensor takes the request and answers
        echo = port.read(8)
        assert echo[:6] == bytes.fromhex("0910019A0001") and struct.unpack("<H", echo[6:])[0] == _crc_modbus(echo[:6])
        assert sim.wait_streaming(True, 1.0)
        for _ in range(3):
            sim.emit()
        sim.serve_pending()
        frames = port.read(48)
        for k in range(3):
            f = frames[16 * k : 16 * (k + 1)]
            assert f[:2] == b"\x20\x4e" and struct.unpack("<H", f[14:])[0] == _crc_modbus(f[:14])
            raw = struct.unpack("<6h", f[2:14])
            np.testing.assert_allclose(np.array(raw) / [100, 100, 100, 1000, 1000, 1000], WRENCH)
        for _ in range(10):  # Robotiq's jam: 0xFF bytes (10 at a time, 0.5 s of them at 19 200 Bd)
            port.write(b"\xff" * 10)
            sim.serve_pending()
        assert not sim.streaming
        port.reset_input_buffer()
        req = bytes.fromhex("090300B40006")
        port.write(req + struct.pack("<H", _crc_modbus(req)))
        sim.serve_pending()
        reply = port.read(17)
        assert reply[:3] == bytes.fromhex("09030C") and struct.unpack("<H", reply[15:])[0] == _crc_modbus(reply[:15])
        regs = struct.unpack(">6h", reply[3:15])
        np.testing.assert_allclose(np.array(regs) / [100, 100, 100, 1000, 1000, 1000], WRENCH)


def test_raw_pymodbus_client_reads_the_simulated_polled_sensor():
    """Independent client (pymodbus only) against the pymodbus-served FT-300: FC03 180..185."""
    from pymodbus.client import ModbusTcpClient

    from hil.mocks.modbus_devices import SimulatedFT300

    with SimulatedFT300(lambda: WRENCH, port=0) as sim:
        client = ModbusTcpClient("127.0.0.1", port=sim.port, timeout=10.0)  # a bound: the server answers
        assert client.connect()
        try:
            rr = client.read_holding_registers(180, count=6, device_id=9)
            assert not rr.isError()
            regs = [r - 65536 if r > 32767 else r for r in rr.registers]
            np.testing.assert_allclose(np.array(regs) / [100, 100, 100, 1000, 1000, 1000], WRENCH)
            fw = client.read_holding_registers(500, count=3, device_id=9)
            assert not fw.isError() and chr(fw.registers[0] >> 8) == "F"  # "FTS..." (rq_sensor_com.c)
        finally:
            client.close()


def test_free_running_stream_keeps_the_sensors_100_hz():
    """A stream simulator built for a lockstep bench (tick_s = 0.5 ms) and then started free
    running (hil mock serve): each thread call stands for its own period, so the sensor clock
    follows the thread and the frames come at the sensor's rate, not at tick_s per call."""
    with SimFT300Stream(lambda: WRENCH, streaming=True, tick_s=0.0005) as sim:
        sim.start(200.0)
        assert sim.tick_s == pytest.approx(1 / 200)
        sim.stop()
    with SimFT300Stream(lambda: WRENCH, streaming=True, tick_s=0.0005) as sim:
        for _ in range(40):  # 40 x 0.5 ms = 20 ms of simulated time: frames at 0 and 10 ms
            sim.emit()
        assert sim.stats["frames"] == 2
