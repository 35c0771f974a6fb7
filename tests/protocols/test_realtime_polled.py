"""Non-blocking reads (``read(timeout=0)``, the realtime loop) of the polled adapters: DYNAMIXEL X
(Protocol 2.0 sync read), Robotiq FT-300 over Modbus (RTU framing and Modbus/TCP) and CiA 402
(SYNC + TPDOs), against their simulated twins.

The twins answer as the devices do (at once); what the tests control is the *line* between host
and device: a relay (a second pty, or a TCP proxy) passes the host's bytes on at once and hands
the device's reply to the host only when the test releases it, in pieces if it likes (a slow or
fragmenting line). So "the reply has not arrived yet", "half of it has" and "it never comes" are
states a test sets, never races it hopes to win. Nothing asserts wall-clock time: the waits are for
states (no deadline: a loaded machine only makes them longer), and the adapters' timeouts (30 s,
wall clock: these are realtime reads) are never reached unless a test moves the adapter's record of
when it asked back by one timeout.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import select
import socket
import termios
import threading
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from hil.errors import DeviceFault
from hil.mocks.dynamixel_devices import ADDR_GOAL_CURRENT, ADDR_TORQUE_ENABLE, DynamixelChain, build_status
from hil.mocks.faults import FaultInjector, FaultPlan
from hil.mocks.interfaces import FreeJoints
from hil.mocks.pty import close_fds, open_raw_pty
from hil.protocols.base import sample_age
from hil.protocols.codecs.dynamixel import RAD_PER_TICK, StatusParser
from hil.protocols.codecs.robotiq import mbap_frame, parse_mbap_reply, rtu_frame, rtu_silence_s, wrench_request_pdu
from hil.protocols.dynamixel_x import DynamixelX

pytestmark = pytest.mark.timeout(300)
_chan = itertools.count()
BAUD = 1_000_000

@contextlib.contextmanager
def _released(relay: Any) -> Iterator[None]:
    """For the block, the relay lets the bytes through as they come (a thread releases them)."""
    done = threading.Event()

    def pass_through() -> None:
        while not done.is_set():
            relay.release()
            time.sleep(0.0005)
    th = threading.Thread(target=pass_through, daemon=True)
    th.start()
    try:
        yield
    finally:
        done.set()
        th.join()



#: the adapters' timeout (s, host clock): a bound a loaded machine never reaches
TIMEOUT = 30.0


def _wait(cond) -> None:
    """Wait until ``cond()`` (a state of the line or the device, not a duration; no deadline: the
    test's own timeout is the guard against a state that never comes)."""
    while not cond():
        time.sleep(0.001)


# -- pure codecs ----------------------------------------------------------------------------------


def test_status_parser_joins_split_packets_skips_noise_and_drops_bad_crc():
    a = build_status(1, 0, bytes(range(10)))
    b = build_status(2, 0x80, b"\xff\xff\xfd\x01")  # needs byte stuffing on the wire
    assert b"\xff\xff\xfd\xfd" in b
    p = StatusParser()
    stream = b"\x00\x13" + a + b
    got = []
    for k in range(0, len(stream), 3):  # three bytes at a time: every packet split
        got += p.feed(stream[k:k + 3])
    assert got == [(1, 0, bytes(range(10))), (2, 0x80, b"\xff\xff\xfd\x01")]
    assert p.skipped_bytes == 2 and p.crc_errors == 0 and p.pending == 0
    bad = bytearray(a)
    bad[12] ^= 0x01
    assert p.feed(bytes(bad) + b) == [(2, 0x80, b"\xff\xff\xfd\x01")] and p.crc_errors == 1


def test_modbus_framing_matches_the_manual_and_mbap_pairs_transactions():
    # FT-300 manual: "09 03 00 B4 00 06 84 A6" reads the six wrench registers
    assert rtu_frame(9, wrench_request_pdu()) == bytes.fromhex("090300B4000684A6")
    assert rtu_silence_s(19200) == pytest.approx(3.5 * 11 / 19200)
    assert rtu_silence_s(115200) == 1.75e-3
    reply = mbap_frame(7, 9, b"\x03\x0c" + bytes(12))
    buf = bytearray(mbap_frame(6, 9, b"\x03\x0c" + bytes(12)) + reply[:5])
    assert parse_mbap_reply(buf, 7, 9) == (None, 21)  # another transaction's reply: dropped whole
    del buf[:21]
    assert parse_mbap_reply(buf, 7, 9) == (None, 0)  # incomplete
    buf += reply[5:]
    assert parse_mbap_reply(buf, 7, 9) == (b"\x03\x0c" + bytes(12), 21)


# -- DYNAMIXEL --------------------------------------------------------------------------------------


class PtyRelay:
    """A serial line between the host and the chain: host bytes go to the chain at once, the
    chain's bytes wait in ``held`` until :meth:`release`."""

    def __init__(self, chain: DynamixelChain) -> None:
        self.master, self.slave, self.port = open_raw_pty()
        self.dev = os.open(chain.port, os.O_RDWR | os.O_NOCTTY)
        attrs = termios.tcgetattr(self.dev)  # the line speed the chain expects from its host
        attrs[4] = attrs[5] = termios.B1000000
        termios.tcsetattr(self.dev, termios.TCSANOW, attrs)
        os.set_blocking(self.dev, False)
        self.held = bytearray()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._th = threading.Thread(target=self._run, daemon=True)
        self._th.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            r, _, _ = select.select([self.master, self.dev], [], [], 0.01)
            for fd in r:
                try:
                    data = os.read(fd, 4096)
                except OSError:
                    continue
                if fd == self.master:
                    os.write(self.dev, data)
                else:
                    with self._lock:
                        self.held += data

    def release(self, n: int | None = None) -> int:
        with self._lock:
            n = len(self.held) if n is None else n
            data, self.held[:] = bytes(self.held[:n]), self.held[n:]
        os.write(self.master, data)
        return len(data)

    def close(self) -> None:
        self._stop.set()
        self._th.join(2.0)
        close_fds(self.master, self.slave, self.dev)


@pytest.fixture
def dxl():
    joints = FreeJoints(2)
    chain = DynamixelChain(joints, [1, 2], baudrate=BAUD, return_delay=0)
    relay = PtyRelay(chain)
    with _released(relay):  # the open sequence's request/answer traffic: released as it comes
        dev = DynamixelX(relay.port, [1, 2], baudrate=BAUD, timeout=TIMEOUT, scan_baudrates=False)
    relay.release()
    yield dev, chain, relay, joints
    dev.close()
    relay.close()
    chain.close()


REPLY = 2 * (11 + 10)  # two status packets of the 10-byte present block


def _prime(dev, relay) -> None:
    """The first non-blocking read reads once, waiting for its answer (released as it comes)."""
    with _released(relay):
        s = dev.read(timeout=0.0)
    assert s.seq == 1


def test_dynamixel_sync_read_follows_the_sync_write_and_is_collected_by_the_next_read(dxl):
    dev, chain, relay, joints = dxl
    _prime(dev, relay)
    n0 = chain.packets
    dev.command_effort(np.array([0.1, -0.1]))
    _wait(lambda: chain.packets == n0 + 2 and len(relay.held) == REPLY)
    # half duplex: the sync write (no reply) first, then the sync read on the quiet line
    assert [f[7] for f in list(chain.rx_frames)[-2:]] == [0x83, 0x82]
    joints.step(0.01)  # the plant moves after the servos answered: the answer is what they sampled
    s_stale = dev.read(timeout=0.0)  # nothing released yet: previous sample, never a wait
    assert s_stale.seq == 1 and dev.counters()["stale"] == 1
    relay.release(REPLY // 2 + 3)  # one packet and a piece of the next
    assert dev.read(timeout=0.0).seq == 1 and dev.counters()["stale"] == 2
    relay.release()
    _wait(lambda: dev._port.ser.in_waiting >= REPLY // 2 - 3)
    s = dev.read(timeout=0.0)
    assert s.seq == 2 and dev.counters()["stale"] == 2
    # the chain encodes the plant position it saw when the request came (before joints.step)
    assert np.all(s.position == 0.0) and np.all(joints.position() != 0.0)
    # the next request goes after the next command; the next read, with no command in between,
    # sends it itself (and one outstanding request is never doubled)
    n1 = chain.packets
    dev.read(timeout=0.0)
    dev.read(timeout=0.0)
    _wait(lambda: chain.packets == n1 + 1 and len(relay.held) >= REPLY)
    assert list(chain.rx_frames)[-1][7] == 0x82
    relay.release()
    _wait(lambda: dev._port.ser.in_waiting >= REPLY)
    s = dev.read(timeout=0.0)
    assert s.seq == 3
    np.testing.assert_allclose(s.position, np.round(joints.position() / RAD_PER_TICK) * RAD_PER_TICK)


def test_dynamixel_corrupt_status_is_dropped_counted_and_asked_again(dxl):
    dev, chain, relay, _joints = dxl
    _prime(dev, relay)
    chain.injector = FaultInjector(FaultPlan(corrupt_ticks={chain.tick + 2}))  # the coming sync read's
    dev.command_effort(np.zeros(2))
    _wait(lambda: len(relay.held) >= REPLY)
    relay.release()
    _wait(lambda: dev._port.ser.in_waiting >= REPLY)
    s = dev.read(timeout=0.0)
    assert s.seq == 1 and dev.counters()["crc_errors"] >= 1 and dev.counters()["stale"] == 1
    n = chain.packets
    dev.command_effort(np.zeros(2))  # the request is asked again after the command
    _wait(lambda: chain.packets == n + 2 and len(relay.held) >= REPLY)
    relay.release()
    _wait(lambda: dev._port.ser.in_waiting >= REPLY)
    assert dev.read(timeout=0.0).seq == 2


def test_dynamixel_reply_that_never_comes_ages_the_sample_then_is_asked_again(dxl):
    dev, chain, relay, _joints = dxl
    clock = {"t": 0.0}
    dev._clock = lambda: clock["t"]
    _prime(dev, relay)
    dev.command_effort(np.zeros(2))
    _wait(lambda: len(relay.held) >= REPLY)
    relay.held.clear()  # lost on the line
    ages = []
    for k in range(1, 4):
        clock["t"] = 0.01 * k
        s = dev.read(timeout=0.0)
        ages.append(sample_age(s))
    assert ages == pytest.approx([0.01, 0.02, 0.03]) and s.seq == 1  # the watchdog's evidence
    n = chain.packets
    dev._ahead_at -= dev.timeout  # as if the adapter's timeout had passed on the host clock
    dev.read(timeout=0.0)
    assert dev.counters()["timeouts"] == 1
    dev.command_effort(np.zeros(2))
    _wait(lambda: chain.packets == n + 2)  # asked again, after the command


def test_dynamixel_close_with_a_request_outstanding_still_stops_and_is_idempotent(dxl):
    dev, chain, relay, _joints = dxl
    _prime(dev, relay)
    dev.command_effort(np.array([0.3, 0.3]))
    _wait(lambda: len(relay.held) >= REPLY)
    servo = chain.servos[1]
    assert servo.get(ADDR_GOAL_CURRENT, 2, signed=True) != 0

    with _released(relay):  # the line carries the stop's request/answer traffic
        dev.close()
        dev.close()
    for sv in chain.servos.values():
        assert sv.get(ADDR_GOAL_CURRENT, 2, signed=True) == 0 and sv.table[ADDR_TORQUE_ENABLE] == 0
    assert dev.closed


def test_dynamixel_blocking_read_after_non_blocking_ones_answers_its_own_request(dxl):
    dev, _chain, relay, joints = dxl
    _prime(dev, relay)
    dev.command_effort(np.zeros(2))
    _wait(lambda: len(relay.held) >= REPLY)
    joints.step(0.02)
    with _released(relay):
        s = dev.read(timeout=TIMEOUT)
    assert s.seq == 2  # the outstanding sync read is settled and dropped, not taken as this answer
    np.testing.assert_allclose(s.position, np.round(joints.position() / RAD_PER_TICK) * RAD_PER_TICK)


# -- FT-300 over Modbus -------------------------------------------------------------------------------


class TcpRelay:
    """A TCP proxy in front of the simulated FT-300: requests pass at once, replies wait in
    ``held`` until :meth:`release`."""

    def __init__(self, port: int) -> None:
        self.lsock = socket.socket()
        self.lsock.bind(("127.0.0.1", 0))
        self.lsock.listen(1)
        self.port = self.lsock.getsockname()[1]
        self.target = port
        self.held = bytearray()
        self.conn: socket.socket | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._th = threading.Thread(target=self._run, daemon=True)
        self._th.start()

    def _run(self) -> None:
        conn, _ = self.lsock.accept()
        up = socket.create_connection(("127.0.0.1", self.target))
        self.conn = conn
        try:
            while not self._stop.is_set():
                r, _, _ = select.select([conn, up], [], [], 0.01)
                for s in r:
                    data = s.recv(4096)
                    if not data:
                        return
                    if s is conn:
                        up.sendall(data)
                    else:
                        with self._lock:
                            self.held += data
        finally:
            up.close()

    def release(self, n: int | None = None) -> int:
        with self._lock:
            n = len(self.held) if n is None else n
            data, self.held[:] = bytes(self.held[:n]), self.held[n:]
        if data and self.conn is not None:
            self.conn.sendall(data)
        return len(data)

    def close(self) -> None:
        self._stop.set()
        self._th.join(2.0)
        if self.conn is not None:
            self.conn.close()
        self.lsock.close()


@pytest.fixture(params=["tcp", "rtu"])
def ft300(request):
    from hil.mocks.modbus_devices import SimulatedFT300
    from hil.protocols.modbus_robotiq import RobotiqFT300

    wrench = np.array([1.0, -2.0, 3.5, 0.1, -0.2, 0.3])
    sim = SimulatedFT300(lambda: wrench, framing=request.param)
    relay = TcpRelay(sim.port)
    scheme = "rtu-over-tcp" if request.param == "rtu" else "tcp"
    with _released(relay):
        # a constant source stands for one sampled value here: frozen readings are tested elsewhere
        # (tests/run/test_fault_matrix.py), these tests are about the transaction
        dev = RobotiqFT300(f"{scheme}://127.0.0.1:{relay.port}", timeout=TIMEOUT, frozen_is_stale=False)
        s = dev.read(timeout=0.0)  # primes with one blocking read (Modbus/TCP: and sends the next request)
        dev._settle(0.5)  # that request answered and dropped: the tests start with nothing outstanding
    relay.release()
    assert s.seq == 1
    assert not dev._ahead
    yield dev, sim, relay, wrench, request.param
    dev.close()
    relay.close()
    sim.close()


def _received(dev) -> int:
    """Bytes waiting in the adapter's socket (peeked, not taken)."""
    try:
        return len(dev._client.socket.recv(4096, socket.MSG_PEEK | socket.MSG_DONTWAIT))
    except BlockingIOError:
        return 0


def _reply_len(framing: str) -> int:
    return 5 + 12 if framing == "rtu" else 7 + 2 + 12


def _send_request(dev, sim, framing):
    """The next non-blocking read that may send (after t3.5 on RTU framing) sends the request."""
    if dev._ahead:  # Modbus/TCP: the read that collected a reply sent the next request itself
        return
    n = sim.requests
    if framing == "rtu":  # t3.5 since the reply was seen: the silence of the serial line
        dev._quiet_since -= dev.silence_s
    dev.read(timeout=0.0)
    _wait(lambda: sim.requests == n + 1)


def test_ft300_reply_split_over_reads_is_stale_until_complete(ft300):
    dev, sim, relay, wrench, framing = ft300
    base = dev._last.seq
    _send_request(dev, sim, framing)
    _wait(lambda: len(relay.held) == _reply_len(framing))
    wrench[0] = 9.0  # the device sampled before this
    relay.release(5)
    _wait(lambda: _received(dev) >= 5)
    assert dev.read(timeout=0.0).seq == base
    n = relay.release()
    _wait(lambda: _received(dev) >= n)
    s = dev.read(timeout=0.0)
    assert s.seq == base + 1 and sample_age(s) == 0.0
    np.testing.assert_allclose(s.wrench, [1.0, -2.0, 3.5, 0.1, -0.2, 0.3])
    # RTU: the reply's last byte may have arrived just now, so the next request waits for t3.5 of
    # silence (a later read sends it); Modbus/TCP has no such gap: sent by this read
    assert dev._ahead == (framing == "tcp")
    stale = dev.counters()["stale"]
    assert stale >= 1 and dev.counters()["timeouts"] == 0


def test_ft300_corrupt_reply_is_dropped_and_counted(ft300):
    dev, sim, relay, _wrench, framing = ft300
    base = dev._last.seq
    sim.injector = FaultInjector(FaultPlan(corrupt_ticks={sim._tick + 1}))
    _send_request(dev, sim, framing)
    _wait(lambda: len(relay.held) >= 5)
    n = relay.release()
    _wait(lambda: _received(dev) >= n)
    s = dev.read(timeout=0.0)
    c = dev.counters()
    assert s.seq == base and c["stale"] >= 1
    # RTU: the CRC catches the flipped byte; Modbus/TCP: the gateway's serial-side CRC did, and it
    # answered exception 11 (the simulated FT-300's default "gateway" corruption)
    assert c["crc_errors" if framing == "rtu" else "gateway_errors"] == 1
    _send_request(dev, sim, framing)  # asked again: the next reply is fresh
    _wait(lambda: len(relay.held) == _reply_len(framing))
    n = relay.release()
    _wait(lambda: _received(dev) >= n)
    assert dev.read(timeout=0.0).seq == base + 1


def test_ft300_reply_that_never_comes_times_out_and_is_asked_again(ft300):
    dev, sim, relay, _wrench, framing = ft300
    base = dev._last.seq
    _send_request(dev, sim, framing)
    _wait(lambda: len(relay.held) == _reply_len(framing))
    relay.held.clear()  # lost
    assert dev.read(timeout=0.0).seq == base
    dev._ahead_at -= dev.timeout  # the adapter's timeout passed (host clock)
    dev.read(timeout=0.0)
    assert dev.counters()["timeouts"] == 1
    assert dev._ahead == (framing == "tcp")  # asked again at once; on RTU after t3.5 of silence
    _send_request(dev, sim, framing)
    _wait(lambda: len(relay.held) == _reply_len(framing))
    n = relay.release()
    _wait(lambda: _received(dev) >= n)
    assert dev.read(timeout=0.0).seq == base + 1


def test_ft300_exception_reply_is_a_fault(ft300):
    dev, sim, relay, _wrench, framing = ft300
    sim.injector = FaultInjector(FaultPlan(error_code=4, error_at_tick=sim._tick + 1, error_until_tick=sim._tick + 2))
    _send_request(dev, sim, framing)
    _wait(lambda: len(relay.held) >= 5)
    n = relay.release()
    _wait(lambda: _received(dev) >= n)
    with pytest.raises(DeviceFault) as err:
        dev.read(timeout=0.0)
    assert err.value.code == 4


# -- CiA 402 ----------------------------------------------------------------------------------------


@pytest.fixture
def drive():
    pytest.importorskip("canopen")
    import can

    from hil.mocks.cia402_drive import SimCiA402
    from hil.protocols.cia402 import CiA402Drive

    ch = f"test-rt-cia402-{next(_chan)}"
    joints = FreeJoints(1, 0.01)
    clock = {"t": 0.0}
    sim = SimCiA402(joints, ch, 7, dt=0.001, counts_per_rev=4096, rated_torque_mNm=500, heartbeat_ms=0)
    stop = threading.Event()

    def answer() -> None:  # the drive answering on its own during the open sequence
        while not stop.is_set():
            sim.process_pending()
            stop.wait(0.0005)
    th = threading.Thread(target=answer, daemon=True)
    th.start()
    try:
        dev = CiA402Drive(7, ch, "virtual", clock=lambda: clock["t"], timeout=TIMEOUT, heartbeat_ms=0)
        s = dev.read(timeout=0.0)  # primes: one blocking read, then the SYNC for the next one
    finally:
        stop.set()
        th.join()
    assert s.seq == 1
    spy = can.Bus(interface="virtual", channel=ch)
    yield dev, sim, joints, clock, spy
    spy.shutdown()
    stop2 = threading.Event()
    th2 = threading.Thread(target=lambda: [sim.process_pending() or stop2.wait(0.0005)
                                           for _ in iter(lambda: stop2.is_set(), True)], daemon=True)
    th2.start()
    try:
        dev.close()
    finally:
        stop2.set()
        th2.join()
    sim.close()


def _pairs(dev) -> int:
    with dev._cond:
        return dev._pairs


def test_cia402_takes_the_pair_answering_the_previous_sync(drive):
    dev, sim, joints, clock, _spy = drive
    p0 = _pairs(dev)
    assert sim.process_pending() >= 1  # the SYNC sent ahead (maybe with the prime's own)
    _wait(lambda: _pairs(dev) > p0)
    joints._x[:] = 1.0  # moves after the drive sampled at that SYNC
    clock["t"] = 0.002
    s = dev.read(timeout=0.0)
    assert s.seq == 2 and s.produced_at == 0.0 and s.position[0] == 0.0
    clock["t"] = 0.003
    s2 = dev.read(timeout=0.0)  # the drive has not processed the SYNC of the read before: stale
    assert (s2.seq, s2.produced_at, s2.t) == (2, 0.0, 0.003) and dev.counters()["stale"] == 1
    p1 = _pairs(dev)
    sim.process_pending()
    _wait(lambda: _pairs(dev) > p1)
    s3 = dev.read(timeout=0.0)
    assert s3.seq == 3 and s3.position[0] == pytest.approx(2 * np.pi * round(4096 / (2 * np.pi)) / 4096, abs=2e-3)


def test_cia402_half_a_pair_is_not_a_sample(drive):
    import can

    dev, sim, _joints, _clock, spy = drive
    sim.process_pending()
    _wait(lambda: dev._t1 is None and _pairs(dev) >= 2)
    dev.read(timeout=0.0)  # takes that pair
    p = _pairs(dev)
    # a TPDO1 alone on the bus (its TPDO2 lost): statusword, position, torque of another SYNC
    spy.send(can.Message(arbitration_id=0x187, data=bytes([0x37, 0x06]) + (123).to_bytes(4, "little") + bytes(2),
                         is_extended_id=False))
    _wait(lambda: dev._t1 is not None)
    s = dev.read(timeout=0.0)
    assert _pairs(dev) == p and dev.counters()["stale"] >= 1 and s.position[0] == 0.0


def test_dynamixel_two_adapters_on_one_port_keep_blocking_reads(caplog):
    """Two adapters on one bus (the lockstep leader/follower scene opens it so) would take each
    other's status packets: their non-blocking reads stay request/answer (fresh every time)."""
    joints = FreeJoints(2)
    with DynamixelChain(joints, [1, 2], baudrate=BAUD, return_delay=0) as chain, \
            DynamixelX(chain.port, [1], baudrate=BAUD, timeout=0.5) as a, \
            DynamixelX(chain.port, [2], baudrate=BAUD, timeout=0.5) as b:
        joints._x[:] = [0.5, -0.25]
        for k in range(3):
            sa, sb = a.read(timeout=0.0), b.read(timeout=0.0)
            assert (sa.seq, sb.seq) == (k + 1, k + 1)
        np.testing.assert_allclose([sa.position[0], sb.position[0]], [0.5, -0.25], atol=RAD_PER_TICK)
        assert "stale" not in a.counters() and "another adapter" in caplog.text
    with DynamixelChain(joints, [1, 2], baudrate=BAUD, return_delay=0) as chain, \
            DynamixelX(chain.port, [1, 2], baudrate=BAUD, timeout=0.5) as one:
        one.read(timeout=0.0)
        assert one._due  # alone on its port again (the closed adapters were counted out): reads ahead
