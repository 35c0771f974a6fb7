"""The record's background writer (``RecordWriter(background=True)``; ``background="process"``,
the realtime runner's mode, has the h5py calls made by a writer process fed through shared memory):
the same file as synchronous writing, a write error (full disk) in the writer thread is raised at the
next append and keeps every row flushed before it, a writer that falls behind is a bounded
:class:`RecordLagError` (a safe stop in the runner) with nothing lost, and close joins the writer
with everything queued on disk. No wall-clock time is asserted; waits are bounded.
"""

from __future__ import annotations

import errno
import logging
import math
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest
import yaml  # type: ignore[import-untyped]  # no PyYAML stubs in the env

import hil.record.hdf5 as record_mod
from hil.bench.runtime import Bench
from hil.record.hdf5 import ChannelSpec, RecordLagError, RecordWriteError, RecordWriter, RunRecord
from hil.run.runner import Runner
from hil.scene.spec import load_scene, scene_from_dict

pytestmark = pytest.mark.timeout(120)

RATE = 1000.0
BLOCK = 100  # samples per block: RATE * flush_every_s (0.1 s)
CHANNELS = {"motor.position": ChannelSpec((), "rad"), "master.position": ChannelSpec((2,), "rad")}


def _vals(k: int) -> dict[str, Any]:
    return {"motor.position": math.sin(0.01 * k), "master.position": [k / 7, -3.25 * k]}


def _writer(path: Path, **kw: Any) -> RecordWriter:
    args: dict[str, Any] = {"scene_text": "name: bg\n", "scene_sha256": "x", "meta": {"seed": 3},
                            "channels": CHANNELS, "rate_hz": RATE, "flush_every_s": 0.1}
    args.update(kw)
    return RecordWriter(path, **args)


def _check_exact(rec: RunRecord, n: int) -> None:
    """The record holds samples 0..n-1 exactly once, in order, with their exact values."""
    assert rec.t.size == n
    k = np.arange(n)
    np.testing.assert_array_equal(rec.t, k / RATE)
    np.testing.assert_array_equal(rec.channels["motor.position"], [math.sin(0.01 * i) for i in range(n)])
    np.testing.assert_array_equal(rec.channels["master.position"], np.column_stack([k / 7, -3.25 * k]))


def _wait_for(cond: Any, what: str, timeout: float = 20.0) -> None:
    end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.002)


def _datasets(path: Path) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    with h5py.File(path, "r") as f:
        def visit(name: str, obj: Any) -> None:
            if isinstance(obj, h5py.Dataset) and name not in ("status", "scene"):
                out[name] = obj[()]
        f.visititems(visit)
    return out


def _script(w: RecordWriter, n: int) -> None:
    for k in range(n):
        w.append(k / RATE, _vals(k))
        if k % 97 == 0:
            w.event(k / RATE, "mark", str(k))
        if k == 555:
            w.set_device_counters({"bus": {"frames": k}})
    w.set_results("exp", {"gain": 2.5, "curve": np.arange(7.0)})


def test_background_writing_gives_the_same_datasets_as_synchronous_writing(tmp_path: Path) -> None:
    n = 1234  # 12 full blocks and a partial one
    sync = _writer(tmp_path / "sync.h5")
    _script(sync, n)
    sync.close()
    bg = _writer(tmp_path / "bg.h5", background=True, max_pending_blocks=64)  # the pool holds the whole run
    _script(bg, n)
    bg.close()
    a, b = _datasets(tmp_path / "sync.h5"), _datasets(tmp_path / "bg.h5")
    assert sorted(a) == sorted(b) and "channels/motor.position" in a and "events" in a
    for name in a:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)  # bit for bit (NaN == NaN)
    rec = RunRecord.open(tmp_path / "bg.h5")
    _check_exact(rec, n)
    assert rec.status == "ok" and rec.results["exp"]["gain"] == 2.5
    np.testing.assert_array_equal(rec.results["exp"]["curve"], np.arange(7.0))
    assert bg.samples_flushed == n and bg._thread is None  # joined by close


