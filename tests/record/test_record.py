"""Run records (hil.record.hdf5): round trip, flush cadence, errors, crash safety under SIGKILL, summary, replay."""

from __future__ import annotations

import hashlib
import json
import math
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest

from hil.cli.main import main as hil_main
from hil.record.hdf5 import FORMAT_VERSION, ChannelSpec, RecordError, RecordWriter, RunRecord

SCENE = "name: bench\n# µ-scene with unicode: Ω\nrate_hz: 1000\n"
SHA = hashlib.sha256(SCENE.encode()).hexdigest()


def _channels() -> dict[str, ChannelSpec]:
    return {
        "motor.position": ChannelSpec((), "rad", "encoder"),
        "master.position": ChannelSpec((2,), "rad", "two joints"),
        "operator.energy": ChannelSpec((1,), "J"),
        "loop.overrun": ChannelSpec((), "1"),
        "loop.latency": ChannelSpec((), "s"),
    }


def _writer(path: Path, **kw) -> RecordWriter:
    args = {"scene_text": SCENE, "scene_sha256": SHA, "channels": _channels(), "rate_hz": 1000.0,
            "meta": {"seed": 7, "devices": {"motor": {"driver": "odrive_can", "serial": "0x1234"}}}}
    args.update(kw)
    return RecordWriter(path, **args)


def _values(k: int) -> dict[str, object]:
    return {
        "motor.position": math.sin(0.01 * k),
        "master.position": np.array([k / 7, -3.25 * k]),
        "operator.energy": 0.5 * k,  # a float for a (1,) channel is accepted
        "loop.overrun": float(k % 13 == 0),
        "loop.latency": 1e-4 * (k % 5),
    }


@pytest.mark.timeout(60)
def test_clean_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    n = 1234
    with _writer(path) as w:
        assert w.flush_samples == 100
        for k in range(n):
            vals = _values(k)
            if k == 10:
                del vals["motor.position"]  # missing channel -> NaN
            w.append(k / 1000, vals)
        w.event(0.5, "experiment", "chirp started")
        w.event(1.0, "safety", "max_velocity: 21 > 20 rad/s")
        assert w.samples == n and w.samples_flushed == 1200  # 34 samples still buffered
        w.set_results("chirp", {"f": np.linspace(1, 10, 4), "H": np.array([1 + 2j, 3 - 1j]),
                                "nested": {"gain": np.float64(2.5), "ok": True, "names": ["a", "b"]}})
        assert w.samples_flushed == n  # set_results writes at once (and the buffered samples with it)
    rec = RunRecord.open(path)
    assert rec.status == "ok" and rec.stop_reason == "completed" and rec.closed
    assert rec.scene_text == SCENE and rec.scene_sha256 == SHA
    assert rec.meta == {"seed": 7, "devices": {"motor": {"driver": "odrive_can", "serial": "0x1234"}}}
    assert rec.rate_hz == 1000.0
    np.testing.assert_array_equal(rec.t, np.arange(n) / 1000)
    mp = np.array([math.sin(0.01 * k) for k in range(n)])
    mp[10] = np.nan
    np.testing.assert_array_equal(rec.channels["motor.position"], mp)
    np.testing.assert_array_equal(rec.channels["master.position"],
                                  np.column_stack([np.arange(n) / 7, -3.25 * np.arange(n)]))
    assert rec.channels["operator.energy"].shape == (n, 1)
    np.testing.assert_array_equal(rec.channels["operator.energy"][:, 0], 0.5 * np.arange(n))
    assert list(rec.channels) == list(_channels())  # declaration order kept
    assert rec.units == {k: s.unit for k, s in _channels().items()}
    assert rec.descriptions["master.position"] == "two joints"
    assert rec.events == [{"t": 0.5, "kind": "experiment", "message": "chirp started"},
                          {"t": 1.0, "kind": "safety", "message": "max_velocity: 21 > 20 rad/s"}]
    res = rec.results["chirp"]
    np.testing.assert_array_equal(res["f"], np.linspace(1, 10, 4))
    np.testing.assert_array_equal(res["H"], np.array([1 + 2j, 3 - 1j]))
    assert res["nested"] == {"gain": 2.5, "ok": True, "names": ["a", "b"]}
    with h5py.File(path, "r") as f:  # the documented layout
        assert f.attrs["format"] == "hil-record" and f.attrs["format_version"] == FORMAT_VERSION
        assert f.attrs["seed"] == 7 and f.attrs["rate_hz"] == 1000.0
        for pkg in ("hil", "numpy", "scipy", "h5py", "python"):
            assert f.attrs[f"software.{pkg}"]
        assert f["scene"][()].decode() == SCENE
        assert f["t"].chunks is not None and f["t"].maxshape == (None,)
        assert f["channels/master.position"].maxshape == (None, 2)
        assert f["channels/motor.position"].attrs["unit"] == "rad"
        assert f["status"].shape == (1024,)  # fixed, written in place at close
        status = json.loads(bytes(f["status"][:]).rstrip(b"\0"))
        assert (status["status"], status["stop_reason"], status["samples"]) == ("ok", "completed", n)
        line = json.loads(bytes(f["results"][:]).decode())
        assert line["experiment"] == "chirp" and set(line["arrays"]) == {"f", "H"}
        for name in ("results_npy", "device_counters", "events"):
            assert f[name].dtype == np.uint8 and f[name].maxshape == (None,)


