"""Realtime at the bench (issue 17): the loop's clock, a late loop is a safe stop, lateness in the
record and in ``hil replay``, sample timing checked before identification, ``hil check-realtime``.

No test here depends on the machine's timing: the loop's clock and sleep are a fake (:class:`FakeClock`)
whose time only moves when the code under test reads it or sleeps, and a tick is made late by
charging its work to that clock. The simulated bench is the in-process lockstep one (same data on
every run); only the realtime *pacing* is exercised.
"""

from __future__ import annotations

import gc
import json
import logging
import math

import numpy as np
import pytest
import yaml  # type: ignore[import-untyped]  # no PyYAML stubs in the env

from hil.bench.runtime import Bench
from hil.certify.lateness import lateness_measurements
from hil.cli.main import main as hil_main
from hil.errors import SafetyStop
from hil.identify.diagnostics import check_sample_times
from hil.record.hdf5 import RunRecord, lateness_distribution
from hil.run.realtime import (
    LatenessGuard,
    Pacer,
    WakeupStats,
    gc_paused,
    holdable_rates,
    measure_wakeup,
    realtime_scheduling,
    run_cyclictest,
)
from hil.run.runner import Runner
from hil.scene.spec import load_scene, scene_from_dict

pytestmark = pytest.mark.timeout(120)


class FakeClock:
    """Nanosecond clock that advances ``step_ns`` per read and exactly what is slept, plus
    ``oversleep(i)`` ns on the i-th sleep (a machine's wake-up latency, chosen by the test)."""

    def __init__(self, step_ns: int = 1_000, oversleep=None) -> None:
        self.now = 5_000_000_000
        self.step_ns = step_ns
        self.sleeps = 0
        self.oversleep = oversleep or (lambda i: 0)

    def clock(self) -> int:
        self.now += self.step_ns
        return self.now

    def sleep(self, s: float) -> None:
        self.now += round(s * 1e9) + int(self.oversleep(self.sleeps))
        self.sleeps += 1

    def work(self, s: float) -> None:
        """Charge ``s`` seconds of work to the clock (a slow tick)."""
        self.now += round(s * 1e9)


# -- the pacer ------------------------------------------------------------------------------------
def test_pacer_deadlines_are_absolute_and_lateness_is_start_minus_deadline():
    fc = FakeClock(step_ns=1_000)
    p = Pacer(1000.0, clock_ns=fc.clock, sleep=fc.sleep)
    t0 = p.start()
    assert p.wait(0) <= 1_000  # deadline of tick 0 is t0: one clock read later
    fc.work(0.0035)  # tick 0's work overruns into tick 3's period
    late = p.wait(1)
    # tick 1's deadline is t0 + 1 ms, not "now + 1 ms": lateness = (t0 + 3.5 ms + 2 reads) - (t0 + 1 ms)
    assert late == pytest.approx(2_500_000, abs=3_000)
    assert p.start_ns - t0 == pytest.approx(3_500_000, abs=3_000)
    # no drift: after a late tick the next deadlines are still t0 + k ms (tick 4 starts on time)
    late4 = p.wait(4)
    assert 0 <= late4 <= 1_000 and p.start_ns >= t0 + 4_000_000


def test_pacer_sleeps_until_spin_window_then_spins():
    """The hybrid wait asks the OS for (remaining - spin) and spins the rest: a 150 µs oversleep
    inside the 200 µs spin window costs nothing."""
    fc = FakeClock(step_ns=500, oversleep=lambda i: 150_000)
    p = Pacer(500.0, clock_ns=fc.clock, sleep=fc.sleep, spin_ns=200_000)
    p.start()
    for k in range(1, 50):
        assert p.wait(k) <= 500  # one clock step at most
    assert fc.sleeps == 49
    # an oversleep longer than the spin window is lateness: 350 µs - 200 µs = 150 µs
    fc.oversleep = lambda i: 350_000
    late = p.wait(50)
    assert late == pytest.approx(150_000, abs=1_000)


# -- the lateness guard ----------------------------------------------------------------------------
def test_guard_stops_a_tick_later_than_max_lateness_naming_it():
    g = LatenessGuard(2000.0, max_lateness_s=0.005)
    g.check(0, 0.005)  # at the limit: fine
    with pytest.raises(SafetyStop, match=r"late loop: tick 7 started 5\.001 ms after its deadline \(limit "
                                         r"max_lateness_ms = 5 ms\)"):
        g.check(7, 0.005001)
    with pytest.raises(SafetyStop, match="late loop"):
        g.check(8, math.nan)  # a NaN lateness never passes


