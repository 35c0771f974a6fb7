"""Scene files: built-in scenes load; malformed scenes give one line naming file, field and expectation."""

from __future__ import annotations

import copy
import hashlib
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from hil.errors import SceneError
from hil.scene.spec import Scene, builtin_scenes, load_scene

pytestmark = pytest.mark.timeout(120)

BUILTINS = [name for name, _ in builtin_scenes()]
EXPECTED = {
    "sdea_bench", "bilateral_2dof_A1", "bilateral_2dof_A2", "bilateral_2dof_B", "mcet_trilateral",
    "dual_master_3dof", "dynamixel_leader_follower",
}


def test_builtin_list_has_every_scene_with_a_description() -> None:
    scenes = dict(builtin_scenes())
    assert set(scenes) >= EXPECTED
    for name, desc in scenes.items():
        assert len(desc) > 20, name


@pytest.mark.parametrize("name", BUILTINS)
def test_builtin_scene_loads(name: str) -> None:
    sc = load_scene(name)
    assert isinstance(sc, Scene)
    assert sc.name == name
    assert sc.simulation is not None and sc.run_mode == "lockstep"
    assert sc.path == f"builtin:{name}"
    assert sc.sha256 == hashlib.sha256(sc.source_text.encode("utf-8")).hexdigest()
    assert yaml.safe_load(sc.source_text)["name"] == name
    # controller and experiments are handed over as plain, JSON-able dicts
    cfg = sc.controller_config()
    assert cfg["type"] == sc.controller.type
    json.dumps(cfg)
    exps = sc.experiment_configs()
    assert exps and all(e["name"] for e in exps)
    json.dumps(exps)


def test_load_by_path_keeps_exact_text(tmp_path: Path) -> None:
    src = load_scene("sdea_bench").source_text + "\n# a trailing comment changes the hash\n"
    p = tmp_path / "mine.yaml"
    p.write_text(src, encoding="utf-8")
    sc = load_scene(p)
    assert sc.source_text == src
    assert sc.sha256 == hashlib.sha256(src.encode()).hexdigest() != load_scene("sdea_bench").sha256
    assert sc.path == str(p)


def test_paper_parameters_in_builtin_scenes() -> None:
    from hil.models.teleop import MCET_TABLE1, TWO_DOF_ROBOT, TWO_DOF_TABLE2

    s = load_scene("sdea_bench").simulation.sdea
    assert (s.M, s.B, s.K_f, s.B_f) == (6.399e-4, 0.169, 362.0, 0.05)
    c = load_scene("sdea_bench").controller
    assert (c.P_m, c.I_m, c.P_f, c.I_f, c.k22, c.b22, c.alpha) == (0.28, 100.0, 40.0, 70.0, 300.0, 0.17, 1.0)
    for gs, g in TWO_DOF_TABLE2.items():
        sc = load_scene(f"bilateral_2dof_{gs}")
        assert sc.controller.Kp_m == [[g["k_pyy"], g["k_pyz"]], [g["k_pyz"], g["k_pzz"]]]
        assert sc.controller.Kv_s == [[g["k_vyy"], g["k_vyz"]], [g["k_vyz"], g["k_vzz"]]]
        mass = sc.simulation.bodies[0].M
        assert mass == [[TWO_DOF_ROBOT["m_yy"], TWO_DOF_ROBOT["m_yz"]], [TWO_DOF_ROBOT["m_yz"], TWO_DOF_ROBOT["m_zz"]]]
        assert sc.simulation.terminations[0].stiffness == [[45.0, 0.0], [0.0, 45.0]]
    m = load_scene("mcet_trilateral")
    for key in ("k_pm1", "k_vm1", "k_pm2", "k_vm2", "k_ps", "k_vs", "alpha"):
        assert getattr(m.controller, key) == MCET_TABLE1[key]
    assert [b.M for b in m.simulation.bodies] == [0.7, 0.5, 1.5]
    d = load_scene("dual_master_3dof")
    assert d.controller.C_m.kp[1][2] == 30.0 and d.controller.C_4.kp[2][1] == 30.0
    assert d.simulation.terminations[0].name == "T2"


