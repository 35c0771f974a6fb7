"""hil export (hil.record.export, issue 30): MCAP read back with the mcap reader, CSV read back by hil import."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from hil.record.hdf5 import ChannelSpec, RecordWriter, RunRecord


def _record(path: Path) -> RunRecord:
    """A record with scalar, vector and NaN-holding channels, events, a safety stop and device counters."""
    rng = np.random.default_rng(5)
    n = 300
    t = np.arange(n) / 1000.0
    specs = {"motor.position": ChannelSpec((1,), "rad", "measured position"), "motor.effort": ChannelSpec((1,), "N.m"),
             "spring_ft.wrench": ChannelSpec((6,), "N, N.m"), "loop.late": ChannelSpec((1,), "s"),
             "gain": ChannelSpec((), "1")}
    data = {"motor.position": rng.standard_normal((n, 1)), "motor.effort": np.full((n, 1), np.nan),
            "spring_ft.wrench": rng.standard_normal((n, 6)), "loop.late": np.zeros((n, 1)),
            "gain": rng.standard_normal(n) * 1e-300}
    data["motor.effort"][::7] = 1.5
    data["spring_ft.wrench"][10, 2] = np.inf
    with RecordWriter(path, scene_text="", scene_sha256="", meta={"operator": "x"}, channels=specs,
                      rate_hz=1000.0) as w:
        w.append_block(t, data)
        w.event(0.1, "realtime", "loop scheduling: SCHED_OTHER")
        w.event(0.299, "safety_stop", "position limit 1.2 rad exceeded")
        w.event(0.299, "safe_stop", "zero effort commanded (motor: ok)")
        w.set_device_counters({"motor": {"crc_errors": 3, "stale": 0}})
        w.close(stop_reason="position limit 1.2 rad exceeded", status="safety_stop")
    return RunRecord.open(path)


def _read_mcap(path: Path) -> tuple[dict[str, list[dict]], dict[str, dict], dict[str, str]]:
    from mcap.reader import make_reader

    msgs: dict[str, list[dict]] = {}
    schemas: dict[str, dict] = {}
    with path.open("rb") as fh:
        reader = make_reader(fh)
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            assert channel.message_encoding == "json" and schema.encoding == "jsonschema"
            body = json.loads(message.data)
            msgs.setdefault(channel.topic, []).append(body)
            schemas[channel.topic] = json.loads(schema.data)
            if "t" in body:
                assert message.log_time == message.publish_time
        with path.open("rb") as fh2:
            meta = {m.name: m.metadata for m in make_reader(fh2).iter_metadata()}
    return msgs, schemas, meta["hil.record"]


@pytest.mark.timeout(60)
def test_mcap_export_read_back_has_every_channel_event_and_stop(tmp_path: Path) -> None:
    pytest.importorskip("mcap", reason="the 'formats' extra is not installed")
    from hil.cli.main import main

    rec = _record(tmp_path / "run.h5")
    assert main(["export", str(tmp_path / "run.h5"), "--format", "mcap"]) == 0
    msgs, schemas, meta = _read_mcap(tmp_path / "run.mcap")
    assert set(msgs) == {"/motor", "/spring_ft", "/loop", "/record", "/events", "/stop", "/device_counters"}
    fields = {"/motor": {"position": "motor.position", "effort": "motor.effort"},
              "/spring_ft": {"wrench": "spring_ft.wrench"}, "/loop": {"late": "loop.late"}, "/record": {"gain": "gain"}}
    for topic, fmap in fields.items():
        got = msgs[topic]
        assert len(got) == rec.t.size
        np.testing.assert_array_equal([m["t"] for m in got], rec.t)
        for field, ch in fmap.items():
            back = np.array([[np.nan if x is None else x for x in np.atleast_1d(m[field])] for m in got])
            want = rec.channels[ch].reshape(rec.t.size, -1)
            finite = np.isfinite(want)
            np.testing.assert_array_equal(back[finite], want[finite])  # bit for bit
            assert np.all(np.isnan(back[~finite]))  # NaN and inf are JSON null
            assert rec.units[ch] in schemas[topic]["properties"][field]["description"]
    assert [(e["t"], e["kind"], e["message"]) for e in msgs["/events"]] == \
        [(e["t"], e["kind"], e["message"]) for e in rec.events]
    assert [e["level"] for e in msgs["/events"]] == [2, 3, 3]  # foxglove.Log: INFO, WARNING, WARNING
    (stop,) = msgs["/stop"]
    assert stop == {"t": rec.t[-1], "stop_reason": "position limit 1.2 rad exceeded", "status": "safety_stop",
                    "samples": 300}
    assert msgs["/device_counters"][0]["counters"] == {"motor": {"crc_errors": 3, "stale": 0}}
    assert json.loads(meta["units"]) == rec.units and json.loads(meta["meta"])["operator"] == "x"
    assert float(meta["rate_hz"]) == 1000.0


@pytest.mark.timeout(120)
def test_mcap_export_of_a_lockstep_run_reimports(tmp_path: Path) -> None:
    """A real lockstep record exported to MCAP and imported back (hil import, /device:quantity
    sources): the same samples."""
    pytest.importorskip("mcap", reason="the 'formats' extra is not installed")
    from hil.record.export import export_record
    from hil.record.importers import import_file
    from hil.run.runner import Runner
    from hil.scene.spec import load_scene, scene_from_dict

    d = yaml.safe_load(load_scene("sdea_bench").source_text)
    d["experiments"] = d["experiments"][:1]
    d.pop("certification", None)
    out = Runner(scene_from_dict(d, label="export-test"), tmp_path, max_ticks=400).run()[0]
    rec = RunRecord.open(out.record)
    export_record(out.record, tmp_path / "run.mcap", "mcap")
    back = RunRecord.open(import_file(tmp_path / "run.mcap", tmp_path / "back.h5", mapping={
        "motor.position": "/motor:position", "motor.effort_cmd": "/motor:effort_cmd"}))
    np.testing.assert_allclose(back.t, rec.t, rtol=0, atol=1e-9)  # log times in ns
    np.testing.assert_array_equal(back.channels["motor.position"], rec.channels["motor.position"])
    np.testing.assert_array_equal(back.channels["motor.effort_cmd"], rec.channels["motor.effort_cmd"])


@pytest.mark.timeout(60)
def test_csv_export_imports_back_without_a_mapping(tmp_path: Path) -> None:
    from hil.cli.main import main
    from hil.record.importers import import_csv

    rec = _record(tmp_path / "run.h5")
    assert main(["export", str(tmp_path / "run.h5"), "--format", "csv", "--out", str(tmp_path / "x.csv")]) == 0
    text = (tmp_path / "x.csv").read_text().splitlines()
    assert text[0].startswith("# exported from") and "motor.position=rad" in text[1]
    assert text[2].startswith("t,motor.position[0],motor.effort[0],spring_ft.wrench[0],")
    back = RunRecord.open(import_csv(tmp_path / "x.csv", tmp_path / "back.h5"))
    np.testing.assert_array_equal(back.t, rec.t)
    assert set(back.channels) == set(rec.channels)
    for name, a in rec.channels.items():
        np.testing.assert_array_equal(back.channels[name].reshape(a.shape), a, err_msg=name)  # NaN, inf too
    assert main(["export", str(tmp_path / "run.h5"), "--format", "csv", "--out", str(tmp_path / "x.csv")]) == 2
