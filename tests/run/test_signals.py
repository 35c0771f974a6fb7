"""Every stop is a safe stop: SIGINT / SIGTERM / SIGHUP are flags handled at safe points.

Black-box through ``hil run`` in subprocesses where possible: signals at random points of a
multi-experiment lockstep run end the whole run (exit 20 / 130, every record closed with the
reason, no later experiment started); a second signal during a deliberately slowed safe stop still
zeroes every actuator; a third one ends the process only after the safe stop. In-process: a signal
while the bench opens, between experiments and while the last bench closes.
"""

from __future__ import annotations

import json
import os
import random
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from hil.bench.runtime import Bench
from hil.bench.stopflag import STOP, StopRequest
from hil.record.hdf5 import RunRecord
from hil.run.runner import Runner
from hil.scene.spec import load_scene

SCENE_YAML = Path(__file__).resolve().parents[2] / "hil" / "scene" / "builtin" / "sdea_bench.yaml"
EXPECTED = {"SIGTERM": ("safety_stop", 20), "SIGHUP": ("safety_stop", 20), "SIGINT": ("interrupted", 130)}


@pytest.fixture(scope="module")
def short_scene(tmp_path_factory):
    """sdea_bench with short experiments: chirp_locked, chirp_free (1 s each), static_hold (0.6 s)."""
    d = yaml.safe_load(SCENE_YAML.read_text())
    d.pop("certification", None)
    for e in d["experiments"]:
        if e["type"] == "chirp":
            e.update(duration=1.0, periods=2, f0=2.0)
        else:
            e.update(duration=0.6, settle=0.3)
    p = tmp_path_factory.mktemp("scene") / "sdea_short.yaml"
    p.write_text(yaml.safe_dump(d, sort_keys=False))
    return p


def _names(scene_path):
    sc = load_scene(str(scene_path))
    return [f"{i:02d}_{e['name']}" for i, e in enumerate(sc.experiment_configs())]


def _check_stopped_run(doc, out, names, sig):
    """The run stopped on ``sig``: completed experiments, then exactly one stopped one, then none;
    every record on disk belongs to an outcome, is closed, and says why."""
    status, _ = EXPECTED[sig]
    exps = doc["experiments"]
    assert [e["name"] for e in exps] == names[: len(exps)]
    assert all(e["status"] == "completed" for e in exps[:-1]), exps
    last = exps[-1]
    if last["status"] == "completed":  # signal while the last bench closed
        assert len(exps) == len(names)
    else:
        assert last["status"] == status and last["stop_reason"].startswith(f"signal: {sig}"), last
        if last["record"] is None:
            assert last["stop_reason"].endswith(("(before it started)", "(while the bench was opening)")), last
    assert doc["stop"] == {"status": status, "reason": f"signal: {sig}"}
    on_disk = sorted(p.name for p in out.glob("*.h5"))
    assert on_disk == sorted(Path(e["record"]).name for e in exps if e["record"]), "no later experiment started"
    for e in exps:
        if not e["record"]:
            continue
        rec = RunRecord.open(e["record"])
        assert rec.closed and (rec.status, rec.stop_reason) == (e["status"], e["stop_reason"])
        assert rec.t.size == e["loop"]["ticks"]
        if e["status"] != "completed":
            kinds = [ev["kind"] for ev in rec.events]
            assert status in kinds and "safe_stop" in kinds