def test_loading_imports_no_driver() -> None:
    code = ("import sys; from hil.scene.spec import load_scene\n"
            "[load_scene(n) for n in ('sdea_bench', 'bilateral_2dof_A1', 'mcet_trilateral')]\n"
            "bad = [m for m in ('can', 'pymodbus', 'dynamixel_sdk', 'serial', 'hil.protocols.can_odrive') "
            "if m in sys.modules]\nprint(bad)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "[]"


# ---------------------------------------------------------------------------------------------
# malformed scenes
# ---------------------------------------------------------------------------------------------


def _base(name: str = "sdea_bench") -> dict[str, Any]:
    return yaml.safe_load(load_scene(name).source_text)


def _error(tmp_path: Path, data: Any, fname: str = "bad.yaml") -> str:
    p = tmp_path / fname
    p.write_text(data if isinstance(data, str) else yaml.safe_dump(data), encoding="utf-8")
    with pytest.raises(SceneError) as info:
        load_scene(p)
    exc = info.value
    assert exc.__cause__ is None and (exc.__suppress_context__ or exc.__context__ is None)  # no chained traceback
    msg = str(exc)
    assert "\n" not in msg, msg
    assert msg.startswith(f"{fname}: "), msg
    return msg


def _set(path: str, value: Any, scene: str = "sdea_bench") -> dict[str, Any]:
    d = copy.deepcopy(_base(scene))
    cur: Any = d
    parts = path.split(".")
    for part in parts[:-1]:
        cur = cur[int(part)] if part.isdigit() else cur[part]
    last = parts[-1]
    if last.isdigit():
        cur[int(last)] = value
    else:
        cur[last] = value
    return d


CASES = [
    # (description, scene, path, value, expected fragments)
    ("typo in a device key", "sdea_bench", "devices.0.drvier", "x",
     ["devices[0].drvier:", "unknown key", "did you mean 'driver'"]),
    ("typo in a simulation key", "sdea_bench", "simulation.sdea.K_ff", 1.0,
     ["simulation.sdea.K_ff:", "did you mean 'K_f'"]),
    ("typo at the top level", "sdea_bench", "experimnets", [], ["experimnets:", "did you mean 'experiments'"]),
    ("typo in a controller key", "sdea_bench", "controller.Pm", 1.0, ["controller.Pm:", "did you mean 'P_m'"]),
    ("unit string in a number", "sdea_bench", "safety.max_effort", "5 Nm",
     ["safety.max_effort:", "expected a number in N or N.m", "'5 Nm'", "numbers are SI: write 5.0"]),
    ("unit string in a physics number", "sdea_bench", "simulation.sdea.K_f", "362 Nm/rad",
     ["simulation.sdea.K_f:", "expected a number", "write 362.0"]),
    ("unit string in a matrix", "bilateral_2dof_A1", "controller.Kp_m", [["500 N/m", 450], [450, 500]],
     ["controller.Kp_m:", "expected a number in N/m or N.m/rad", "write 500.0"]),
    ("unknown driver", "sdea_bench", "devices.0.driver", "odrive_cna",
     ["devices[0].driver:", "unknown driver 'odrive_cna'", "did you mean 'odrive_can'"]),
    ("missing device in the controller", "sdea_bench", "controller.force_sensor", "spring_fT",
     ["controller.force_sensor:", "unknown device 'spring_fT'", "did you mean 'spring_ft'"]),
    ("missing device in the network", "bilateral_2dof_A1", "network.ports.0.actuator", "mastr",
     ["network.ports[0].actuator:", "unknown device 'mastr'", "did you mean 'master'"]),
    ("missing device in an experiment", "sdea_bench", "experiments.2.target", "motr",
     ["experiments[2].target:", "unknown device 'motr'"]),
    ("missing port in an experiment", "mcet_trilateral", "experiments.0.port", "operator",
     ["experiments[0].port:", "unknown port 'operator'"]),
    ("a sensor used as an actuator", "sdea_bench", "controller.actuator", "spring_ft",
     ["controller.actuator:", "is a force_sensor, expected a actuator"]),
    ("wrong PD gain shape", "bilateral_2dof_A1", "controller.Kv_s", [[300, 250, 0], [250, 300, 0]],
     ["controller.Kv_s:", "expected a 2x2 matrix", "got 2x3"]),
    ("wrong dual-master gain shape", "dual_master_3dof", "controller.C_1.kp", [[1, 0], [0, 1]],
     ["controller.C_1.kp:", "expected a 3x3 matrix", "got 2x2"]),
    ("ragged matrix", "bilateral_2dof_A1", "controller.Kp_s", [[1, 2], [3]],
     ["controller.Kp_s:", "rectangular"]),
    ("unknown controller type", "sdea_bench", "controller.type", "vsci",
     ["controller.type:", "unknown type 'vsci'", "did you mean 'vsic'"]),
    ("unknown experiment type", "sdea_bench", "experiments.0.type", "chrip",
     ["experiments[0].type:", "did you mean 'chirp'"]),
    ("unknown body", "sdea_bench", "devices.1.body", "motr", ["devices[1].body:", "unknown body 'motr'"]),
    ("termination shape", "mcet_trilateral", "simulation.terminations.0.tf",
     [[{"num": [1.0], "den": [1.0, 1.0]}, {"num": [0.0]}], [{"num": [0.0]}, {"num": [1.0], "den": [1.0, 1.0]}]],
     ["simulation.terminations[0].tf:", "expected a 1x1 transfer matrix"]),
    ("bad fault plan", "sdea_bench", "devices.0.sim", {"faults": {"drop_prb": 0.1}},
     ["devices[0].sim.faults:", "drop_prb"]),
    ("chirp band", "sdea_bench", "experiments.0.f1", 0.5, ["experiments[0].f1:", "must exceed f0"]),
    ("bool for a number", "sdea_bench", "rate_hz", True, ["rate_hz:", "expected a number in Hz"]),
    ("negative noise", "sdea_bench", "simulation.sensor_noise.force_std", -1.0,
     ["simulation.sensor_noise.force_std:", "greater than or equal to 0"]),
]


@pytest.mark.parametrize(("desc", "scene", "path", "value", "fragments"), CASES, ids=[c[0] for c in CASES])
def test_malformed_scene_one_line(tmp_path: Path, desc: str, scene: str, path: str, value: Any,
                                  fragments: list[str]) -> None:
    msg = _error(tmp_path, _set(path, value, scene))
    for frag in fragments:
        assert frag in msg, f"{desc}: {frag!r} not in {msg!r}"


def test_missing_required_field(tmp_path: Path) -> None:
    d = _base()
    del d["devices"][0]["driver"]
    msg = _error(tmp_path, d)
    assert "devices[0].driver: required field is missing" in msg


def test_duplicate_device_name(tmp_path: Path) -> None:
    d = _base()
    d["devices"][1]["name"] = "motor"
    assert "devices[1].name: duplicate device name 'motor'" in _error(tmp_path, d)


def test_invalid_yaml(tmp_path: Path) -> None:
    msg = _error(tmp_path, "name: x\ndevices: [a, b\n", "broken.yaml")
    assert msg.startswith("broken.yaml: not valid YAML (line ")


def test_scene_never_holds_code(tmp_path: Path) -> None:
    text = load_scene("sdea_bench").source_text.replace("seed: 0", "seed: !!python/object/apply:os.getpid []")
    msg = _error(tmp_path, text, "code.yaml")
    assert "not valid YAML" in msg


def test_top_level_must_be_a_mapping(tmp_path: Path) -> None:
    assert "expected a mapping" in _error(tmp_path, "- a\n- b\n", "list.yaml")
    assert "an empty file" in _error(tmp_path, "", "empty.yaml")


def test_unknown_builtin_name_suggests() -> None:
    with pytest.raises(SceneError, match=r"sdea_bnch: no such file or built-in scene \(did you mean 'sdea_bench'\?\)"):
        load_scene("sdea_bnch")
    with pytest.raises(SceneError, match="no such file"):
        load_scene("/nonexistent/dir/scene.yaml")


def test_yaml11_exponent_strings_are_numbers(tmp_path: Path) -> None:
    text = load_scene("sdea_bench").source_text.replace("M: 6.399e-4", "M: 6399e-7")
    assert "6399e-7" in text
    p = tmp_path / "exp.yaml"
    p.write_text(text)
    inertia = load_scene(p).simulation.sdea.M
    assert inertia == pytest.approx(6.399e-4)


def test_scalar_gain_means_identity_and_flat_list_diagonal(tmp_path: Path) -> None:
    from hil.scene.spec import as_matrix

    d = _set("controller.Kp_m", 500.0, "bilateral_2dof_A1")
    d["controller"]["Kv_m"] = [300.0, 200.0]
    p = tmp_path / "s.yaml"
    p.write_text(yaml.safe_dump(d))
    c = load_scene(p).controller
    assert as_matrix(c.Kp_m, 2).tolist() == [[500.0, 0.0], [0.0, 500.0]]
    assert c.model_dump()["Kp_m"] == [[500.0, 0.0], [0.0, 500.0]]  # consumers always get full matrices
    assert c.Kv_m == [[300.0, 0.0], [0.0, 200.0]]


def test_cross_checks_are_pure_and_normalization_is_a_validator(tmp_path: Path) -> None:
    """issue 13: the checks change nothing; the final values (full gain matrices) come from the
    Scene model validator, so a scene validated without the checks already holds them."""
    from hil.scene.checks import cross_check

    d = _set("controller.C_4", {"kp": 7.0, "kv": [1.0, 2.0, 3.0]}, "dual_master_3dof")
    d.pop("certification")
    sc = Scene.model_validate(d)  # validation + normalization only
    assert sc.controller.model_dump()["C_4"] == {"kp": [[7.0, 0.0, 0.0], [0.0, 7.0, 0.0], [0.0, 0.0, 7.0]],
                                                 "kv": [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0]]}
    for name, _ in builtin_scenes():
        sc = load_scene(name)
        before = sc.model_dump()
        cross_check(sc)
        assert sc.model_dump() == before, name


