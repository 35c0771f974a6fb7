"""Records that survive anything: signals inside a flush, SIGKILL at any point (also inside close()),
a full disk (a real file-size limit), existing files, and truncated / garbage files given to the reader.

Every subprocess here is bounded (timeouts) and every reader call runs under a pytest-timeout marker:
a hang is a failure, no wall-clock time is asserted.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import random
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import h5py
import numpy as np
import pytest

import hil.record.hdf5 as record_mod
from hil.cli.main import main as hil_main
from hil.errors import HilError
from hil.record.hdf5 import ChannelSpec, RecordError, RecordWriter, RunRecord

RATE = 1000.0
CHANNELS = {"motor.position": ChannelSpec((), "rad"), "master.position": ChannelSpec((2,), "rad")}


def _vals(k: int) -> dict[str, Any]:
    return {"motor.position": math.sin(0.01 * k), "master.position": [k / 7, -3.25 * k]}


def _writer(path: Path, **kw) -> RecordWriter:
    args: dict[str, Any] = {"scene_text": "name: crash\n", "scene_sha256": "x", "meta": {"seed": 3},
                            "channels": CHANNELS, "rate_hz": RATE, "flush_every_s": 0.1}
    args.update(kw)
    return RecordWriter(path, **args)


def _check_exact(rec: RunRecord, n: int | None = None) -> None:
    """The record holds samples 0..n-1 exactly once, in order, with their exact values (no NaN)."""
    m = rec.t.size if n is None else n
    assert rec.t.size == m
    k = np.arange(m)
    np.testing.assert_array_equal(rec.t, k / RATE)
    np.testing.assert_array_equal(rec.channels["motor.position"], [math.sin(0.01 * i) for i in range(m)])
    np.testing.assert_array_equal(rec.channels["master.position"], np.column_stack([k / 7, -3.25 * k]))


class _Interrupt(Exception):
    """What a signal handler raises here (as the old runner's handlers did)."""


@pytest.fixture
def signal_between_resize_and_write(monkeypatch: pytest.MonkeyPatch):
    """SIGUSR1 (handler raising :class:`_Interrupt`) sent by the writer itself inside a block: after
    the channels were written, just before ``/t`` is grown and written (``hil.record.hdf5._write_rows``).
    Yields a dict counting the deliveries."""
    seen = {"sent": 0, "raised": 0}

    def handler(signum, frame):
        seen["raised"] += 1
        raise _Interrupt("SIGUSR1")

    old_handler = signal.signal(signal.SIGUSR1, handler)
    real_write_rows = record_mod._write_rows

    def write_rows(ds, start, data):
        if ds.name == "/t":
            seen["sent"] += 1
            os.kill(os.getpid(), signal.SIGUSR1)
        real_write_rows(ds, start, data)

    monkeypatch.setattr(record_mod, "_write_rows", write_rows)
    try:
        yield seen
    finally:
        signal.signal(signal.SIGUSR1, old_handler)


@pytest.mark.timeout(60)
def test_a_signal_inside_a_flush_runs_after_the_block_never_duplicating_it(
        tmp_path: Path, signal_between_resize_and_write: dict[str, int]) -> None:
    seen = signal_between_resize_and_write
    path = tmp_path / "sig.h5"
    n, interrupted = 350, []
    w = _writer(path)
    for k in range(n):
        try:
            w.append(k / RATE, _vals(k))
        except _Interrupt:
            interrupted.append(k)
            # the handler ran after the block was written *and* accounted for
            assert w.samples_flushed == k + 1 and w.failure is None
    assert interrupted == [99, 199, 299]
    with pytest.raises(_Interrupt):  # the last flush, inside close(): the handler runs once it is closed
        w.close()
    assert w.closed and w.status == "ok"
    assert seen == {"sent": 4, "raised": 4}
    rec = RunRecord.open(path)
    assert rec.status == "ok"
    _check_exact(rec, n)
    with h5py.File(path, "r") as f:  # on disk too: exactly n rows, no NaN block anywhere
        assert f["t"].shape == (n,) and np.all(np.isfinite(f["t"][:]))


@pytest.mark.timeout(60)
def test_an_interrupted_flush_is_written_once_by_close_even_without_held_signals(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # Defence in depth: with signal holding disabled, a KeyboardInterrupt between the /t resize and its
    # write leaves the block half-written; close() then writes it at the same rows (absolute positions),
    # not after the half-written one (the old code wrote it twice, with 100 NaN times in between).
    monkeypatch.setattr(record_mod, "_signals_held", contextlib.nullcontext)
    real_write_rows = record_mod._write_rows
    armed = {"on": True}

    def write_rows(ds, start, data):  # the second block's /t: grown, then interrupted before its write
        if ds.name == "/t" and armed["on"] and start >= 100:
            armed["on"] = False
            ds.resize((start + len(data),))
            raise KeyboardInterrupt
        real_write_rows(ds, start, data)

    monkeypatch.setattr(record_mod, "_write_rows", write_rows)
    path = tmp_path / "ki.h5"
    w = _writer(path)
    with pytest.raises(KeyboardInterrupt):
        for k in range(250):
            w.append(k / RATE, _vals(k))
    assert w.samples == 200 and w.samples_flushed == 100
    w.close("interrupted", "interrupted")
    rec = RunRecord.open(path)
    assert rec.status == "interrupted"
    _check_exact(rec, 200)


# -- SIGKILL at any moment, including inside close() ----------------------------------------------------

CHILD = textwrap.dedent(
    """
    import math, os, sys, time
    import hil.record.hdf5 as R
    from hil.record.hdf5 import ChannelSpec, RecordWriter
    path, mode, arg = sys.argv[1], sys.argv[2], sys.argv[3]
    ch = {"motor.position": ChannelSpec((), "rad"), "master.position": ChannelSpec((2,), "rad")}

    def hook(point, w):
        if mode == "pause" and point == arg:
            print("P", w.samples_flushed, flush=True)
            time.sleep(60)

    R._TEST_HOOK = hook
    w = RecordWriter(path, scene_text="name: kill\\n", scene_sha256="x", meta={"seed": 1}, channels=ch,
                     rate_hz=1000.0, flush_every_s=0.02)
    n = 1234
    for k in range(n):
        w.append(k / 1000, {"motor.position": math.sin(0.01 * k), "master.position": [k / 7, -3.25 * k]})
    w.set_device_counters({"odrive0": {"crc_errors": 2, "stale": 1}})
    w.set_results("chirp", {"f": [1.0, 2.0], "ok": True})
    print("C", w.samples_flushed, flush=True)  # about to close: every sample is flushed
    if mode == "delay":  # the parent kills after a random delay: somewhere in, or after, close()
        sys.stdin.readline()
    w.close()
    print("D", w.samples_flushed, flush=True)
    time.sleep(60)
    """
)


def _kill_child(tmp_path: Path, mode: str, arg: str, delay_s: float = 0.0) -> tuple[Path, str, int]:
    path = tmp_path / f"k_{mode}_{arg}.h5"
    script = tmp_path / "child.py"
    script.write_text(CHILD)
    p = subprocess.Popen([sys.executable, str(script), str(path), mode, arg], stdin=subprocess.PIPE,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    last_kind, last = "", 0
    assert p.stdin is not None and p.stdout is not None and p.stderr is not None
    try:
        while True:
            line = p.stdout.readline()
            assert line, f"child ended early: {p.stderr.read()}"
            last_kind, num = line.split()
            last = int(num)
            if mode == "pause" and last_kind == "P":
                break
            if mode == "delay" and last_kind == "C":
                p.stdin.write("go\n")
                p.stdin.flush()
                if delay_s:
                    with contextlib.suppress(subprocess.TimeoutExpired):
                        p.wait(timeout=delay_s)
                break
        os.kill(p.pid, signal.SIGKILL)
    finally:
        p.wait(timeout=30)
        for pipe in (p.stdin, p.stdout, p.stderr):
            pipe.close()
    assert p.returncode == -signal.SIGKILL
    return path, last_kind, last


@pytest.mark.timeout(120)
@pytest.mark.parametrize("point", ["close", "close:flushed", "close:status"])
def test_sigkill_paused_inside_close_leaves_a_readable_record(tmp_path: Path, point: str) -> None:
    path, _, flushed = _kill_child(tmp_path, "pause", point)
    assert flushed == 1234
    rec = RunRecord.open(path)
    _check_exact(rec, 1234)
    assert rec.results["chirp"]["f"] == [1.0, 2.0]  # results are written when set, not at close
    assert rec.device_counters == {"odrive0": {"crc_errors": 2, "stale": 1}}
    # the status is there exactly when close() got past writing it
    assert (rec.status, rec.stop_reason) == (("ok", "completed") if point == "close:status" else (None, None))


@pytest.mark.timeout(180)
def test_sigkill_at_random_moments_around_close_leaves_a_readable_record(tmp_path: Path) -> None:
    rng = random.Random(1234)
    delays = [0.0] + [rng.uniform(0.0, 0.004) for _ in range(5)]
    statuses = []
    for i, delay in enumerate(delays):
        sub = tmp_path / f"trial{i}"
        sub.mkdir()
        path, _, flushed = _kill_child(sub, "delay", "x", delay)
        assert flushed == 1234
        rec = RunRecord.open(path)
        _check_exact(rec, 1234)
        assert rec.status in (None, "ok")
        statuses.append(rec.status)
    assert len(statuses) == len(delays)


STREAM_CHILD = textwrap.dedent(
    """
    import logging, math, sys, time
    from hil.record.hdf5 import ChannelSpec, RecordLagError, RecordWriter
    logging.disable(logging.ERROR)  # the lag's log line per retry would fill the unread stderr pipe
    ch = {"motor.position": ChannelSpec((), "rad"), "master.position": ChannelSpec((2,), "rad")}
    w = RecordWriter(sys.argv[1], scene_text="", scene_sha256="", meta={}, channels=ch, rate_hz=1000.0,
                     flush_every_s=0.007,  # 7-sample blocks: a kill mostly lands inside some write
                     background=sys.argv[2] == "background")  # writer thread: blocks written off this thread
    flushed = 0
    for k in range(10**7):
        while True:  # background: a writer behind refuses the sample (not stored) until a block is free
            n0 = w.samples
            try:
                w.append(k / 1000, {"motor.position": math.sin(0.01 * k), "master.position": [k / 7, -3.25 * k]})
                break
            except RecordLagError:
                if w.samples > n0:  # stored; only its block's hand-over was refused
                    break
                time.sleep(0.001)
        if k % 97 == 0:
            w.event(k / 1000, "mark", str(k))
        if k % 1000 == 999:
            w.set_device_counters({"bus": {"frames": k}})
        if w.samples_flushed != flushed:
            flushed = w.samples_flushed
            print(flushed, flush=True)
    """
)


@pytest.mark.timeout(180)
@pytest.mark.parametrize("mode", ["sync", "background"])
def test_sigkill_at_random_moments_while_streaming_keeps_every_flushed_sample(tmp_path: Path, mode: str) -> None:
    script = tmp_path / "stream.py"
    script.write_text(STREAM_CHILD)
    rng = random.Random(99)
    for i in range(5):
        path = tmp_path / f"s{i}.h5"
        target = rng.randrange(500, 6000)
        p = subprocess.Popen([sys.executable, str(script), str(path), mode], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
        last = 0
        assert p.stdout is not None and p.stderr is not None
        try:
            while last < target:
                line = p.stdout.readline()
                assert line, p.stderr.read()
                last = int(line)
            os.kill(p.pid, signal.SIGKILL)
        finally:
            p.wait(timeout=30)
            p.stdout.close()
            p.stderr.close()
        rec = RunRecord.open(path)
        assert rec.t.size >= last and not rec.closed
        _check_exact(rec)
        kept = [e["message"] for e in rec.events]
        assert kept == [str(k) for k in range(0, 97 * len(kept), 97)]  # in order, none twice, none torn
        if rec.device_counters:
            assert rec.device_counters["bus"]["frames"] % 1000 == 999


# -- full disk: a real file-size limit in a subprocess ---------------------------------------------------

FULL_CHILD = textwrap.dedent(
    """
    import json, math, resource, signal, sys
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # writes past the limit then fail with EFBIG
    from hil.record.hdf5 import ChannelSpec, RecordError, RecordWriter
    path, limit = sys.argv[1], int(sys.argv[2])
    ch = {"motor.position": ChannelSpec((), "rad"), "master.position": ChannelSpec((2,), "rad")}
    w = RecordWriter(path, scene_text="name: full\\n", scene_sha256="x", meta={}, channels=ch, rate_hz=1000.0,
                     flush_every_s=0.05)
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, resource.RLIM_INFINITY))
    out = {}
    try:
        for k in range(10**6):
            w.append(k / 1000, {"motor.position": math.sin(0.01 * k), "master.position": [k / 7, -3.25 * k]})
            if k % 500 == 0:
                w.event(k / 1000, "mark", "x" * 40)
    except RecordError as exc:
        out["append"] = [type(exc).__name__, str(exc)]
    out["flushed"] = w.samples_flushed
    try:
        w.append(10**6, {})
    except RecordError as exc:
        out["again"] = str(exc)
    try:
        w.close()
    except RecordError as exc:
        out["close"] = [type(exc).__name__, str(exc)]
    print(json.dumps(out), flush=True)
    """
)


@pytest.mark.timeout(120)
@pytest.mark.parametrize("limit", [60_000, 400_000])
def test_full_disk_is_a_one_line_error_and_keeps_what_was_flushed(tmp_path: Path, limit: int) -> None:
    path = tmp_path / "full.h5"
    script = tmp_path / "full_child.py"
    script.write_text(FULL_CHILD)
    p = subprocess.run([sys.executable, str(script), str(path), str(limit)], capture_output=True, text=True,
                       timeout=90)
    assert p.returncode == 0, p.stderr[-2000:]  # no segfault, no traceback
    assert "Exception ignored" not in p.stderr and "Traceback" not in p.stderr
    assert len(p.stderr.strip().splitlines()) <= 1  # at most the writer's one logged line
    out = json.loads(p.stdout)
    kind, msg = out["append"]
    assert kind == "RecordWriteError" and "\n" not in msg
    assert str(path) in msg and "File too large" in msg and f"{out['flushed']} samples" in msg
    assert out["again"] == msg  # a failed writer stays failed, the file is not touched again
    assert out["close"] == ["RecordWriteError", msg]
    assert path.stat().st_size <= limit
    rec = RunRecord.open(path)
    assert rec.t.size == out["flushed"] > (0 if limit > 100_000 else -1)
    _check_exact(rec)
    assert rec.status == "error" and "File too large" in (rec.stop_reason or "")


@pytest.mark.timeout(60)
def test_planned_run_size_is_checked_against_free_space(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "big.h5"
    w = _writer(tmp_path / "probe.h5", overwrite=True)
    assert w.bytes_per_sample() == 8 * (1 + 1 + 2)  # /t + motor.position + 2 x master.position
    one_hour = int(3600 * RATE)
    need = w.estimated_bytes(one_hour)
    assert need >= one_hour * 32
    w.close()
    free = shutil.disk_usage(tmp_path).free
    with pytest.raises(RecordError, match=r"not enough disk space for \d+ samples: need about .* MiB .* free") as ei:
        _writer(path, planned_samples=free // 16)  # 32 B/sample: twice what the disk holds
    assert "\n" not in str(ei.value) and not path.exists()

    monkeypatch.setattr(record_mod.shutil, "disk_usage", lambda p: SimpleNamespace(free=need - 1))
    with pytest.raises(RecordError, match="not enough disk space"):
        _writer(path, planned_samples=one_hour)
    monkeypatch.setattr(record_mod.shutil, "disk_usage", lambda p: SimpleNamespace(free=need))
    _writer(path, planned_samples=one_hour).close()  # exactly enough
    assert RunRecord.open(path).closed


FSIZE_CHILD = textwrap.dedent(
    """
    import resource, sys
    from hil.record.hdf5 import ChannelSpec, RecordError, RecordWriter
    resource.setrlimit(resource.RLIMIT_FSIZE, (1 << 20, resource.RLIM_INFINITY))
    try:
        RecordWriter(sys.argv[1], scene_text="", scene_sha256="", meta={}, rate_hz=1000.0,
                     channels={"x": ChannelSpec((), "m")}, planned_samples=3600 * 1000)
    except RecordError as exc:
        print(exc)
    """
)


@pytest.mark.timeout(60)
def test_planned_run_size_is_checked_against_the_file_size_limit(tmp_path: Path) -> None:
    script = tmp_path / "fsize.py"
    script.write_text(FSIZE_CHILD)
    p = subprocess.run([sys.executable, str(script), str(tmp_path / "r.h5")], capture_output=True, text=True,
                       timeout=60)
    assert p.returncode == 0, p.stderr
    assert "file-size limit (ulimit -f) 1.0 MiB is below the" in p.stdout
    assert not (tmp_path / "r.h5").exists()


# -- never overwrite -------------------------------------------------------------------------------------


@pytest.mark.timeout(60)
def test_an_existing_record_is_refused_unless_overwrite(tmp_path: Path) -> None:
    path = tmp_path / "r.h5"
    with _writer(path) as w:
        for k in range(10):
            w.append(k / RATE, _vals(k))
    with pytest.raises(RecordError) as ei:
        _writer(path)
    assert str(ei.value) == f"{path}: a record already exists; refusing to overwrite it"
    _check_exact(RunRecord.open(path), 10)  # untouched
    with pytest.raises(RecordError, match="is a directory"):
        _writer(tmp_path)
    with _writer(path, overwrite=True) as w:
        w.append(0.0, _vals(0))
    _check_exact(RunRecord.open(path), 1)


# -- truncated, garbage, empty, directory: the reader fails fast with one line ---------------------------


def _closed_record(path: Path) -> bytes:
    with _writer(path) as w:
        for k in range(3000):
            w.append(k / RATE, _vals(k))
        w.set_results("chirp", {"H": np.arange(5.0)})
    return path.read_bytes()


def _live_copy(tmp_path: Path) -> bytes:
    """The bytes of a record whose writer is still running (= a killed one): flagged open for SWMR write."""
    w = _writer(tmp_path / "live.h5")
    for k in range(3000):
        w.append(k / RATE, _vals(k))
    w.flush()
    data = (tmp_path / "live.h5").read_bytes()
    w.close()
    assert data[11] & 0b101  # the superblock's "open for (SWMR) write" flags
    return data


def _stored_end(data: bytes) -> int:
    """The end-of-file address in a version-2/3 superblock (8-byte offsets, base address 0)."""
    assert data[8] in (2, 3) and data[9] == 8
    return int.from_bytes(data[28:36], "little")


def _assert_one_line_record_error(path: Path) -> str:
    with pytest.raises(RecordError) as ei:
        RunRecord.open(path)
    msg = str(ei.value)
    assert str(path) in msg and "\n" not in msg
    return msg


@pytest.mark.timeout(60)
@pytest.mark.parametrize("source", ["closed", "killed"])
def test_truncated_records_fail_fast_with_one_line(tmp_path: Path, source: str) -> None:
    data = _closed_record(tmp_path / "c.h5") if source == "closed" else _live_copy(tmp_path)
    (tmp_path / "whole.h5").write_bytes(data)
    _check_exact(RunRecord.open(tmp_path / "whole.h5"), 3000)  # the uncut bytes read
    end = _stored_end(data)  # a live/killed file also holds the writer's disk reserve (zeros) past this
    assert len(data) >= end
    (tmp_path / "at_end.h5").write_bytes(data[:end])
    _check_exact(RunRecord.open(tmp_path / "at_end.h5"), 3000)
    for cut in (0, 8, 47, 100, 1000, 4096, end // 3, end // 2, end - 100, end - 1):
        path = tmp_path / f"cut_{cut}.h5"
        path.write_bytes(data[:cut])
        msg = _assert_one_line_record_error(path)
        assert ("empty file" if cut == 0 else "truncated HDF5 file") in msg


@pytest.mark.timeout(60)
def test_garbage_empty_directory_and_foreign_files_fail_fast(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    cases = {
        "garbage.h5": rng.integers(0, 256, 4096, dtype=np.uint8).tobytes(),
        "text.h5": b"name: not a record\n",
        "empty.h5": b"",
        "sig_only.h5": b"\x89HDF\r\n\x1a\n",
        "sig_garbage.h5": b"\x89HDF\r\n\x1a\n" + rng.integers(0, 256, 4096, dtype=np.uint8).tobytes(),
    }
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
        _assert_one_line_record_error(tmp_path / name)
    assert "is a directory" in _assert_one_line_record_error(tmp_path)
    with h5py.File(tmp_path / "foreign.h5", "w") as f:
        f["x"] = np.arange(3)
    assert "not a hil-record file" in _assert_one_line_record_error(tmp_path / "foreign.h5")


@pytest.mark.timeout(120)
def test_damaged_metadata_of_a_killed_record_fails_fast(tmp_path: Path) -> None:
    # SWMR-read mode retries every failed metadata checksum (HDF5's default: 100 times with back-off,
    # minutes per file): the reader caps the attempts, so damage is an error (or, when only sample
    # bytes are hit, a record) within the timeout
    data = _live_copy(tmp_path)
    rng = random.Random(7)
    outcomes = set()
    for i in range(12):
        bad = bytearray(data)
        off = rng.randrange(48, 4096)
        bad[off:off + 64] = bytes(rng.randrange(256) for _ in range(64))
        path = tmp_path / f"bad{i}.h5"
        path.write_bytes(bytes(bad))
        try:
            RunRecord.open(path)
            outcomes.add("read")
        except RecordError as exc:
            assert str(path) in str(exc) and "\n" not in str(exc)
            outcomes.add("error")
    assert "error" in outcomes


@pytest.mark.timeout(120)
def test_cli_replay_and_identify_on_a_truncated_record_exit_2_with_one_line(tmp_path: Path) -> None:
    data = _live_copy(tmp_path)
    path = tmp_path / "trunc.h5"
    path.write_bytes(data[: _stored_end(data) // 2])
    for argv in (["replay", str(path)], ["replay", str(path), "--json"], ["identify", str(path)]):
        p = subprocess.run([sys.executable, "-m", "hil.cli.main", *argv], capture_output=True, text=True, timeout=60)
        assert p.returncode == 2, (argv, p.stderr)
        lines = p.stderr.strip().splitlines()
        assert len(lines) == 1 and str(path) in lines[0] and "truncated HDF5 file" in lines[0], (argv, p.stderr)


# -- faults are evidence: per-device counters -------------------------------------------------------------


@pytest.mark.timeout(60)
def test_device_counters_are_stored_and_shown_by_replay(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "c.h5"
    with _writer(path) as w:
        w.set_device_counters({"odrive0": {"crc_errors": 1}})
        for k in range(150):
            w.append(k / RATE, _vals(k))
        numpy_counts: Any = {"odrive0": {"crc_errors": 3, "resyncs": 1, "dropped": 0, "late": 2, "stale": 0,
                                         "retries": np.int64(7)},
                             "bota": {"crc_errors": 0}}
        w.set_device_counters(numpy_counts)
        with pytest.raises(RecordError, match="counter 'late' must be an integer"):
            w.set_device_counters({"odrive0": {"late": 1.5}})  # type: ignore[dict-item]  # the bad input tested
        with pytest.raises(RecordError, match="counters must be a mapping"):
            w.set_device_counters({"odrive0": 3})  # type: ignore[dict-item]  # the bad input tested
    rec = RunRecord.open(path)
    want = {"odrive0": {"crc_errors": 3, "resyncs": 1, "dropped": 0, "late": 2, "stale": 0, "retries": 7},
            "bota": {"crc_errors": 0}}
    assert rec.device_counters == want  # the last snapshot
    assert hil_main(["replay", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["device_counters"] == want
    assert hil_main(["replay", str(path)]) == 0
    text = capsys.readouterr().out
    assert "device counters:" in text
    assert "odrive0: crc_errors=3  resyncs=1  dropped=0  late=2  stale=0  retries=7" in text
    assert "bota: crc_errors=0" in text
    # a record without counters says nothing about them
    _closed_record(tmp_path / "none.h5")
    assert RunRecord.open(tmp_path / "none.h5").device_counters == {}
    assert hil_main(["replay", str(tmp_path / "none.h5")]) == 0
    assert "device counters" not in capsys.readouterr().out


@pytest.mark.timeout(60)
def test_format_1_records_still_read(tmp_path: Path) -> None:
    # the layout before format 2: /status and /results/<experiment> groups written at close
    path = tmp_path / "v1.h5"
    with h5py.File(path, "w", libver="latest") as f:
        f.attrs.update({"format": "hil-record", "format_version": 1, "rate_hz": 1000.0, "meta": "{}",
                        "scene_sha256": ""})
        f.create_dataset("scene", data="", dtype=h5py.string_dtype("utf-8"))
        f["t"] = np.arange(4) / 1000
        f.create_group("channels")["x"] = np.arange(4.0)
        f["events"] = np.frombuffer(b'{"t": 0.0, "kind": "k", "message": "m"}\n', dtype=np.uint8)
        f.create_group("results/chirp").attrs["json"] = json.dumps({"f": {"__dataset__": "f"}, "ok": True})
        f["results/chirp/f"] = np.array([1.0, 2.0])
        st = f.create_group("status")
        st.attrs.update({"stop_reason": "completed", "status": "ok"})
    rec = RunRecord.open(path)
    assert (rec.status, rec.stop_reason) == ("ok", "completed")
    assert rec.results["chirp"]["ok"] is True
    np.testing.assert_array_equal(rec.results["chirp"]["f"], [1.0, 2.0])
    assert rec.events == [{"t": 0.0, "kind": "k", "message": "m"}] and rec.t.size == 4


@pytest.mark.timeout(120)
def test_identify_loader_gives_one_line_for_unreadable_mat_npz_csv_and_h5(tmp_path: Path) -> None:
    from hil.identify.api import load_record

    scipy_io = pytest.importorskip("scipy.io")
    t = np.arange(500) / 1000
    scipy_io.savemat(tmp_path / "ok.mat", {"t": t, "x": np.sin(t)})
    np.savez(tmp_path / "ok.npz", t=t, x=np.sin(t))
    mat, npz = (tmp_path / "ok.mat").read_bytes(), (tmp_path / "ok.npz").read_bytes()
    h5 = _live_copy(tmp_path)
    cases = {"empty.mat": b"", "half.mat": mat[: len(mat) // 2], "half.npz": npz[: len(npz) // 2],
             "binary.csv": bytes(range(256)) * 8, "half.h5": h5[: _stored_end(h5) // 2], "empty.h5": b""}
    for name, data in cases.items():
        path = tmp_path / name
        path.write_bytes(data)
        with pytest.raises(HilError) as ei:
            load_record(path)
        assert str(path) in str(ei.value) and "\n" not in str(ei.value), name
