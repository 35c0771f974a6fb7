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


def _hold(t_slow: np.ndarray, v_slow: np.ndarray, t: np.ndarray, tol: float = 1e-12) -> np.ndarray:
    """Zero-order hold written out independently of the importer: for each t, the slow sample with the
    largest time <= t + tol (a loop over the samples)."""
    out = np.empty(t.size)
    j = 0
    for i, ti in enumerate(t):
        while j + 1 < t_slow.size and t_slow[j + 1] <= ti + tol:
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


# ------------------------------------------------------------------------------------------- ROS bags

BAG_MAP = {"motor.position": "/joint_states:position[axis]", "motor.velocity": "/joint_states:velocity[axis]",
           "motor.effort_cmd": "/effort_cmd:data", "spring_ft.wrench": "/ft:wrench.force.z",
           "debug.state": ["/debug:data[0]", "/debug:data[1]"]}


def _bag_truth() -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray, np.ndarray]:
    t, d = _truth()
    t_ft = np.arange(N // 4) / (RATE / 4)  # the force sensor at 250 Hz, the loop at 1 kHz
    force = np.random.default_rng(11).standard_normal(t_ft.size)
    return t, d, t_ft, force


@pytest.mark.timeout(120)
@pytest.mark.parametrize("storage", ["sqlite3", "mcap", "ros1"])
def test_ros_bag_1khz_and_250hz_onto_one_time_base(tmp_path: Path, storage: str) -> None:
    pytest.importorskip("rosbags", reason="the 'ros' extra is not installed")
    from rosbag_synth import write_bag

    from hil.identify.sensor_hold import age_distribution

    t, d, t_ft, force = _bag_truth()
    bag = write_bag(tmp_path / "run_bag", storage, t, d["pos"], d["vel"], d["tau"], t_ft, force,
                    flip_joint_order_at=N // 2)
    rec = RunRecord.open(import_file(bag, tmp_path / "r.h5", mapping=BAG_MAP))
    expected_t = (np.round(t * 1e9).astype(np.int64)).astype(float) * 1e-9  # stamps in ns, from the first
    np.testing.assert_array_equal(rec.t, expected_t)
    assert rec.rate_hz == pytest.approx(RATE)
    np.testing.assert_array_equal(rec.channels["motor.position"], d["pos"])  # by joint name, order flipped mid-way
    np.testing.assert_array_equal(rec.channels["motor.velocity"], d["vel"])
    np.testing.assert_array_equal(rec.channels["motor.effort_cmd"], d["tau"])  # Float64: the bag's receive time
    np.testing.assert_array_equal(rec.channels["debug.state"], np.column_stack([d["pos"], d["vel"]]))
    np.testing.assert_array_equal(rec.channels["spring_ft.wrench"], _hold(t_ft, force, t))
    imp = rec.meta["imported_from"]
    assert imp["format"] == "rosbag" and rec.meta["held_channels"] == ["spring_ft.wrench"]
    assert imp["resampling"]["spring_ft.wrench"]["source_rate_hz"] == pytest.approx(250.0)
    assert imp["time_base"]["source"] in ("/joint_states", "/effort_cmd", "/debug")
    assert imp["time_stamps"] == {"/joint_states": "header.stamp", "/effort_cmd": "log time", "/ft": "header.stamp",
                                  "/debug": "log time"}
    assert imp["t0_ns"] == 1_700_000_000 * 1_000_000_000
    np.testing.assert_allclose(age_distribution(rec.channels["spring_ft.wrench"]), [0.25] * 4, atol=1 / N)


@pytest.mark.timeout(120)
def test_ros_bag_list_and_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("rosbags", reason="the 'ros' extra is not installed")
    from rosbag_synth import write_bag

    from hil.cli.main import main

    t, d, t_ft, force = _bag_truth()
    bag = write_bag(tmp_path / "run_bag", "sqlite3", t, d["pos"], d["vel"], d["tau"], t_ft, force)
    fmt, rows = describe(bag)
    sources = {r.source: r for r in rows}
    assert fmt == "rosbag"
    assert sources["/joint_states"].kind == "sensor_msgs/msg/JointState" and sources["/joint_states"].samples == N
    assert sources["/joint_states"].rate_hz == pytest.approx(RATE) and sources["/ft"].rate_hz == pytest.approx(250.0)
    for s in ("/joint_states:position[axis]", "/joint_states:effort[base]", "/ft:wrench.force.z", "/effort_cmd:data",
              "/debug:data"):
        assert s in sources, s
    assert main(["import", str(bag), "--list"]) == 0
    assert "/joint_states:velocity[axis]" in capsys.readouterr().out
    cases = [({"x": "/nope:data"}, r"no topic /nope in the bag"),
             ({"x": "/joint_states:position[elbow]"}, r"no joint 'elbow' \(names: base, axis\)"),
             ({"x": "/ft:wrench.force.w"}, r"no field 'w' \(fields there: x, y, z\)"),
             ({"x": "/joint_states"}, r"expected /topic:field"),
             ({"x": "/ft:wrench.force.z", "t": "/debug"}, r"t: '/debug' is not a mapped topic")]
    for mapping, msg in cases:
        with pytest.raises(RecordError, match=msg):
            import_file(bag, tmp_path / "x.h5", mapping=mapping)
    # the slower topic as the time base: the fast ones are sampled at its stamps (not held)
    rec = RunRecord.open(import_file(bag, tmp_path / "slow.h5", mapping={**BAG_MAP, "t": "/ft"}))
    assert rec.rate_hz == pytest.approx(250.0)
    np.testing.assert_array_equal(rec.channels["motor.position"], d["pos"][::4])
    assert "held_channels" not in rec.meta
    capsys.readouterr()
    assert main(["import", str(bag), "--out", str(tmp_path / "c.h5")]) == 2
    err = capsys.readouterr().err
    assert "--map CHANNEL=SOURCE" in err and "--list" in err and "\n" not in err.strip()


@pytest.mark.timeout(300)
def test_identification_on_an_imported_bag_equals_the_same_data_in_csv(tmp_path: Path) -> None:
    """A 1-400 Hz SDEA chirp at 5 kHz logged as a ROS 2 bag (JointState velocity, Float64 command,
    WrenchStamped torque) and as a CSV of the same values: the imported records are identical, and so
    are the identified parameters, their standard deviations and the posterior."""
    pytest.importorskip("rosbags", reason="the 'ros' extra is not installed")
    from rosbag_synth import write_bag
    from sdea_synth import TRUTH, log_chirp_record

    from hil.identify.api import identify_record

    c = log_chirp_record(1, 1.0, 400.0, duration=2.0)
    t = np.round(c.t * 1e9) * 1e-9  # the bag's ns stamps, from its first one
    bag = write_bag(tmp_path / "chirp_bag", "mcap", c.t, np.zeros_like(c.v), c.v, c.u, c.t, c.f)
    rec_bag = RunRecord.open(import_file(bag, tmp_path / "bag.h5", mapping={
        "motor.effort_cmd": "/effort_cmd:data", "motor.velocity": "/joint_states:velocity[axis]",
        "spring_ft.wrench": "/ft:wrench.force.z"}))
    np.savetxt(tmp_path / "run.csv", np.column_stack([t, c.u, c.v, c.f]), delimiter=",", header="t,tau,vel,torque",
               comments="", fmt="%.17g")
    rec_csv = RunRecord.open(import_file(tmp_path / "run.csv", tmp_path / "csv.h5", mapping={
        "motor.effort_cmd": "tau", "motor.velocity": "vel", "spring_ft.wrench": "torque"}))
    np.testing.assert_array_equal(rec_bag.t, rec_csv.t)
    for name in rec_csv.channels:
        np.testing.assert_array_equal(rec_bag.channels[name], rec_csv.channels[name], err_msg=name)
    # the chirp is simulated with a piecewise-linear input (sdea_synth): the continuous-time model fits it
    a = identify_record(tmp_path / "bag.h5", max_steps=200, excitation="warn", sampling="continuous")
    b = identify_record(tmp_path / "csv.h5", max_steps=200, excitation="warn", sampling="continuous")
    assert a.ls.names == b.ls.names and a.method == b.method
    np.testing.assert_array_equal(a.ls.theta, b.ls.theta)
    np.testing.assert_array_equal(a.ls.std, b.ls.std)
    np.testing.assert_array_equal(a.posterior.samples, b.posterior.samples)
    # and they are estimates of the truth the chirp was simulated from (not a shared failure)
    for name, value in zip(a.ls.names, a.ls.theta, strict=True):
        if name in TRUTH:
            assert value == pytest.approx(TRUTH[name], rel=0.05), name


# ----------------------------------------------------------------------------------------------- MCAP


@pytest.mark.timeout(120)
def test_mcap_json_messages(tmp_path: Path) -> None:
    """JSON-encoded MCAP (as Foxglove writes it): one topic with header stamps at 1 kHz (the stamps,
    not the log times, are the time), one without at 500 Hz (log time), joined on one time base."""
    pytest.importorskip("mcap", reason="the 'formats' extra is not installed")
    import json

    from mcap.writer import Writer

    t, d = _truth()
    t_slow, v_slow = t[::2], d["tau"][::2]
    t0 = 1_650_000_000_000_000_000
    with (tmp_path / "run.mcap").open("wb") as fh:
        w = Writer(fh)
        w.start()
        s1 = w.register_schema("Joint", "jsonschema", json.dumps({"type": "object"}).encode())
        s2 = w.register_schema("Cmd", "jsonschema", json.dumps({"type": "object"}).encode())
        c1 = w.register_channel("/joint", "json", s1)
        c2 = w.register_channel("/cmd", "json", s2)
        events = sorted([(round(tt * 1e9), 0, k) for k, tt in enumerate(t)] +
                        [(round(tt * 1e9), 1, k) for k, tt in enumerate(t_slow)])
        for ns, which, k in events:
            if which == 0:
                msg = {"header": {"stamp": {"sec": (t0 + ns) // 10**9, "nsec": (t0 + ns) % 10**9}},
                       "q": [float(d["q"][k, 0]), float(d["q"][k, 1])], "pos": float(d["pos"][k])}
                # logged 3 ms late: the stamp, not the log time, is the sample's time
                w.add_message(c1, log_time=t0 + ns + 3_000_000, data=json.dumps(msg).encode(), publish_time=t0 + ns)
            else:
                w.add_message(c2, log_time=t0 + ns, data=json.dumps({"value": float(v_slow[k])}).encode(),
                              publish_time=t0 + ns)
        w.finish()
    rec = RunRecord.open(import_file(tmp_path / "run.mcap", tmp_path / "r.h5", mapping={
        "master.position": "/joint:q", "motor.position": "/joint:pos", "motor.effort_cmd": "/cmd:value"}))
    np.testing.assert_allclose(rec.t, t, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(rec.channels["master.position"], d["q"])
    np.testing.assert_array_equal(rec.channels["motor.position"], d["pos"])
    np.testing.assert_array_equal(rec.channels["motor.effort_cmd"], _hold(t_slow, v_slow, t))
    assert rec.meta["held_channels"] == ["motor.effort_cmd"]
    assert rec.meta["imported_from"]["time_stamps"] == {"/cmd": "log time", "/joint": "header.stamp"}
    fmt, rows = describe(tmp_path / "run.mcap")
    srcs = {r.source: r for r in rows}
    assert fmt == "mcap" and srcs["/joint"].kind == "Joint" and srcs["/joint"].samples == N
    assert srcs["/cmd"].rate_hz == pytest.approx(RATE / 2) and "/joint:q" in srcs and "/cmd:value" in srcs


@pytest.mark.timeout(120)
def test_mcap_ros2_cdr_file_reads_like_the_bag(tmp_path: Path) -> None:
    """The .mcap storage file of a ROS 2 bag (CDR messages with ros2msg schemas), read alone by the
    MCAP importer (mcap-ros2-support's decoder), gives the record the bag importer (rosbags) gives."""
    pytest.importorskip("mcap_ros2", reason="the 'formats' extra is not installed")
    pytest.importorskip("rosbags", reason="the 'ros' extra is not installed")
    from rosbag_synth import write_bag

    t, d, t_ft, force = _bag_truth()
    bag = write_bag(tmp_path / "run_bag", "mcap", t, d["pos"], d["vel"], d["tau"], t_ft, force)
    (mcap_file,) = bag.glob("*.mcap")
    a = RunRecord.open(import_file(bag, tmp_path / "a.h5", mapping=BAG_MAP))
    b = RunRecord.open(import_file(mcap_file, tmp_path / "b.h5", mapping=BAG_MAP))
    assert b.meta["imported_from"]["format"] == "mcap"
    np.testing.assert_array_equal(a.t, b.t)
    for name in a.channels:
        np.testing.assert_array_equal(a.channels[name], b.channels[name], err_msg=name)
    assert b.meta["held_channels"] == ["spring_ft.wrench"]
    assert b.meta["imported_from"]["topics"]["/ft"] == "geometry_msgs/msg/WrenchStamped"


# ------------------------------------------------------------------------------------ missing extras

_WITHOUT = """
import sys

BLOCKED = set(sys.argv[1].split(","))

class _NotInstalled:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None

sys.meta_path.insert(0, _NotInstalled())
from hil.cli.main import main

sys.exit(main(sys.argv[2:]))
"""


@pytest.mark.timeout(180)
@pytest.mark.parametrize(("blocked", "file", "argv", "fragments"), [
    ("nptdms", "r.tdms", ["--map", "x=g/c"], ["npTDMS", "pip install 'hil-certify[formats]'"]),
    ("rosbags", "r.bag", ["--map", "x=/a:b"], ["rosbags", "pip install 'hil-certify[ros]'"]),
    ("mcap", "r.mcap", ["--map", "x=/a:b"], ["mcap", "pip install 'hil-certify[formats]'"]),
    ("pint", "r.csv", ["--unit", "v=mm"], ["'pint'", "pip install 'hil-certify[units]'"]),
], ids=["tdms", "rosbag", "mcap", "units"])
def test_a_missing_extra_is_one_line_naming_it(tmp_path: Path, blocked: str, file: str, argv: list[str],
                                               fragments: list[str]) -> None:
    """As a base install answers (tests/test_base_install.py): the format's library not installed is exit 2
    and one stderr line with the pip command, nothing written."""
    import subprocess
    import sys

    (tmp_path / file).write_bytes(b"t,v\n0,1\n0.001,2\n" if file.endswith(".csv") else b"\x00" * 64)
    proc = subprocess.run([sys.executable, "-c", _WITHOUT, blocked, "import", str(tmp_path / file), *argv],
                          capture_output=True, text=True, timeout=120)
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(err) == 1, proc.stderr
    for frag in fragments:
        assert frag in err[0], (frag, err[0])
    assert not (tmp_path / "r.h5").exists()


@pytest.mark.timeout(120)
def test_live_without_the_extra_is_one_line(tmp_path: Path) -> None:
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-c", _WITHOUT, "foxglove", "run", "bilateral_2dof_B", "--live", "0",
                           "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=120)
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(err) == 1, proc.stderr
    assert "pip install 'hil-certify[live]'" in err[0]
    assert not (tmp_path / "o").exists()


@pytest.mark.timeout(120)
def test_jittered_stamps_need_resample_onto_a_uniform_grid(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Header stamps with +-30 % jitter (a loop on a loaded machine): not a grid, refused with the fix named;
    --resample 1000 holds every topic onto a uniform 1 kHz grid (values: the latest sample at or before
    each grid time, written out independently)."""
    pytest.importorskip("rosbags", reason="the 'ros' extra is not installed")
    from rosbag_synth import write_bag

    from hil.cli.main import main

    t, d, t_ft, force = _bag_truth()
    rng = np.random.default_rng(2)
    tj = t + rng.uniform(-0.3e-3, 0.3e-3, t.size)
    tj[0] = 0.0
    tj = np.sort(tj)
    bag = write_bag(tmp_path / "jit_bag", "sqlite3", tj, d["pos"], d["vel"], d["tau"], t_ft, force)
    m = {"motor.position": "/joint_states:position[axis]", "spring_ft.wrench": "/ft:wrench.force.z"}
    with pytest.raises(RecordError, match=r"not uniformly sampled.*hil import --resample HZ"):
        import_file(bag, tmp_path / "x.h5", mapping=m)
    code = main(["import", str(bag), "--map", "motor.position=/joint_states:position[axis]", "--map",
                 "spring_ft.wrench=/ft:wrench.force.z", "--resample", "1000", "--out", str(tmp_path / "r.h5")])
    assert code == 0, capsys.readouterr().err
    rec = RunRecord.open(tmp_path / "r.h5")
    stamps = np.round(tj * 1e9) * 1e-9
    grid = np.arange(rec.t.size) / 1000.0
    np.testing.assert_allclose(rec.t, grid, rtol=0, atol=1e-12)
    assert rec.t[-1] <= min(stamps[-1], t_ft[-1]) + 1e-12 and rec.rate_hz == pytest.approx(1000.0)
    ft_stamps = np.round(t_ft * 1e9) * 1e-9  # the bag's stamps [s] from its first, as the importer reads them
    np.testing.assert_array_equal(rec.channels["motor.position"], _hold(stamps, d["pos"], rec.t, tol=0.0))
    np.testing.assert_array_equal(rec.channels["spring_ft.wrench"], _hold(ft_stamps, force, rec.t, tol=0.0))
    # the jittered 1 kHz stream is reused where two grid times fall between its samples: held there too
    i = np.searchsorted(stamps, rec.t, side="right") - 1
    rs = rec.meta["imported_from"]["resampling"]
    assert rs["motor.position"]["repeated_fraction"] == pytest.approx(np.mean(i[1:] == i[:-1]))
    assert 0.01 < rs["motor.position"]["repeated_fraction"] < 0.3
    assert rs["spring_ft.wrench"]["repeated_fraction"] == pytest.approx(0.75, abs=2 / N)
    assert rec.meta["held_channels"] == ["motor.position", "spring_ft.wrench"]
    assert rec.meta["imported_from"]["mapping"]["resample_hz"] == 1000.0
    with pytest.raises(RecordError, match=r"applies to time-stamped formats .* not to csv"):
        np.savetxt(tmp_path / "a.csv", np.column_stack([t, d["pos"]]), delimiter=",", header="t,p", comments="")
        import_file(tmp_path / "a.csv", tmp_path / "y.h5", resample_hz=1000.0)


# ------------------------------------------------------------------------------- a format from outside

PLUGIN_IMPORTER = '''
"""An outside package's importer: ".kv" files, lines "t=<s> <name>=<value> ...". """
from pathlib import Path

import numpy as np

from hil.record.importers.base import Entry, Sampled


class KvImporter:
    name = "kv"
    suffixes = (".kv",)
    extra = None
    time_required = False

    def claims(self, path):
        return path.suffix == ".kv"

    def _rows(self, path):
        return [dict(kv.split("=") for kv in ln.split()) for ln in Path(path).read_text().splitlines() if ln]

    def source_names(self, path):
        return sorted(self._rows(path)[0])

    def default_mapping(self, path):
        return None

    def inventory(self, path):
        return [Entry(k, "key", len(self._rows(path))) for k in self.source_names(path)]

    def read(self, path, mapping):
        rows = self._rows(path)
        t = np.array([float(r["t"]) for r in rows])
        return Sampled(t=t, data={ch: np.array([float(r[mapping.channels[ch]]) for r in rows])
                                  for ch in mapping.channels})
'''


@pytest.mark.timeout(60)
def test_an_importer_from_another_distribution(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """One module and one entry point (group hil_certify.importers) add a format; no edit of the suite."""
    import importlib
    import sys

    from hil import plugins
    from hil.cli.main import main
    from hil.record.importers import base

    root = tmp_path / "site"
    info = root / "hil_kv_demo-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: hil-kv-demo\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[hil_certify.importers]\nkv = hil_kv_demo:KvImporter\n"
                                           "broken = hil_kv_demo:NoSuchThing\n")
    (root / "hil_kv_demo.py").write_text(PLUGIN_IMPORTER)
    monkeypatch.setattr(base, "_REGISTRY", dict(base._REGISTRY))
    monkeypatch.setattr(plugins, "_loaded", set())
    monkeypatch.syspath_prepend(str(root))
    importlib.invalidate_caches()
    try:
        t = np.arange(50) / 500.0
        (tmp_path / "run.kv").write_text("".join(f"t={a!r} p={2 * a!r}\n" for a in t.tolist()))
        assert main(["import", str(tmp_path / "run.kv"), "--map", "motor.position=p", "--unit", "motor.position=mm",
                     "--out", str(tmp_path / "r.h5")]) == 0
        rec = RunRecord.open(tmp_path / "r.h5")
        np.testing.assert_array_equal(rec.t, t)
        np.testing.assert_allclose(rec.channels["motor.position"], 2e-3 * t, rtol=1e-15)
        assert rec.meta["imported_from"]["format"] == "kv" and rec.units == {"motor.position": "m"}
        assert "broken" not in importers()  # logged and skipped
    finally:
        sys.modules.pop("hil_kv_demo", None)