def test_signal_at_random_points_ends_the_whole_run_with_closed_records(short_scene, tmp_path):
    names = _names(short_scene)
    rng = random.Random(10)
    sigs = ["SIGTERM", "SIGINT", "SIGHUP", "SIGTERM", "SIGINT", "SIGTERM"]
    stopped = 0
    for trial, sig in enumerate(sigs):
        out = tmp_path / f"run{trial}"
        marker = out / f"{names[rng.choice([0, 0, 1])]}.h5"  # readiness: that experiment's record exists
        delay = rng.uniform(0.0, 0.8)
        p = subprocess.Popen([sys.executable, "-m", "hil.cli.main", "run", str(short_scene), "--lockstep", "--out",
                              str(out), "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            t_end = time.monotonic() + 60
            while not marker.exists() and p.poll() is None and time.monotonic() < t_end:
                time.sleep(0.002)
            time.sleep(delay)
            sent = p.poll() is None
            if sent:
                p.send_signal(getattr(signal, sig))
            so, se = p.communicate(timeout=60)
        finally:
            if p.poll() is None:
                p.kill()
        if not sent:
            assert p.returncode == 0
            continue
        doc = json.loads(so)
        if doc["stop"] is None:  # the signal came after the results were printed: a complete run
            assert all(e["status"] == "completed" for e in doc["experiments"]) and len(doc["experiments"]) == 3
            continue
        stopped += 1
        print(sig, f"{delay:.2f}", marker.name, [(e["name"], e["status"], e["stop_reason"], e["loop"]["ticks"])
                                                 for e in doc["experiments"]])
        assert p.returncode == EXPECTED[sig][1], (sig, p.returncode, se[-1500:])
        assert "Traceback" not in se and "Exception ignored" not in se, se[-1500:]
        _check_stopped_run(doc, out, names, sig)
    assert stopped >= 4, f"only {stopped} of {len(sigs)} trials were stopped by their signal"


# -- in-process: opening, between experiments, closing ------------------------------------------


def _kill_self(sig=signal.SIGTERM):
    os.kill(os.getpid(), sig)


def test_signal_while_the_bench_opens_is_a_safe_stop_and_nothing_runs(short_scene, tmp_path, monkeypatch):
    orig = Bench._open_devices
    stops = []

    def opening(self):
        orig(self)  # every device opened (actuators armed) ...
        _kill_self()  # ... then SIGTERM

    monkeypatch.setattr(Bench, "_open_devices", opening)
    orig_stop = Bench.safe_stop
    monkeypatch.setattr(Bench, "safe_stop", lambda self: stops.append(orig_stop(self)) or stops[-1])
    r = Runner(load_scene(str(short_scene)), tmp_path)
    outs = r.run()
    assert [(o.status, o.stop_reason, o.record) for o in outs] == [
        ("safety_stop", "signal: SIGTERM (while the bench was opening)", None)]
    assert stops == [{"motor": "ok"}]  # zero effort went to the actuator before the bench closed
    assert r.stop_reason == "signal: SIGTERM" and not list(tmp_path.glob("*.h5"))
    assert signal.getsignal(signal.SIGTERM) is not STOP._handler  # handlers removed after the run


def test_signal_while_a_bench_closes_stops_before_the_next_experiment(short_scene, tmp_path, monkeypatch):
    orig = Bench.close
    closes = []

    def close(self):
        closes.append(1)
        if len(closes) == 1:
            _kill_self(signal.SIGINT)  # Ctrl-C while the first bench closes
        orig(self)

    monkeypatch.setattr(Bench, "close", close)
    r = Runner(load_scene(str(short_scene)), tmp_path, max_ticks=100)
    outs = r.run()
    assert [o.status for o in outs] == ["completed", "interrupted"]
    assert outs[1].stop_reason == "signal: SIGINT (before it started)" and outs[1].record is None
    assert sorted(p.name for p in tmp_path.glob("*.h5")) == ["00_chirp_locked.h5"]
    assert RunRecord.open(outs[0].record).status == "completed"
    assert (r.stop_status, r.stop_reason) == ("interrupted", "signal: SIGINT")


def test_signal_while_the_last_bench_closes_is_reported_by_the_run(short_scene, tmp_path, monkeypatch):
    from hil.cli.run import run_exit_code

    orig = Bench.close

    def close(self):
        _kill_self(signal.SIGHUP)
        orig(self)

    monkeypatch.setattr(Bench, "close", close)
    r = Runner(load_scene(str(short_scene)), tmp_path, max_ticks=50)
    outs = r.run([2])
    assert [o.status for o in outs] == ["completed"]
    assert (r.stop_status, r.stop_reason) == ("safety_stop", "signal: SIGHUP")
    assert run_exit_code(outs, r) == 20


def test_safe_stop_attempts_every_actuator_even_if_one_raises(tmp_path):
    from hil.errors import DeviceTimeout

    sc = load_scene("dual_master_3dof")
    with Bench(sc) as b:
        for _ in range(3):
            b.read()
            b.command({"master1": [0.5], "master2": [0.3, -0.2], "slave": [0.1, 0.2, 0.3]})
            b.advance()
        assert all(np.any(d.effort != 0) for d in b._drives.values())

        def broken():
            raise DeviceTimeout("master1: no answer in 0.05 s")

        b.actuators["master1"].safe_stop = broken
        done = b.safe_stop()
        assert done == {"master1": "DeviceTimeout: master1: no answer in 0.05 s", "master2": "ok", "slave": "ok"}
        assert np.all(b._drives["master2"].effort == 0) and np.all(b._drives["slave"].effort == 0)


def test_safe_stop_moves_on_from_a_hung_actuator():
    import threading

    sc = load_scene("dual_master_3dof")
    release = threading.Event()
    with Bench(sc) as b:
        b.safe_stop_timeout = 0.2
        for _ in range(3):
            b.read()
            b.command({"master1": [0.5], "master2": [0.3, -0.2], "slave": [0.1, 0.2, 0.3]})
            b.advance()
        orig = b.actuators["master2"].safe_stop

        def hung():
            release.wait(30)  # a bus that never answers
            orig()

        b.actuators["master2"].safe_stop = hung
        done = b.safe_stop()
        still_hung = any(t.name == "safe-stop-master2" and t.is_alive() for t in threading.enumerate())
        release.set()
        assert done == {"master1": "ok", "master2": "timeout after 0.2 s", "slave": "ok"}
        assert still_hung  # safe_stop returned without waiting for it ...
        assert np.all(b._drives["master1"].effort == 0) and np.all(b._drives["slave"].effort == 0)  # ... others zeroed


def test_stop_request_counts_and_escalation_rules():
    s = StopRequest()
    with s.install():
        assert signal.getsignal(signal.SIGTERM) == s._handler
        with s.install():  # re-entrant
            pass
        assert signal.getsignal(signal.SIGTERM) == s._handler
        exits = []
        s._force_exit = exits.append
        s._handler(signal.SIGTERM, None)
        assert (s.requested, s.reason, s.status, s.count) == (True, "signal: SIGTERM", "safety_stop", 1)
        s._handler(signal.SIGINT, None)  # second signal before any safe stop: wait for it
        s._handler(signal.SIGINT, None)  # third, before the safe stop: still wait for it
        assert exits == [] and s.reason == "signal: SIGTERM"
        with s.critical():
            s._handler(signal.SIGINT, None)  # fourth, inside the safe stop: deferred
            assert exits == []
        assert exits == [signal.SIGTERM]  # ... acted on once the safe stop is done
    assert signal.getsignal(signal.SIGTERM) != s._handler
    s2 = StopRequest()
    with s2.install():
        s2._force_exit = exits.append
        s2._handler(signal.SIGINT, None)
        assert s2.status == "interrupted"
        with s2.critical():
            s2._handler(signal.SIGINT, None)  # second during the safe stop: no exit
        assert len(exits) == 1
        s2._handler(signal.SIGINT, None)  # another one after the safe stop completed: exit
        assert exits[-1] == signal.SIGINT
    s3 = StopRequest()
    with s3.install():
        s3._force_exit = exits.append
        for _ in range(4):
            s3._handler(signal.SIGTERM, None)
        assert len(exits) == 2  # no safe point reached yet: waiting
        s3._handler(signal.SIGTERM, None)  # the fifth: escape hatch
        assert len(exits) == 3


# -- subprocess: a slowed safe stop and repeated signals ---------------------------------------

_SLOW_STOP = r'''
import json, sys, time
import numpy as np
from hil.bench.runtime import Bench
from hil.cli.run import run_exit_code
from hil.run.runner import Runner
from hil.scene.spec import load_scene
from hil.bench.stopflag import STOP

out, slow = sys.argv[1], float(sys.argv[2])
sc = load_scene("dual_master_3dof")
benches = []

def efforts(b):
    return {k: d.effort.tolist() for k, d in b._drives.items()}

def factory(variant):
    b = Bench(sc, seed=sc.seed, variant=variant)
    benches.append(b)
    for name, ad in b.actuators.items():
        def slow_stop(orig=ad.safe_stop, name=name):
            if STOP.in_critical and not getattr(b, "began", False):
                b.began = True
                print("SAFE_STOP_BEGIN", json.dumps(efforts(b)), flush=True)
            if STOP.in_critical:
                time.sleep(slow)  # a slow bus: every zero-effort frame takes this long
            orig()
        ad.safe_stop = slow_stop
    orig_flush = b._flush_devices
    def flush():
        orig_flush()
        if STOP.in_critical:
            print("FLUSHED", json.dumps(efforts(b)), flush=True)
    b._flush_devices = flush
    return b

def progress(name, k, n):
    # tick 400: every body driven (master2's DYNAMIXEL servos only from ~tick 300 since the twins
    # quantize their encoders); the run holds there until the signal has arrived, so the stop comes
    # at tick 400 however late a loaded machine delivers it (a state waited for, no deadline)
    if k >= 400 and not getattr(progress, "ready", False):
        progress.ready = True
        print("READY", flush=True)
        while not STOP.requested:
            time.sleep(0.001)

r = Runner(sc, out, bench_factory=factory, progress=progress, max_ticks=20000)
outs = r.run()
print("RESULT", json.dumps({"outcomes": [o.to_dict() for o in outs], "stop": r.stop_reason}, default=str), flush=True)
sys.exit(run_exit_code(outs, r))
'''


def _wait_line(p, prefix, timeout=60.0):
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        r, _, _ = select.select([p.stdout], [], [], 0.1)
        if r:
            line = p.stdout.readline()
            if not line:
                break
            if line.startswith(prefix):
                return line[len(prefix):].strip()
    raise AssertionError(f"no {prefix!r} line from the subprocess (rc {p.poll()})")


def _start_slow(tmp_path, slow=0.3):
    script = tmp_path / "slow_stop.py"
    script.write_text(_SLOW_STOP)
    out = tmp_path / "out"
    return out, subprocess.Popen([sys.executable, str(script), str(out), str(slow)], stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True)


def test_second_signal_during_a_slow_safe_stop_still_zeroes_every_actuator(tmp_path):
    out, p = _start_slow(tmp_path)
    try:
        _wait_line(p, "READY")
        p.send_signal(signal.SIGTERM)
        before = json.loads(_wait_line(p, "SAFE_STOP_BEGIN "))
        p.send_signal(signal.SIGINT)  # a second signal while the first actuator's stop is on the bus
        after = json.loads(_wait_line(p, "FLUSHED "))
        res = json.loads(_wait_line(p, "RESULT "))
        p.wait(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    assert sum(np.any(np.asarray(v) != 0) for v in before.values()) == 3, before  # all three bodies were driven
    assert all(np.all(np.asarray(v) == 0) for v in after.values()), after  # ... and all got zero
    assert p.returncode == 20
    (o,) = res["outcomes"]
    assert (o["status"], o["stop_reason"]) == ("safety_stop", "signal: SIGTERM")
    rec = RunRecord.open(o["record"])
    assert (rec.status, rec.stop_reason) == ("safety_stop", "signal: SIGTERM")
    assert res["stop"] == "signal: SIGTERM" and [p_.name for p_ in out.glob("*.h5")] == ["00_inject_operator1.h5"]


def test_third_signal_ends_the_process_only_after_the_safe_stop(tmp_path):
    out, p = _start_slow(tmp_path)
    try:
        _wait_line(p, "READY")
        p.send_signal(signal.SIGTERM)
        _wait_line(p, "SAFE_STOP_BEGIN ")
        p.send_signal(signal.SIGTERM)
        time.sleep(0.05)
        p.send_signal(signal.SIGTERM)
        after = json.loads(_wait_line(p, "FLUSHED "))
        rest, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    assert all(np.all(np.asarray(v) == 0) for v in after.values()), after
    assert p.returncode == -signal.SIGTERM and "RESULT" not in rest
    assert "SIGTERM received again: exiting now (safe stop done)" in err
    rec = RunRecord.open(out / "00_inject_operator1.h5")  # never closed, but readable up to the last flush
    assert not rec.closed and rec.t.size >= 400  # READY came at tick 400; flushed every 100 samples
