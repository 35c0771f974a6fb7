"""Freshness from the device and a watchdog that means ``watchdog_ms`` (issue 10, items 2, 4, 8).

Every timing here is read from the record or the simulated clock of a lockstep run, never from
wall-clock sleeps: the stop tick is a function of the scene, the fault plan and the seed.
"""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from hil.bench.runtime import LOCKSTEP_WAIT_FACTOR, Bench
from hil.cli.main import main
from hil.errors import SafetyStop
from hil.record.hdf5 import RunRecord
from hil.run.runner import Runner, SafetyMonitor
from hil.scene.spec import load_scene, scene_from_dict

pytestmark = pytest.mark.timeout(300)


def _scene(name: str, edit, label: str = "watchdog-test"):
    d = yaml.safe_load(load_scene(name).source_text)
    edit(d)
    return scene_from_dict(d, label=label), d


def _first_experiment_only(d: dict, duration: float = 1.0) -> None:
    d["experiments"] = d["experiments"][:1]
    d["experiments"][0]["duration"] = duration
    d.pop("certification", None)


def _stop_event_time(rec: RunRecord) -> float:
    ev = [e for e in rec.events if e.get("kind") == "safety_stop"]
    assert ev, rec.events
    return float(ev[0]["t"])


def _last_change_index(x: np.ndarray) -> int:
    """Index of the last sample that differs from its predecessor (the last fresh sample of a
    signal that keeps changing while fresh)."""
    x = np.asarray(x).reshape(x.shape[0], -1)
    changed = np.flatnonzero(np.any(np.diff(x, axis=0) != 0, axis=1))
    return int(changed[-1]) + 1


# -- the SafetyMonitor on its own -----------------------------------------------------------------
def _sample(t: float, produced_at: float, seq: int = 1):
    return SimpleNamespace(t=t, produced_at=produced_at, seq=seq, position=np.zeros(1), velocity=np.zeros(1))


def test_monitor_stops_on_data_older_than_watchdog_naming_the_device():
    mon = SafetyMonitor({"watchdog_ms": 20}, rate_hz=1000.0)
    mon.check_feedback(0.0, {"motor": _sample(0.020, 0.0)})  # exactly 20 ms old: still fine
    with pytest.raises(SafetyStop, match=r"watchdog: feedback of 'motor' is 21\.0 ms old \(limit 20 ms"):
        mon.check_feedback(0.0, {"motor": _sample(0.021, 0.0)})


def test_monitor_age_is_judged_on_the_adapter_clock_not_the_run_time():
    """Run time t is irrelevant when the sample carries its own dates (same seq every tick)."""
    mon = SafetyMonitor({"watchdog_ms": 20}, rate_hz=1000.0)
    for k in range(100):
        mon.check_feedback(k * 1e-3, {"s": _sample(5.0 + k * 1e-3, 5.0 + k * 1e-3, seq=7)})


def test_monitor_without_produced_at_falls_back_to_the_sequence_number():
    mon = SafetyMonitor({"watchdog_ms": 20}, rate_hz=1000.0)
    s = SimpleNamespace(seq=3, position=None)
    mon.check_feedback(0.0, {"s": s})
    mon.check_feedback(0.020, {"s": s})
    with pytest.raises(SafetyStop, match="'s' stale for 21 ms"):
        mon.check_feedback(0.021, {"s": s})


def test_monitor_nan_age_is_a_stop():
    mon = SafetyMonitor({"watchdog_ms": 20}, rate_hz=1000.0)
    with pytest.raises(SafetyStop, match="'m'"):
        mon.check_feedback(0.0, {"m": _sample(math.nan, 0.0)})


# -- timeouts and device watchdogs come from the scene ----------------------------------------------
def test_bench_timeouts_and_device_watchdogs_derive_from_watchdog_ms():
    sc, _ = _scene("sdea_bench", lambda d: d["safety"].update(watchdog_ms=30))
    with Bench(sc, variant="locked") as bench:
        assert bench.watchdog_s == pytest.approx(0.030)
        assert bench.timeout == pytest.approx(LOCKSTEP_WAIT_FACTOR * 0.030)  # wall wait of a lockstep bench
        motor = bench._devs[0]
        assert motor.adapter.watchdog_armed
        assert motor.sim.watchdog_configured and motor.sim.watchdog_ticks == 60  # 30 ms at 2 kHz
    with Bench(sc, variant="locked", timeout=0.25) as bench:
        assert bench.timeout == 0.25


