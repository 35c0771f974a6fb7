"""A record writer process that freezes or dies (issue 27 item 6).

Before: a writer process stopped with SIGSTOP made ``hil run`` wait about 51 s (five waits of
``writer_timeout_s`` in a row), left the record unclosed, and outlived ``hil run`` holding its
stdout/stderr (a CI job reading them blocked until SIGCONT); a writer killed with SIGKILL left the
reason only on stderr. Now a call the process does not answer within ``writer_timeout_s`` kills
it (SIGKILL also ends a stopped process), the record holds the samples of its last flushed block,
and its ``/status`` says so (written directly at the fixed offset of ``/status``'s bytes, since
nothing holds the file any more); the process never has the caller's stdout/stderr.

No wall-clock time is asserted: the waits that matter are counted (calls of the bounded wait), and
the test's own timeout only catches a hang.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hil.record.hdf5 import ChannelSpec, RecordLagError, RecordWriteError, RecordWriter, RunRecord

pytestmark = pytest.mark.timeout(180)

RATE = 1000.0
BLOCK = 100
CHANNELS = {"x": ChannelSpec((), "m")}


def _writer(path: Path, **kw: Any) -> RecordWriter:
    return RecordWriter(path, scene_text="name: lost\n", scene_sha256="x", meta={}, channels=CHANNELS, rate_hz=RATE,
                        flush_every_s=0.1, background="process", **kw)


def _fill(w: RecordWriter, start: int, stop: int) -> int:
    """Append samples start..stop-1 until the writer refuses; returns the next sample index."""
    k = start
    try:
        for k in range(start, stop):
            w.append(k / RATE, {"x": math.sin(k)})
        k = stop
    except (RecordLagError, RecordWriteError):
        pass
    return k


def _fd_target(pid: int, fd: int) -> str:
    return os.readlink(f"/proc/{pid}/fd/{fd}")


def test_the_writer_process_never_holds_the_callers_stdout_or_stderr(tmp_path: Path) -> None:
    w = _writer(tmp_path / "fds.h5")
    try:
        pid = w._proc.pid
        for fd in (1, 2):  # ours may be a terminal or a pipe a CI job reads until every holder closes it
            assert _fd_target(pid, fd) != _fd_target(os.getpid(), fd)
        assert _fd_target(pid, 1) == "/dev/null"
    finally:
        w.close()


def test_a_frozen_writer_process_is_killed_and_the_record_says_what_it_holds(tmp_path: Path) -> None:
    path = tmp_path / "frozen.h5"
    w = _writer(path, writer_timeout_s=1.0)
    pid = w._proc.pid
    _fill(w, 0, 2 * BLOCK)
    w.flush()  # 200 samples on disk
    os.kill(pid, signal.SIGSTOP)
    nxt = _fill(w, 2 * BLOCK, 50 * BLOCK)  # a lag error once the blocks in shared memory are all queued
    assert 2 * BLOCK < nxt < 50 * BLOCK
    with pytest.raises(RecordWriteError) as ei:
        w.close("safety_stop: test", "safety_stop")
    assert "did not answer within 1 s and was killed" in str(ei.value)
    assert w._proc.poll() == -signal.SIGKILL  # never left frozen behind the caller
    rec = RunRecord.open(path)
    assert rec.t.size == 2 * BLOCK and rec.closed and rec.status == "safety_stop"
    assert "did not answer within 1 s and was killed" in rec.stop_reason
    assert f"the record holds the {2 * BLOCK} samples of its last flushed block" in rec.stop_reason
    assert f"the {w.samples - 2 * BLOCK} samples taken after it are not in it" in rec.stop_reason
    np.testing.assert_array_equal(rec.channels["x"], np.sin(np.arange(2 * BLOCK)))


def test_a_sigkilled_writer_process_leaves_its_reason_in_the_record(tmp_path: Path) -> None:
    path = tmp_path / "killed.h5"
    w = _writer(path)
    _fill(w, 0, 3 * BLOCK)
    w.flush()
    os.kill(w._proc.pid, signal.SIGKILL)
    w._proc.wait(20)
    _fill(w, 3 * BLOCK, 6 * BLOCK)
    with pytest.raises(RecordWriteError):
        w.close()
    rec = RunRecord.open(path)
    assert rec.t.size == 3 * BLOCK and rec.closed and rec.status == "error"
    assert rec.stop_reason.startswith("record writer process was killed by SIGKILL")
    assert f"holds the {3 * BLOCK} samples of its last flushed block" in rec.stop_reason


def test_a_writer_that_dies_at_start_up_says_why_in_one_line_and_prints_nothing(tmp_path: Path) -> None:
    """The shared memory gone before the process opens it (its creator was killed during the
    start-up): before, the writer printed a FileNotFoundError traceback on the caller's terminal."""
    code = """
import sys
from hil.record import hdf5
from multiprocessing import shared_memory
orig = shared_memory.SharedMemory.__init__
def init(self, name=None, create=False, size=0, **kw):
    orig(self, name=name, create=create, size=size, **kw)
    if create:
        self.unlink()  # as the resource tracker does when the creator dies
shared_memory.SharedMemory.__init__ = init
try:
    hdf5.RecordWriter(sys.argv[1], scene_text="", scene_sha256="", meta={},
                      channels={"x": hdf5.ChannelSpec((), "m")}, rate_hz=100.0, background="process")
except hdf5.RecordWriteError as exc:
    print("ERR", exc)
"""
    p = subprocess.run([sys.executable, "-c", code, str(tmp_path / "s.h5")], capture_output=True, text=True,
                       timeout=120)
    assert "Traceback" not in p.stderr and "Traceback" not in p.stdout, p.stderr
    lines = p.stdout.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ERR ") and "FileNotFoundError" in lines[0], p.stdout