@pytest.fixture
def full_disk_after(monkeypatch: pytest.MonkeyPatch):
    """``posix_fallocate`` (the writer's reserve before every block) fails with ENOSPC from call
    ``calls[0] + 1`` on: a full disk as the writer meets it. Yields the mutable limit."""
    limit = [10**9]
    seen = {"n": 0}
    real = os.posix_fallocate

    def fallocate(fd: int, offset: int, length: int) -> None:
        seen["n"] += 1
        if seen["n"] > limit[0]:
            raise OSError(errno.ENOSPC, "No space left on device")
        real(fd, offset, length)

    monkeypatch.setattr(os, "posix_fallocate", fallocate)
    return limit


def test_a_full_disk_in_the_writer_thread_is_raised_at_the_next_append_and_keeps_the_flushed_rows(
        tmp_path: Path, full_disk_after: list[int]) -> None:
    full_disk_after[0] = 2  # blocks 1 and 2 written, block 3's reserve fails
    path = tmp_path / "full.h5"
    w = _writer(path, background=True)
    for k in range(3 * BLOCK):  # the 300th append hands block 3 over
        w.append(k / RATE, _vals(k))
    _wait_for(lambda: w.failure is not None, "the writer thread's failure")
    with pytest.raises(RecordWriteError) as ei:
        w.append(3 * BLOCK / RATE, _vals(3 * BLOCK))  # the loop's next tick: the failure, one line
    msg = str(ei.value)
    assert "\n" not in msg and "No space left on device" in msg and f"the {2 * BLOCK} samples flushed" in msg
    with pytest.raises(RecordWriteError):
        w.event(0.5, "x", "y")  # a failed writer stays failed
    with pytest.raises(RecordWriteError) as ei2:
        w.close(stop_reason="record: disk full", status="safety_stop")
    assert str(ei2.value) == msg
    rec = RunRecord.open(path)
    _check_exact(rec, 2 * BLOCK)  # every row flushed before the failure, intact
    assert rec.closed and rec.status == "safety_stop" and rec.stop_reason == "record: disk full"


