"""Bota serial adapter against the simulated sensor over a real pty.

The sensor is served in the test's thread and the adapter waits on simulated time
(``tests/simtime``), except in the free-running test: nothing depends on how fast the machine runs."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from simtime import served

from hil.errors import ChecksumError, DeviceDisconnected, DeviceFault, DeviceTimeout
from hil.mocks.faults import FaultPlan
from hil.mocks.interfaces import FreeJoints
from hil.mocks.serial_devices import SimBota
from hil.protocols.crc import crc16_x25
from hil.protocols.serial_bota import FRAME_LEN, BotaSerial, FrameParser, encode_frame

pytestmark = pytest.mark.timeout(120)


def test_frame_layout_vector():
    f = encode_frame(0x0002, [1.0, -2.0, 3.5, 0.0, 0.25, -0.5], 123456, 31.5)
    assert len(f) == FRAME_LEN == 37
    assert f[0] == 0xAA
    payload = f[1:35]
    assert payload[:2] == b"\x02\x00"
    assert struct.unpack_from("<6f", payload, 2) == (1.0, -2.0, 3.5, 0.0, 0.25, -0.5)
    assert struct.unpack_from("<If", payload, 26) == (123456, 31.5)
    assert f[35:] == crc16_x25(payload).to_bytes(2, "little")


def test_parser_resync_after_garbage_and_crc_errors():
    good = [encode_frame(0, [i] * 6, i, 20.0) for i in range(1, 4)]
    bad = bytearray(good[1])
    bad[10] ^= 0xFF
    stream = b"\x00\xaa\x13garbage\xaa" + good[0] + bytes(bad) + good[2][:20]
    p = FrameParser()
    frames = p.feed(stream)
    assert [f.timestamp for f in frames] == [1]
    assert p.stats["crc_errors"] >= 1
    frames = p.feed(good[2][20:])
    assert [f.timestamp for f in frames] == [3]


def Sim(j, **kw) -> SimBota:
    """A sensor served in the test's thread (the adapter's waits run it)."""
    return SimBota(j, threaded=False, **kw)


def Dev(sim: SimBota, **kw) -> BotaSerial:
    """The adapter on ``sim``, waiting on simulated time."""
    return BotaSerial(sim.path, waits=served(sim), **kw)


@pytest.fixture
def rig():
    j = FreeJoints()
    sim = Sim(j, period_s=0.001)
    dev = Dev(sim, period_s=0.001)
    yield j, sim, dev
    dev.close()
    sim.close()


def test_wrench_decodes(rig):
    j, sim, dev = rig
    j.apply_effort(np.array([4.25]))
    sim.emit()
    s = dev.read()
    np.testing.assert_allclose(s.wrench, [0, 0, 4.25, 0, 0, 0])
    assert s.seq == 1 and s.status == 0
    again = dev.read(timeout=0.01)  # nothing new: no hang, the previous data with its seq and date
    assert again.seq == 1 and again.produced_at == s.produced_at
    np.testing.assert_array_equal(again.wrench, s.wrench)
    assert dev.counters()["stale"] == 1


def test_first_read_without_any_frame_times_out():
    j = FreeJoints()
    with Sim(j) as sim, Dev(sim) as dev:
        with pytest.raises(DeviceTimeout):
            dev.read(timeout=0.01)
        assert dev.counters()["timeouts"] == 1


def _outcome(dev: BotaSerial, sim: SimBota) -> str:
    """One lockstep read: wait for every byte the sensor wrote, then "ok" (new data) or "stale"."""
    assert dev.wait_rx(sim.tx_bytes, timeout=10.0)
    before = dev._seq
    try:
        s = dev.read(timeout=0.0)
    except DeviceTimeout:
        return "timeout"
    return "ok" if s.seq > before else "stale"


def test_drop_records_gap():
    j = FreeJoints()
    with Sim(j, faults=FaultPlan(drop_ticks=frozenset({3, 4}))) as sim, Dev(sim, period_s=0.001) as dev:
        got = []
        for _ in range(6):
            sim.emit()
            got.append(_outcome(dev, sim))
        assert got == ["ok", "ok", "stale", "stale", "ok", "ok"]
        assert dev.stats["gaps"] == 1 and dev.stats["missed_samples"] == 2
        assert dev.counters()["dropped"] == 2 and dev.counters()["stale"] == 2


def test_corrupt_counts_crc_and_raise_mode():
    j = FreeJoints()
    with Sim(j, faults=FaultPlan(corrupt_ticks=frozenset({2}))) as sim, Dev(sim, period_s=0.001
    ) as dev:
        for _ in range(3):
            sim.emit()
            _outcome(dev, sim)
        assert dev.stats["crc_errors"] >= 1 and dev.stats["gaps"] == 1
        assert dev.counters()["crc_errors"] == dev.stats["crc_errors"]
    with Sim(j, faults=FaultPlan(corrupt_ticks=frozenset({2}))) as sim, Dev(sim, on_crc_error="raise"
    ) as dev:
        sim.emit()
        dev.read()
        sim.emit()
        assert dev.wait_rx(sim.tx_bytes, timeout=10.0)
        with pytest.raises(ChecksumError):
            dev.read(timeout=0.01)


def test_garbage_resync():
    j = FreeJoints()
    j.apply_effort(np.array([1.0]))
    with Sim(j, faults=FaultPlan(garbage_prob=1.0, garbage_len=40)) as sim, Dev(sim) as dev:
        for _ in range(20):
            sim.emit()
            assert dev.read(timeout=0.05).wrench[2] == 1.0
        assert dev.stats["resync_bytes"] > 0


def test_stale_is_not_fresh():
    j = FreeJoints()
    with Sim(j, faults=FaultPlan(stale_prob=1.0)) as sim, Dev(sim, clock=lambda: len(ts)) as dev:
        ts: list = []
        sim.emit()
        first = dev.read()
        ts.append(1)
        j.apply_effort(np.array([3.0]))
        sim.emit()  # repeats the previous frame (same timestamp, same values)
        assert dev.wait_rx(sim.tx_bytes, timeout=10.0)
        s = dev.read(timeout=0.0)
        assert s.seq == first.seq and s.produced_at == first.produced_at == 0 and s.t == 1 and s.age == 1
        assert dev.stats["stale"] == 1 and dev.counters()["repeated_frames"] == 1


def test_scheduled_stale_freezes_the_timestamp():
    j = FreeJoints()
    plan = FaultPlan(stale_at_tick=3, stale_until_tick=5)
    with Sim(j, faults=plan) as sim, Dev(sim, period_s=0.001) as dev:
        got = []
        for _ in range(6):
            sim.emit()
            got.append(_outcome(dev, sim))
        assert got == ["ok", "ok", "stale", "stale", "ok", "ok"]
        assert dev.counters()["repeated_frames"] == 2 and dev.counters()["dropped"] == 2


def test_status_fault():
    j = FreeJoints()
    plan = FaultPlan(error_code=0x2, error_at_tick=2, error_until_tick=3)  # overrange at tick 2
    with Sim(j, faults=plan) as sim, Dev(sim) as dev:
        sim.emit()
        dev.read()
        sim.emit()
        with pytest.raises(DeviceFault) as ei:
            dev.read()
        assert ei.value.code == 0x2
        sim.emit()
        assert dev.read().status == 0


def test_disconnect_then_reconnect_and_hangup():
    j = FreeJoints()
    plan = FaultPlan(disconnect_at_tick=2, reconnect_at_tick=3)
    with Sim(j, faults=plan) as sim:
        dev = Dev(sim)
        got = []
        for _ in range(3):
            sim.emit()
            got.append(_outcome(dev, sim))
        assert got == ["ok", "stale", "ok"]
        sim.hangup()
        with pytest.raises(DeviceDisconnected):
            dev.read(timeout=0.05)
        dev.close()
        dev.close()
        with pytest.raises(DeviceDisconnected):
            dev.read()


def test_free_running_stream():
    j = FreeJoints()
    with SimBota(j, period_s=0.002) as sim, BotaSerial(sim.path) as dev:
        sim.start()
        seqs = [dev.read(timeout=30.0).seq for _ in range(10)]  # ends at each frame: a bound, not a pace
        assert seqs == list(range(1, 11))


def _run(seed: int) -> list:
    """A lockstep read sequence: after each frame the reader waits for every byte the sensor wrote
    (a byte-count barrier, not a wall-clock timeout), then reads without waiting. What it sees is
    then a function of the seed only, whatever the machine's load."""
    j = FreeJoints()
    plan = FaultPlan(drop_prob=0.2, corrupt_prob=0.1, garbage_prob=0.2, stale_prob=0.1, late_prob=0.1)
    out: list = []
    k = 0
    with Sim(j, faults=plan, seed=seed) as sim, Dev(sim, clock=lambda: float(k)) as dev:
        for k in range(60):  # the adapter clock reads k: produced_at = the tick of arrival
            j.apply_effort(np.array([float(k)]))
            sim.emit()
            assert dev.wait_rx(sim.tx_bytes, timeout=30.0)
            try:
                s = dev.read(timeout=0.0)
                out.append((s.seq, s.produced_at, float(s.wrench[2])))
            except DeviceTimeout:
                out.append(None)
        out.append(dict(dev.stats))
        out.append(dev.counters())
    return out


