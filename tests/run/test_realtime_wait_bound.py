"""The watchdog bounds every wait, on every bench (issue 27 item 8).

An in-process simulated bench is a lockstep bench: its own device timeout is
``LOCKSTEP_WAIT_FACTOR`` x ``watchdog_ms`` (1 s at 50 ms), because in a lockstep run the wall-clock
wait only bounds how long the host waits for a reply the simulator is sure to send. Run in realtime
mode, though, the loop is on the wall clock, and a device that does not answer within
``watchdog_ms`` is lost: before, such a run stopped about 1 s after the loss. Now the realtime
runner passes ``watchdog_ms`` (or the bench's timeout when shorter) to every read and command.

The adapters' calls are spied on, so what is asserted is the bound each wait was given, never how
long anything took; the loop's pacing runs on a fake clock.
"""

from __future__ import annotations

import pytest
import yaml
from test_realtime import FakeClock

from hil.bench.runtime import LOCKSTEP_WAIT_FACTOR, Bench
from hil.run.runner import Runner
from hil.scene.spec import load_scene, scene_from_dict

pytestmark = pytest.mark.timeout(120)


def _scene(faults: dict | None = None):
    d = yaml.safe_load(load_scene("sdea_bench").source_text)
    d["experiments"] = d["experiments"][:1]
    d["experiments"][0]["duration"] = 0.3
    d.pop("certification", None)
    if faults:
        d["devices"][0]["sim"] = {"faults": faults}
    return scene_from_dict(d, label="wait-bound-test")


def _spied(scene, waits: list[tuple[str, str, float | None]]):
    def make(variant):
        b = Bench(scene, seed=scene.seed, variant=variant)
        for name, dev in {**b.actuators, **b.sensors}.items():
            read, command = dev.read, getattr(dev, "command_effort", None)

            def spy_read(timeout=None, _r=read, _n=name):
                waits.append((_n, "read", timeout))
                return _r(timeout)

            dev.read = spy_read
            if hasattr(dev, "wait_rx"):  # a simulated stream's pty byte barrier
                def spy_wait(n, timeout, _w=dev.wait_rx, _n=name):
                    waits.append((_n, "byte barrier", timeout))
                    return _w(n, timeout)

                dev.wait_rx = spy_wait
            if command is not None:
                def spy_command(effort, timeout=None, _c=command, _n=name):
                    waits.append((_n, "command", timeout))
                    return _c(effort, timeout)

                dev.command_effort = spy_command
        return b

    return make


def _realtime(scene, out, waits):
    fc = FakeClock()
    return Runner(scene, out, realtime=True, bench_factory=_spied(scene, waits), clock_ns=fc.clock,
                  sleep=fc.sleep, rt_scheduling=False)


def test_every_device_wait_of_a_realtime_loop_on_an_in_process_bench_is_bounded_by_the_watchdog(tmp_path):
    sc = _scene()
    waits: list[tuple[str, str, float | None]] = []
    o = _realtime(sc, tmp_path, waits).run()[0]
    assert o.status == "completed", o.stop_reason
    w = sc.safety.watchdog_ms / 1000.0
    # before: the bench's own lockstep bound, 20 x watchdog_ms (1 s at 50 ms); on simulated time
    # (issue 26) a lockstep bench's factor is LOCKSTEP_WAIT_FACTOR, a realtime loop's bound stays watchdog_ms
    assert LOCKSTEP_WAIT_FACTOR >= 1.0
    calls = {kind: [t for _, k, t in waits if k == kind] for kind in ("read", "command", "byte barrier")}
    ticks = round(0.3 * sc.rate_hz)
    assert len(calls["read"]) >= 2 * ticks and len(calls["command"]) >= ticks and len(calls["byte barrier"]) >= ticks
    bounds = [t for v in calls.values() for t in v]
    assert all(t is not None and t <= w for t in bounds), sorted({t for *_, t in waits}, key=str)


def test_a_device_lost_in_realtime_on_an_in_process_bench_stops_on_a_wait_of_watchdog_ms(tmp_path):
    sc = _scene({"disconnect_at_tick": 200})
    waits: list[tuple[str, str, float | None]] = []
    o = _realtime(sc, tmp_path, waits).run()[0]
    assert o.status == "safety_stop" and o.stop_reason.startswith("watchdog:") and "'motor'" in o.stop_reason
    last = [t for name, kind, t in waits if name == "motor" and kind == "read"][-1]
    assert last == sc.safety.watchdog_ms / 1000.0  # the read that found the drive gone waited that long