def test_a_write_that_raises_in_the_writer_thread_keeps_the_rows_flushed_before(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    real = record_mod._write_rows
    calls = {"t": 0}

    def write_rows(ds: Any, start: int, data: np.ndarray) -> None:
        if ds.name == "/t":
            calls["t"] += 1
        if calls["t"] >= 3 and ds.name.endswith("master.position"):  # inside block 4, channels half written
            raise OSError(errno.EIO, "Input/output error")
        real(ds, start, data)

    monkeypatch.setattr(record_mod, "_write_rows", write_rows)
    path = tmp_path / "eio.h5"
    w = _writer(path, background=True)
    with pytest.raises(RecordWriteError, match="Input/output error"):
        for k in range(10 * BLOCK):
            w.append(k / RATE, _vals(k))
            if k % BLOCK == BLOCK - 1 and k >= 4 * BLOCK - 1:
                _wait_for(lambda: w.failure is not None, "the failure")
    assert w.samples_flushed == 3 * BLOCK
    with pytest.raises(RecordWriteError):
        w.close()
    rec = RunRecord.open(path)  # HDF5 may have been mid-block: not closed, the flushed rows are all there
    _check_exact(rec, 3 * BLOCK)


class _Gate:
    """Holds the writer thread inside its first ``/t`` write until released (a writer behind)."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.open = threading.Event()
        self.entered = threading.Event()
        real = record_mod._write_rows

        def write_rows(ds: Any, start: int, data: np.ndarray) -> None:
            if ds.name == "/t":
                self.entered.set()
                assert self.open.wait(60), "gate never opened"
            real(ds, start, data)

        monkeypatch.setattr(record_mod, "_write_rows", write_rows)


def test_a_writer_that_falls_behind_is_a_bounded_lag_error_and_close_writes_everything(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    gate = _Gate(monkeypatch)
    path = tmp_path / "lag.h5"
    pending = 2
    w = _writer(path, background=True, max_pending_blocks=pending)
    raised: list[int] = []
    for k in range(10 * BLOCK):
        try:
            w.append(k / RATE, _vals(k))
        except RecordLagError as exc:
            raised.append(k)
            msg = str(exc)
            if len(raised) == 3:
                break
        if k == BLOCK:  # block 1 handed over at k = 99: the writer is now held inside it
            assert gate.entered.wait(20)
    # pool = the current block + `pending` free ones: block 1 and 2 handed over, block 3 (k = 299, stored)
    # has no free successor; the following appends are refused (not stored) -- memory never grows
    assert raised == [(pending + 1) * BLOCK - 1, (pending + 1) * BLOCK, (pending + 1) * BLOCK + 1]
    assert "fell behind" in msg and f"the {(pending + 1) * BLOCK} samples taken are kept" in msg and "\n" not in msg
    assert w.failure is None and w.samples == (pending + 1) * BLOCK
    gate.open.set()
    w.close(stop_reason="record: writer behind", status="safety_stop")  # joins the writer: all queued on disk
    assert w._thread is None
    rec = RunRecord.open(path)
    _check_exact(rec, (pending + 1) * BLOCK)
    assert rec.status == "safety_stop" and rec.stop_reason == "record: writer behind"


def test_flush_waits_until_everything_handed_over_is_readable(tmp_path: Path) -> None:
    path = tmp_path / "live.h5"
    w = _writer(path, background=True)
    for k in range(250):
        w.append(k / RATE, _vals(k))
    w.event(0.2, "mark", "x")
    try:
        w.flush()
        # a SWMR reader of the live file (another process, as the same one is refused by HDF5's locking)
        code = ("import sys; from hil.record.hdf5 import RunRecord; r = RunRecord.open(sys.argv[1]); "
                "print(r.t.size, float(r.t[-1]), [e['message'] for e in r.events], r.closed)")
        p = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=60)
        assert p.returncode == 0, p.stderr[-2000:]
        assert p.stdout.split(maxsplit=2)[:2] == ["250", repr(249 / RATE)]
        assert p.stdout.strip().endswith("['x'] False")
    finally:
        w.close()
    _check_exact(RunRecord.open(path), 250)
    assert RunRecord.open(path).closed


# -- the realtime runner: record errors off the tick are safe stops --------------------------------


class _FakeClock:
    """Nanosecond clock advancing 1 µs per read and exactly what is slept (no machine timing)."""

    def __init__(self) -> None:
        self.now = 5_000_000_000

    def clock(self) -> int:
        self.now += 1_000
        return self.now

    def sleep(self, s: float) -> None:
        self.now += round(s * 1e9)


def _runner(tmp_path: Path) -> Runner:
    d = yaml.safe_load(load_scene("sdea_bench").source_text)
    d["experiments"] = d["experiments"][:1]
    d["experiments"][0]["duration"] = 0.5
    d.pop("certification", None)
    sc = scene_from_dict(d, label="writer-thread-test")
    fc = _FakeClock()
    r = Runner(sc, tmp_path, realtime=True, bench_factory=lambda v: Bench(sc, seed=sc.seed, variant=v),
               clock_ns=fc.clock, sleep=fc.sleep, rt_scheduling=False)
    r.record_process = False  # the failures below are injected into this process's h5py calls
    return r


def test_realtime_runner_full_disk_in_the_writer_is_a_safe_stop_keeping_the_flushed_rows(
        tmp_path: Path, full_disk_after: list[int]) -> None:
    full_disk_after[0] = 2
    r = _runner(tmp_path)
    assert r.record_thread and r.rate_hz == 2000.0
    o = r.run()[0]
    assert o.status == "safety_stop" and o.stop_reason.startswith("record: "), o.stop_reason
    assert "No space left on device" in o.stop_reason and "400 samples flushed" in o.stop_reason
    assert o.stats["ticks"] > 400  # the loop went on until a tick saw the failure
    assert o.record is not None
    rec = RunRecord.open(o.record)
    assert rec.t.size == 400  # two 0.1 s blocks of 200 samples, exact times
    np.testing.assert_array_equal(rec.t, np.arange(400) * (1 / 2000.0))  # the runner: t = k * dt
    assert np.all(np.isfinite(rec.channels["motor.position"]))
    assert rec.status == "safety_stop" and "No space left on device" in (rec.stop_reason or "")


def test_realtime_runner_writer_behind_is_a_safe_stop_and_every_sample_is_recorded(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # the writer is held inside its first block until the record logs that it fell behind
    released = threading.Event()

    class Release(logging.Handler):
        def emit(self, rec: logging.LogRecord) -> None:
            if "fell behind" in rec.getMessage():
                released.set()

    real = record_mod._write_rows

    def held_write_rows(ds: Any, start: int, data: np.ndarray) -> None:
        if ds.name == "/t":
            assert released.wait(60), "never released"
        real(ds, start, data)

    monkeypatch.setattr(record_mod, "_write_rows", held_write_rows)
    handler = Release()
    record_mod.logger.addHandler(handler)
    try:
        o = _runner(tmp_path).run()[0]
    finally:
        record_mod.logger.removeHandler(handler)
    assert o.status == "safety_stop" and "fell behind" in o.stop_reason, o.stop_reason
    # 2 kHz, 200-sample blocks, 4 free blocks besides the current one: the 5th full block (tick 999,
    # the last) finds none free -- the limit, not memory, ends it; that tick stops inside its append
    # (its sample is kept, its command never sent), so 999 ticks completed
    assert o.stats["ticks"] == 999
    assert o.record is not None
    rec = RunRecord.open(o.record)
    assert rec.t.size == 1000  # every tick's sample is on disk: close joined the writer
    np.testing.assert_array_equal(rec.t, np.arange(1000) * (1 / 2000.0))
    assert np.all(np.isfinite(rec.channels["motor.position"]))
    assert rec.status == "safety_stop" and "fell behind" in (rec.stop_reason or "")


def test_writer_scheduling_is_applied_to_the_writer_thread_or_explained(tmp_path: Path) -> None:
    sync = _writer(tmp_path / "sync.h5")
    assert sync.set_writer_scheduling(79) == "no writer thread"
    sync.close()
    w = _writer(tmp_path / "bg.h5", background=True)
    try:
        why = w.set_writer_scheduling(79)
        assert w._thread is not None and w._thread.native_id is not None
        policy = os.sched_getscheduler(w._thread.native_id)
        if why is None:  # permitted (root / CAP_SYS_NICE): the writer thread, not this one, is FIFO 79
            assert policy == os.SCHED_FIFO and os.sched_getparam(w._thread.native_id).sched_priority == 79
            assert os.sched_getscheduler(0) != os.SCHED_FIFO
        else:
            assert "not permitted" in why and "\n" not in why and policy != os.SCHED_FIFO
        for k in range(150):
            w.append(k / RATE, _vals(k))
    finally:
        w.close()
    _check_exact(RunRecord.open(tmp_path / "bg.h5"), 150)


# -- the writer process (background="process"): the same file, its failures are the caller's ----------


def test_process_writing_gives_the_same_datasets_as_synchronous_writing(tmp_path: Path) -> None:
    n = 1234
    sync = _writer(tmp_path / "sync.h5")
    _script(sync, n)
    sync.close()
    pw = _writer(tmp_path / "proc.h5", background="process", max_pending_blocks=64)
    assert pw._proc is not None and pw._proc.pid != os.getpid() and pw._shm is not None
    _script(pw, n)
    pw.close()
    assert pw._proc.poll() is not None  # the writer process ended with the record
    a, b = _datasets(tmp_path / "sync.h5"), _datasets(tmp_path / "proc.h5")
    assert sorted(a) == sorted(b) and "channels/master.position" in a and "results_npy" in a
    for name in a:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    rec = RunRecord.open(tmp_path / "proc.h5")
    _check_exact(rec, n)
    assert rec.status == "ok" and rec.closed and rec.results["exp"]["gain"] == 2.5


def test_a_file_size_limit_in_the_writer_process_is_raised_at_the_next_append_keeping_the_flushed_rows(
        tmp_path: Path) -> None:
    import resource

    path = tmp_path / "fsize.h5"
    w = _writer(path, background="process")
    for k in range(2 * BLOCK):
        w.append(k / RATE, _vals(k))
    w.flush()  # blocks 1 and 2 on disk
    size = path.stat().st_size
    resource.prlimit(w._proc.pid, resource.RLIMIT_FSIZE, (size, size))  # the disk is "full" for the writer
    k = 2 * BLOCK
    with pytest.raises(RecordWriteError) as ei:  # the blocks the earlier reserve covers fit; then one fails
        while k < 200 * BLOCK:
            w.append(k / RATE, _vals(k))
            k += 1
            if k % BLOCK == 0:
                _wait_for(lambda: w._free.qsize() == w.max_pending_blocks or w.failure is not None, "the writer")
    flushed = w.samples_flushed
    assert 2 * BLOCK <= flushed < k and flushed % BLOCK == 0
    msg = str(ei.value)
    assert "\n" not in msg and "File too large" in msg and f"the {flushed} samples flushed" in msg
    with pytest.raises(RecordWriteError) as ei2:
        w.close(stop_reason="record: disk full", status="safety_stop")
    assert str(ei2.value) == msg
    rec = RunRecord.open(path)
    _check_exact(rec, flushed)  # every row flushed before the failure, intact
    assert rec.closed and rec.status == "safety_stop" and rec.stop_reason == "record: disk full"


def test_a_killed_writer_process_is_a_write_error_at_the_next_call_keeping_the_flushed_rows(
        tmp_path: Path) -> None:
    import signal

    path = tmp_path / "killed.h5"
    w = _writer(path, background="process")
    for k in range(2 * BLOCK):
        w.append(k / RATE, _vals(k))
    w.flush()
    os.kill(w._proc.pid, signal.SIGKILL)
    w._proc.wait(20)
    with pytest.raises(RecordWriteError) as ei:
        for k in range(2 * BLOCK, 10 * BLOCK):
            w.append(k / RATE, _vals(k))
            if k % BLOCK == BLOCK - 1:
                _wait_for(lambda: w.failure is not None, "the failure")
    msg = str(ei.value)
    assert "\n" not in msg and "record writer process" in msg and f"the {2 * BLOCK} samples flushed" in msg
    with pytest.raises(RecordWriteError):
        w.close()
    rec = RunRecord.open(path)  # as a kill leaves it: every flushed row; the reason written into it (issue 27)
    _check_exact(rec, 2 * BLOCK)
    assert rec.closed and "record writer process was killed by SIGKILL" in rec.stop_reason


def test_writer_scheduling_applies_to_the_writer_process_too(tmp_path: Path) -> None:
    w = _writer(tmp_path / "p.h5", background="process")
    try:
        cpus = sorted(os.sched_getaffinity(0))[:1]
        why = w.set_writer_scheduling(79, cpus, process_priority=60)
        pid = w._proc.pid
        if why is None:  # the process (h5py) at 60, the thread (shares the loop's GIL) at 79, both on `cpus`
            assert os.sched_getscheduler(pid) == os.SCHED_FIFO and os.sched_getparam(pid).sched_priority == 60
            assert w._thread is not None and w._thread.native_id is not None
            assert os.sched_getparam(w._thread.native_id).sched_priority == 79
            assert sorted(os.sched_getaffinity(pid)) == cpus == sorted(os.sched_getaffinity(w._thread.native_id))
        else:
            assert "not permitted" in why and "\n" not in why
        for k in range(150):
            w.append(k / RATE, _vals(k))
    finally:
        w.close()
    _check_exact(RunRecord.open(tmp_path / "p.h5"), 150)


def test_realtime_runner_records_every_tick_through_the_writer_process(tmp_path: Path) -> None:
    r = _runner(tmp_path)
    r.record_process = True  # the realtime default
    o = r.run()[0]
    assert o.status == "completed", o.stop_reason
    assert o.record is not None
    rec = RunRecord.open(o.record)
    np.testing.assert_array_equal(rec.t, np.arange(1000) * (1 / 2000.0))
    assert np.all(np.isfinite(rec.channels["motor.position"])) and rec.closed and rec.status == "completed"
    assert o.results and "error" not in o.results  # finish() read the record while the writer process held it
