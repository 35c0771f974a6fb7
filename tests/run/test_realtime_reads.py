"""Non-blocking device reads of the realtime loop and its allocation-free tick (issue 17).

What is asserted is what a read returns and what the loop records or keeps alive, never how fast:
the adapters are driven against simulated devices that answer only when the test tells them to
(``process_pending``), and the loop runs on the fake clock of ``tests/run/test_realtime.py``.
"""

from __future__ import annotations

import itertools
import threading
import tracemalloc

import numpy as np
import pytest
import yaml  # type: ignore[import-untyped]  # no PyYAML stubs in the env
from test_realtime import FakeClock

from hil.bench.runtime import Bench
from hil.mocks.can_devices import SimCubeMars, SimODrive
from hil.mocks.interfaces import FreeJoints
from hil.protocols.base import sample_age
from hil.protocols.can_cubemars import CubeMarsMIT
from hil.protocols.can_odrive import ODriveCAN
from hil.record.hdf5 import RunRecord
from hil.run.runner import REALTIME_READ_TIMEOUT_S, Runner
from hil.scene.spec import load_scene, scene_from_dict

pytestmark = pytest.mark.timeout(120)
_chan = itertools.count()


def _scene(duration: float = 0.05, rate: float = 2000.0):
    d = yaml.safe_load(load_scene("sdea_bench").source_text)
    d["rate_hz"] = rate
    d["experiments"] = d["experiments"][:1]
    d["experiments"][0].update(duration=duration, f1=min(200.0, rate / 10))
    d.pop("certification", None)
    d["safety"].update(max_lateness_ms=10_000.0, max_overrun_fraction=1.0)
    return scene_from_dict(d, label="realtime-reads-test")


# -- adapters -------------------------------------------------------------------------------------


def test_odrive_poll_with_zero_timeout_takes_the_previous_answer_and_never_waits():
    """read(timeout=0) in poll mode: the answer to the request of the previous read if it arrived
    (fresh: seq advances), else the previous sample again (stale: same seq and produced_at, counted);
    each read sends the next request. After the first one (which polls once, nothing being requested
    ahead) the drive answers only in process_pending(), so a read that waited for its answer could
    not return it."""
    ch = f"test-rt-odrive-{next(_chan)}"
    j = FreeJoints(mass=2.0)
    clock = {"t": 0.0}
    with SimODrive(j, ch, node_id=5, heartbeat_every=0) as node, \
            ODriveCAN(5, ch, "virtual", enable=False, clock=lambda: clock["t"], timeout=2.0) as dev:
        stop = threading.Event()

        def answer() -> None:  # the drive answering on its own, for the priming poll only
            while not stop.is_set():
                node.process_pending()
                stop.wait(0.001)
        th = threading.Thread(target=answer)
        th.start()
        try:
            s0 = dev.read(timeout=0.0)  # primes: one blocking poll, then the request for the next read
        finally:
            stop.set()
            th.join()
        assert s0.seq == 1
        pending = node.process_pending()  # the request sent ahead (the answer thread may have taken it)
        assert pending in (0, 1)
        j.step(0.01)
        clock["t"] = 1.0
        s1 = dev.read(timeout=0.0)  # that answer, taken off the bus now; the next request sent
        assert s1.seq == 2 and s1.produced_at == 1.0
        clock["t"] = 2.0
        s2 = dev.read(timeout=0.0)  # that request is not answered yet: stale
        assert (s2.seq, s2.produced_at, s2.t) == (2, 1.0, 2.0)
        assert sample_age(s2) == 1.0 and dev.counters()["stale"] == 1
        np.testing.assert_array_equal(s2.position, s1.position)
        assert node.process_pending() == 2  # the requests of s1's and s2's reads
        clock["t"] = 3.0
        s3 = dev.read(timeout=0.0)
        assert s3.seq == 3 and s3.produced_at == 3.0 and dev.counters()["stale"] == 1