def test_dynamixel_bus_watchdog_armed_from_the_scene():
    from hil.mocks.dynamixel_devices import ADDR_BUS_WATCHDOG

    sc, _ = _scene("dynamixel_leader_follower", lambda d: d["safety"].update(watchdog_ms=45))
    with Bench(sc) as bench:
        chains = {id(d.chain): d.chain for d in bench._devs if d.chain is not None}
        for chain in chains.values():
            assert {s.table[ADDR_BUS_WATCHDOG] for s in chain.servos.values()} == {3}  # ceil(45 / 20)


def test_simulated_drive_watchdog_stops_a_motor_the_host_no_longer_commands():
    """The host goes silent (no command, no read): after watchdog_ms of simulated time the ODrive
    idles itself and latches WATCHDOG_TIMER_EXPIRED; the next read reports it."""
    from hil.errors import DeviceFault

    sc, _ = _scene("sdea_bench", lambda d: None)
    with Bench(sc, variant="locked") as bench:
        bench.read()
        bench.command({"motor": [0.3]})
        node = bench._devs[0].sim
        ticks = 0
        while node.axis_state == 8 and ticks < 1000:
            bench.advance()
            ticks += 1
        assert ticks == round(0.050 / sc.dt) + 1  # first tick past 50 ms without a torque command
        assert node.applied_motor_torque() == 0.0 and node.watchdog_expired == 1
        for _ in range(node.heartbeat_every):  # the next heartbeat carries the error
            bench.advance()
        with pytest.raises(DeviceFault, match="WATCHDOG_TIMER_EXPIRED"):
            bench.read()


# -- stale and silent devices end in a safe stop within watchdog_ms + one tick ---------------------
def _cyclic_motor(faults: dict):
    def edit(d):
        _first_experiment_only(d)
        d["devices"][0]["params"]["feedback"] = "cyclic"
        d["devices"][0]["sim"] = {"faults": faults}
    return edit


@pytest.mark.parametrize("faults", [{"stale_at_tick": 400}, {"disconnect_at_tick": 400}],
                         ids=["stale-estimates", "silent-drive"])
def test_stale_or_silent_odrive_stops_within_watchdog_plus_one_tick(tmp_path, faults):
    sc, _ = _scene("sdea_bench", _cyclic_motor(faults))
    o = Runner(sc, tmp_path).run()[0]
    assert o.status == "safety_stop" and "watchdog: feedback of 'motor'" in o.stop_reason, o.stop_reason
    rec = RunRecord.open(o.record)
    pos = rec.channels["motor.position"]
    fresh = _last_change_index(pos)
    assert np.all(pos[fresh:] == pos[fresh])  # the stale data is in the record
    t_fresh, t_stop = float(rec.t[fresh]), _stop_event_time(rec)
    w, dt = sc.safety.watchdog_ms / 1000.0, sc.dt
    assert w < t_stop - t_fresh <= w + dt + 1e-12
    assert t_stop - t_fresh == pytest.approx((math.floor(w / dt + 1e-9) + 1) * dt)
    assert rec.t[-1] == pytest.approx(t_stop)  # every tick up to and including the breach tick is recorded


def test_stale_bota_frames_stop_within_watchdog_plus_one_tick_deterministically(tmp_path):
    def edit(d):
        _first_experiment_only(d)
        d["devices"][1]["sim"] = {"measure": "body", "faults": {"stale_at_tick": 300}}

    sc, _ = _scene("sdea_bench", edit)
    stops = []
    for run in ("a", "b"):
        o = Runner(sc, tmp_path / run).run()[0]
        assert o.status == "safety_stop" and "'spring_ft'" in o.stop_reason, o.stop_reason
        rec = RunRecord.open(o.record)
        wrench = rec.channels["spring_ft.wrench"]
        fresh = _last_change_index(wrench)
        t_fresh, t_stop = float(rec.t[fresh]), _stop_event_time(rec)
        w, dt = sc.safety.watchdog_ms / 1000.0, sc.dt
        assert w < t_stop - t_fresh <= w + dt + 1e-12
        stops.append((t_stop, rec.t.size, o.stop_reason))
    assert stops[0] == stops[1]