@pytest.mark.timeout(60)
def test_flush_cadence_by_samples_and_run_time(tmp_path: Path) -> None:
    with _writer(tmp_path / "a.h5", rate_hz=500.0, flush_every_s=0.05) as w:
        assert w.flush_samples == 25
        for k in range(24):
            w.append(k / 500, {})
        assert w.samples_flushed == 0
        w.append(24 / 500, {})
        assert w.samples_flushed == 25 and w.flushes == 1
        # a stalled loop: run time jumps by >= flush_every_s, so the next sample flushes early
        w.append(1.0, {})
        w.append(1.06, {})
        assert w.samples_flushed == 27 and w.flushes == 2
    rec = RunRecord.open(tmp_path / "a.h5")
    assert rec.t.size == 27 and np.all(np.isnan(rec.channels["master.position"]))


@pytest.mark.timeout(60)
def test_append_errors_and_idempotent_close(tmp_path: Path) -> None:
    w = _writer(tmp_path / "e.h5")
    with pytest.raises(RecordError, match=r"master\.position.*expected shape \(2,\), got \(3,\)"):
        w.append(0.0, {"master.position": np.zeros(3)})
    with pytest.raises(RecordError, match=r"unknown channel 'motr\.position'"):
        w.append(0.0, {"motr.position": 1.0})
    with pytest.raises(RecordError, match=r"motor\.position.*not numeric"):
        w.append(0.0, {"motor.position": "x"})
    w.append(0.0, {"motor.position": 1.0})
    with pytest.raises(RecordError, match="not after the previous"):
        w.append(0.0, {"motor.position": 2.0})
    with pytest.raises(RecordError, match="result obj: object is not JSON-serializable"):
        w.set_results("x", {"obj": object()})
    with pytest.raises(RecordError, match="experiment name 'a/b'"):
        w.set_results("a/b", {})
    w.close("first", "ok")
    w.close("second", "error")  # no-op
    with pytest.raises(RecordError, match="closed"):
        w.append(1.0, {})
    rec = RunRecord.open(tmp_path / "e.h5")
    assert (rec.stop_reason, rec.status) == ("first", "ok")
    assert rec.t.tolist() == [0.0] and rec.channels["motor.position"].tolist() == [1.0]
    with pytest.raises(RecordError, match="not JSON-serializable"):
        _writer(tmp_path / "m.h5", meta={"bad": object()})


@pytest.mark.timeout(60)
def test_exception_inside_with_closes_as_error_and_keeps_samples(tmp_path: Path) -> None:
    path = tmp_path / "x.h5"
    with pytest.raises(ZeroDivisionError), _writer(path) as w:
        for k in range(150):  # 100 flushed + 50 buffered
            w.append(k / 1000, _values(k))
        w.event(0.149, "note", "about to fail")
        raise ZeroDivisionError("controller diverged at t=0.149 s")
    rec = RunRecord.open(path)
    assert rec.status == "error" and rec.stop_reason == "controller diverged at t=0.149 s"
    np.testing.assert_array_equal(rec.t, np.arange(150) / 1000)
    assert rec.channels["loop.latency"][149] == 1e-4 * (149 % 5)
    assert rec.events[0]["message"] == "about to fail"


# -- crash safety: a child writes at a fixed run-time pace and is killed with SIGKILL -------------------

CHILD = textwrap.dedent(
    """
    import math, sys, time
    import numpy as np
    from hil.record.hdf5 import ChannelSpec, RecordWriter
    path, pause_at = sys.argv[1], int(sys.argv[2])
    ch = {"motor.position": ChannelSpec((), "rad"), "master.position": ChannelSpec((2,), "rad")}
    w = RecordWriter(path, scene_text="name: kill\\n", scene_sha256="x", meta={"seed": 1}, channels=ch,
                     rate_hz=1000.0, flush_every_s=0.02)
    start = time.monotonic()
    flushed = 0
    for k in range(10**7):
        t = k / 1000
        w.append(t, {"motor.position": math.sin(0.01 * k), "master.position": [k / 7, -3.25 * k]})
        if k in (50, 105):
            w.event(t, "mark", f"k={k}")
        if w.samples_flushed != flushed:
            flushed = w.samples_flushed
            print("F", flushed, flush=True)
        if pause_at and w.samples == pause_at:
            print("P", w.samples_flushed, flush=True)
            time.sleep(60)
        if k % 10 == 9:  # run time follows wall time (a 1 kHz loop)
            time.sleep(max(0.0, start + t - time.monotonic()))
    """
)