def test_guard_overrun_fraction_over_a_sliding_window():
    """window 100, fraction 0.03: 3 overruns in any 100 ticks are allowed, the 4th stops; overruns
    that left the window no longer count (counted here independently by a brute-force window)."""
    g = LatenessGuard(1000.0, max_lateness_s=1.0, max_overrun_fraction=0.03, window=100)
    assert g.allowed == 3
    late = np.zeros(400)
    late[[5, 50, 99]] = 0.002  # 3 in the first window
    late[[150, 200, 240]] = 0.002  # tick 150 sees only 50 and 99 in ticks 51..150 ... fine
    late[[260]] = 0.002  # ticks 161..260 hold 200, 240, 260: 3 -> fine
    late[[270]] = 0.002  # ticks 171..270 hold 200, 240, 260, 270: 4 -> stop
    stopped = None
    for k, x in enumerate(late):
        try:
            g.check(k, float(x))
        except SafetyStop as exc:
            stopped = (k, str(exc))
            break
    over = np.flatnonzero(late > 1e-3)
    brute = next(k for k in over if np.count_nonzero((over > k - 100) & (over <= k)) > 3)
    assert stopped is not None and stopped[0] == brute == 270
    assert "4 overruns" in stopped[1] and "max_overrun_fraction = 0.03" in stopped[1]


# -- the runner: a late tick is a safe stop, lateness is in the record ----------------------------
def _scene(safety: dict | None = None, rate: float | None = None):
    d = yaml.safe_load(load_scene("sdea_bench").source_text)
    d["experiments"] = d["experiments"][:1]
    d["experiments"][0]["duration"] = 0.5
    d.pop("certification", None)
    d["safety"].update(safety or {})
    if rate:
        d["rate_hz"] = rate
    return scene_from_dict(d, label="realtime-test")


def _slow_tick_factory(scene, fc: FakeClock, slow: dict[int, float]):
    """In-process lockstep bench whose reads charge ``slow[tick]`` seconds of work to the fake clock
    (adapter read 0 is the runner's first reading; loop tick k is read k + 1)."""
    def make(variant):
        b = Bench(scene, seed=scene.seed, variant=variant)
        orig, n = b.read, {"reads": 0}

        def read(*a, **kw):
            out = orig(*a, **kw)
            k = n["reads"] - 1
            n["reads"] += 1
            fc.work(slow.get(k, 0.0))
            return out
        b.read = read
        return b
    return make


def _realtime_runner(scene, out, fc, slow=None, **kw):
    return Runner(scene, out, realtime=True, bench_factory=_slow_tick_factory(scene, fc, slow or {}),
                  clock_ns=fc.clock, sleep=fc.sleep, rt_scheduling=False, **kw)


def test_a_late_tick_beyond_max_lateness_is_a_safe_stop_with_its_reason_recorded(tmp_path):
    sc = _scene({"max_lateness_ms": 5})
    fc = FakeClock()
    o = _realtime_runner(sc, tmp_path, fc, slow={40: 0.0123}).run()[0]
    assert o.status == "safety_stop"
    assert o.stop_reason.startswith("late loop: tick 41 started 11.8"), o.stop_reason  # 12.3 ms - one 0.5 ms period
    rec = RunRecord.open(o.record)
    assert rec.status == "safety_stop" and rec.stop_reason == o.stop_reason
    kinds = [e["kind"] for e in rec.events]
    assert kinds[0] == "realtime" and "safety_stop" in kinds and "safe_stop" in kinds
    stop = next(e for e in rec.events if e["kind"] == "safety_stop")
    assert stop["t"] == pytest.approx(41 / sc.rate_hz)
    # the late tick is the last sample: its timing recorded, its device channels NaN (never read)
    assert rec.t.size == 42
    late, start = rec.channels["loop.late"][:, 0], rec.channels["loop.tick_start"][:, 0]
    assert late[-1] == pytest.approx(0.0123 - 0.0005, abs=5e-6)
    assert start[-1] == pytest.approx(41 * 0.0005 + late[-1], abs=1e-9)
    assert np.isnan(rec.channels["motor.position"][-1]).all()
    assert np.all(late[:40] < 1e-5)  # on time before (fake clock steps only)