def test_polled_odrive_repeating_nothing_new_is_a_safe_stop_exit_20(tmp_path, capsys):
    """The issue's case: the simulated ODrive "repeating its last estimate forever" (stale_prob 1:
    no new estimate, so no answer) used to complete with exit 0."""
    _, d = _scene("sdea_bench", lambda d: (_first_experiment_only(d),
                                            d["devices"][0].update(sim={"faults": {"stale_prob": 1.0}})))
    f = tmp_path / "stale_odrive.yaml"
    f.write_text(yaml.safe_dump(d))
    code = main(["run", str(f), "--out", str(tmp_path / "out"), "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 20
    (exp,) = out["experiments"]
    assert exp["status"] == "safety_stop" and "device 'motor'" in exp["stop_reason"], exp["stop_reason"]


def test_cyclic_stale_odrive_via_cli_exit_20_naming_the_device(tmp_path, capsys):
    _, d = _scene("sdea_bench", _cyclic_motor({"stale_at_tick": 100}))
    f = tmp_path / "stale_cyclic.yaml"
    f.write_text(yaml.safe_dump(d))
    code = main(["run", str(f), "--out", str(tmp_path / "out"), "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 20
    assert "feedback of 'motor'" in out["experiments"][0]["stop_reason"]


# -- fault counters ---------------------------------------------------------------------------------
def test_device_counters_are_per_device_ints_that_count_injected_faults():
    def edit(d):
        # 1 kHz loop: the Bota (sinc 51, 1004 Hz) then sends exactly one frame per tick over these 30
        # ticks (its first second frame in one tick comes at ~255 ms), so each fault tick hits a frame
        d["rate_hz"] = 1000
        d["experiments"] = [e for e in d["experiments"] if e["type"] == "static_hold"]  # chirps need 2 kHz
        d.pop("certification")
        d["devices"][1]["sim"] = {"measure": "body", "faults": {"corrupt_ticks": [5, 9], "stale_at_tick": 20,
                                                                 "stale_until_tick": 23}}

    sc, _ = _scene("sdea_bench", edit)
    with Bench(sc, variant="locked") as bench:
        for _ in range(30):
            bench.read()
            bench.command({"motor": [0.0]})
            bench.advance()
        c = bench.device_counters()
    assert set(c) == {"motor", "spring_ft"}
    assert all(isinstance(v, int) for d in c.values() for v in d.values())
    json.dumps(c)
    bota = c["spring_ft"]
    assert bota["crc_errors"] == 2  # two frames destroyed
    assert bota["repeated_frames"] == 3  # three frozen frames (same timestamp)
    assert bota["stale"] == 3 + 2  # reads without new data: the 3 frozen and the 2 destroyed ticks
    assert bota["dropped"] == 2 + 3  # samples missing from the timestamps: 2 destroyed, 3 frozen
    assert c["motor"] == {"error_frames": 0, "stale": 0, "late": 0, "retries": 0, "timeouts": 0}


def test_simulated_can_command_log_is_bounded():
    from hil.mocks.can_devices import LOG_LEN

    sc, _ = _scene("sdea_bench", lambda d: None)
    with Bench(sc, variant="locked") as bench:
        node = bench._devs[0].sim
        for k in range(LOG_LEN + 500):
            bench.command({"motor": [1e-4 * (k % 7)]})
            bench.advance()
        assert len(node.commands) == LOG_LEN and node.commands_total == LOG_LEN + 500
        assert node.commands[-1][1] == pytest.approx(1e-4 * ((LOG_LEN + 499) % 7), rel=1e-6)