def _run_and_kill(tmp_path: Path, pause_at: int, min_flushed: int) -> tuple[RunRecord, int]:
    path = tmp_path / "killed.h5"
    script = tmp_path / "child.py"
    script.write_text(CHILD)
    p = subprocess.Popen([sys.executable, str(script), str(path), str(pause_at)], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    last = 0
    try:
        while True:
            line = p.stdout.readline()
            assert line, f"child ended early: {p.stderr.read()}"
            kind, num = line.split()
            last = int(num)
            if (pause_at and kind == "P") or (not pause_at and last >= min_flushed):
                break
        os.kill(p.pid, signal.SIGKILL)
    finally:
        p.wait(timeout=30)
        p.stdout.close()
        p.stderr.close()
    assert p.returncode == -signal.SIGKILL
    return RunRecord.open(path), last


def _check_exact(rec: RunRecord) -> None:
    n = rec.t.size
    k = np.arange(n)
    np.testing.assert_array_equal(rec.t, k / 1000)
    assert np.all(np.diff(rec.t) > 0)
    np.testing.assert_array_equal(rec.channels["motor.position"], [math.sin(0.01 * i) for i in range(n)])
    np.testing.assert_array_equal(rec.channels["master.position"], np.column_stack([k / 7, -3.25 * k]))


@pytest.mark.timeout(60)
def test_sigkill_while_streaming_keeps_every_flushed_sample(tmp_path: Path) -> None:
    rec, last = _run_and_kill(tmp_path, pause_at=0, min_flushed=100)  # >= 5 flushes of 20 samples
    assert rec.stop_reason is None and rec.status is None and not rec.closed
    assert rec.t.size >= last >= 100
    _check_exact(rec)
    assert rec.events[0] == {"t": 0.05, "kind": "mark", "message": "k=50"}
    assert rec.scene_text == "name: kill\n" and rec.meta == {"seed": 1}
    assert rec.summary()["closed"] is False


@pytest.mark.timeout(60)
def test_sigkill_loses_only_the_unflushed_buffer(tmp_path: Path) -> None:
    # killed while idle with 110 samples appended: 100 flushed (5 x 20), 10 buffered in memory
    rec, flushed = _run_and_kill(tmp_path, pause_at=110, min_flushed=0)
    assert flushed == 100
    assert rec.t.size == 100 and rec.stop_reason is None
    _check_exact(rec)
    assert [e["message"] for e in rec.events] == ["k=50"]  # the k=105 event was still buffered


# -- summary, identification view, replay CLI ---------------------------------------------------------


def _small_record(path: Path) -> None:
    with _writer(path) as w:
        for k in range(100):
            w.append(k / 1000, _values(k))
        w.event(0.05, "safety", "stop")
        w.set_results("chirp", {"ok": True})


@pytest.mark.timeout(60)
def test_summary_and_identify_dict(tmp_path: Path) -> None:
    path = tmp_path / "s.h5"
    _small_record(path)
    rec = RunRecord.open(path)
    s = rec.summary()
    assert s["samples"] == 100 and s["duration_s"] == pytest.approx(0.099)
    assert s["measured_rate_hz"] == pytest.approx(1000.0)
    assert s["stop_reason"] == "completed" and s["experiments"] == ["chirp"] and s["event_kinds"] == {"safety": 1}
    mp = s["channels"]["master.position"]
    assert mp["unit"] == "rad" and mp["shape"] == [2]
    assert mp["min"] == [0.0, -3.25 * 99] and mp["max"] == [99 / 7, 0.0]
    assert s["channels"]["loop.latency"]["mean"] == pytest.approx(2e-4)
    assert s["loop"]["overrun_samples"] == 8  # k = 0, 13, ..., 91
    assert s["loop"]["latency_max"] == pytest.approx(4e-4) and s["loop"]["latency_unit"] == "s"

    d = rec.to_identify_dict(meta={"model": "mbk"}, t_range=(0.01, 0.05))
    assert set(d["signals"]) == {"motor.position", "master.position[0]", "master.position[1]",
                                 "operator.energy[0]", "loop.overrun", "loop.latency"}
    np.testing.assert_array_equal(d["t"], np.arange(10, 51) / 1000)
    np.testing.assert_array_equal(d["signals"]["master.position[1]"], -3.25 * np.arange(10, 51))
    assert all(v.ndim == 1 and v.size == 41 for v in d["signals"].values())
    assert d["meta"]["model"] == "mbk" and d["meta"]["seed"] == 7
    assert d["meta"]["channel_units"]["motor.position"] == "rad"


@pytest.mark.timeout(60)
def test_hil_replay(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "r.h5"
    _small_record(path)
    assert hil_main(["replay", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["samples"] == 100 and out["channels"]["motor.position"]["unit"] == "rad"
    assert hil_main(["replay", str(path)]) == 0
    text = capsys.readouterr().out
    assert "master.position" in text and "completed" in text

    assert hil_main(["replay", str(tmp_path / "missing.h5")]) == 2
    err = capsys.readouterr().err
    assert "no such file" in err and len(err.strip().splitlines()) == 1
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"not hdf5 at all")
    assert hil_main(["replay", str(junk)]) == 2
    assert "not an HDF5 file" in capsys.readouterr().err
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["x"] = 1
    assert hil_main(["replay", str(tmp_path / "other.h5")]) == 2
    assert "not a hil-record file" in capsys.readouterr().err
