"""Importers (hil.record.importers): CSV and .mat runs from the same data as a native run give the same record."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import scipy.io
import yaml

from hil.record.hdf5 import ChannelSpec, RecordError, RecordWriter, RunRecord
from hil.record.importers import import_csv, import_mat

RATE = 500.0
N = 400
UNITS = {"motor.position": "rad", "master.position": "rad", "loop.overrun": "1"}
MAPPING = {"t": "time", "motor.position": "pos", "master.position": ["q1", "q2"], "loop.overrun": "ovr",
           "units": UNITS}


def _data() -> tuple[np.ndarray, dict[str, np.ndarray]]:
    rng = np.random.default_rng(42)
    t = np.arange(N) / RATE
    return t, {
        "motor.position": rng.standard_normal(N),
        "master.position": rng.standard_normal((N, 2)) * 1e-3,
        "loop.overrun": (rng.random(N) < 0.05).astype(float),
    }


def _native(path: Path) -> RunRecord:
    t, d = _data()
    specs = {"motor.position": ChannelSpec((), "rad"), "master.position": ChannelSpec((2,), "rad"),
             "loop.overrun": ChannelSpec((), "1")}
    with RecordWriter(path, scene_text="", scene_sha256="", meta={}, channels=specs, rate_hz=RATE) as w:
        for k in range(N):
            w.append(t[k], {name: a[k] for name, a in d.items()})
    return RunRecord.open(path)


def _write_csv(path: Path, t: np.ndarray, d: dict[str, np.ndarray], header: str = "time,pos,q1,q2,ovr") -> None:
    cols = [t, d["motor.position"], d["master.position"][:, 0], d["master.position"][:, 1], d["loop.overrun"]]
    lines = [header] + [",".join(repr(float(c[k])) for c in cols) for k in range(t.size)]
    path.write_text("\n".join(lines) + "\n")


def _assert_same(a: RunRecord, b: RunRecord) -> None:
    np.testing.assert_array_equal(a.t, b.t)
    assert set(a.channels) == set(b.channels)
    for name in a.channels:
        assert a.channels[name].shape == b.channels[name].shape, name
        np.testing.assert_array_equal(a.channels[name], b.channels[name], err_msg=name)
    assert a.units == b.units
    assert a.rate_hz == pytest.approx(b.rate_hz)


@pytest.mark.timeout(60)
def test_csv_and_mat_imports_equal_native_record(tmp_path: Path) -> None:
    native = _native(tmp_path / "native.h5")
    t, d = _data()
    _write_csv(tmp_path / "run.csv", t, d)
    out = import_csv(tmp_path / "run.csv", tmp_path / "csv.h5", mapping=MAPPING, meta={"operator": "A"})
    rec = RunRecord.open(out)
    _assert_same(native, rec)
    assert rec.status == "ok" and rec.stop_reason == "imported"
    assert rec.meta["operator"] == "A" and rec.meta["imported_from"]["format"] == "csv"

    # .mat: separate variables, (n, 2) matrix mapped to the vector channel directly
    scipy.io.savemat(tmp_path / "vars.mat", {"time": t, "pos": d["motor.position"], "q": d["master.position"],
                                             "ovr": d["loop.overrun"]})
    m = {"t": "time", "motor.position": "pos", "master.position": "q", "loop.overrun": "ovr", "units": UNITS}
    _assert_same(native, RunRecord.open(import_mat(tmp_path / "vars.mat", tmp_path / "mat1.h5", mapping=m)))

    # .mat: one struct, vector channel from two column vectors
    scipy.io.savemat(tmp_path / "struct.mat", {"run": {"time": t[:, None], "pos": d["motor.position"][:, None],
                                                       "q1": d["master.position"][:, 0],
                                                       "q2": d["master.position"][:, 1],
                                                       "ovr": d["loop.overrun"]}})
    m2 = {"t": "run.time", "channels": {"motor.position": "run.pos", "master.position": ["run.q1", "run.q2"],
                                        "loop.overrun": {"column": "run.ovr", "unit": "1"}},
          "units": {"motor.position": "rad", "master.position": "rad"}}
    rec2 = RunRecord.open(import_mat(tmp_path / "struct.mat", tmp_path / "mat2.h5", mapping=m2))
    _assert_same(native, rec2)
    assert rec2.meta["imported_from"]["format"] == "mat"


@pytest.mark.timeout(60)
def test_sidecar_files(tmp_path: Path) -> None:
    native = _native(tmp_path / "native.h5")
    t, d = _data()
    _write_csv(tmp_path / "run.csv", t, d)
    (tmp_path / "map.json").write_text(json.dumps(MAPPING))
    _assert_same(native, RunRecord.open(import_csv(tmp_path / "run.csv", tmp_path / "a.h5",
                                                   sidecar=tmp_path / "map.json")))
    # a YAML sidecar next to the CSV is found automatically; time given in ms with a scale
    _write_csv(tmp_path / "ms.csv", t * 1000, d, header="time_ms;pos;q1;q2;ovr".replace(";", ","))
    side = {**MAPPING, "t": "time_ms", "scale": {"t": 1e-3}, "meta": {"rig": "sdea"}}
    (tmp_path / "ms.yaml").write_text(yaml.safe_dump(side))
    rec = RunRecord.open(import_csv(tmp_path / "ms.csv", tmp_path / "b.h5"))
    np.testing.assert_allclose(rec.t, t, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(rec.channels["master.position"], d["master.position"])
    assert rec.meta["rig"] == "sdea" and rec.units == UNITS
    with pytest.raises(RecordError, match="not both"):
        import_csv(tmp_path / "run.csv", tmp_path / "c.h5", mapping=MAPPING, sidecar=tmp_path / "map.json")


@pytest.mark.timeout(60)
def test_default_mapping_groups_vector_columns(tmp_path: Path) -> None:
    t, d = _data()
    _write_csv(tmp_path / "plain.csv", t, d,
               header="t;motor.position;master.position[0];master.position[1];loop.overrun".replace(";", "\t"))
    # tab-separated body to match the header
    text = (tmp_path / "plain.csv").read_text().splitlines()
    (tmp_path / "plain.csv").write_text("\n".join([text[0]] + [ln.replace(",", "\t") for ln in text[1:]]) + "\n")
    rec = RunRecord.open(import_csv(tmp_path / "plain.csv", tmp_path / "p.h5"))
    assert rec.channels["master.position"].shape == (N, 2)
    np.testing.assert_array_equal(rec.channels["master.position"], d["master.position"])
    np.testing.assert_array_equal(rec.t, t)
    assert rec.units == {"motor.position": "", "master.position": "", "loop.overrun": ""}


@pytest.mark.timeout(60)
def test_time_checks(tmp_path: Path) -> None:
    t, d = _data()
    bad = t.copy()
    bad[100], bad[101] = bad[101], bad[100]
    _write_csv(tmp_path / "dec.csv", bad, d)
    with pytest.raises(RecordError, match=r"time decreases at row 101"):
        import_csv(tmp_path / "dec.csv", tmp_path / "x.h5", mapping=MAPPING)
    rep = t.copy()
    rep[50] = rep[49]
    _write_csv(tmp_path / "rep.csv", rep, d)
    with pytest.raises(RecordError, match="time repeats at row 50"):
        import_csv(tmp_path / "rep.csv", tmp_path / "x.h5", mapping=MAPPING)
    var = t.copy()
    var[200:] += 0.4 / RATE  # off the sampling grid (a variable-step solver's output)
    _write_csv(tmp_path / "var.csv", var, d)
    with pytest.raises(RecordError, match="not uniformly sampled"):
        import_csv(tmp_path / "var.csv", tmp_path / "x.h5", mapping=MAPPING)
    assert not (tmp_path / "x.h5").exists()

    # missing samples (a gap of 3 periods) are accepted and recorded as events
    keep = np.ones(N, bool)
    keep[300:303] = False
    _write_csv(tmp_path / "gap.csv", t[keep], {k: v[keep] for k, v in d.items()})
    rec = RunRecord.open(import_csv(tmp_path / "gap.csv", tmp_path / "g.h5", mapping=MAPPING))
    assert rec.t.size == N - 3
    assert [(e["kind"], e["t"]) for e in rec.events] == [("import.gap", t[299])]
    assert rec.events[0]["message"].startswith("3 sample(s) missing")


@pytest.mark.timeout(60)
def test_input_errors_name_the_problem(tmp_path: Path) -> None:
    t, d = _data()
    _write_csv(tmp_path / "run.csv", t, d)
    with pytest.raises(RecordError, match=r"channel 'master\.position': no column 'q3'"):
        import_csv(tmp_path / "run.csv", tmp_path / "x.h5", mapping={**MAPPING, "master.position": ["q1", "q3"]})
    with pytest.raises(RecordError, match="'t' must name one column"):
        import_csv(tmp_path / "run.csv", tmp_path / "x.h5", mapping={"t": None, "motor.position": "pos"})
    lines = (tmp_path / "run.csv").read_text().splitlines()
    lines[5] = lines[5].replace(lines[5].split(",")[1], "abc", 1)
    (tmp_path / "bad.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(RecordError, match=r"bad\.csv:6: column 'pos': 'abc' is not a number"):
        import_csv(tmp_path / "bad.csv", tmp_path / "x.h5", mapping=MAPPING)
    _write_csv(tmp_path / "clock.csv", t, d, header="clock,pos,q1,q2,ovr")
    with pytest.raises(RecordError, match="no 't' or 'time' column"):
        import_csv(tmp_path / "clock.csv", tmp_path / "x.h5")
    with pytest.raises(RecordError, match="names no time column and there is no 't' or 'time' column"):
        import_csv(tmp_path / "clock.csv", tmp_path / "x.h5", mapping={"motor.position": "pos"})
    with pytest.raises(RecordError, match="no such file"):
        import_mat(tmp_path / "nope.mat", tmp_path / "x.h5")
    scipy.io.savemat(tmp_path / "v.mat", {"time": t, "pos": d["motor.position"][:10]})
    with pytest.raises(RecordError, match=r"'pos' has shape \(10,\)"):
        import_mat(tmp_path / "v.mat", tmp_path / "x.h5", mapping={"t": "time", "motor.position": "pos"})


# ------------------------------------------------------------------ import defaults (issue 12)


@pytest.mark.timeout(60)
def test_map_without_time_uses_the_default_time_column(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from hil.cli.main import main

    t, d = _data()
    _write_csv(tmp_path / "run.csv", t, d)  # time column "time"
    code = main(["import", str(tmp_path / "run.csv"), "--map", "motor.position=pos", "--map",
                 "master.position=q1,q2", "--out", str(tmp_path / "run.h5")])
    assert code == 0, capsys.readouterr().err
    rec = RunRecord.open(tmp_path / "run.h5")
    np.testing.assert_array_equal(rec.t, t)
    np.testing.assert_array_equal(rec.channels["motor.position"], d["motor.position"])
    assert set(rec.channels) == {"motor.position", "master.position"}  # only the mapped channels
    assert rec.meta["imported_from"]["mapping"]["t"] == "time"
    scipy.io.savemat(tmp_path / "run.mat", {"t": t, "pos": d["motor.position"]})  # .mat: variable "t"
    assert main(["import", str(tmp_path / "run.mat"), "--map", "motor.position=pos",
                 "--out", str(tmp_path / "mat.h5")]) == 0
    np.testing.assert_array_equal(RunRecord.open(tmp_path / "mat.h5").t, t)
    _write_csv(tmp_path / "clock.csv", t, d, header="clock,pos,q1,q2,ovr")  # no default time column: exit 2
    capsys.readouterr()
    assert main(["import", str(tmp_path / "clock.csv"), "--map", "motor.position=pos",
                 "--out", str(tmp_path / "c.h5")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "--time" in err and "'t' or 'time'" in err
    assert not (tmp_path / "c.h5").exists()


@pytest.mark.timeout(120)
def test_imported_chirp_band_follows_the_input_spectrum(tmp_path: Path) -> None:
    """A one-shot 1-400 Hz log chirp logged at 5 kHz by another tool: the default band of the imported
    record is the band its input excites, not 0.45 fs (where 82 % of the bins carry no excitation and
    the velocity's coherence sits at the noise-only level)."""
    from sdea_synth import log_chirp_record

    from hil.cli.main import main
    from hil.identify.api import identify_record
    from hil.identify.errors import DataQualityError
    from hil.identify.records import plan_from_record

    c = log_chirp_record(1, 1.0, 400.0, duration=2.0)
    cols = np.column_stack([c.t, c.u, c.v, c.f])
    np.savetxt(tmp_path / "run.csv", cols, delimiter=",", header="t,tau,vel,torque", comments="", fmt="%.17g")
    assert main(["import", str(tmp_path / "run.csv"), "--map", "motor.effort_cmd=tau", "--map", "motor.velocity=vel",
                 "--map", "spring_ft.wrench=torque", "--out", str(tmp_path / "run.h5")]) == 0
    rec = RunRecord.open(tmp_path / "run.h5")
    plan = plan_from_record(rec, rec.to_identify_dict()["signals"], {})
    lo, hi = plan.kwargs["band"]
    # 99.8 % of the power of a 1-400 Hz sweep lies in it, widened by the leakage of the abrupt start and
    # stop by a few 0.5 Hz periodogram bins (measured 402.5 Hz): within 3 % of the sweep's end
    assert lo <= 1.0 and 400.0 <= hi <= 412.0
    assert any("measured input power" in n for n in plan.notes)
    res = identify_record(tmp_path / "run.h5", max_steps=200, excitation="warn")
    assert res.frf.f[-1] <= hi and res.frf.f[-1] > 395.0
    assert "excitation" not in {d.kind for d in res.data_report.diagnoses}  # 1-400 Hz pins every parameter
    # control: the former default band (to 0.45 fs = 2250 Hz) refuses the same record
    with pytest.raises(DataQualityError, match="noise-only level"):
        identify_record(tmp_path / "run.h5", max_steps=200, band=(4.0, 2250.0))


# ------------------------------------------------------------------ scale, units, v7.3 (issues 25, 28, 30)

# the EMPS records: ../shared/data/emps next to the repository (CI's layout), or two levels up (a worktree)
_ROOT = Path(__file__).resolve().parents[2]
EMPS = next((p for p in (_ROOT.parent / "shared" / "data" / "emps" / "DATA_EMPS.mat",
                         _ROOT.parent.parent / "shared" / "data" / "emps" / "DATA_EMPS.mat") if p.is_file()),
            _ROOT.parent / "shared" / "data" / "emps" / "DATA_EMPS.mat")
GTAU = 35.15  # N/V, the EMPS amplifier gain (SOURCE.txt)


def _emps() -> dict[str, np.ndarray]:
    if not EMPS.is_file():
        pytest.skip(f"EMPS benchmark record not found at {EMPS} (the shared data folder is absent)")
    raw = scipy.io.loadmat(EMPS)
    return {k: np.asarray(v, float) for k, v in raw.items() if not k.startswith("__")}


def _write_v73(path: Path, variables: dict[str, object]) -> None:
    """A .mat file laid out as MATLAB's ``save -v7.3`` writes it (512-byte user block with the MATLAB
    header text, one dataset per variable stored column-major, i.e. transposed, with MATLAB_class;
    structs as groups), written with h5py independently of the reader under test."""
    import h5py

    def put(group: h5py.Group, name: str, value: object) -> None:
        if isinstance(value, dict):
            sub = group.create_group(name)
            sub.attrs["MATLAB_class"] = np.bytes_("struct")
            for k, v in value.items():
                put(sub, k, v)
        elif isinstance(value, str):
            ds = group.create_dataset(name, data=np.array([[ord(c) for c in value]], dtype=np.uint16).T)
            ds.attrs["MATLAB_class"] = np.bytes_("char")
        else:
            a = np.atleast_2d(np.asarray(value, float))  # MATLAB has no 1-D arrays: a vector is 1 x n
            ds = group.create_dataset(name, data=a.T)  # column-major: an n x k array is stored (k, n)
            ds.attrs["MATLAB_class"] = np.bytes_("double")

    with h5py.File(path, "w", userblock_size=512) as f:
        for k, v in variables.items():
            put(f, k, v)
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 HDF5 schema 1.00 ."
    with path.open("r+b") as fh:
        fh.write(header.ljust(116) + b"\x00" * 8 + b"\x00\x02IM")  # version 0x0200, endian 'IM'


@pytest.mark.timeout(60)
def test_emps_documented_user_path_mat_and_csv(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 25 item 6: ``hil import DATA_EMPS.mat --time t --map motor.position=qm --map
    motor.effort_cmd=vir --scale motor.effort_cmd=35.15`` (force = 35.15 N/V x vir), and the same for
    a CSV of the same columns; both records hold exactly the file's values times the gain."""
    from hil.cli.main import main

    d = _emps()
    t, qm, vir = d["t"].ravel(), d["qm"].ravel(), d["vir"].ravel()
    out = tmp_path / "emps.h5"
    code = main(["import", str(EMPS), "--time", "t", "--map", "motor.position=qm", "--map", "motor.effort_cmd=vir",
                 "--scale", f"motor.effort_cmd={GTAU}", "--unit", "motor.position=m", "--unit", "motor.effort_cmd=N",
                 "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    rec = RunRecord.open(out)
    np.testing.assert_array_equal(rec.t, t)
    np.testing.assert_array_equal(rec.channels["motor.position"], qm)
    np.testing.assert_array_equal(rec.channels["motor.effort_cmd"], vir * GTAU)
    assert rec.units == {"motor.position": "m", "motor.effort_cmd": "N"}
    assert rec.rate_hz == pytest.approx(1000.0, rel=1e-4)  # 1 ms sampling (a median interval of 1.00002 ms)
    assert rec.meta["imported_from"]["mapping"]["scale"] == {"motor.effort_cmd": GTAU}
    # the same columns as CSV (17 significant digits: exact), plus a sidecar for the .mat (defect 4)
    cols = np.column_stack([t, qm, vir])
    np.savetxt(tmp_path / "emps.csv", cols, delimiter=",", header="t,qm,vir", comments="", fmt="%.17g")
    assert main(["import", str(tmp_path / "emps.csv"), "--map", "motor.position=qm", "--map", "motor.effort_cmd=vir",
                 "--scale", f"motor.effort_cmd={GTAU}", "--out", str(tmp_path / "csv.h5")]) == 0
    rec_csv = RunRecord.open(tmp_path / "csv.h5")
    np.testing.assert_array_equal(rec_csv.t, rec.t)
    for name in rec.channels:
        np.testing.assert_array_equal(rec_csv.channels[name], rec.channels[name])
    side = tmp_path / "emps_map.yaml"
    side.write_text(yaml.safe_dump({"t": "t", "motor.position": "qm", "motor.effort_cmd": "vir",
                                    "scale": {"motor.effort_cmd": GTAU}}))
    assert main(["import", str(EMPS), "--sidecar", str(side), "--out", str(tmp_path / "side.h5")]) == 0
    np.testing.assert_array_equal(RunRecord.open(tmp_path / "side.h5").channels["motor.effort_cmd"], vir * GTAU)


@pytest.mark.timeout(60)
def test_mat_v73_reads_like_v5(tmp_path: Path) -> None:
    """A MATLAB v7.3 file (HDF5) imports to the same record as the v5 file of the same variables
    (scipy.io.loadmat refused it with "Unknown mat file type, version 0, 0")."""
    t, d = _data()
    variables = {"time": t[:, None], "pos": d["motor.position"][:, None], "q": d["master.position"],
                 "ovr": d["loop.overrun"][:, None], "gain": 35.15, "label": "bench 3"}
    scipy.io.savemat(tmp_path / "v5.mat", variables)
    _write_v73(tmp_path / "v73.mat", variables)
    with pytest.raises(NotImplementedError):  # the old reader's failure: the file really is v7.3
        scipy.io.loadmat(tmp_path / "v73.mat")
    m = {"t": "time", "motor.position": "pos", "master.position": "q", "loop.overrun": "ovr", "units": UNITS}
    native = _native(tmp_path / "native.h5")
    a = RunRecord.open(import_mat(tmp_path / "v5.mat", tmp_path / "a.h5", mapping=m))
    b = RunRecord.open(import_mat(tmp_path / "v73.mat", tmp_path / "b.h5", mapping=m))
    _assert_same(native, a)
    _assert_same(native, b)
    assert b.meta["imported_from"]["format"] == "mat-v7.3"
    # a struct, as in MATLAB's `run.time`, `run.q1`; and no mapping: the struct's numeric vectors
    _write_v73(tmp_path / "s.mat", {"run": {"t": t, "x": d["motor.position"], "k": 2.0}})
    rec = RunRecord.open(import_mat(tmp_path / "s.mat", tmp_path / "s.h5"))
    assert set(rec.channels) == {"x"}  # the scalar k is not a channel
    np.testing.assert_array_equal(rec.channels["x"], d["motor.position"])
    np.testing.assert_array_equal(rec.t, t)


@pytest.mark.timeout(60)
def test_mat_v73_of_the_emps_record(tmp_path: Path) -> None:
    """The EMPS record saved as v7.3 (as MATLAB's save -v7.3 lays it out) imports bit for bit like
    the original v5 file."""
    d = _emps()
    _write_v73(tmp_path / "emps73.mat", d)
    m = {"t": "t", "motor.position": "qm", "motor.effort_cmd": "vir"}
    a = RunRecord.open(import_mat(EMPS, tmp_path / "a.h5", mapping=m, scale={"motor.effort_cmd": GTAU}))
    b = RunRecord.open(import_mat(tmp_path / "emps73.mat", tmp_path / "b.h5", mapping=m,
                                  scale={"motor.effort_cmd": GTAU}))
    np.testing.assert_array_equal(a.t, b.t)
    for name in a.channels:
        np.testing.assert_array_equal(a.channels[name], b.channels[name])


@pytest.mark.timeout(60)
def test_units_convert_to_si_and_the_record_states_it(tmp_path: Path) -> None:
    """``--unit`` names the file's unit: mm -> m (x 1e-3), deg -> rad (x pi/180), ms -> s; the record
    states the SI unit. Factors checked against their definitions, not against pint."""
    t, d = _data()
    pos_mm = d["motor.position"] * 1e3
    ang_deg = np.degrees(d["master.position"])
    _write_csv(tmp_path / "u.csv", t * 1000.0, {"motor.position": pos_mm, "master.position": ang_deg,
                                               "loop.overrun": d["loop.overrun"]})
    rec = RunRecord.open(import_csv(tmp_path / "u.csv", tmp_path / "u.h5", mapping=MAPPING | {"units": {}},
                                    units={"t": "ms", "motor.position": "mm", "master.position": "deg"}))
    np.testing.assert_allclose(rec.t, t, rtol=1e-15, atol=1e-15)
    np.testing.assert_allclose(rec.channels["motor.position"], d["motor.position"], rtol=1e-15)
    np.testing.assert_allclose(rec.channels["master.position"], d["master.position"], rtol=1e-15)
    assert rec.units == {"motor.position": "m", "master.position": "rad", "loop.overrun": ""}
    assert rec.rate_hz == pytest.approx(RATE)
    # scale and unit together: a torque logged in mN.m per count, 0.5 mN.m/count
    cnt = np.round(d["motor.position"] * 100)
    _write_csv(tmp_path / "c.csv", t, {"motor.position": cnt, "master.position": d["master.position"],
                                       "loop.overrun": d["loop.overrun"]})
    rec = RunRecord.open(import_csv(tmp_path / "c.csv", tmp_path / "c.h5", mapping={"t": "time", "motor.effort": "pos"},
                                    scale={"motor.effort": 0.5}, units={"motor.effort": "mN.m"}))
    np.testing.assert_allclose(rec.channels["motor.effort"], cnt * 0.5e-3, rtol=1e-15)
    assert rec.units == {"motor.effort": "N.m"}


@pytest.mark.timeout(60)
def test_time_in_ms_read_as_seconds_warns(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """Issue 28 item 9: a 1 kHz log whose time column is in ms reads as a 1 Hz record: a warning says
    so and names the fix; the same file with --unit t=ms is 1 kHz and silent."""
    n = 200
    t_ms = np.arange(n, dtype=float)  # 1 kHz, in ms
    (tmp_path / "ms.csv").write_text("t,v\n" + "".join(f"{a!r},{float(np.sin(a / 10))!r}\n" for a in t_ms.tolist()))
    with caplog.at_level("WARNING", logger="hil.record.importers"):
        rec = RunRecord.open(import_csv(tmp_path / "ms.csv", tmp_path / "a.h5"))
    assert rec.rate_hz == pytest.approx(1.0)
    warned = [r.getMessage() for r in caplog.records if "implausible" in r.getMessage()]
    assert len(warned) == 1 and "1 Hz" in warned[0] and "--unit t=ms" in warned[0]
    caplog.clear()
    with caplog.at_level("WARNING", logger="hil.record.importers"):
        rec = RunRecord.open(import_csv(tmp_path / "ms.csv", tmp_path / "b.h5", units={"t": "ms"}))
    assert rec.rate_hz == pytest.approx(1000.0)
    assert not [r for r in caplog.records if "implausible" in r.getMessage()]


def test_a_unit_needing_pint_without_pint_names_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    from hil.record.importers import units

    def missing() -> None:
        raise ImportError("No module named 'pint'")

    units.to_si.cache_clear()
    monkeypatch.setattr(units, "_registry", missing)
    try:
        assert units.to_si("N.m") == (1.0, "N.m")  # the records' own SI spellings need no pint
        with pytest.raises(RecordError, match=r"unit 'mm' needs the 'pint' package: pip install 'hil-certify\[units"):
            units.to_si("mm")
    finally:
        units.to_si.cache_clear()
