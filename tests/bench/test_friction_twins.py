"""Friction and encoders of the simulated twins on a bench (hil.bench.mechanics, scene options).

The device kinds' defaults (hil.mocks.twins) reach the simulated plant, the scene's
``devices[].sim.friction`` / ``sim.encoder`` replace them, an encoder quantizes what the adapter reads
and a ``difference`` velocity is the quantized positions' backward difference over one period.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from hil.bench.mechanics import body_truth, device_mechanics, friction_truth
from hil.bench.runtime import Bench
from hil.errors import SceneError
from hil.mocks.twins import CUBEMARS, DYNAMIXEL, ODRIVE
from hil.scene.spec import load_scene, scene_from_dict


def _axis_scene(sim: dict[str, Any] | None = None, *, B: float = 50.0) -> dict[str, Any]:
    """A 1-DOF linear axis (20 kg) on one ODrive in linear mode, no experiment."""
    dev: dict[str, Any] = {"name": "axis", "role": "actuator", "driver": "odrive_can", "dof": 1, "body": "axis",
                           "params": {"interface": "virtual", "bitrate": 1000000, "channel": "hil0", "node_id": 1,
                                      "linear_scale": 0.01}}
    if sim is not None:
        dev["sim"] = sim
    return {"name": "axis", "seed": 0, "rate_hz": 1000, "mode": "lockstep", "units": "linear",
            "devices": [dev], "simulation": {"bodies": [{"name": "axis", "M": 20.0, "B": B}]},
            "network": {"ports": [{"name": "p", "actuator": "axis", "dofs": 1}]},
            "controller": {"type": "none"}, "safety": {"max_effort": 500.0, "max_velocity": 5.0,
                                                       "position_limits": [-1.0, 1.0]}}


def test_kind_defaults_reach_the_plant_and_the_scene_replaces_them() -> None:
    sc = load_scene("dynamixel_leader_follower")
    assert device_mechanics(sc.device("leader")) == DYNAMIXEL.mechanics
    with Bench(sc) as bench:
        ss = bench.simulator.stick_slip
        assert ss is not None and len(ss.dofs) == 2  # leader and follower, each its servo's gear friction
        assert {ss.fr[j] for j in ss.dofs} == {DYNAMIXEL.mechanics.friction}
        step = DYNAMIXEL.mechanics.encoder_step
        for _ in range(50):
            bench.command({"leader": [0.1]})
            bench.advance()
        q = bench.read()["leader"].position[0]
        assert q != 0.0 and abs(q / step - round(q / step)) < 1e-9  # on the 4096-pulse grid
    import yaml

    d = yaml.safe_load(sc.source_text)
    for dev in d["devices"]:
        dev["sim"] = {"friction": {"coulomb": 0.0}}
    with Bench(scene_from_dict(d, label="no-friction")) as bench:
        assert bench.simulator.stick_slip is None
    # drives add none: the ODrive/CiA 402 built-in benches keep their linear twins (and their records)
    assert ODRIVE.mechanics.friction.active is False and CUBEMARS.mechanics.friction.F_c > 0
    with Bench(load_scene("sdea_bench")) as bench:
        assert bench.simulator.stick_slip is None


def test_scene_friction_and_viscous_reach_the_body() -> None:
    sc = scene_from_dict(_axis_scene({"friction": {"coulomb": 20.0, "static": 25.0, "stribeck_velocity": 0.01,
                                                   "viscous": 150.0}}), label="axis")
    with Bench(sc) as bench:
        plant = bench.plant
        # v' row of the axis: -(B_body + viscous)/M
        assert plant.system.A[1, 1] == pytest.approx(-(50.0 + 150.0) / 20.0, rel=1e-14)
        ss = bench.simulator.stick_slip
        assert ss is not None and ss.fr[0].F_c == 20.0 and ss.fr[0].F_s == 25.0
        # a force below the breakaway level moves nothing at all (commanded every tick: the drive's
        # CAN watchdog idles an axis that hears nothing for watchdog_ms)
        for _ in range(100):
            bench.command({"axis": [24.0]})
            bench.advance()
        assert bench.simulator.state[0] == 0.0 and bench.read()["axis"].position[0] == 0.0
    # identification's F_s is the Stribeck excess (break-away F_c + F_s): 25 - 20
    assert friction_truth(sc, "axis") == {"F_c": 20.0, "F_0": 0.0, "F_s": 5.0, "v_s": 0.01}
    assert body_truth(sc, "axis") == {"M": 20.0, "B": 200.0}


def test_encoder_quantizes_and_difference_velocity_is_the_backward_difference() -> None:
    step = 1e-5
    sc = scene_from_dict(_axis_scene({"friction": {"coulomb": 5.0}, "encoder": {"step": step,
                                                                              "velocity": "difference"}}),
                         label="axis")
    with Bench(sc) as bench:
        sim = bench.simulator
        qs, vs, q_true = [], [], []
        for k in range(400):
            bench.command({"axis": [30.0 * math.sin(2 * math.pi * 2.0 * k / 1000.0)]})
            bench.advance()
            s = bench.read()["axis"]
            qs.append(float(s.position[0]))
            vs.append(float(s.velocity[0]))
            q_true.append(float(sim.state[0]))
    q, v, qt = np.array(qs), np.array(vs), np.array(q_true)
    grid = np.round(qt / step) * step
    # the adapter's float32 turns carry the quantized position (linear_scale 0.01 m/turn): within half
    # a float32 ULP, 2**-24 of the value
    np.testing.assert_allclose(q, grid, rtol=2.0**-24, atol=1e-12)
    dv = np.diff(grid) / 1e-3
    np.testing.assert_allclose(v[1:], dv, rtol=0, atol=1e-6 * max(1.0, np.max(np.abs(dv))))
    assert np.mean(np.diff(v) == 0.0) > 0.1  # a differentiated encoder repeats exact values


def test_friction_options_on_a_sensor_are_refused() -> None:
    import yaml

    d = yaml.safe_load(load_scene("sdea_bench").source_text)
    d["devices"][1]["sim"]["friction"] = {"coulomb": 1.0}
    with pytest.raises(SceneError, match=r"devices\[1\]: sim.friction applies to actuators only"):
        scene_from_dict(d, label="s")


def test_truth_of_a_group_target_is_empty() -> None:
    # mbk_2dof_bench identifies the group "device" (two drives): no single body or friction to show;
    # found by comparing the built-in certificates before/after (the identify stage raised)
    sc = load_scene("mbk_2dof_bench")
    assert friction_truth(sc, "device") == {} and body_truth(sc, "device") == {}
    assert device_mechanics(sc.device("device")).friction.active is False


def test_lockstep_records_with_friction_are_identical_for_a_seed() -> None:
    # the friction twin (stick-slip events located inside ticks, a quantized encoder, a differentiated
    # velocity): two lockstep runs of the same seed give the same record bit for bit
    from test_lockstep_records import run_records

    a, b = (run_records("emps_axis", [0], ticks=600)[0] for _ in range(2))
    assert sorted(a) == sorted(b)
    for k, v in a.items():
        if isinstance(v, str):
            continue
        assert np.array_equal(v, b[k], equal_nan=True), k
    v = a["channels/axis.velocity"].reshape(-1)
    assert np.any(v != 0.0) and np.any(v[1:] == v[:-1])  # it moved; the encoder's derivative repeats values