def test_lockstep_determinism():
    a, b, c = _run(3), _run(3), _run(4)
    assert a == b
    assert a != c
    assert any(x is not None and x[0] < i for i, x in enumerate(a[:60]))  # some reads were stale


def test_open_missing_port():
    with pytest.raises(DeviceDisconnected):
        BotaSerial("/dev/does-not-exist-hil")


def test_tare(rig):
    j, sim, dev = rig
    j.apply_effort(np.array([2.0]))
    sim.emit()
    dev.tare()
    j.apply_effort(np.array([5.0]))
    sim.emit()
    assert dev.read().wrench[2] == pytest.approx(3.0)


def test_configuration_writes_use_the_configuration_timeout(monkeypatch):
    """pyserial's POSIX write raises "Write timeout" when the call, preemption included, outlasts the
    write timeout even though every byte went out: with a 5 ms watchdog a loaded machine made the
    configuration on open fail ("port lost ... while the bench was opening"). The configuration
    commands (open, read_identity) are written under ``config_timeout``; the run's writes under
    ``timeout`` again."""
    import serial

    import hil.protocols.serial_bota as sb

    seen: list[float | None] = []
    real = serial.serial_for_url

    def recording(*args, **kwargs):
        port = real(*args, **kwargs)
        write = port.write

        def write_recorded(data):
            seen.append(port.write_timeout)
            return write(data)

        port.write = write_recorded
        return port

    monkeypatch.setattr(sb.serial, "serial_for_url", recording)
    j = FreeJoints()
    with SimBota(j, period_s=0.002) as sim, BotaSerial(sim.path, timeout=0.005, config_timeout=2.0) as dev:
        assert seen == [2.0] * 4  # the four configuration commands
        assert dev._ser.write_timeout == 0.005
        sim.start()
        dev.read_identity(timeout=0.2, config_timeout=3.0)
        assert seen[4:] == [3.0] * 5  # the reset "#", then the four commands again
        assert dev._ser.write_timeout == 0.005