# ---------------------------------------------------------------------------------------------
# hil run --realtime with the writer process frozen (SIGSTOP) mid-run


def _children(pid: int) -> list[int]:
    out = []
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                with open(f"/proc/{d}/stat") as f:
                    if int(f.read().rsplit(")", 1)[1].split()[1]) == pid:
                        out.append(int(d))
            except (OSError, ValueError, IndexError):
                continue
    return out


def _cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


@pytest.mark.slow
def test_hil_run_with_a_frozen_writer_ends_with_the_reason_in_the_record_and_frees_its_pipes(tmp_path: Path) -> None:
    import time

    import yaml

    from hil.scene.spec import load_scene

    d = yaml.safe_load(load_scene("sdea_bench").source_text)
    d["experiments"] = d["experiments"][:1]
    d["experiments"][0]["duration"] = 30.0
    d.pop("certification", None)
    # on a loaded machine the loop must not stop on its own first (lateness, a slow device)
    d["safety"].update(max_overrun_fraction=1.0, max_lateness_ms=10_000, watchdog_ms=5_000)
    scene = tmp_path / "long.yaml"
    scene.write_text(yaml.safe_dump(d, sort_keys=False), encoding="utf-8")
    out = tmp_path / "run"
    p = subprocess.Popen([sys.executable, "-m", "hil", "run", str(scene), "--realtime", "--out", str(out), "--json"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    writer = None
    end = time.monotonic() + 120
    while writer is None and time.monotonic() < end and p.poll() is None:  # a hang guard, not a time bound
        writer = next((c for c in _children(p.pid) if "_writer_process_entry" in _cmdline(c)), None)
        time.sleep(0.05)
    assert writer is not None, "no writer process found"
    records = out / "00_chirp_locked.h5"
    # Freeze the writer once hil run holds a flushed block (a state, not a time). Each block is one call
    # to the writer process that starts by reserving disk for the block past HDF5's end of file: the
    # file grows (past the ~20 kB of a new record's metadata) at the start of every block's call, and
    # the next call is sent only after the previous one answered. So a second growth means the first
    # block was flushed and acknowledged. (Freezing at the first growth could stop the writer inside
    # the first block's call: nothing flushed, an empty record.)
    grown: list[int] = []
    while time.monotonic() < end and len(grown) < 2 and p.poll() is None:  # a hang guard, not a time bound
        size = records.stat().st_size if records.exists() else 0
        if size >= 200_000 and (not grown or size > grown[-1]):
            grown.append(size)
        time.sleep(0.01)
    assert len(grown) == 2 and p.poll() is None, (grown, p.poll())
    os.kill(writer, signal.SIGSTOP)
    try:
        # communicate() returns only once every holder of hil's stdout/stderr has closed them: before,
        # the frozen writer held them until someone sent SIGCONT
        _, stderr = p.communicate(timeout=120)
    finally:
        with contextlib_suppress():
            os.kill(writer, signal.SIGKILL)
    assert p.returncode == 20, stderr.decode()
    assert not os.path.exists(f"/proc/{writer}")  # killed and reaped by hil run, not left frozen
    rec = RunRecord.open(records)
    assert rec.closed and rec.status == "safety_stop", rec.stop_reason
    assert "record writer process did not answer within" in rec.stop_reason and "last flushed block" in rec.stop_reason
    assert rec.t.size > 0 and np.all(np.diff(rec.t) > 0)


def contextlib_suppress():
    import contextlib

    return contextlib.suppress(OSError)
