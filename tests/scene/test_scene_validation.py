"""The whole scene is checked at load time, before any hardware moves (issue 9, item 4).

Each mistake in the ``certification`` section (and the cross-references it shares with the
experiments) is a :class:`SceneError` from :func:`load_scene` naming the file and the field, and
``hil certify BADSCENE`` exits 2 with one stderr line and creates no output folder: nothing runs.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

from hil.cli.main import main
from hil.errors import SceneError
from hil.scene.spec import load_scene


def _data(name: str) -> dict[str, Any]:
    return yaml.safe_load(load_scene(name).source_text)


def _write(tmp_path: Path, data: dict[str, Any], fname: str = "bad_scene.yaml") -> Path:
    p = tmp_path / fname
    p.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return p


def _cert(d: dict[str, Any]) -> dict[str, Any]:
    return d["certification"]


def _set_design(d: dict[str, Any], rng: list[Any], parameter: str = "k22") -> None:
    _cert(d)["design"] = {"parameter": parameter, "range": rng}


def _policy(d: dict[str, Any], **kw: Any) -> None:
    _cert(d)["policy"] = {**_cert(d).get("policy", {}), **kw}


def _default_names_clash(d: dict[str, Any]) -> None:
    """Two unnamed chirps are chirp_1 and chirp_2; a third experiment named chirp_1 clashes."""
    for e in d["experiments"][:2]:
        e.pop("name")
    d["experiments"][2]["name"] = "chirp_1"
    _cert(d)["identify"][0]["experiment"] = "chirp_2"


def _drop_force_sensor(d: dict[str, Any]) -> None:
    """The SDEA bench without its spring-torque sensor (and the VSIC that needs it)."""
    d["devices"] = d["devices"][:1]
    d["network"]["ports"][0].pop("force_sensor")
    d["controller"] = {"type": "none"}


Mutation = Callable[[dict[str, Any]], None]

# (id, base scene, mutation, field path expected in the message, message fragment)
CASES: list[tuple[str, str, Mutation, str, str]] = [
    ("identify names a missing experiment", "sdea_bench",
     lambda d: _cert(d)["identify"][0].update(experiment="chirp_lockd"),
     "certification.identify[0].experiment", "no experiment 'chirp_lockd' in the scene (did you mean 'chirp_locked'?)"),
    ("identify names a static hold", "sdea_bench",
     lambda d: _cert(d)["identify"][0].update(experiment="static_hold"),
     "certification.identify[0].experiment", "identification needs a chirp or a multisine"),
    ("negative seed", "sdea_bench", lambda d: d.update(seed=-5), "seed", "[0, 2**32-1], got -5"),
    ("seed above 2**32-1", "sdea_bench", lambda d: d.update(seed=2**32), "seed", "got 4294967296"),
    ("negative device seed", "sdea_bench", lambda d: d["devices"][0].update(sim={"seed": -1}),
     "devices[0].sim.seed", "got -1"),
    ("design range reversed", "sdea_bench", lambda d: _set_design(d, [800.0, 50.0]),
     "certification.design.range", "low < high, got [800.0, 50.0]"),
    ("design range empty", "sdea_bench", lambda d: _set_design(d, [300.0, 300.0]),
     "certification.design.range", "low < high"),
    ("design range not finite", "sdea_bench", lambda d: _set_design(d, [50.0, float("inf")]),
     "certification.design.range[1]", "expected a number"),
    ("design range negative", "sdea_bench", lambda d: _set_design(d, [-10.0, 800.0]),
     "certification.design.range", "k22 must be >= 0"),
    ("design parameter unknown", "sdea_bench", lambda d: _set_design(d, [50.0, 800.0], "k23"),
     "certification.design.parameter", "model sdea has no parameter 'k23' (did you mean 'k22'?)"),
    ("design of an uncertain parameter", "sdea_bench",
     lambda d: _set_design(d, [50.0, 800.0]) or _cert(d).update(uncertain={"k22": {"value": 300.0}}),
     "certification.design.parameter", "identified or uncertain"),
    ("design outside the SDEA coupler", "bilateral_2dof_B", lambda d: _set_design(d, [1.0, 10.0], "k_pyy"),
     "certification.design.parameter", "implemented for the SDEA coupler"),
    ("duplicate experiment names", "sdea_bench", lambda d: d["experiments"][1].update(name="chirp_locked"),
     "experiments[1].name", "duplicate experiment name 'chirp_locked' (also experiments[0])"),
    ("duplicate default experiment names", "sdea_bench",
     lambda d: _default_names_clash(d),
     "experiments[2].name", "duplicate experiment name 'chirp_1'"),
    ("required probability 1", "sdea_bench", lambda d: _policy(d, required_probability=1.0),
     "certification.policy.required_probability", "less than 1"),
    ("confidence 0", "sdea_bench", lambda d: _policy(d, confidence=0.0),
     "certification.policy.confidence", "greater than 0"),
    ("credible above 1", "sdea_bench", lambda d: _policy(d, credible=1.5),
     "certification.policy.credible", "less than 1"),
    ("probability as a boolean", "sdea_bench", lambda d: _policy(d, confidence=True),
     "certification.policy.confidence", "expected a number"),
    ("no draws", "sdea_bench", lambda d: _cert(d).update(draws=0), "certification.draws", "greater than or equal"),
    ("map source the identification model lacks", "sdea_bench",
     lambda d: _cert(d)["identify"][0]["map"].update(K_ff="K_f"),
     "certification.identify[0].map.K_ff", "identification model sdea_locked has no parameter 'K_ff'"),
    ("map destination the network lacks", "sdea_bench",
     lambda d: _cert(d)["identify"][0]["map"].update(M="M_motor"),
     "certification.identify[0].map.M", "'M_motor', which is not a parameter of model sdea"),
    ("empty map with names the network lacks", "mbk_2dof_bench", lambda d: _cert(d)["identify"][0].update(map={}),
     "certification.identify[0].map", "'LM_00' is not a parameter of model mbk_impedance"),
    ("mbk entry beyond the excited DOFs", "mbk_2dof_bench",
     lambda d: _cert(d)["identify"][0]["map"].update(M_22="M_22"),
     "certification.identify[0].map.M_22", "identification model mbk has no parameter 'M_22'"),
    ("free-output parameter on the network", "sdea_bench",
     lambda d: _cert(d)["identify"][0].update(model="sdea_free", map={}),
     "certification.identify[0].map", "'m_h' is not a parameter of model sdea"),
    ("unknown identification model", "sdea_bench", lambda d: _cert(d)["identify"][0].update(model="sdea_lockd"),
     "certification.identify[0].model", "unknown identification model 'sdea_lockd' (did you mean 'sdea_locked'?)"),
    ("unknown network model", "sdea_bench", lambda d: _cert(d).update(model="sdae"),
     "certification.model", "unknown model 'sdae' (did you mean 'sdea'?)"),
    ("criterion unknown", "sdea_bench", lambda d: _cert(d).update(criterion="lewellyn"),
     "certification.criterion", "got 'lewellyn'"),
    ("criterion not for this network", "bilateral_2dof_B", lambda d: _cert(d).update(criterion="llewellyn"),
     "certification.criterion", "llewellyn applies to 1-DOF two-ports"),
    ("uncertain parameter unknown", "mcet_trilateral",
     lambda d: _cert(d)["uncertain"].update(m_m3={"value": 1.0, "rel_std": 0.1}),
     "certification.uncertain.m_m3", "model mcet_trilateral has no parameter 'm_m3'"),
    ("uncertain value not positive", "mcet_trilateral", lambda d: _cert(d)["uncertain"]["m_s"].update(value=-1.5),
     "certification.uncertain.m_s.value", "greater than 0"),
    ("identified and uncertain", "sdea_bench", lambda d: _cert(d).update(uncertain={"M": {"value": 6e-4}}),
     "certification.identify[0].map.M", "also in certification.uncertain"),
    ("fixed parameter unknown", "dynamixel_leader_follower", lambda d: _cert(d)["parameters"].update(m_x=1.0),
     "certification.parameters.m_x", "model bilateral_1dof has no parameter 'm_x'"),
    ("fixed parameter not a number", "sdea_bench", lambda d: _cert(d).update(parameters={"k22": "stiff"}),
     "certification.parameters.k22", "expected a finite number, got 'stiff'"),
    ("unknown gain set", "bilateral_2dof_B", lambda d: _cert(d).update(parameters={"gains": "Z"}),
     "certification.parameters.gains", "unknown gain set 'Z'"),
    ("network that cannot be built", "sdea_bench", lambda d: _cert(d).update(parameters={"k22": 0.0, "b22": 0.0}),
     "certification", "needs k22 > 0 or b22 > 0"),
    ("locked SDEA without a force sensor", "sdea_bench", lambda d: _drop_force_sensor(d),
     "certification.identify[0].model", "B and B_f are inseparable"),
    ("sdea model on a 2-DOF excitation", "mbk_2dof_bench", lambda d: _cert(d)["identify"][0].update(model="sdea"),
     "certification.identify[0].model", "excites 2 DOF"),
]


@pytest.mark.parametrize(("desc", "base", "mutate", "field", "fragment"), CASES, ids=[c[0] for c in CASES])
def test_certification_mistake_is_found_at_load(tmp_path: Path, desc: str, base: str, mutate: Mutation,
                                                field: str, fragment: str) -> None:
    d = copy.deepcopy(_data(base))
    mutate(d)
    path = _write(tmp_path, d)
    with pytest.raises(SceneError) as info:
        load_scene(path)
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith(f"bad_scene.yaml: {field}: "), msg
    assert fragment in msg, msg


# a subset through the command line: exit 2, one stderr line, nothing run, no output folder
CLI_CASES = [c for c in CASES if c[0] in (
    "identify names a missing experiment", "negative seed", "design range reversed", "duplicate experiment names",
    "map destination the network lacks", "unknown network model", "criterion not for this network")]


@pytest.mark.parametrize(("desc", "base", "mutate", "field", "fragment"), CLI_CASES, ids=[c[0] for c in CLI_CASES])
def test_hil_certify_refuses_a_bad_scene_before_running(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                        capsys: pytest.CaptureFixture[str], desc: str, base: str,
                                                        mutate: Mutation, field: str, fragment: str) -> None:
    import hil.run.runner

    def must_not_run(*_a: Any, **_k: Any) -> None:
        raise AssertionError("the runner was started for a scene that does not load")

    monkeypatch.setattr(hil.run.runner.Runner, "__init__", must_not_run)
    monkeypatch.chdir(tmp_path)
    d = copy.deepcopy(_data(base))
    mutate(d)
    path = _write(tmp_path, d)
    out = tmp_path / "tmp" / "x"
    code = main(["certify", str(path), "--out", str(out)])
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1, err
    assert "bad_scene.yaml" in lines[0] and field in lines[0] and fragment in lines[0], lines[0]
    assert "Traceback" not in err
    assert not out.exists() and not (tmp_path / "tmp").exists()
    assert not (tmp_path / "reports").exists()


def test_bad_seed_flag_is_refused_before_anything(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    code = main(["run", "sdea_bench", "--seed", "-5", "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "--seed" in err[0] and "got -5" in err[0], err
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------------------------
# experiment and controller checks: at load time, naming the file


@pytest.mark.parametrize(("key", "value", "fragment"), [
    ("f1", 450.0, "exceeds Nyquist/5 = 200 Hz"),
    ("amplitude", 5.0, "peak effort 5 exceeds safety.max_effort 2"),
    ("fade", 3.0, "exceeds the period"),
])
def test_experiment_check_names_the_scene_file(tmp_path: Path, key: str, value: Any, fragment: str) -> None:
    d = _data("sdea_bench")
    d["experiments"][1][key] = value  # the second experiment: found before the first one runs
    with pytest.raises(SceneError) as info:
        load_scene(_write(tmp_path, d, "rig.yaml"))
    msg = str(info.value)
    assert msg.startswith(f"rig.yaml: experiments[chirp_free].{key}: "), msg
    assert fragment in msg and "\n" not in msg


def test_energy_injection_profile_is_checked_at_load(tmp_path: Path) -> None:
    d = _data("bilateral_2dof_B")
    d["experiments"][0]["profile"] = {"kind": "noise", "amplitude": 2.0, "freq": 1.0e6}
    with pytest.raises(SceneError) as info:
        load_scene(_write(tmp_path, d, "noise.yaml"))
    msg = str(info.value)
    assert msg.startswith("noise.yaml: experiments[energy_injection].profile.freq: noise cutoff must lie in"), msg


# --------------------------------------------------------------------------------------------
# YAML: duplicate keys at any depth, unknown keys with did-you-mean


def _text_with(tmp_path: Path, old: str, new: str, fname: str = "dup.yaml") -> Path:
    text = load_scene("sdea_bench").source_text
    assert text.count(old) == 1, old
    p = tmp_path / fname
    p.write_text(text.replace(old, new), encoding="utf-8")
    return p


@pytest.mark.parametrize(("old", "new", "path"), [
    ("seed: 0\n", "seed: 0\nseed: 1\n", "seed"),
    ("  P_m: 0.28\n", "  P_m: 0.28\n  P_m: 0.5\n", "controller.P_m"),
    ("max_effort: 2.0\n", "max_effort: 2.0\n  max_effort: 20.0\n", "safety.max_effort"),
    ("draws: 4000", "draws: 4000\n  draws: 20", "certification.draws"),
    ("{name: chirp_locked, type: chirp,", "{name: chirp_locked, type: chirp, f1: 100.0,", "experiments[0].f1"),
])
def test_duplicate_keys_are_refused_at_any_depth(tmp_path: Path, old: str, new: str, path: str) -> None:
    p = _text_with(tmp_path, old, new)
    with pytest.raises(SceneError) as info:
        load_scene(p)
    msg = str(info.value)
    key = path.rsplit(".", 1)[-1].split("]")[-1].lstrip(".") or path
    assert msg.startswith(f"dup.yaml: {path}: duplicate key {key!r} (line "), msg
    assert "first at line" in msg and "\n" not in msg
    # the line numbers are those of the file
    first, second = (int(x) for x in msg.split("(line ")[1].rstrip(")").split("; first at line ")[::-1])
    lines = p.read_text(encoding="utf-8").splitlines()
    assert f"{key}:" in lines[first - 1] and f"{key}:" in lines[second - 1]
    assert first <= second


def test_merge_keys_may_override() -> None:
    from hil.scene.spec import parse_yaml

    d = parse_yaml("lim: &lim {max_effort: 1.0, max_velocity: 60.0}\nsafety:\n  <<: *lim\n  max_effort: 2.0\n",
                   "merge.yaml")
    assert d["safety"] == {"max_effort": 2.0, "max_velocity": 60.0}  # YAML's merge override, not a duplicate
    with pytest.raises(SceneError, match=r"^merge.yaml: safety.max_effort: duplicate key 'max_effort' \(line 4; "
                                         r"first at line 3\)$"):
        parse_yaml("lim: 1\nsafety:\n  max_effort: 1.0\n  max_effort: 2.0\n", "merge.yaml")


@pytest.mark.parametrize(("container", "typo", "right"), [
    ("", "experimnets", "experiments"),
    ("devices.0", "drivr", "driver"),
    ("certification", "identfy", "identify"),
    ("certification.identify.0", "mapp", "map"),
    ("certification.design", "rnage", "range"),
])
def test_unknown_key_says_did_you_mean(tmp_path: Path, container: str, typo: str, right: str) -> None:
    d = _data("sdea_bench")
    cur: Any = d
    for part in container.split(".") if container else []:
        cur = cur[int(part)] if part.isdigit() else cur[part]
    cur[typo] = cur.pop(right)
    with pytest.raises(SceneError) as info:
        load_scene(_write(tmp_path, d, "typo.yaml"))
    msg = str(info.value)
    assert msg.startswith("typo.yaml: "), msg
    assert f"unknown key {typo!r}, did you mean {right!r}?" in msg, msg
    assert "Field required" not in msg and "\n" not in msg
