"""Bench: every built-in scene runs on mocks through the real transports; lockstep determinism;
physics seen through the adapters."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np
import pytest
import yaml

from hil.bench.runtime import Bench
from hil.errors import HilError, SceneError
from hil.protocols.base import JointSample, WrenchSample
from hil.scene.spec import builtin_scenes, load_scene, scene_from_dict

pytestmark = pytest.mark.timeout(120)

BUILTINS = [name for name, _ in builtin_scenes()]


def _flat(meas: dict) -> np.ndarray:
    parts = []
    for name in sorted(meas):
        s = meas[name]
        if isinstance(s, JointSample):
            parts += [s.position, s.velocity, [s.t, s.seq]]
        else:
            parts += [s.wrench, [s.t, s.seq]]
    return np.concatenate([np.asarray(p, dtype=float).ravel() for p in parts])


@pytest.mark.parametrize("name", BUILTINS)
def test_builtin_scene_bench_runs_and_closes(name: str) -> None:
    sc = load_scene(name)
    threads_before = threading.active_count()
    bench = Bench(sc)
    try:
        assert set(bench.actuators) == {d.name for d in sc.actuators}
        assert set(bench.sensors) == {d.name for d in sc.force_sensors}
        ids = bench.device_identities()
        json.dumps(ids)
        assert set(ids) == {d.name for d in sc.devices}
        assert all(v["simulated"] for v in ids.values())
        # 0.5 N or N.m, or twice the actuator's breakaway friction (emps_axis: 20 N): a force below it
        # moves nothing, exactly (hil.mocks.friction)
        from hil.bench.mechanics import device_mechanics

        efforts = {a: np.full(sc.device(a).dof, max(0.5, 2.0 * device_mechanics(sc.device(a)).friction.F_s))
                   for a in bench.actuators}
        n = 200
        for k in range(n):
            meas = bench.read()
            assert set(meas) == {d.name for d in sc.devices} | {g.name for g in sc.groups}
            for d in sc.devices:
                s = meas[d.name]
                assert isinstance(s, JointSample if d.role == "actuator" else WrenchSample)
                assert s.t == pytest.approx(k * sc.dt)  # simulated clock
                if d.role == "force_sensor":
                    assert bench.force(meas, d.name).shape == (d.dof,)
                else:
                    assert s.position.shape == (d.dof,)
            bench.command(efforts)
            bench.advance()
        assert bench.ticks == n and bench.time == pytest.approx(n * sc.dt)
        # something moved under a positive effort
        moved = [np.max(meas[a].position) for a in bench.actuators]
        assert max(moved) > 0.0
        bench.safe_stop()
    finally:
        bench.close()
    bench.close()  # idempotent
    with pytest.raises(HilError, match="closed"):
        bench.read()
    # nothing left running (server / bus threads joined)
    for _ in range(50):
        if threading.active_count() <= threads_before:
            break
        threading.Event().wait(0.02)
    assert threading.active_count() <= threads_before


def _run(name: str, seed: int | None, n: int = 150, **kw) -> np.ndarray:
    sc = load_scene(name)
    rows = []
    with Bench(sc, seed=seed, **kw) as bench:
        for k in range(n):
            meas = bench.read()
            rows.append(_flat(meas))
            bench.command({a: np.full(sc.device(a).dof, 0.1 * np.sin(0.05 * k)) for a in bench.actuators})
            if bench._humans:
                bench.set_human_force(next(iter(bench._humans)), 0.5)
            bench.advance()
    return np.array(rows)


@pytest.mark.parametrize("name", ["sdea_bench", "mcet_trilateral", "dynamixel_leader_follower"])
def test_same_seed_bit_identical_other_seed_differs(name: str) -> None:
    a = _run(name, 7)
    b = _run(name, 7)
    assert a.tobytes() == b.tobytes()
    c = _run(name, 8)
    assert not np.array_equal(a, c)  # every scene here configures sensor noise


def test_default_seed_is_the_scene_seed() -> None:
    assert _run("sdea_bench", None, 50).tobytes() == _run("sdea_bench", 0, 50).tobytes()


def _exact_encoders(name: str):
    """A built-in scene with its encoders' noise set to zero: these tests check the simulated plant's
    physics from one sample (the built-in scenes give their encoders realistic noise, issue 28)."""
    sc = load_scene(name)
    sc.simulation.sensor_noise.velocity_std = 0.0
    sc.simulation.sensor_noise.position_std = 0.0
    return sc


def test_sdea_locked_static_effort_settles_at_spring_deflection() -> None:
    sc = _exact_encoders("sdea_bench")
    k_f = sc.simulation.sdea.K_f
    u = 0.5
    with Bench(sc, variant="locked") as bench:
        for _ in range(1500):  # 1.5 s >> the 2 ms decay time of the locked mode
            meas = bench.read()
            bench.command({"motor": [u]})
            bench.advance()
        meas = bench.read()
        x = meas["motor"].position[0]
        f = bench.force(meas, "spring_ft")[0]
    assert x == pytest.approx(u / k_f, rel=1e-4)  # float32 turns on the wire
    assert f == pytest.approx(u, abs=0.01)  # spring torque = motor torque at DC (noise std 0.002)
    assert "motor_out" not in bench.plant.joints


def test_sdea_free_output_drifts_at_effort_over_damping() -> None:
    sc = _exact_encoders("sdea_bench")
    s = sc.simulation.sdea
    u = 0.05
    with Bench(sc, variant="free") as bench:
        assert "motor_out" in bench.plant.joints
        for _ in range(600):  # time constant (M + m_out) / B = 16 ms
            bench.read()
            bench.command({"motor": [u]})
            bench.advance()
        meas = bench.read()
    assert meas["motor"].velocity[0] == pytest.approx(u / (s.B + s.b_out), rel=1e-3)
    assert abs(bench.force(meas, "spring_ft")[0]) < 0.01  # nothing to push against at steady drift


def test_human_force_reaches_the_master_sensor() -> None:
    sc = _exact_encoders("mcet_trilateral")
    with Bench(sc) as bench:
        bench.set_human_force("operator1", 1.0)  # by network port
        bench.advance()
        meas = bench.read()
        # F_h = f_act - (m_h a + b_h v): positive, a bit below the active force
        f = bench.force(meas, "master1_ft")[0]
        assert 0.3 < f < 1.0
        for _ in range(100):  # zero commands feed the drives' watchdogs (armed from watchdog_ms)
            bench.command({name: [0.0] for name in bench.actuators})
            bench.advance()
        meas = bench.read()
        assert meas["master1"].velocity[0] > 0.0
        assert meas["master2"].position[0] == 0.0 and meas["slave"].position[0] == 0.0  # no controller
        bench.set_human_force({"master1": 0.0})  # by body, mapping form
        with pytest.raises(ValueError, match="no simulated human"):
            bench.set_human_force("slave", 1.0)


def test_shared_dynamixel_bus_maps_each_servo_to_its_body() -> None:
    sc = load_scene("dynamixel_leader_follower")
    with Bench(sc) as bench:
        for _ in range(200):
            bench.read()
            bench.command({"leader": [0.1]})
            bench.advance()
        meas = bench.read()
    # 0.1 N.m for 0.2 s on 0.01 kg.m², 0.05 N.m.s/rad: 0.2 rad without friction; against the XM430
    # twin's default friction (F_s 0.06, F_c 0.04 N.m, hil.mocks.twins) it slides about 0.06 rad
    assert meas["leader"].position[0] > 0.04
    assert abs(meas["follower"].position[0]) < 0.01  # only position noise + quantization


def test_safe_stop_zeroes_the_applied_effort() -> None:
    sc = load_scene("mcet_trilateral")
    with Bench(sc) as bench:
        bench.command({"master1": [1.0], "slave": [2.0]})
        bench.advance()
        assert np.any(bench.simulator.last_input != 0.0)
        bench.safe_stop()
        bench.advance()
        body_efforts = [bench.simulator.last_input[bench.plant.inputs[f"{b}.effort"]] for b in
                        ("master1", "master2", "slave")]
        assert all(np.all(e == 0.0) for e in body_efforts)


def test_command_rejects_unknown_actuator_and_wrong_size() -> None:
    with Bench(load_scene("sdea_bench")) as bench:
        with pytest.raises(ValueError, match="not an actuator"):
            bench.command({"spring_ft": [1.0]})
        with pytest.raises(ValueError, match="1 DOF"):
            bench.command({"motor": [1.0, 2.0]})


def test_read_twice_in_one_tick_returns_the_same_samples() -> None:
    with Bench(load_scene("sdea_bench")) as bench:
        bench.advance()
        a, b = bench.read(), bench.read()
        assert a["motor"].seq == b["motor"].seq and a["spring_ft"].seq == b["spring_ft"].seq


def test_free_variant_without_output_inertia_is_a_scene_error() -> None:
    d = yaml.safe_load(load_scene("sdea_bench").source_text)
    d["simulation"]["sdea"]["m_out"] = None
    d["experiments"] = [e for e in d["experiments"] if e.get("variant") != "free"]
    sc = scene_from_dict(d, label="nofree.yaml")
    with pytest.raises(SceneError, match="variant 'free' needs the output inertia"):
        Bench(sc, variant="free")


def test_hardware_bench_opens_adapters_with_scene_params(tmp_path: Path) -> None:
    """Without `simulation` the bench opens adapters as configured; advance() is a no-op."""
    from hil.mocks.interfaces import FreeJoints
    from hil.mocks.serial_devices import SimBota

    joints = FreeJoints(dof=1)
    joints.apply_effort(np.array([1.25]))
    with SimBota(joints, period_s=0.001) as dev:
        data = {
            "name": "hw", "units": "linear",
            "devices": [{"name": "ft", "role": "force_sensor", "driver": "bota_serial",
                         "params": {"url": dev.path, "period_s": 0.001}, "axes": [2]}],
        }
        sc = scene_from_dict(data, label="hw.yaml")
        assert sc.run_mode == "realtime"
        with Bench(sc) as bench:
            assert not bench.lockstep
            dev.emit()
            meas = bench.read(timeout=1.0)
            assert bench.force(meas, "ft")[0] == pytest.approx(1.25)
            bench.advance()  # no-op apart from counting
            assert bench.ticks == 1
            assert bench.device_identities()["ft"]["simulated"] is False


def test_device_group_reads_and_commands_as_one_actuator() -> None:
    sc = load_scene("bilateral_2dof_A1")
    with Bench(sc) as bench:
        for _ in range(50):
            meas = bench.read()
            g = meas["master"]
            np.testing.assert_array_equal(g.position, np.r_[meas["master_y"].position, meas["master_z"].position])
            np.testing.assert_array_equal(g.velocity, np.r_[meas["master_y"].velocity, meas["master_z"].velocity])
            assert g.seq == min(meas["master_y"].seq, meas["master_z"].seq)
            bench.command({"master": np.array([1.0, -2.0])})
            bench.advance()
        meas = bench.read()
        # a +y / -z effort on the free (human-held) coupled master moves it +y and -z
        assert meas["master"].velocity[0] > 0 > meas["master"].velocity[1]
        with pytest.raises(ValueError, match="group 'master' has 2 DOF"):
            bench.command({"master": np.array([1.0])})
