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
