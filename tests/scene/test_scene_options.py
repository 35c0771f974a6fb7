"""Every documented experiment and controller option, written in a YAML scene file, loads and
reaches the implementation (issue 13: one schema per concept).

Where the options are documented: the schemas and implementations of :mod:`hil.experiments` and
:mod:`hil.controllers` (``hil.scene.spec`` points there: "see ``hil.scene.spec`` for every field", the
user guide's scene section), docs/RUNNER_SPEC.md's scene example and the guide's minimal scene. The tests below

* load one scene per option (a built-in scene with one experiment or controller entry replaced by
  YAML text using the option) and check that the built experiment / controller carries the value
  (an attribute, or a gain matrix entry computed from the option by the paper's formula);
* check that the option table covers every field of every registered schema (an option that
  exists is tested), that every field is named in the documentation of its type, and that every
  key docs/RUNNER_SPEC.md uses in its experiments and controllers is a field of that type's schema
  (the docs document no option that does not exist).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from hil.controllers import CONTROLLER_TYPES, FourChannelMCET, NullController, make_controller
from hil.errors import SceneError
from hil.experiments import EXPERIMENT_TYPES, ExperimentConfig, make_experiment
from hil.scene.spec import Scene, load_scene

ROOT = Path(__file__).resolve().parents[2]

# ---------------------------------------------------------------------------------------------
# scenes: a built-in scene with its controller or experiments replaced


def _base(name: str) -> dict[str, Any]:
    data = yaml.safe_load(load_scene(name).source_text)
    data.pop("certification", None)  # not under test here (and it names the experiments it uses)
    return data


def _load(tmp_path: Path, data: dict[str, Any]) -> Scene:
    p = tmp_path / "options.yaml"
    p.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return load_scene(p)


def _entry(base: str, fragment: str) -> dict[str, Any]:
    """A base entry (YAML flow mapping text) updated with ``fragment`` (YAML text, as written in a file)."""
    out = yaml.safe_load("{" + base + "}")
    out.update(yaml.safe_load("{" + fragment + "}") if fragment else {})
    return out


# base entries: required fields only (each also counts as covering the fields it uses)
CHIRP = "type: chirp, name: c, controller: none, f0: 1.0, f1: 50.0, duration: 2.0, amplitude: 0.05, target: motor"
CHIRP_2DOF = "type: chirp, name: c, controller: none, f0: 1.0, f1: 40.0, duration: 2.0, amplitude: 5.0, target: device"
MULTISINE = ("type: multisine, name: m, controller: none, f0: 1.0, f1: 60.0, duration: 4.0, amplitude: 10.0, "
             "target: device, n_lines: 10")
INJECT = "type: energy_injection, name: e, port: operator1, duration: 1.0, profile: {kind: sine, amplitude: 1.0}"
HOLD = "type: static_hold, name: h, controller: none, target: motor, effort: 0.5, duration: 2.0, settle: 1.0"

#: experiments: (type, scene, base entry, option as YAML text, check on the built experiment)
EXPERIMENT_OPTIONS: list[tuple[str, str, str, str, Callable[[Any], bool]]] = [
    ("chirp", "sdea_bench", CHIRP, "", lambda e: (e.name, e.target, e.f0, e.f1) == ("c", "motor", 1.0, 50.0)),
    ("chirp", "sdea_bench", CHIRP, "f0: 2.5", lambda e: e.f0 == 2.5),
    ("chirp", "sdea_bench", CHIRP, "f1: 80.0", lambda e: e.f1 == 80.0),
    ("chirp", "sdea_bench", CHIRP, "duration: 3.0", lambda e: e.n_block == 6000 and e.duration == 3.0),  # 2 kHz
    ("chirp", "sdea_bench", CHIRP, "amplitude: 0.1", lambda e: np.max(np.abs(e.wave)) == pytest.approx(0.1, rel=1e-3)),
    ("chirp", "sdea_bench", CHIRP, "sweep: linear", lambda e: e.sweep == "linear"
     and e.f_inst[e.n_period // 2] == pytest.approx(25.5, rel=1e-3)),  # linear: f0 + (f1 - f0)/2 halfway
    ("chirp", "sdea_bench", CHIRP, "fade: 0.1", lambda e: e.fade == 0.1 and e.wave[0, 0] == 0.0),
    ("chirp", "sdea_bench", CHIRP, "dofs: [0]", lambda e: e.sel == [0]),
    ("chirp", "sdea_bench", CHIRP, "excite: motion, servo: {kp: 5.0, kv: 0.01}",
     lambda e: (e.excite, e.kp, e.kv) == ("motion", 5.0, 0.01)),
    ("chirp", "sdea_bench", CHIRP, "periodic: true, periods: 4", lambda e: e.periodic and e.periods == 4
     and e.n_period == 1000),
    ("chirp", "mbk_2dof_bench", CHIRP_2DOF, "simultaneous: true",
     lambda e: e.simultaneous and e.n_blocks == 1 and e.duration == 2.0),
    ("chirp", "mbk_2dof_bench", CHIRP_2DOF, "simultaneous: false", lambda e: e.n_blocks == 2 and e.duration == 4.0),
    ("chirp", "sdea_bench", CHIRP, "variant: free", lambda e: e.variant == "free"),
    ("chirp", "sdea_bench", CHIRP, "controller: scene", lambda e: e.cfg.controller == "scene"),
    ("multisine", "mbk_2dof_bench", MULTISINE, "", lambda e: (e.name, e.target, e.n_lines) == ("m", "device", 10)),
    ("multisine", "mbk_2dof_bench", MULTISINE, "f0: 2.0, f1: 50.0",
     lambda e: min(min(f) for f in e.line_frequencies()) >= 2.0 and max(max(f) for f in e.line_frequencies()) <= 50),
    ("multisine", "mbk_2dof_bench", MULTISINE, "n_lines: 7", lambda e: all(len(f) == 7 for f in e.line_frequencies())),
    ("multisine", "mbk_2dof_bench", MULTISINE, "duration: 8.0, periods: 4", lambda e: e.periods == 4
     and e.period == 2.0),
    ("multisine", "mbk_2dof_bench", MULTISINE, "amplitude: 20.0",
     lambda e: np.max(np.abs(e.wave)) == pytest.approx(20.0)),  # scaled so that the peak is the amplitude
    ("multisine", "mbk_2dof_bench", MULTISINE, "dofs: [1]", lambda e: e.sel == [1]),
    ("multisine", "mbk_2dof_bench", MULTISINE, "simultaneous: false", lambda e: e.n_blocks == 2),
    ("multisine", "mbk_2dof_bench", MULTISINE, "seed: 7", lambda e: e.seed == 7),
    ("multisine", "mbk_2dof_bench", MULTISINE, "variant: locked", lambda e: e.variant == "locked"),
    ("multisine", "mbk_2dof_bench", MULTISINE, "spacing: log, n_lines: 5",
     # log spacing: the ratios of consecutive lines are nearly constant (geomspace rounded to the grid)
     lambda e: e.spacing == "log" and np.ptp(np.diff(np.log(np.sort(np.concatenate(e.lines))))) < 0.5),
    ("multisine", "mbk_2dof_bench", MULTISINE, "excite: motion, servo: {kp: 100.0, kv: 1.0}, amplitude: 0.01",
     lambda e: (e.excite, e.kp, e.kv) == ("motion", 100.0, 1.0)),
    ("energy_injection", "mcet_trilateral", INJECT, "",
     lambda e: (e.name, e.port, e.duration) == ("e", "operator1", 1.0)),
    ("energy_injection", "mcet_trilateral", INJECT, "profile: {kind: square, amplitude: 1.5, freq: 2.0, phase: 0.5}",
     lambda e: np.array_equal(np.unique(e._samples), [-1.5, 1.5])),
    ("energy_injection", "mcet_trilateral", INJECT, "profile: {kind: step, amplitude: 0.7}",
     lambda e: np.all(e._samples == 0.7)),
    ("energy_injection", "mcet_trilateral", INJECT, "profile: {kind: multisine, amplitude: 1.0, freqs: [1.0, 3.0]}",
     # independent: amplitude/2 (sin(2π t + φ1) + sin(6π t + φ2)), Schroeder phases -π l(l-1)/L = 0, -π (L = 2)
     lambda e: np.allclose(e._samples[:, 0], 0.5 * (np.sin(2 * np.pi * np.arange(1000) / 1000)
                                                    + np.sin(6 * np.pi * np.arange(1000) / 1000 - np.pi)),
                           rtol=0, atol=1e-12)),
    ("energy_injection", "mcet_trilateral", INJECT, "profile: {kind: noise, amplitude: 0.5, freq: 5.0, seed: 3}",
     lambda e: e.profile_cfg.seed == 3 and np.std(e._samples) == pytest.approx(0.5)),
    ("energy_injection", "mcet_trilateral", INJECT, "profile: {kind: sine, amplitude: 1.0, direction: [0.5]}",
     lambda e: np.max(np.abs(e._samples)) == pytest.approx(0.5, rel=1e-4)),
    ("energy_injection", "mcet_trilateral", INJECT, "noise_bound: 0.25", lambda e: e.noise_bound == 0.25),
    ("energy_injection", "mcet_trilateral", INJECT, "via: actuator", lambda e: e.via == "actuator"),
    ("energy_injection", "mcet_trilateral", INJECT, "force_sign: -1", lambda e: e.force_sign == -1.0),
    ("energy_injection", "mcet_trilateral", INJECT, "k_sigma: 3.0", lambda e: e.k_sigma == 3.0),
    ("energy_injection", "mcet_trilateral", INJECT, "bound_mode: running", lambda e: e.bound_mode == "running"),
    ("energy_injection", "mcet_trilateral", INJECT, "controller: none", lambda e: e.cfg.controller == "none"),
    ("static_hold", "sdea_bench", HOLD, "", lambda e: (e.name, e.target, e.settle) == ("h", "motor", 1.0)),
    ("static_hold", "sdea_bench", HOLD, "effort: 0.25, duration: 3.0",
     lambda e: e.effort.tolist() == [0.25] and e.excitation(5999, 0.0, {}).effort["motor"][0] == 0.25
     and e.excitation(6000, 0.0, {}).effort["motor"][0] == 0),  # 3 s at 2 kHz: ticks 0..5999
    ("static_hold", "sdea_bench", HOLD, "effort: [0.3], dofs: [0]",
     lambda e: e.effort.tolist() == [0.3] and e.sel == [0]),
    ("static_hold", "sdea_bench", HOLD, "variant: free", lambda e: e.variant == "free"),
]

#: fields a base entry covers besides the options (every entry has them)
EXPERIMENT_BASE_FIELDS = {
    "chirp": {"type", "name", "controller", "f0", "f1", "duration", "amplitude", "target"},
    "multisine": {"type", "name", "controller", "f0", "f1", "duration", "amplitude", "target", "n_lines"},
    "energy_injection": {"type", "name", "port", "duration", "profile", "profile.kind", "profile.amplitude"},
    "static_hold": {"type", "name", "controller", "target", "effort", "duration", "settle"},
}


def _keys(fragment: str) -> set[str]:
    """Top-level and nested (``a.b``) keys of a YAML fragment."""
    out: set[str] = set()
    for k, v in (yaml.safe_load("{" + fragment + "}") or {}).items():
        out.add(k)
        if isinstance(v, dict):
            out |= {f"{k}.{sub}" for sub in v}
    return out


@pytest.mark.parametrize(("etype", "scene", "base", "fragment", "check"), EXPERIMENT_OPTIONS,
                         ids=[f"{o[0]}:{o[3] or 'base'}" for o in EXPERIMENT_OPTIONS])
def test_experiment_option_loads_and_reaches_the_experiment(tmp_path: Path, etype: str, scene: str, base: str,
                                                            fragment: str, check: Callable[[Any], bool]) -> None:
    data = _base(scene)
    data["experiments"] = [_entry(base, fragment)]
    sc = _load(tmp_path, data)
    (model,) = sc.experiment_models()
    assert model.type == etype
    exp = make_experiment(model, rate_hz=sc.rate_hz)
    exp.check(sc)
    assert check(exp), (etype, fragment)


# ---------------------------------------------------------------------------------------------
# controllers

_SENSOR = {"role": "force_sensor", "driver": "bota_serial", "dof": 1, "sim": {"measure": "body"}}


def _mcet_scene() -> dict[str, Any]:
    """mcet_trilateral with a force sensor on every robot (the force channels need them)."""
    data = _base("mcet_trilateral")
    data["devices"] += [{"name": "master2_ft", "params": {"url": "/dev/ttyUSB1"}, "body": "master2", "axes": [2],
                         **_SENSOR},
                        {"name": "slave_ft", "params": {"url": "/dev/ttyUSB2"}, "body": "slave", "axes": [2],
                         **_SENSOR}]
    return data


def _vsic_scene() -> dict[str, Any]:
    """sdea_bench with an encoder on the free output body (for ``output``)."""
    data = _base("sdea_bench")
    data["devices"].append({"name": "out_enc", "role": "actuator", "driver": "odrive_can", "dof": 1,
                            "body": "motor_out",
                            "params": {"interface": "virtual", "bitrate": 1000000, "channel": "hil5", "node_id": 5}})
    return data


PD = "type: pd_position_position, master: master, slave: slave, Kp_m: 500, Kv_m: 300, Kp_s: 400, Kv_s: 200"
MCET = ("type: mcet, masters: [master1, master2], slave: slave, alpha: 0.5, k_pm1: 160.0, k_vm1: 64.0, "
        "k_pm2: 120.0, k_vm2: 48.0, k_ps: 150.0, k_vs: 85.0")
SENSORS = "force_sensors: {master1: master1_ft, master2: master2_ft, slave: slave_ft}"
_G = "{kp: [[400, 0, 0], [0, 300, 30], [0, 30, 250]], kv: 10.0}"
DUAL = (f"type: dual_master, masters: [{{device: master1, slave_dofs: [0]}}, {{device: master2, slave_dofs: [1, 2]}}], "
        f"slave: slave, C_m: {_G}, C_4: {_G}, C_s: {_G}, C_1: {_G}")
VSIC = "type: vsic, actuator: motor, P_m: 0.28, I_m: 100.0, P_f: 40.0, I_f: 70.0, k22: 300.0, b22: 0.17"
D3 = np.array([[400.0, 0, 0], [0, 300, 30], [0, 30, 250]])


def _kp(c: Any) -> np.ndarray:
    return c.pd.Kp if isinstance(c, FourChannelMCET) else c.Kp


#: controllers: (type, scene builder, base entry, option as YAML text, check on the built controller)
CONTROLLER_OPTIONS: list[tuple[str, Callable[[], dict[str, Any]], str, str, Callable[[Any], bool]]] = [
    ("none", lambda: _base("sdea_bench"), "type: none", "", lambda c: isinstance(c, NullController)),
    # eq. (42)-(43): Kp = [[Kp_m, -Kp_m], [-Kp_s, Kp_s]]; a number is k I, a flat list a diagonal
    ("pd_position_position", lambda: _base("bilateral_2dof_A1"), PD, "",
     lambda c: [d for d, _ in c.layout] == ["master", "slave"]
     and np.array_equal(c.Kp, np.block([[500 * np.eye(2), -500 * np.eye(2)], [-400 * np.eye(2), 400 * np.eye(2)]]))
     and np.array_equal(c.Kv, np.block([[300 * np.eye(2), -300 * np.eye(2)], [-200 * np.eye(2), 200 * np.eye(2)]]))),
    ("pd_position_position", lambda: _base("bilateral_2dof_A1"), PD, "Kp_m: [500, 450]",
     lambda c: np.array_equal(c.Kp[:2, :2], np.diag([500.0, 450.0]))),
    ("pd_position_position", lambda: _base("bilateral_2dof_A1"), PD, "Kv_s: [[200, 10], [10, 100]]",
     lambda c: np.array_equal(c.Kv[2:, 2:], [[200.0, 10.0], [10.0, 100.0]])),
    ("pd_position_position", lambda: _base("bilateral_2dof_A1"), PD, "dof: 2", lambda c: c.n == 4),
    # eq. (22)-(23): rows [c_m1, c_4m1, 0], [c_4m2, c_m2, 0], [-α c_1, -(1-α) c_1, c_s]
    ("mcet", _mcet_scene, MCET, "", lambda c: np.array_equal(_kp(c), [[160, -160, 0], [-120, 120, 0],
                                                                        [-75, -75, 150]])
     and np.array_equal(c.pd.Kv, [[64, -64, 0], [-48, 48, 0], [-42.5, -42.5, 85]])),
    ("mcet", _mcet_scene, MCET, "alpha: 0.2", lambda c: np.array_equal(_kp(c)[2], [-30.0, -120.0, 150.0])),
    ("mcet", _mcet_scene, MCET, "k_p4m1: -100.0, k_v4m1: -40.0",
     lambda c: (c.pd.Kp[0, 1], c.pd.Kv[0, 1]) == (-100, -40)),
    ("mcet", _mcet_scene, MCET, "k_p4m2: -90.0, k_v4m2: -30.0",
     lambda c: (c.pd.Kp[1, 0], c.pd.Kv[1, 0]) == (-90, -30)),
    ("mcet", _mcet_scene, MCET, "k_p1: 100.0, k_v1: 60.0", lambda c: (c.pd.Kp[2, 0], c.pd.Kv[2, 0]) == (-50, -30)),
    ("mcet", _mcet_scene, MCET, f"c6m1: 0.5, c2m1: 0.2, {SENSORS}", lambda c: c.G[0, 0] == 0.5 and c.G[0, 2] == -0.1),
    ("mcet", _mcet_scene, MCET, f"c6m2: 0.4, c2m2: 0.6, {SENSORS}", lambda c: c.G[1, 1] == 0.4 and c.G[1, 2] == -0.3),
    # products with 0.5 are exact in binary: == is the right comparison
    ("mcet", _mcet_scene, MCET, f"c3: 0.8, c5: 0.3, {SENSORS}",
     lambda c: (c.G[2, 0], c.G[2, 1], c.G[2, 2]) == (0.4, 0.4, -0.3)),
    ("mcet", _mcet_scene, MCET, SENSORS, lambda c: c.sensors == ["master1_ft", "master2_ft", "slave_ft"]),
    ("mcet", _mcet_scene, MCET, f"{SENSORS}, force_axes: {{master1: [2], master2: [0], slave: [1]}}",
     lambda c: c.axes == [[2], [0], [1]]),
    ("mcet", _mcet_scene, MCET, "slave_force_sign: 1", lambda c: c.signs == [1.0, 1.0, 1.0]),
    ("mcet", _mcet_scene, MCET, "dof: 1", lambda c: c.d == 1),
    # eq. (15): Kp = [[C_m, -C_4], [-C_1, C_s]], masters at their slave DOF indices
    ("dual_master", lambda: _base("dual_master_3dof"), DUAL, "",
     lambda c: [(d, list(i)) for d, i in c.layout] == [("master1", [0]), ("master2", [1, 2]), ("slave", [3, 4, 5])]
     and np.array_equal(c.Kp, np.block([[D3, -D3], [-D3, D3]])) and np.array_equal(c.Kv[:3, :3], 10 * np.eye(3))),
    ("dual_master", lambda: _base("dual_master_3dof"), DUAL, "C_4: {kp: 7.0, kv: [1, 2, 3]}",
     lambda c: np.array_equal(c.Kp[:3, 3:], -7 * np.eye(3)) and np.array_equal(c.Kv[:3, 3:], -np.diag([1.0, 2, 3]))),
    ("dual_master", lambda: _base("dual_master_3dof"), DUAL, "C_1: {kp: 5.0, kv: 1.0}, C_s: {kp: 6.0, kv: 2.0}",
     lambda c: np.array_equal(c.Kp[3:, :3], -5 * np.eye(3)) and np.array_equal(c.Kv[3:, 3:], 2 * np.eye(3))),
    ("vsic", _vsic_scene, VSIC, "", lambda c: c.params == {"P_m": 0.28, "I_m": 100.0, "P_f": 40.0, "I_f": 70.0,
                                                            "alpha": 1.0, "k22": 300.0, "b22": 0.17}
     and c.force_sensor is None and c.output is None and c.environment == {"type": "none"}),
    ("vsic", _vsic_scene, VSIC, "alpha: 0.6", lambda c: c.alpha == 0.6),
    ("vsic", _vsic_scene, VSIC, "force_sensor: spring_ft", lambda c: c.force_sensor == "spring_ft"
     and c.force_axis == 5),  # from the sensor's axes: [5]
    ("vsic", _vsic_scene, VSIC, "force_sensor: spring_ft, force_axis: 2", lambda c: c.force_axis == 2),
    ("vsic", _vsic_scene, VSIC, "force_sign: -1", lambda c: c.force_sign == -1.0),
    ("vsic", _vsic_scene, VSIC, "output: out_enc", lambda c: c.output == "out_enc"),
    ("vsic", _vsic_scene, VSIC, "environment: {type: none}", lambda c: c.environment == {"type": "none"}),
    ("vsic", _vsic_scene, VSIC, "environment: {type: spring, k: 100.0, b: 0.5}",
     lambda c: c.environment == {"type": "spring", "k": 100.0, "b": 0.5}),
    ("vsic", _vsic_scene, VSIC, "environment: {type: spring_damper, k: 50.0, b: 0.1}",
     lambda c: c.environment == {"type": "spring_damper", "k": 50.0, "b": 0.1}),
    ("vsic", _vsic_scene, VSIC, "environment: {type: mass_spring_damper, m: 0.001, k: 20.0, b: 0.2}",
     lambda c: c.environment == {"type": "mass_spring_damper", "m": 0.001, "k": 20.0, "b": 0.2}
     and c._env.n == 2),  # a mass: two states (position, velocity of the virtual environment)
]

CONTROLLER_BASE_FIELDS = {
    "none": {"type"},
    "pd_position_position": {"type", "master", "slave", "Kp_m", "Kv_m", "Kp_s", "Kv_s"},
    "mcet": {"type", "masters", "slave", "alpha", "k_pm1", "k_vm1", "k_pm2", "k_vm2", "k_ps", "k_vs"},
    "dual_master": {"type", "masters", "masters.device", "masters.slave_dofs", "slave", *(
        f"C_{t}{s}" for t in "m4s1" for s in ("", ".kp", ".kv"))},
    "vsic": {"type", "actuator", "P_m", "I_m", "P_f", "I_f", "k22", "b22"},
}


@pytest.mark.parametrize(("ctype", "scene", "base", "fragment", "check"), CONTROLLER_OPTIONS,
                         ids=[f"{o[0]}:{o[3] or 'base'}" for o in CONTROLLER_OPTIONS])
def test_controller_option_loads_and_reaches_the_controller(tmp_path: Path, ctype: str,
                                                            scene: Callable[[], dict[str, Any]], base: str,
                                                            fragment: str, check: Callable[[Any], bool]) -> None:
    data = scene()
    data["controller"] = _entry(base, fragment)
    sc = _load(tmp_path, data)
    assert sc.controller.type == ctype
    ctrl = make_controller(sc.controller, units=sc.units, scene=sc)
    assert check(ctrl), (ctype, fragment)


# ---------------------------------------------------------------------------------------------
# the tables cover every option; the docs name every option and no other


def _schema_fields(schema: Any, prefix: str = "") -> set[str]:
    """Field names of a schema, nested models as ``a.b`` (one level: what the scene files nest)."""
    from pydantic import BaseModel

    out: set[str] = set()
    for name, f in schema.model_fields.items():
        out.add(prefix + name)
        if prefix:
            continue
        for arg in [f.annotation, *getattr(f.annotation, "__args__", ())]:
            for sub in [arg, *getattr(arg, "__args__", ())]:
                if isinstance(sub, type) and issubclass(sub, BaseModel):
                    out |= _schema_fields(sub, f"{name}.")
    return out


def _covered(options: list[tuple], base_fields: dict[str, set[str]]) -> dict[str, set[str]]:
    got = {k: set(v) for k, v in base_fields.items()}
    for kind, _, _, fragment, _ in options:
        got[kind] |= _keys(fragment)
    return got


def test_option_tables_cover_every_field_of_every_registered_schema() -> None:
    exp = _covered(EXPERIMENT_OPTIONS, EXPERIMENT_BASE_FIELDS)
    for name, t in EXPERIMENT_TYPES.items():
        assert _schema_fields(t.schema) - exp.get(name, set()) == set(), name
    ctl = _covered(CONTROLLER_OPTIONS, CONTROLLER_BASE_FIELDS)
    for name, t in CONTROLLER_TYPES.items():
        assert _schema_fields(t.schema) - ctl.get(name, set()) == set(), name


def _doc_text(*objs: Any) -> str:
    return "\n".join((o.__doc__ or "") for o in objs)


@pytest.mark.parametrize("name", sorted(EXPERIMENT_TYPES))
def test_every_experiment_field_is_documented(name: str) -> None:
    t = EXPERIMENT_TYPES[name]
    bases = [c for c in t.schema.__mro__ if c.__module__ == t.schema.__module__]
    text = _doc_text(t.schema, t.impl, ExperimentConfig, *bases)
    from hil.experiments import ForceProfileCfg, ServoCfg

    text += _doc_text(ForceProfileCfg, ServoCfg)
    missing = [f for f in _schema_fields(t.schema) if not re.search(rf"\b{re.escape(f.split('.')[-1])}\b", text)]
    assert missing == [], (name, missing)


@pytest.mark.parametrize("name", sorted(CONTROLLER_TYPES))
def test_every_controller_field_is_documented(name: str) -> None:
    t = CONTROLLER_TYPES[name]
    from hil.controllers import McetForceAxes, McetForceSensors, PdGain, VsicEnvironment

    text = _doc_text(t.schema, PdGain, VsicEnvironment, McetForceSensors, McetForceAxes)
    missing = [f for f in _schema_fields(t.schema) if f != "type"
               and not re.search(rf"\b{re.escape(f.split('.')[-1])}\b", text)]
    assert missing == [], (name, missing)


def _runner_spec_yaml() -> str:
    text = (ROOT / "docs" / "RUNNER_SPEC.md").read_text(encoding="utf-8")
    i = text.index("## `hil/scene/spec.py`")
    block = text[text.index("```yaml", i) + len("```yaml"):]
    return block[:block.index("```")]


def test_runner_spec_documents_only_existing_experiment_options() -> None:
    block = _runner_spec_yaml()
    exps = block[block.index("\nexperiments:"):]
    exps = exps.replace("..", "1.0")  # placeholders for values
    entries = yaml.safe_load(exps)["experiments"]
    assert {e["type"] for e in entries} == set(EXPERIMENT_TYPES)
    for e in entries:
        assert _keys(yaml.safe_dump(e, default_flow_style=True)[1:-2]) <= _schema_fields(
            EXPERIMENT_TYPES[e["type"]].schema), e


def test_runner_spec_documents_only_existing_controller_options() -> None:
    block = _runner_spec_yaml()
    ctl = block[block.index("\ncontroller:"):block.index("\nsafety:")]
    seen: dict[str, set[str]] = {}
    main: set[str] = set()
    for line in ctl.strip().splitlines()[1:]:  # the lines under "controller:"
        body = line.split("#", 1)
        code, comment = body[0], (body[1] if len(body) > 1 else "")
        for part in code.split(";"):  # "Kp_m: [[...]]; Kv_m: [[...]]"
            if ":" in part:
                main.add(part.split(":", 1)[0].strip())
        m = re.match(r"\s*type: (\w+)\s*(?:\([^)]*\))?:?\s*(.*)", comment)
        if m:
            rest = re.sub(r"\{[^}]*\}|\[[^]]*\]", "", m.group(2))
            seen[m.group(1)] = {w.group(1) for p in rest.split(",")
                                if (w := re.match(r"\s*([A-Za-z_]\w*)", p)) is not None}
    seen["pd_position_position"] = main - {""}
    assert set(seen) == set(CONTROLLER_TYPES)
    for name, keys in seen.items():
        assert keys <= _schema_fields(CONTROLLER_TYPES[name].schema) | {"type"}, (name, keys)


def test_guide_minimal_scene_loads(tmp_path: Path) -> None:
    text = (ROOT / "docs" / "guide" / "bench-runs.md").read_text(encoding="utf-8")
    i = text.index("A minimal scene")
    block = text[text.index("```yaml", i) + len("```yaml"):]
    p = tmp_path / "minimal.yaml"
    p.write_text(block[:block.index("```")], encoding="utf-8")
    sc = load_scene(p)
    assert [e.type for e in sc.experiment_models()] == ["chirp"]
    exp = make_experiment(sc.experiment_models()[0], rate_hz=sc.rate_hz)
    assert exp.periods == 8 and exp.sweep == "log"


@pytest.mark.parametrize(("fragment", "message"), [
    ("excite: motion", "experiments[0].servo: excite: motion needs servo"),
    ("servo: {kp: 5.0, kv: 0.01, ki: 1.0}", "experiments[0].servo.ki: unknown key 'ki'"),
    ("spacing: cubic", "experiments[0].spacing: expected 'linear' or 'log'"),
    ("simultaneus: true", "experiments[0].simultaneus: unknown key 'simultaneus', did you mean 'simultaneous'?"),
])
def test_wrong_options_are_refused_with_the_scene_path(tmp_path: Path, fragment: str, message: str) -> None:
    data = _base("mbk_2dof_bench")
    data["experiments"] = [_entry(MULTISINE.replace("name: m, ", ""), fragment)]
    with pytest.raises(SceneError) as err:
        _load(tmp_path, data)
    assert message in str(err.value)


def test_vsic_environment_parameter_of_another_type_is_refused(tmp_path: Path) -> None:
    data = _vsic_scene()
    data["controller"] = _entry(VSIC, "environment: {type: spring, k: 10.0, m: 0.5}")
    with pytest.raises(SceneError, match=r"controller\.environment\.m: m does not apply to a spring environment"):
        _load(tmp_path, data)
