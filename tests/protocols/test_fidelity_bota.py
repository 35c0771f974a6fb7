"""Bota serial sensor: the ASCII configuration protocol, the sample rate set by the sinc filter and
the line's byte budget (issue 14, items 1 and 2).

Spec followed: Bota Systems' ``bota_serial_example.py`` (python_interface repository): wait for
``App Init``, ``C`` -> ``r,0,C,0``, ``c,TEMP,CALIB,FORMAT,BAUD`` -> ``r,0,c,0``, ``f,SINC,CHOP,FAST,
FIR`` -> ``r,0,f,0``, ``R`` -> ``r,0,R,0``, ``time_step = 0.00001953125 * SINC_LENGTH``; frames
``0xAA | 34 bytes | CRC-16/X-25``. The client below is that example reimplemented with raw pyserial
(and its own CRC), no project code on the host side. The sensor is served in the test's thread
(``threaded=False``: the test lets it answer after each write; the adapter's waits do it
themselves, ``tests/simtime``), so no answer depends on how fast the machine runs a thread.
"""

from __future__ import annotations

import struct

import numpy as np
import pytest
import serial
from simtime import served

from hil.errors import DeviceTimeout
from hil.mocks.interfaces import FreeJoints
from hil.mocks.serial_devices import SimBota
from hil.protocols.serial_bota import BotaSerial

pytestmark = pytest.mark.timeout(30)


def _crc_x25(data: bytes) -> int:
    """CRC-16/X-25 (poly 0x1021 reflected = 0x8408, init 0xFFFF, xorout 0xFFFF), bit by bit."""
    crc = 0xFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0x8408 if crc & 1 else crc >> 1
    return crc ^ 0xFFFF


def test_crc_reference_value():
    # the CRC catalogue's check value of CRC-16/X-25 for b"123456789"
    assert _crc_x25(b"123456789") == 0x906E


def test_bota_example_client_configures_and_reads_the_simulated_sensor():
    """Bota's example, step by step, against the simulator (the sensor is powered after the port
    is opened, so its App Init is seen)."""
    j = FreeJoints()
    j.apply_effort(np.array([3.5]))
    with SimBota(j, period_s=0.001, threaded=False) as sim:
        ser = serial.Serial()
        ser.baudrate, ser.port, ser.timeout = 460800, sim.path, 2.0  # a bound, never reached: the
        ser.open()                                                 # answers are written before each read
        try:
            sim.power_on()
            sim.serve_pending()
            assert b"App Init" in ser.read_until(b"App Init")
            ser.reset_input_buffer()  # (the example sleeps 0.5 s before: the boot text is all there)
            ser.reset_output_buffer()
            for cmd, reply in ((b"C", b"r,0,C,0"), (b"c,0,1,0,4", b"r,0,c,0"), (b"f,512,0,0,1", b"r,0,f,0"),
                               (b"R", b"r,0,R,0")):
                ser.write(cmd)
                sim.serve_pending()  # the sensor takes the command and answers
                assert reply in ser.read_until(reply), cmd
            assert sim.config == {"temp_compensation": 0, "use_calibration": 1, "data_format": 0, "baud_code": 4,
                                  "sinc_length": 512, "chop_enable": 0, "fast_enable": 0, "fir_disable": 1}
            for _ in range(4):
                sim.emit()
            sim.serve_pending()  # the frames into the host's input queue
            frames = []
            while len(frames) < 4:  # the example's processing loop
                if ser.read(1) != b"\xaa":
                    continue
                data, crc = ser.read(34), ser.read(2)
                assert struct.unpack("<H", crc)[0] == _crc_x25(data)
                frames.append(struct.unpack("<H6fIf", data))
        finally:
            ser.close()
    status = [f[0] for f in frames]
    fz = [f[3] for f in frames]
    ts = [f[7] for f in frames]
    assert status == [0] * 4 and fz == [3.5] * 4
    # sinc 512 -> 512 * 19.53125 us = 10 000 us between samples
    assert np.diff(ts).tolist() == [10_000] * 3


def test_adapter_sends_the_example_configuration():
    """The adapter configures the sensor on open as the example does; its sinc length comes
    from period_s (1 ms -> round(51.2) = 51)."""
    with SimBota(FreeJoints(), threaded=False) as sim, BotaSerial(sim.path, period_s=0.001, waits=served(sim)) as dev:
        assert sim.commands == ["C", "c,0,1,0,4", "f,51,0,0,1", "R"]
        assert dev.sinc_length == 51 and sim.period_s == pytest.approx(51 / 51200)
        sim.emit()
        assert dev.wait_rx(sim.tx_bytes, 5.0)
        dev.read()


def test_adapter_times_out_on_a_sensor_that_does_not_answer():
    """A silent line (wrong port or baud): DeviceTimeout naming the command, not a hang."""
    import os
    import tty

    m, s = os.openpty()
    tty.setraw(s)
    try:
        with pytest.raises(DeviceTimeout, match="r,0,C,0 reply to 'C'"):
            BotaSerial(os.ttyname(s), config_timeout=0.1)
    finally:
        os.close(m)
        os.close(s)


def test_sensor_rate_follows_the_simulated_clock_not_the_loop():
    """tick_s = 0.5 ms (a 2 kHz loop), sinc 51 (51200/51 = 1003.9 Hz): over 2000 ticks (1 s of
    simulated time) the sensor samples at t = 0, P, 2P, ... < 1 s: floor(1 s / P) + 1 = 1004
    frames, so about every other tick brings a new frame."""
    with SimBota(FreeJoints(), sinc_length=51, tick_s=0.0005) as sim:
        for _ in range(2000):
            sim.emit()
        period = 51 / 51200
        assert sim.stats["frames"] == int(0.9995 / period) + 1 == 1004
        assert sim.stats["link_dropped"] == 0


def test_simulated_line_carries_at_most_baud_over_10_bytes_per_simulated_second():
    """sinc 20 (2560 Hz x 37 B = 94 720 B/s) on 460 800 baud (46 080 B/s): over 1 s of simulated
    time the line delivers at most 46 080 B plus the initial burst allowance, the rest is lost and
    counted; no sleeping (simulated time, so a lockstep run is not slowed down)."""
    with SimBota(FreeJoints(), sinc_length=20, tick_s=0.001) as sim, \
            serial.Serial(sim.path, 460800, timeout=0) as host:
        got = 0
        for _ in range(1000):
            sim.emit()
            got += len(host.read(host.in_waiting or 1))  # keep the pty from filling up
        while got < sim.tx_bytes:
            got += len(host.read(host.in_waiting or 1))
        sent = sim.tx_bytes
        assert sim.stats["overflow_frames"] == 0 and got == sent
        assert sent <= 46_080 + sim.link.cap
        assert sent >= 46_080 - 37  # the line is used to capacity (within one frame)
        sampled = int(0.999 / (20 / 51200)) + 1  # samples at t = 0, P, ... <= 0.999 s (the last tick)
        assert sim.stats["link_dropped"] == sampled - sim.stats["frames"] > 0