def test_default_max_lateness_is_the_watchdog(tmp_path):
    # a 19.9 ms stall: tick 11 + j starts 19.4 - 0.5 j ms late (absolute deadlines: the loop catches up),
    # 38 overruns (j = 0..37 later than 0.5 ms), within 5 % of the 2000-tick window; 19.4 ms < 20 ms
    sc = _scene({"watchdog_ms": 20, "max_overrun_fraction": 0.05})
    o = _realtime_runner(sc, tmp_path / "a", FakeClock(), slow={10: 0.0199}).run()[0]
    assert o.status == "completed", o.stop_reason
    assert o.stats["overruns"] == 38 and o.stats["late_max_us"] == pytest.approx(19400, abs=10)
    o = _realtime_runner(sc, tmp_path / "b", FakeClock(), slow={10: 0.0212}).run()[0]
    assert o.status == "safety_stop" and "limit max_lateness_ms = 20 ms" in o.stop_reason, o.stop_reason


def test_an_overrun_rate_above_the_limit_is_a_safe_stop(tmp_path):
    sc = _scene({"max_overrun_fraction": 0.002})  # 2 kHz: window 2000 ticks, 4 overruns allowed
    slow = {k: 0.0011 for k in (20, 60, 100, 140, 180, 220)}  # each makes the next tick 0.6 ms late: an overrun
    o = _realtime_runner(sc, tmp_path, FakeClock(), slow=slow).run()[0]
    assert o.status == "safety_stop"
    assert o.stop_reason.startswith("late loop: 5 overruns") and "up to tick 181" in o.stop_reason, o.stop_reason
    assert o.stats["overruns"] == 5


