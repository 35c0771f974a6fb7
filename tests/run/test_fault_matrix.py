"""Every injected fault kind x every device family ends in a safe stop or is counted in the record
(issue 27 item 7).

Each cell runs the family's scene in lockstep for a short experiment with one fault kind injected
into one simulated device (:mod:`hil.mocks.faults`), and reads the record:

* the run ended in a safe stop (status ``safety_stop``), or
* it completed and one of the counters that kind shows in (``COUNTED_IN``) is higher in the
  record's device counters than in the same run without the fault, or
* the kind is one the device documents it never injects (``NOT_INJECTED``), and its injector
  indeed injected none.

A cell where the fault was injected, the run completed, and no counter moved, fails: that is what
the issue found for CubeMars dropped/late/stale replies, FT-300 (Modbus/TCP and RTU) stale
readings and DYNAMIXEL stale readings and garbage bursts. A frozen *sensor* is a stale device: the
FT-300s and the Bota must stop on the watchdog when their readings freeze for good, the polled
FT-300 within ``watchdog_ms`` + one tick of its last fresh reading, as the timestamped Bota does.

Everything is read from the record or the simulated clock (lockstep); no wall-clock time is asserted.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np
import pytest
import yaml

from hil.bench.runtime import Bench
from hil.record.hdf5 import RunRecord
from hil.run.runner import Runner
from hil.scene.spec import load_scene, scene_from_dict

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

DURATION = 0.4  # s of the first experiment (2 kHz loop: 800 ticks)

#: family -> (built-in scene, device index, edit of that device, the device's tick for scheduled faults)
FAMILIES: dict[str, tuple[str, int, dict[str, Any], int]] = {
    "odrive": ("sdea_bench", 0, {}, 300),
    "cubemars": ("sdea_bench", 0, {"driver": "cubemars_mit",
                                   "params": {"interface": "virtual", "bitrate": 1000000, "channel": "hil0",
                                              "motor_id": 3}}, 300),
    "cia402": ("cia402_bench", 0, {}, 300),
    "bota": ("sdea_bench", 1, {}, 150),  # 1004 frames/s
    "ft300_tcp": ("dual_master_3dof", 4, {"sim": {"framing": "tcp"}}, 300),  # one tick per request
    "ft300_rtu": ("dual_master_3dof", 4, {"sim": {"framing": "rtu"}}, 300),
    "ft300_stream": ("sdea_bench", 1, {"driver": "robotiq_ft300_stream", "params": {"url": "/dev/ttyUSB0"}},
                     15),  # 100 frames/s
    "dynamixel": ("dynamixel_leader_follower", 0, {}, 600),  # one tick per instruction packet
}

#: fault kind -> plan (``T``: the family's tick for scheduled faults)
KINDS = {
    "drop": lambda T: {"drop_prob": 0.02, "drop_ticks": [T, T + 1, T + 2]},
    "corrupt": lambda T: {"corrupt_prob": 0.02, "corrupt_ticks": [T, T + 3]},
    # two ticks: a reply one tick late still comes before the next read of a request/response device
    # (CubeMars), i.e. on time for the loop, which reads once per tick
    "late": lambda T: {"late_prob": 0.05, "late_ticks": 2},
    "stale": lambda T: {"stale_prob": 0.2},
    "stale_forever": lambda T: {"stale_at_tick": T},
    "garbage": lambda T: {"garbage_prob": 0.05},
    "error": lambda T: {"error_code": 1, "error_at_tick": T},
    "disconnect": lambda T: {"disconnect_at_tick": T},
}

#: the injector's counter of each kind (FaultInjector.injected; disconnect and error are schedules)
INJECTED_AS = {"stale_forever": "stale"}

#: counters a completed run shows each kind in (any of them above the fault-free run's)
COUNTED_IN = {
    # a stream without a frame counter (FT-300) shows a dropped frame only as reads without new
    # data: "stale" (exact in lockstep, compared with the same run without the fault)
    "drop": {"dropped", "timeouts", "retries", "gaps", "stale"},
    "corrupt": {"crc_errors", "error_frames", "gateway_errors", "invalid_replies", "resync_bytes", "decode_errors"},
    "late": {"late", "skipped", "retries"},
    "stale": {"repeated_frames", "repeated", "frozen", "timeouts", "retries"},
    "stale_forever": {"repeated_frames", "repeated", "frozen", "timeouts", "retries"},
    "garbage": {"resync_bytes", "crc_errors"},
    "error": {"app_took_too_long", "exceptions", "emcy"},
    "disconnect": {"timeouts", "dropped", "gaps"},
}

#: (family, kind) a simulated device documents it never injects (its transport has no such fault)
NOT_INJECTED = {
    ("odrive", "garbage"), ("cubemars", "garbage"), ("cia402", "garbage"),  # CAN: message-based
    ("ft300_tcp", "late"), ("ft300_tcp", "garbage"),  # hil.mocks.modbus_devices: request/response
    ("ft300_rtu", "late"), ("ft300_rtu", "garbage"),
    ("dynamixel", "late"),  # hil.mocks.dynamixel_devices: drop, corrupt, garbage, stale, error
    ("ft300_stream", "error"),  # hil.mocks.ft300_stream: no place for an error code in the stream
}

#: sensors: readings frozen for good are a stale device (a safe stop on the watchdog)
SENSORS = {"bota", "ft300_tcp", "ft300_rtu", "ft300_stream"}


def _scene(family: str, faults: dict[str, Any] | None) -> tuple[Any, str]:
    name, idx, edit, _ = FAMILIES[family]
    d = yaml.safe_load(load_scene(name).source_text)
    d.pop("certification", None)
    d["experiments"] = d["experiments"][:1]
    d["experiments"][0]["duration"] = DURATION
    if "fade" in d["experiments"][0]:
        d["experiments"][0]["fade"] = 0.0  # the scene's fade would not fit the short chirp
    dev = d["devices"][idx]
    sim = dict(dev.get("sim") or {})
    sim.update(edit.get("sim", {}))
    dev.update({k: v for k, v in edit.items() if k != "sim"})
    if faults:
        sim["faults"] = faults
    dev["sim"] = sim
    return scene_from_dict(d, label=f"fault-matrix-{family}"), dev["name"]


def _run(family: str, faults: dict[str, Any] | None, out) -> tuple[Any, RunRecord | None, Any, str]:
    scene, dev = _scene(family, faults)
    benches: list[Bench] = []

    def factory(variant):
        b = Bench(scene, seed=scene.seed, variant=variant)
        benches.append(b)
        return b

    o = Runner(scene, out, bench_factory=factory).run()[0]
    rec = RunRecord.open(o.record) if o.record is not None else None
    sim = next(d.sim for d in benches[-1]._devs if d.name == dev) if benches else None
    return o, rec, sim, dev


_BASELINE: dict[str, dict[str, int]] = {}


def _baseline(family: str, tmp_path_factory) -> dict[str, int]:
    if family not in _BASELINE:
        o, rec, _, dev = _run(family, None, tmp_path_factory.mktemp(f"base-{family}"))
        assert o.status == "completed" and rec is not None, (family, o.stop_reason)
        _BASELINE[family] = dict(rec.device_counters.get(dev, {}))
    return _BASELINE[family]


@pytest.mark.parametrize("kind", list(KINDS))
@pytest.mark.parametrize("family", list(FAMILIES))
def test_each_fault_ends_in_a_safe_stop_or_is_counted_in_the_record(family, kind, tmp_path, tmp_path_factory, caplog):
    caplog.set_level(logging.ERROR)  # pymodbus and canopen log every injected fault
    plan = KINDS[kind](FAMILIES[family][3])
    o, rec, sim, dev = _run(family, plan, tmp_path)
    injected = dict(getattr(getattr(sim, "injector", None), "injected", {}) or {})
    if o.status == "safety_stop":
        assert rec is None or (rec.closed and rec.status == "safety_stop" and rec.stop_reason == o.stop_reason)
        return
    assert o.status == "completed", (family, kind, o.status, o.stop_reason)
    assert rec is not None and rec.closed
    counted = rec.device_counters.get(dev, {})
    base = _baseline(family, tmp_path_factory)
    moved = {k: (base.get(k, 0), counted.get(k, 0)) for k in COUNTED_IN[kind] if counted.get(k, 0) > base.get(k, 0)}
    if (family, kind) in NOT_INJECTED:
        assert injected.get(INJECTED_AS.get(kind, kind), 0) == 0, (family, kind, injected)
        return
    if kind not in ("error", "disconnect"):  # schedules, not draws: no injector count
        assert injected.get(INJECTED_AS.get(kind, kind), 0) > 0, (
            f"{family}/{kind}: the fault never happened during the run; choose a plan that hits it")
    assert moved, f"{family}/{kind}: injected {injected}, run completed, no counter moved: {counted} vs {base}"


@pytest.mark.parametrize("family", sorted(SENSORS))
def test_a_sensor_frozen_for_good_is_a_stale_device(family, tmp_path):
    o, rec, _, dev = _run(family, KINDS["stale_forever"](FAMILIES[family][3]), tmp_path)
    assert o.status == "safety_stop" and f"watchdog: feedback of '{dev}'" in o.stop_reason, o.stop_reason
    if family in ("ft300_tcp", "ft300_rtu"):  # polled every tick: the stop tick is exact
        assert rec is not None
        scene, _ = _scene(family, None)
        col = next(k for k in rec.channels if k.startswith(f"{dev}.") and rec.channels[k].ndim == 2
                   and rec.channels[k].shape[1] > 1)
        x = rec.channels[col]
        changed = np.flatnonzero(np.any(np.diff(x, axis=0) != 0, axis=1))
        fresh = int(changed[-1]) + 1  # the last fresh reading
        assert np.all(x[fresh:] == x[fresh])
        stop = next(float(e["t"]) for e in rec.events if e.get("kind") == "safety_stop")
        w, dt = scene.safety.watchdog_ms / 1000.0, scene.dt
        assert w < stop - float(rec.t[fresh]) <= w + dt + 1e-12
        assert stop - float(rec.t[fresh]) == pytest.approx((math.floor(w / dt + 1e-9) + 1) * dt)