def test_cubemars_zero_timeout_read_without_a_new_reply_is_stale_and_sends_nothing():
    """A CubeMars motor answers each command; a non-blocking read (timeout 0) with no reply since the
    previous read repeats the previous sample (same seq and produced_at, counted as stale) instead of
    re-sending the last command and waiting for its reply (what a blocking read does)."""
    ch = f"test-rt-cubemars-{next(_chan)}"
    j = FreeJoints()
    with SimCubeMars(j, ch, motor_id=1, sync=True) as node, CubeMarsMIT(1, ch, "virtual") as dev:
        dev.command_effort(np.array([1.0]))
        s1 = dev.read(timeout=0.0)  # the reply to that command
        sent = len(node.commands)
        s2 = dev.read(timeout=0.0)
        assert len(node.commands) == sent  # nothing re-sent
        assert (s2.seq, s2.produced_at) == (s1.seq, s1.produced_at) and dev.counters()["stale"] == 1
        dev.command_effort(np.array([1.0]))
        assert dev.read(timeout=0.0).seq == s1.seq + 1
        dev.read(timeout=0.2)  # a blocking read re-sends the last command and gets a fresh reply
        assert len(node.commands) == sent + 2 and "stale" in dev.counters()


# -- the loop -------------------------------------------------------------------------------------


class _ExternalBench(Bench):
    """The in-process simulated bench posing as one with external devices (``lockstep`` False),
    recording the timeout of every read the loop makes and the age of every sample it returns."""

    timeouts: list[float | None]
    ages: list[float]

    @property
    def lockstep(self) -> bool:
        return False

    def read(self, timeout: float | None = None):
        self.timeouts.append(timeout)
        out = super().read()  # the simulation itself is still stepped in lockstep
        self.ages.append(sample_age(out["spring_ft"]))
        return out


def _external(scene, made: list):
    def make(variant):
        b = _ExternalBench(scene, seed=scene.seed, variant=variant)
        b.timeouts, b.ages = [], []
        made.append(b)
        return b
    return make


def test_realtime_reads_external_devices_without_waiting_and_records_sample_ages(tmp_path):
    sc = _scene(duration=0.01)
    fc = FakeClock()
    made: list = []
    r = Runner(sc, tmp_path, realtime=True, bench_factory=_external(sc, made), clock_ns=fc.clock,
               sleep=fc.sleep, rt_scheduling=False, gc_pause=False)
    out = r.run()[0]
    assert out.status == "completed", out.stop_reason
    b = made[0]
    n = out.stats["ticks"]
    assert n >= 10 and REALTIME_READ_TIMEOUT_S == 0.0
    # the first reading (channel sizes) waits at most watchdog_ms (issue 27: every realtime wait is
    # bounded by the watchdog; the bench's own timeout here is the lockstep one, 20x); every tick reads with 0
    assert b.timeouts == [sc.safety.watchdog_ms / 1000.0] + [0.0] * n
    rec = RunRecord.open(out.record)
    assert {"motor.age", "spring_ft.age"} <= set(rec.channels)
    np.testing.assert_array_equal(rec.channels["spring_ft.age"][:, 0], np.asarray(b.ages[1:]))


def test_lockstep_reads_and_channels_are_unchanged(tmp_path):
    """Lockstep keeps the bench's own (waiting) reads and records no age channels."""
    sc = _scene(duration=0.005)
    made: list = []

    class _Lockstep(_ExternalBench):
        lockstep = Bench.lockstep

    def make(variant):
        b = _Lockstep(sc, seed=sc.seed, variant=variant)
        b.timeouts, b.ages = [], []
        made.append(b)
        return b
    out = Runner(sc, tmp_path, realtime=False, bench_factory=make).run()[0]
    assert out.status == "completed"
    assert set(made[0].timeouts) == {None}
    assert not any(k.endswith(".age") for k in RunRecord.open(out.record).channels)


