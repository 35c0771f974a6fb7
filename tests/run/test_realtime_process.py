"""Realtime mode of a simulated scene serves the devices from another process (issue 17), and
``hil run --realtime`` ends a late loop in a safe stop with exit 20.

The process test opens real adapters on devices served by ``hil mock serve`` in a child process; it
asserts what crosses the boundary (samples, commands, the child's life cycle), never how fast.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import yaml

from hil.bench.runtime import Bench, ProcessSimBench
from hil.scene.spec import load_scene, scene_from_dict

pytestmark = pytest.mark.timeout(180)


def _scene():
    d = yaml.safe_load(load_scene("sdea_bench").source_text)
    d["experiments"] = d["experiments"][:1]
    d["experiments"][0]["duration"] = 0.5
    d.pop("certification", None)
    return scene_from_dict(d, label="realtime-process-test"), d


def test_devices_are_served_by_another_process_and_stop_with_the_bench():
    sc, _ = _scene()
    with ProcessSimBench(sc, variant="locked", timeout=2.0) as b:  # generous: what is read, not how fast
        child = b._proc
        assert child is not None and child.pid != os.getpid() and child.poll() is None
        assert not b.simulated and b.simulator is None  # this process holds adapters only
        assert b._endpoint_params["motor"][1]["interface"] == "udp_multicast"
        assert b._endpoint_params["spring_ft"][1]["url"].startswith("/dev/")
        s1 = b.read()
        b.command({"motor": [0.05]})
        s2 = b.read()
        assert s2["motor"].seq > s1["motor"].seq  # fresh samples from the served ODrive
        assert np.isfinite(s2["spring_ft"].wrench).all()
        b.advance()  # no-op: the plant runs on its own in the child
        # placement: every thread of the child off the loop's CPU (set before exec, so none escapes)
        from hil.run.realtime import loop_cpu

        lc = loop_cpu()
        tids = [int(t) for t in os.listdir(f"/proc/{child.pid}/task")]
        assert len(tids) > 1  # the device threads are running
        if lc is not None:
            assert all(lc not in os.sched_getaffinity(t) for t in tids)
        policies = {os.sched_getscheduler(t) for t in tids}
        assert ("SCHED_FIFO 70" in b.placement and policies == {os.SCHED_FIFO}) or (
            "not set" in b.placement and "\n" not in b.placement)
        # the CAN frames stay on this host: multicast TTL 0 on this side's socket (and in the child's config)
        import socket

        sock = b._devs[0].adapter._bus._multicast._socket
        assert sock.getsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL) == 0
        env = Path(f"/proc/{child.pid}/environ").read_bytes().split(b"\0")
        can_config = [json.loads(e.split(b"=", 1)[1]) for e in env if e.startswith(b"CAN_CONFIG=")]
        assert can_config and can_config[0]["hop_limit"] == 0
    assert child.returncode is not None  # the child was stopped with the bench


def test_runner_uses_the_process_bench_for_a_simulated_scene_in_realtime_mode(monkeypatch, tmp_path):
    from hil.run.runner import Runner

    sc, _ = _scene()
    made = []
    monkeypatch.setattr("hil.bench.runtime.ProcessSimBench",
                        lambda scene, **kw: made.append("process") or Bench(scene, **kw))
    r = Runner(sc, tmp_path, realtime=True, rt_scheduling=False)
    r.bench_factory("locked").close()
    assert made == ["process"]
    r = Runner(sc, tmp_path)  # lockstep (the scene's mode): the in-process bench
    b = r.bench_factory("locked")
    assert type(b) is Bench
    b.close()


def test_hil_run_realtime_late_tick_is_exit_20_with_the_reason(monkeypatch, tmp_path, capsys):
    """``hil run --realtime`` with a tick made 30 ms late (fake clock charged by a slow read): exit
    20, the reason in the JSON output and in the record."""
    import hil.run.realtime as rt
    from hil.cli.main import main
    from hil.record.hdf5 import RunRecord

    _, d = _scene()
    d["safety"]["max_lateness_ms"] = 10
    f = tmp_path / "late.yaml"
    f.write_text(yaml.safe_dump(d))
    now = {"ns": 10**9}

    def clock():
        now["ns"] += 1_000
        return now["ns"]

    def sleep(s):
        now["ns"] += round(s * 1e9)

    class FakePacer(rt.Pacer):
        def __init__(self, rate_hz, **kw):
            super().__init__(rate_hz, clock_ns=clock, sleep=sleep)

    real_sched = rt.realtime_scheduling
    monkeypatch.setattr(rt, "Pacer", FakePacer)
    monkeypatch.setattr(rt, "realtime_scheduling", lambda **kw: real_sched(enabled=False))

    def slow_bench(scene, **kw):
        b = Bench(scene, **kw)
        orig, n = b.read, {"reads": 0}

        def read(*a, **k):
            n["reads"] += 1
            if n["reads"] == 21:  # loop tick 19's read: tick 20 starts 29.5 ms late
                now["ns"] += 30_000_000
            return orig(*a, **k)
        b.read = read
        return b

    monkeypatch.setattr("hil.bench.runtime.ProcessSimBench", slow_bench)
    code = main(["run", str(f), "--realtime", "--out", str(tmp_path / "out"), "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 20
    (exp,) = out["experiments"]
    assert exp["status"] == "safety_stop" and exp["stop_reason"].startswith("late loop: tick 20 started 29.5")
    rec = RunRecord.open(exp["record"])
    assert rec.stop_reason == exp["stop_reason"] and rec.channels["loop.late"][-1, 0] == pytest.approx(0.0295, abs=1e-5)