def test_lateness_and_tick_start_in_the_record_and_in_replay(tmp_path, capsys):
    sc = _scene()
    rng = np.random.default_rng(3)
    ticks = rng.choice(np.arange(0, 900, 3), 30, replace=False)  # never adjacent: each late tick has one cause
    jitter = {int(k): float(x) for k, x in zip(ticks, rng.uniform(0.0006, 0.0009, 30), strict=True)}
    o = _realtime_runner(sc, tmp_path, FakeClock(), slow=jitter).run()[0]
    assert o.status == "completed", o.stop_reason  # 0.1-0.4 ms late: no overrun, within max_lateness
    rec = RunRecord.open(o.record)
    assert rec.units["loop.late"] == "s" and rec.units["loop.tick_start"] == "s"
    late = rec.channels["loop.late"][:, 0]
    start = rec.channels["loop.tick_start"][:, 0]
    np.testing.assert_allclose(start - rec.t, late, atol=1e-9)  # start = deadline + lateness
    for k, w in jitter.items():  # tick k's work w makes tick k+1 late by w - period (fake clock: exact)
        assert late[k + 1] == pytest.approx(w - 0.0005, abs=5e-6)
    assert hil_main(["replay", str(o.record), "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    lat = s["lateness"]
    assert lat["ticks"] == late.size and lat["max_s"] == pytest.approx(late.max())
    assert lat["p50_s"] == pytest.approx(np.percentile(late, 50)) and lat["p99_s"] == pytest.approx(
        np.percentile(late, 99))
    assert lat["overruns"] == int(np.count_nonzero(late > 0.0005)) == sum(w > 0.001 for w in jitter.values())
    assert sum(c for _, c in lat["histogram"]) == late.size
    assert hil_main(["replay", str(o.record)]) == 0
    text = capsys.readouterr().out
    assert "lateness (tick start after its deadline" in text and f"overruns {lat['overruns']}" in text


def test_lockstep_records_the_simulated_time_as_tick_start(tmp_path):
    o = Runner(_scene(), tmp_path, max_ticks=50).run()[0]
    rec = RunRecord.open(o.record)
    np.testing.assert_array_equal(rec.channels["loop.tick_start"][:, 0], rec.t)
    assert not np.any(rec.channels["loop.late"])
    assert "lateness" not in rec.summary() and o.stats["mode"] == "lockstep"


def test_lateness_distribution_bins_are_half_open():
    late = np.array([0.0, 1e-5, 1.1e-5, 1e-4, 5e-4, 2e-3, 0.5])
    d = lateness_distribution(late, rate_hz=1000.0)
    assert [c for _, c in d["histogram"]] == [2, 2, 1, 1, 1]
    assert d["overruns"] == 2 and d["overrun_fraction"] == pytest.approx(2 / 7)


# -- sample timing before identification ----------------------------------------------------------
def test_check_sample_times_flags_jitter_beyond_tolerance_not_a_constant_delay():
    rate = 1000.0
    t = np.arange(2000) / rate
    assert check_sample_times(t, t + 3e-4, rate_hz=rate) == []  # a constant delay is not jitter
    start = t + 3e-4
    start[[100, 700]] += 0.2 / rate  # two ticks 0.2 period off
    (d,) = check_sample_times(t, start, rate_hz=rate)
    assert d.kind == "nonuniform_sampling" and d.failed and d.details["n_bad"] == 2
    assert d.details["max_rel_deviation"] == pytest.approx(0.2)
    assert check_sample_times(t, start, rate_hz=rate, tolerance=0.25) == []


def test_certificate_rows_from_a_jittered_realtime_record(tmp_path):
    """A record whose ticks started up to 0.3 period late (fake oversleeps past the spin window):
    the lateness rows equal numpy's percentiles of the recorded channel, and the sample timing row
    flags the record (FAIL) because 0.3 period > the 0.1 period tolerance."""
    sc = _scene({"max_lateness_ms": 1})
    over = {i: 350_000 for i in range(0, 1000, 37)}  # 350 µs oversleep: 150 µs = 0.3 period late
    fc = FakeClock(oversleep=lambda i: over.get(i, 0))
    o = _realtime_runner(sc, tmp_path, fc).run()[0]
    assert o.status == "completed", o.stop_reason
    late = RunRecord.open(o.record).channels["loop.late"][:, 0]
    rows = {m.name: m for m in lateness_measurements({"chirp_locked": o}, sc)}
    p99 = rows["loop lateness p99 (chirp_locked)"]
    assert p99.value == pytest.approx(np.percentile(late, 99)) and p99.upper == 0.001 and p99.outcome == "PASS"
    assert rows["loop lateness max (chirp_locked)"].value == pytest.approx(late.max())
    assert rows["loop overruns (chirp_locked)"].value == 0.0
    timing = rows["sample timing (chirp_locked)"]
    assert timing.outcome == "FAIL" and "departs" in timing.value and "0.30 periods" in timing.description
    lock = Runner(sc, tmp_path / "lock", max_ticks=20).run()[0]
    assert lateness_measurements({"x": lock}, sc) == []  # lockstep: no timing evidence to list


# -- scheduling, gc -------------------------------------------------------------------------------
def test_refused_scheduling_gives_one_warning_line_and_restores(monkeypatch, caplog):
    import os

    calls = []
    monkeypatch.setattr(os, "sched_setscheduler", lambda *a: (_ for _ in ()).throw(PermissionError(1, "denied")))
    monkeypatch.setattr("hil.run.realtime._libc", lambda: None)
    monkeypatch.setattr(os, "sched_setaffinity", lambda pid, cpus: calls.append(set(cpus)))
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1})
    monkeypatch.setattr("hil.run.realtime._WARNED", set())
    with caplog.at_level(logging.WARNING, logger="hil.run.realtime"):
        with realtime_scheduling(cpu=1) as got:
            assert got.policy == "SCHED_OTHER" and not got.memlock
        with realtime_scheduling(cpu=1) as again:  # the next experiment: recorded, not logged again
            assert again.warning == got.warning
    msgs = [r.getMessage() for r in caplog.records if r.name == "hil.run.realtime"]
    assert len(msgs) == 1 and "\n" not in msgs[0] and "SCHED_FIFO (denied)" in msgs[0] and "mlockall" in msgs[0]
    assert got.warning == msgs[0]
    assert calls == [{1}, {0, 1}] * 2  # pinned for the block, restored after


def test_gc_paused_disables_and_restores():
    assert gc.isenabled()
    with gc_paused():
        assert not gc.isenabled() and gc.get_freeze_count() > 0
    assert gc.isenabled() and gc.get_freeze_count() == 0


