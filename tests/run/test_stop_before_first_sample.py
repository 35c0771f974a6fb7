"""A stop that comes before the first sample (issue 27 item 9): the record made for the experiment
says it holds none, and ``hil run`` that recorded nothing says so and leaves no empty folder.

Before: a stop in that window left a 0-sample "interrupted" record whose reason did not say it was
empty, and ``hil run`` printed "records in OUT:" followed by "None"."""

from __future__ import annotations

import os
import signal

import yaml

import hil.record.hdf5 as record_mod
from hil.bench.runtime import Bench
from hil.cli.main import main
from hil.record.hdf5 import RunRecord
from hil.run.runner import Runner
from hil.scene.spec import load_scene, scene_from_dict


def _scene() -> object:
    d = yaml.safe_load(load_scene("sdea_bench").source_text)
    d.pop("certification", None)
    d["experiments"] = d["experiments"][:1]
    d["experiments"][0].update(duration=0.5, periods=2, f0=4.0)
    return scene_from_dict(d, label="first-sample-test")


def test_a_stop_between_the_records_creation_and_the_first_sample_is_said_in_the_record(tmp_path, monkeypatch):
    made = []

    class Writer(record_mod.RecordWriter):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            made.append(self)
            os.kill(os.getpid(), signal.SIGINT)  # a flag (STOP is installed): the first tick's safe point stops

    monkeypatch.setattr(record_mod, "RecordWriter", Writer)
    (o,) = Runner(_scene(), tmp_path).run()
    assert o.status == "interrupted" and o.record is not None
    assert o.stop_reason == "signal: SIGINT (before the first sample: the record holds none)"
    rec = RunRecord.open(o.record)
    assert rec.t.size == 0 and rec.closed and rec.stop_reason == o.stop_reason and made[0].samples == 0


def test_hil_run_that_recorded_nothing_says_so_and_leaves_no_folder(tmp_path, monkeypatch, capsys):
    orig = Bench._open_devices

    def opening(self):
        orig(self)
        os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(Bench, "_open_devices", opening)
    scene = tmp_path / "s.yaml"
    scene.write_text(_scene().source_text, encoding="utf-8")
    out = tmp_path / "runs" / "x"
    code = main(["run", str(scene), "--lockstep", "--out", str(out)])
    printed = capsys.readouterr().out
    assert code == 130
    assert "no record was written (the run stopped before its first sample)" in printed and "None" not in printed
    assert not out.exists()
