"""Importers of other tools' formats (hil.record.importers, issue 30): files written with the formats' own
libraries, imported, compared with the truth they were written from."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hil.record.hdf5 import RecordError, RunRecord
from hil.record.importers import describe, import_file, importer_for, importers

RATE = 1000.0
N = 600


def _truth() -> tuple[np.ndarray, dict[str, np.ndarray]]:
    rng = np.random.default_rng(7)
    t = np.arange(N) / RATE
    return t, {"pos": np.sin(2 * np.pi * 3 * t) + 1e-3 * rng.standard_normal(N),
               "vel": 6 * np.pi * np.cos(2 * np.pi * 3 * t), "tau": rng.standard_normal(N),
               "q": rng.standard_normal((N, 2))}


def test_registry_has_one_importer_per_format() -> None:
    regs = importers()
    assert {"csv", "mat", "hdf5", "tdms", "rosbag", "mcap"} <= set(regs)
    for name, suffix in (("csv", "a.csv"), ("csv", "a.TSV"), ("mat", "a.mat"), ("hdf5", "a.hdf5"),
                         ("tdms", "a.tdms"), ("rosbag", "a.bag"), ("mcap", "a.mcap")):
        assert importer_for(Path(suffix)).name == name
    with pytest.raises(RecordError, match=r"not a format hil import reads .*\.tdms"):
        importer_for(Path("a.xlsx"))


# ------------------------------------------------------------------------------------------------ HDF5


@pytest.mark.timeout(60)
def test_hdf5_by_dataset_path(tmp_path: Path) -> None:
    import h5py

    t, d = _truth()
    with h5py.File(tmp_path / "log.h5", "w") as f:
        g = f.create_group("bench")
        g["time"] = t
        g["pos"] = d["pos"] * 1e3
        g["pos"].attrs["units"] = "mm"  # the file states its unit: converted to m
        g["q"] = d["q"].T  # column-major writer: (2, n)
        f["other/tau"] = d["tau"]
    out = import_file(tmp_path / "log.h5", tmp_path / "r.h5",
                      mapping={"motor.position": "/bench/pos", "master.position": "/bench/q",
                               "motor.effort_cmd": "/other/tau", "slave.position": "/bench/q[1]"})
    rec = RunRecord.open(out)
    np.testing.assert_array_equal(rec.t, t)  # the one dataset named time is the default time
    np.testing.assert_allclose(rec.channels["motor.position"], d["pos"], rtol=1e-15)
    np.testing.assert_array_equal(rec.channels["master.position"], d["q"])
    np.testing.assert_array_equal(rec.channels["slave.position"], d["q"][:, 1])
    np.testing.assert_array_equal(rec.channels["motor.effort_cmd"], d["tau"])
    assert rec.units["motor.position"] == "m" and rec.meta["imported_from"]["format"] == "hdf5"
    fmt, rows = describe(tmp_path / "log.h5")
    assert fmt == "hdf5"
    assert {r.source for r in rows} == {"/bench/time", "/bench/pos", "/bench/q", "/other/tau"}
    assert next(r for r in rows if r.source == "/bench/pos").unit == "mm"
    with pytest.raises(RecordError, match=r"no dataset '/bench/nope'"):
        import_file(tmp_path / "log.h5", tmp_path / "x.h5", mapping={"motor.position": "/bench/nope"})
    with pytest.raises(RecordError, match=r"name the channels to import: hil import log.h5 --map"):
        import_file(tmp_path / "log.h5", tmp_path / "x.h5")


def test_list_prints_the_sources(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from hil.cli.main import main

    t, d = _truth()
    np.savetxt(tmp_path / "a.csv", np.column_stack([t, d["pos"]]), delimiter=",", header="time,pos", comments="",
               fmt="%.17g")
    assert main(["import", str(tmp_path / "a.csv"), "--list"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].endswith("(csv): 2 source(s)")
    row = next(ln for ln in out if ln.startswith("time"))
    assert "600" in row and "1000" in row and "time (default)" in row
    assert not (tmp_path / "a.h5").exists()


# ------------------------------------------------------------------------------------------------ TDMS


def _hold(t_slow: np.ndarray, v_slow: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Zero-order hold written out independently of the importer: for each t, the slow sample with the
    largest time <= t (a loop over the samples)."""
    out = np.empty(t.size)
    j = 0
    for i, ti in enumerate(t):
        while j + 1 < t_slow.size and t_slow[j + 1] <= ti + 1e-12:
            j += 1
        out[i] = v_slow[j]
    return out