# -- check-realtime -------------------------------------------------------------------------------
def test_measure_wakeup_reports_the_lateness_of_each_wakeup():
    """Fake wake-ups late by 10, 20, ..., 100 µs in turn: the statistics are numpy's of that list."""
    fc = FakeClock(step_ns=0)
    lat = [10_000 * (1 + i % 10) for i in range(1000)]
    i = {"n": 0}

    def until(deadline_ns):
        fc.now = deadline_ns + lat[i["n"]]
        i["n"] += 1

    st = measure_wakeup(1000.0, 1.0, clock_ns=fc.clock, sleep_until=until)
    ref = np.array(lat) * 1e-9
    assert st.samples == 1000 and st.max == pytest.approx(1e-4)
    assert st.p50 == pytest.approx(np.percentile(ref, 50)) and st.p99 == pytest.approx(np.percentile(ref, 99))
    assert st.overruns == 0


def test_holdable_rates_definition():
    st = WakeupStats("hybrid", 2000.0, 100, 1e-6, 40e-6, 300e-6, 0)
    held = holdable_rates(st, [250, 1000, 2000, 4000])
    # p99 <= 0.1 / R  <=>  R <= 2500 Hz; max < 1 / R  <=>  R < 3333 Hz
    assert held == {250.0: True, 1000.0: True, 2000.0: True, 4000.0: False}
    assert holdable_rates(WakeupStats("h", 1000.0, 1, 0.0, 0.0, 1.5e-3, 1), [500, 1000]) == {500.0: True,
                                                                                            1000.0: False}


def test_cyclictest_missing_is_said_in_one_line_and_its_output_is_parsed():
    msg = run_cyclictest(1000.0, 1.0, which=lambda name: None)
    assert isinstance(msg, str) and "not installed" in msg and "\n" not in msg

    class CP:
        returncode = 0
        stdout = "T: 0 ( 1234) P:80 I:1000 C:   1000 Min:      3 Act:    5 Avg:    6 Max:      42\n"
        stderr = ""

    seen = {}
    st = run_cyclictest(1000.0, 1.0, which=lambda name: "/usr/bin/cyclictest",
                        run=lambda cmd, **kw: seen.setdefault("cmd", cmd) and CP())
    assert st.method == "cyclictest" and st.p50 == pytest.approx(6e-6) and st.max == pytest.approx(42e-6)
    assert seen["cmd"][1:] == ["-m", "-q", "-p", "80", "-i", "1000", "-l", "1000", "-h", "1000"]
    assert st.to_dict()["p99"] is None  # no histogram in that output: no p99, JSON null, not NaN


def test_cyclictest_histogram_gives_nearest_rank_percentiles_and_overflows_as_overruns():
    # 100 wake-ups: 60 at 20 µs, 38 at 21 µs, 1 at 50 µs, 1 beyond the 1000 µs histogram (overflow).
    # Nearest rank: p50 = smallest bin with >= 50 wake-ups at or below it = 20 µs; p99: 99 at or
    # below 50 µs -> 50 µs; Max and the overflow count are cyclictest's own lines.
    bins = {20: 60, 21: 38, 50: 1}
    body = "".join(f"{b:06d} {bins.get(b, 0):06d}\n" for b in range(1000))

    class CP:
        returncode = 0
        stdout = ("# /dev/cpu_dma_latency set to 0us\n# Histogram\n" + body + "# Total: 000000099\n"
                  "# Min Latencies: 00020\n# Avg Latencies: 00031\n# Max Latencies: 01234\n"
                  "# Histogram Overflows: 00001\n# Histogram Overflow at cycle number:\n# Thread 0: 00077\n")
        stderr = ""

    st = run_cyclictest(1000.0, 0.1, which=lambda name: "/usr/bin/cyclictest", run=lambda cmd, **kw: CP())
    assert (st.samples, st.overruns) == (100, 1)
    assert st.p50 == pytest.approx(20e-6) and st.p99 == pytest.approx(50e-6) and st.max == pytest.approx(1234e-6)
    bins[50] = 0  # now the 99th wake-up is the overflow one: p99 is not known from the histogram
    body = "".join(f"{b:06d} {bins.get(b, 0):06d}\n" for b in range(1000))
    CP.stdout = "# Histogram\n" + body + "# Max Latencies: 01234\n# Histogram Overflows: 00002\n"
    st = run_cyclictest(1000.0, 0.1, which=lambda name: "/usr/bin/cyclictest", run=lambda cmd, **kw: CP())
    assert st.overruns == 2 and math.isnan(st.p99) and st.p50 == pytest.approx(20e-6)


