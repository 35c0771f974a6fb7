"""Glue between the runner, the adapters' fault counters, the record and the certificate: tolerated
faults are evidence (stored in the record, listed in a certificate's measurements); a signal during
the runs of ``hil certify`` ends the command (no identification, no certificate) with 130 / 20."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from hil.record.hdf5 import RunRecord
from hil.run.runner import Runner
from hil.scene.spec import load_scene, scene_from_dict

ROOT = Path(__file__).resolve().parents[2]


def _sdea_with_corrupt_frames(prob: float) -> object:
    d = yaml.safe_load(load_scene("sdea_bench").source_text)
    for dev in d["devices"]:
        if dev["name"] == "spring_ft":
            dev.setdefault("sim", {})["faults"] = {"corrupt_prob": prob}
    d["experiments"] = d["experiments"][:1]
    return scene_from_dict(d, label="sdea_bench-corrupt")


@pytest.mark.timeout(120)
def test_tolerated_crc_errors_are_stored_in_the_record(tmp_path):
    """Corrupted Bota frames are dropped by the adapter (CRC) and counted; the counts reach the
    record and the outcome. With corruption off the same counter is 0, so the count is not a
    constant of the code path."""
    counts = {}
    for prob in (0.0, 0.05):
        out = Runner(_sdea_with_corrupt_frames(prob), tmp_path / f"p{prob}", max_ticks=400).run()
        assert out and out[0].record is not None, out
        rec = RunRecord.open(out[0].record)
        assert set(rec.device_counters) >= {"spring_ft"}, rec.device_counters
        assert all(isinstance(v, int) for c in rec.device_counters.values() for v in c.values())
        assert out[0].results["device_counters"] == rec.device_counters
        counts[prob] = rec.device_counters["spring_ft"]["crc_errors"]
    assert counts[0.0] == 0
    assert counts[0.05] > 0, counts


def test_fault_counters_become_info_measurements():
    from types import SimpleNamespace

    from hil.certify.pipeline import _fault_measurements

    faulty = SimpleNamespace(results={"device_counters": {"spring_ft": {"crc_errors": 3, "resync_bytes": 40,
                                                                        "stale": 0}, "motor": {"timeouts": 0}}})
    clean = SimpleNamespace(results={"device_counters": {"spring_ft": {"crc_errors": 0}, "motor": {}}})
    ms: list = []
    _fault_measurements({"chirp_locked": faulty, "chirp_free": clean, "hold": SimpleNamespace(results={})}, ms)
    assert [m.name for m in ms] == ["device faults tolerated (chirp_locked)", "device faults tolerated (chirp_free)"]
    m, z = ms
    assert m.value == 43 and m.outcome == "INFO" and m.unit == "count"
    assert "spring_ft: crc_errors=3, resync_bytes=40" in m.description and "motor" not in m.description
    assert z.value == 0 and "none on 2 device(s)" in z.description


def test_stale_reads_are_not_faults():
    """A sensor slower than the loop leaves ticks without a new sample: listed, not counted."""
    from types import SimpleNamespace

    from hil.certify.pipeline import _fault_measurements

    slow = SimpleNamespace(results={"device_counters": {"spring_ft": {"crc_errors": 1, "stale": 15937}}})
    ms: list = []
    _fault_measurements({"chirp_locked": slow}, ms)
    (m,) = ms
    assert m.value == 1
    assert "crc_errors=1" in m.description and "reads without a new sample (held, not counted): spring_ft=15937" \
        in m.description


@pytest.mark.timeout(180)
@pytest.mark.parametrize(("sig", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 20)])
def test_a_signal_during_the_runs_of_certify_ends_the_command(tmp_path, sig, code):
    out = tmp_path / "cert"
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "COLUMNS": "200"}
    p = subprocess.Popen([sys.executable, "-m", "hil.cli.main", "certify", "sdea_bench", "--out", str(out)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path, env=env)
    # The signal is sent at a state, however long a loaded box takes: a record of the run is open in the
    # certify process. The folder is built under <out>.incomplete-<hex> and moved to <out> only at the
    # end (after identify, robust and reports), so the record is looked for there. The process is
    # frozen while that state is checked and the signal sent, so the run cannot end in between: the
    # signal reaches it while the record is open (during the run, where STOP handles it at the next tick).
    held = None
    while held is None and p.poll() is None:
        staged = list(tmp_path.glob(f"{out.name}.incomplete-*/records/*.h5"))
        if staged:
            p.send_signal(signal.SIGSTOP)
            held = _open_in(p.pid, staged)
            if held is None:
                p.send_signal(signal.SIGCONT)
                break
        else:
            time.sleep(0.01)
    assert held is not None, (p.poll(), p.communicate())
    p.send_signal(sig)  # pending until the process continues
    p.send_signal(signal.SIGCONT)
    _stdout, stderr = p.communicate()
    assert p.returncode == code, stderr
    assert f"signal: {signal.Signals(sig).name}" in stderr
    assert "Traceback" not in stderr
    assert not (out / "certificate.json").exists()  # nothing certified from a run the person stopped
    rec = out / "records" / held.name  # the stopped run's records are kept at --out
    r = RunRecord.open(rec)
    assert r.closed and "signal" in r.stop_reason, r.stop_reason


def _open_in(pid: int, paths: list[Path]) -> Path | None:
    """The first of ``paths`` that process ``pid`` holds open (a record being written), else None."""
    wanted = {os.path.realpath(q): q for q in paths}
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            target = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:
            continue
        if target in wanted:
            return wanted[target]
    return None