@pytest.mark.timeout(60)
def test_tdms_waveforms_at_two_rates(tmp_path: Path) -> None:
    nptdms = pytest.importorskip("nptdms", reason="the 'formats' extra is not installed")
    from hil.identify.sensor_hold import age_distribution

    t, d = _truth()
    t_slow = np.arange(N // 4) / (RATE / 4)
    f_slow = np.random.default_rng(3).standard_normal(t_slow.size)  # no two equal neighbours
    start = np.datetime64("2024-05-02T10:00:00")
    objs = [nptdms.RootObject({"operator": "lab"}), nptdms.GroupObject("Bench"),
            nptdms.ChannelObject("Bench", "Position", d["pos"] * 1e3,
                                 properties={"wf_increment": 1 / RATE, "wf_start_offset": 0.0, "unit_string": "mm",
                                             "wf_start_time": start}),
            nptdms.ChannelObject("Bench", "Torque cmd", d["tau"],
                                 properties={"wf_increment": 1 / RATE, "wf_start_offset": 0.0, "unit_string": "N.m"}),
            nptdms.ChannelObject("Force sensor", "Fz", f_slow,
                                 properties={"wf_increment": 4 / RATE, "wf_start_offset": 0.0, "unit_string": "N"})]
    with nptdms.TdmsWriter(tmp_path / "run.tdms") as w:
        w.write_segment(objs)
    rec = RunRecord.open(import_file(tmp_path / "run.tdms", tmp_path / "r.h5", mapping={
        "motor.position": "Bench/Position", "motor.effort_cmd": "'Bench'/'Torque cmd'",
        "spring_ft.wrench": "Force sensor/Fz"}))
    np.testing.assert_allclose(rec.t, t, rtol=0, atol=1e-12)
    np.testing.assert_allclose(rec.channels["motor.position"], d["pos"], rtol=1e-15)
    np.testing.assert_array_equal(rec.channels["motor.effort_cmd"], d["tau"])
    np.testing.assert_array_equal(rec.channels["spring_ft.wrench"], _hold(t_slow, f_slow, t))
    assert rec.units == {"motor.position": "m", "motor.effort_cmd": "N.m", "spring_ft.wrench": "N"}
    meta = rec.meta
    assert meta["held_channels"] == ["spring_ft.wrench"]
    rs = meta["imported_from"]["resampling"]["spring_ft.wrench"]
    assert rs["held"] and rs["source_rate_hz"] == pytest.approx(250.0)
    assert "2024-05-02T10:00:00" in meta["imported_from"]["wf_start_time"]["motor.position"]
    # the identification sees the 250 Hz sensor as held: ages 0, 1, 2, 3 ticks, a quarter each
    np.testing.assert_allclose(age_distribution(rec.channels["spring_ft.wrench"]), [0.25] * 4, atol=1 / N)
    assert age_distribution(rec.channels["motor.position"]) is None
    fmt, rows = describe(tmp_path / "run.tdms")
    assert fmt == "tdms" and [r.source for r in rows] == ["Bench/Position", "Bench/Torque cmd", "Force sensor/Fz"]
    assert rows[0].rate_hz == pytest.approx(RATE) and rows[0].unit == "mm" and rows[2].rate_hz == pytest.approx(250.0)
    with pytest.raises(RecordError, match=r"no channel 'Bench/Nope'"):
        import_file(tmp_path / "run.tdms", tmp_path / "x.h5", mapping={"motor.position": "Bench/Nope"})

    # a time channel instead of waveform timing (--time GROUP/CHANNEL), time in ms
    with nptdms.TdmsWriter(tmp_path / "tc.tdms") as w:
        w.write_segment([nptdms.ChannelObject("Log", "Time", t * 1e3), nptdms.ChannelObject("Log", "x", d["vel"])])
    rec = RunRecord.open(import_file(tmp_path / "tc.tdms", tmp_path / "tc.h5", mapping={"t": "Log/Time",
                                     "motor.velocity": "Log/x"}, units={"t": "ms"}))
    np.testing.assert_allclose(rec.t, t, rtol=1e-15, atol=1e-15)
    np.testing.assert_array_equal(rec.channels["motor.velocity"], d["vel"])
    with pytest.raises(RecordError, match=r"no waveform timing .*--time GROUP/CHANNEL"):
        import_file(tmp_path / "tc.tdms", tmp_path / "x.h5", mapping={"motor.velocity": "Log/x"})