def test_check_realtime_prints_a_table(capsys, monkeypatch):
    from hil.cli.main import main

    monkeypatch.setattr("hil.run.realtime.shutil.which", lambda name: None)
    code = main(["check-realtime", "--rate", "1000", "--seconds", "0.02", "--no-rt"])
    out = capsys.readouterr().out
    assert code in (0, 21)  # held or not: depends on this machine (not asserted)
    for piece in ("scheduling: SCHED_OTHER", "abs. sleep", "sleep+spin", "p99 µs", "not installed", "1000 Hz:"):
        assert piece in out, out
    code = main(["check-realtime", "--rate", "1000", "--seconds", "0.02", "--no-rt", "--json"])
    js = json.loads(capsys.readouterr().out)
    assert [r["method"] for r in js["rows"]] == ["sleep", "hybrid"] and js["rows"][0]["samples"] == 20
    assert code == (0 if js["rate_held"] else 21)
    assert main(["check-realtime", "--rate", "-5"]) == 2


def test_steal_time_is_the_8th_value_of_the_cpu_line_and_nan_when_unreadable(tmp_path):
    """/proc/stat's ``cpu`` line: user nice system idle iowait irq softirq steal ... (clock ticks)."""
    import os

    from hil.run.realtime import steal_time_s

    stat = tmp_path / "stat"
    tck = os.sysconf("SC_CLK_TCK")
    stat.write_text(f"cpu  1 2 3 4 5 6 7 {3 * tck} 0 0\ncpu0 1 2 3 4 5 6 7 {tck} 0 0\n")
    assert steal_time_s(str(stat)) == pytest.approx(3.0)  # the sum over CPUs, not cpu0's
    stat.write_text("intr 1 2 3\n")
    assert math.isnan(steal_time_s(str(stat)))
    assert math.isnan(steal_time_s(str(tmp_path / "missing")))
    real = steal_time_s()
    assert math.isnan(real) or real >= 0.0  # this machine's counter: a duration, never negative


def test_check_realtime_reports_the_steal_time_of_its_measurement(capsys, monkeypatch):
    """The steal printed is the difference of the counter over the measurement (4.25 s of fake steal)."""
    from hil.cli.main import main

    readings = iter([10.0, 14.25])
    monkeypatch.setattr("hil.run.realtime.shutil.which", lambda name: None)
    monkeypatch.setattr("hil.run.realtime.steal_time_s", lambda path="": next(readings))
    main(["check-realtime", "--rate", "1000", "--seconds", "0.02", "--no-rt", "--json"])
    js = json.loads(capsys.readouterr().out)
    assert js["steal_s"] == pytest.approx(4.25) and js["elapsed_s"] > 0
    readings = iter([10.0, 14.25])
    main(["check-realtime", "--rate", "1000", "--seconds", "0.02", "--no-rt"])
    out = capsys.readouterr().out
    assert "steal time: 4250 ms" in out and "virtual machine" in out, out


def test_a_realtime_run_records_the_steal_time_of_its_loop(tmp_path, monkeypatch):
    """The steal counter read when the loop starts and when it ends (2.0 s -> 2.35 s of fake steal):
    350 ms in the run's stats and as a ``realtime`` event; a lockstep run reads no steal."""
    readings = iter([2.0, 2.35])
    monkeypatch.setattr("hil.run.realtime.steal_time_s", lambda path="": next(readings))
    o = _realtime_runner(_scene(), tmp_path / "rt", FakeClock(), max_ticks=30).run(select=[0])[0]
    assert o.status == "completed", o.stop_reason
    assert o.stats["steal_ms"] == pytest.approx(350.0)
    ev = [e for e in RunRecord.open(o.record).events if e["kind"] == "realtime"]
    assert any("steal time during the loop: 350 ms" in e["message"] for e in ev), ev
    with pytest.raises(StopIteration):
        next(readings)  # read exactly twice
    monkeypatch.setattr("hil.run.realtime.steal_time_s", lambda path="": float("nan"))
    o = _realtime_runner(_scene(), tmp_path / "nan", FakeClock(), max_ticks=30).run(select=[0])[0]
    assert "steal_ms" not in o.stats  # unreadable (not Linux): not reported, not 0
    lock = Runner(_scene(), tmp_path / "lock", max_ticks=20).run(select=[0])[0]
    assert "steal_ms" not in lock.stats