@pytest.mark.slow
def test_steady_state_realtime_tick_keeps_no_memory(tmp_path):
    """tracemalloc: live blocks allocated by the loop's own code (hil/run/runner.py) between tick 200
    and tick 800 of a realtime run on the fake clock. The record's chunk is preallocated and the
    tick row is built once, so a steady-state tick leaves nothing behind: the bound, 0.01 block
    per tick (6 blocks over 600 ticks), allows a few lazily created objects (a dict resize, an
    interned float) but fails for any per-tick object that survives its tick (one block per tick
    would be 600). Transient objects freed within the tick are not live and not counted."""
    sc = _scene(duration=0.5)
    fc = FakeClock()
    snaps: dict[int, tracemalloc.Snapshot] = {}

    def progress(name: str, k: int, n: int) -> None:  # called every 200 ticks, inside the loop
        if k in (200, 800):
            snaps[k] = tracemalloc.take_snapshot()

    r = Runner(sc, tmp_path, realtime=True, bench_factory=_external(sc, []), clock_ns=fc.clock,
               sleep=fc.sleep, rt_scheduling=False, gc_pause=False, progress=progress)
    tracemalloc.start(1)
    try:
        out = r.run()[0]
    finally:
        tracemalloc.stop()
    assert out.status == "completed", out.stop_reason
    flt = [tracemalloc.Filter(True, "*hil/run/runner.py")]
    diff = snaps[800].filter_traces(flt).compare_to(snaps[200].filter_traces(flt), "lineno")
    grown = sum(max(0, st.count_diff) for st in diff)
    assert grown / 600 <= 0.01, [str(st) for st in diff[:5]]


# -- polled adapters: DYNAMIXEL X, FT-300 (Modbus), CiA 402 ------------------------------------------


def _short(name: str, duration: float = 0.3):
    d = yaml.safe_load(load_scene(name).source_text)
    d["experiments"] = d["experiments"][:1]
    e = d["experiments"][0]
    e["duration"] = duration
    if e["type"].startswith("chirp"):
        e.update(fade=0.0, f0=max(float(e.get("f0", 1.0)), 4.0))
    d.pop("certification", None)
    return scene_from_dict(d, label=f"{name}-short")


@pytest.mark.parametrize("name", ["dual_master_3dof", "cia402_bench"])
def test_lockstep_never_takes_the_non_blocking_path(name, tmp_path, monkeypatch):
    """Lockstep runs read with the bench's own timeout, so the polled adapters' request/collect
    split is never entered there: their records are those of the request/answer reads (the branch
    compared them bit for bit against the adapters before the split; see the report)."""
    from hil.protocols.cia402 import CiA402Drive
    from hil.protocols.dynamixel_x import DynamixelX
    from hil.protocols.modbus_robotiq import RobotiqFT300

    def refuse(self):
        raise AssertionError(f"{type(self).__name__}: non-blocking read in a lockstep run")
    for cls in (DynamixelX, RobotiqFT300, CiA402Drive):
        monkeypatch.setattr(cls, "_read_ahead", refuse)
    out = Runner(_short(name), tmp_path).run()[0]
    assert out.status == "completed", out.stop_reason
    counters = out.results["device_counters"]
    polled = [n for n in counters if n in ("master2", "slave", "master2_ft", "motor")]
    assert polled and all("stale" not in counters[n] for n in polled)  # the read-ahead counters never appear


@pytest.mark.parametrize("name", ["dual_master_3dof", "cia402_bench"])
def test_polled_adapters_read_without_waiting_from_devices_served_by_another_process(name):
    """Devices served by ``hil mock serve`` in a child process (the realtime runner's bench):
    every non-blocking read returns (fresh or the previous sample), and each polled device's
    samples advance once its answers to the requests sent ahead arrive."""
    from hil.bench.runtime import ProcessSimBench

    sc = _short(name)
    polled = [d.name for d in sc.devices if d.driver in ("dynamixel_x", "robotiq_ft300", "cia402")]
    with ProcessSimBench(sc, timeout=2.0) as b:
        first = b.read()  # the runner's first reading: the bench's own timeout
        zeros = {a: np.zeros(sc.device(a).dof) for a in b.actuators}
        fresh: set[str] = set()
        for _ in range(2000):  # a bounded number of ticks, each short of any wait
            meas = b.read(REALTIME_READ_TIMEOUT_S)
            b.command(zeros)
            fresh |= {n for n in polled if meas[n].seq > first[n].seq}
            assert all(sample_age(meas[n]) >= 0.0 for n in polled)
            if fresh == set(polled):
                break
            threading.Event().wait(0.002)  # the loop's wait for its next tick
        assert fresh == set(polled)
        counters = b.device_counters()
    assert all("stale" in counters[n] for n in polled)  # they ran the non-blocking path