def test_units_have_one_default() -> None:
    """issue 13: the runner and the records fall back to the scene's default units ("linear")."""
    from hil.controllers import DEFAULT_UNITS

    d = _base("mbk_2dof_bench")
    d.pop("units")
    d.pop("certification")
    assert Scene.model_validate(d).units == DEFAULT_UNITS == "linear"
    import inspect

    from hil.run import runner

    src = inspect.getsource(runner)
    assert '"units", "rotary"' not in src and src.count('"units", DEFAULT_UNITS') >= 2


def test_a_registered_experiment_type_is_a_scene_option(tmp_path: Path) -> None:
    """One schema + one implementation + one registration: after ``register_experiment`` (and
    ``refresh_schema``: the scene composes its union at import) a scene file may use the type,
    with the same did-you-mean messages."""
    from typing import Literal

    import hil.experiments as ex
    from hil.scene.spec import refresh_schema

    class PulseExperiment(ex.ExperimentConfig):
        """A single effort pulse of ``amplitude`` (N) on ``target`` for ``duration`` s."""

        type: Literal["pulse"]
        target: str
        amplitude: float
        duration: float

    class Pulse:
        def __init__(self, cfg: PulseExperiment, rate_hz: float) -> None:
            self.name, self.duration, self.cfg = cfg.name or "pulse", cfg.duration, cfg

        def check(self, scene: Any) -> None:
            pass

    d = _base("sdea_bench")
    d.pop("certification")
    d["experiments"] = [{"type": "pulse", "target": "motor", "amplitude": 0.1, "duration": 0.5}]
    p = tmp_path / "pulse.yaml"
    p.write_text(yaml.safe_dump(d))
    with pytest.raises(SceneError, match=r"experiments\[0\]\.type: unknown type 'pulse'"):
        load_scene(p)
    saved = dict(ex.EXPERIMENT_TYPES)
    try:
        ex.register_experiment("pulse", PulseExperiment, Pulse)  # type: ignore[arg-type]
        with pytest.raises(TypeError, match="Literal"):
            ex.register_experiment("pulse2", PulseExperiment, Pulse)  # type: ignore[arg-type]
        refresh_schema()
        sc = load_scene(p)
        exp = ex.make_experiment(sc.experiment_models()[0], rate_hz=sc.rate_hz)
        assert isinstance(exp, Pulse) and exp.cfg.amplitude == 0.1 and exp.name == "pulse"
        d["experiments"][0]["amplitud"] = 1
        p.write_text(yaml.safe_dump(d))
        with pytest.raises(SceneError, match=r"experiments\[0\]\.amplitud: unknown key 'amplitud', did you mean"):
            load_scene(p)
    finally:
        ex.EXPERIMENT_TYPES.clear()
        ex.EXPERIMENT_TYPES.update(saved)
        refresh_schema()
    assert load_scene("sdea_bench").experiments[0].type == "chirp"
