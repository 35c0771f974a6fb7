"""Network models as registered objects (hil.models): each builds its network, names its
criterion and maps a scene's parameters, so hil certify and hil sweep need no branch on a model's
name; the criterion names come from one list (hil.stability.criteria.CRITERIA)."""

from __future__ import annotations

from typing import Annotated, Any

import numpy as np
import pydantic
import pytest
import yaml

from hil.certify.pipeline import build_network, certify_scene, model_params_from_scene
from hil.errors import ModelError
from hil.models import BUILTIN_MODELS, BuiltinModel, get_model, model_names
from hil.scene.spec import load_scene, scene_from_dict
from hil.stability.criteria import CRITERIA, check


def test_every_model_builds_and_names_a_registered_criterion():
    for name in model_names():
        m = get_model(name)
        assert m.criterion in CRITERIA, name
        tm = m.network({})
        assert tm.n >= 1
        assert str(check(tm, m.criterion).verdict) in ("stable", "marginal", "potentially_unstable")


def test_criterion_names_have_one_source():
    """check() runs exactly the names of CRITERIA (and auto), and the scene schema, the network
    file schema and the CLI offer exactly those."""
    from hil.cli.main import build_parser
    from hil.scene.netfile import NetworkFile
    from hil.scene.spec import CertificationCfg

    tm = get_model("bilateral_1dof").network({})  # a 1-DOF two-port: every criterion applies
    for name in CRITERIA:
        assert check(tm, name).criterion
    with pytest.raises(ModelError):
        check(tm, "no_such_criterion")
    offered = ("auto", *CRITERIA)
    # the schemas validate against the same registry: every offered name passes, others fail
    for schema in (CertificationCfg, NetworkFile):
        fi = schema.model_fields["criterion"]
        adapter = pydantic.TypeAdapter(Annotated[fi.annotation, *fi.metadata])
        for name in offered:
            assert adapter.validate_python(name) == name
        with pytest.raises(pydantic.ValidationError, match=r"unknown criterion: expected one of auto, .*got 'nyquist'"):
            adapter.validate_python("nyquist")
    sub = next(a for a in build_parser()._actions if a.dest == "cmd")
    for cmd, want in (("stability", offered), ("sweep", CRITERIA)):
        opt = next(a for a in sub.choices[cmd]._actions if "--criterion" in a.option_strings)
        assert tuple(opt.choices) == want, cmd


def test_a_gain_given_at_the_top_level_applies_with_or_without_a_gain_table():
    """bilateral_2dof's ``gains`` takes a Table II set name or a mapping; a top-level gain applies
    in both cases, as ``hil stability --set`` does (the pipeline once dropped it for a set name)."""
    m = get_model("bilateral_2dof")
    # z11 = (m s² + (b + k_v) s + k_p)/s: num[0] (ascending powers) is k_p
    z11 = lambda tm: np.asarray(tm[0, 0].num, float)  # noqa: E731
    base = build_network("bilateral_2dof", {})
    over = build_network("bilateral_2dof", {"k_pyy": 5000.0})
    assert z11(over)[0] == 5000.0 != z11(base)[0]
    assert np.array_equal(z11(over), z11(m.build(k_pyy=5000.0)))
    table = dict(model_params_from_scene(load_scene("bilateral_2dof_B"))["gains"])
    tm = build_network("bilateral_2dof", {"gains": table, "k_pmyy": 123.0})
    assert z11(tm)[0] == 123.0  # the top-level entry overrides the table's
    assert z11(build_network("bilateral_2dof", {"gains": table}))[0] == table["k_pmyy"]


def test_scene_parameters_are_read_from_the_scene_file():
    """Each model's scene mapping, checked against the scene's own YAML."""
    for name in ("mcet_trilateral", "sdea_bench", "dynamixel_leader_follower"):
        sc = load_scene(name)
        d = yaml.safe_load(sc.source_text)
        c, p = d["controller"], model_params_from_scene(sc)
        if name == "mcet_trilateral":
            masses = {b["name"]: b["M"] for b in d["simulation"]["bodies"]}
            assert p == {**{k: c[k] for k in ("k_pm1", "k_vm1", "k_pm2", "k_vm2", "k_ps", "k_vs", "alpha")},
                         "m_m1": masses["master1"], "m_m2": masses["master2"], "m_s": masses["slave"]}
        elif name == "sdea_bench":
            sd = d["simulation"]["sdea"]
            assert p == {**{k: c[k] for k in ("P_m", "I_m", "P_f", "I_f", "alpha", "k22", "b22")},
                         **{k: sd[k] for k in ("M", "B", "K_f", "B_f")}}
        else:  # bilateral_1dof: the controller's 1x1 gains, then certification.parameters on top
            assert p == {"k_pm": c["Kp_m"][0][0], "k_vm": c["Kv_m"][0][0], "k_ps": c["Kp_s"][0][0],
                         "k_vs": c["Kv_s"][0][0], **d["certification"]["parameters"]}


def test_a_new_model_is_one_registration(monkeypatch, tmp_path):
    """A model registered from outside (a 1-DOF mass-damper one-port, the leader joint of the
    dynamixel scene, mapped from the scene's simulated body) is certified end to end with no
    change to hil.certify.pipeline: its builder, criterion and scene mapping are all the pipeline uses."""
    from hil.models.teleop import mbk_impedance

    def joint(scene: Any, c: dict[str, Any]) -> dict[str, Any]:
        body = next(b for b in scene.simulation.bodies if b.name == c["master"])
        return {"dof": 1, "M_00": float(np.asarray(body.M).reshape(-1)[0]),
                "B_00": float(np.asarray(body.B).reshape(-1)[0]), "K_00": 0.0}

    toy = BuiltinModel("leader_joint", "the leader joint alone, Z = (M s² + B s)/s", "positive_real",
                       {"dof": 1, "M_00": 0.01, "B_00": 0.05, "K_00": 0.0}, lambda **p: mbk_impedance(p),
                       from_scene=joint)
    get_model("sdea")  # fill the registry first
    monkeypatch.setitem(BUILTIN_MODELS, "leader_joint", toy)
    d = yaml.safe_load(load_scene("dynamixel_leader_follower").source_text)
    d["experiments"] = []
    d["certification"] = {"model": "leader_joint", "uncertain": {"B_00": {"value": 0.05, "rel_std": 0.2}},
                          "draws": 40}
    cert = certify_scene(scene_from_dict(d, label="toy"), tmp_path, run_experiments=False)
    assert cert.nominal is not None and cert.nominal.criterion.startswith("positive_real")
    assert cert.nominal.parameters["M_00"] == 0.01 and cert.nominal.verdict == "stable"
    # a mass and a positive damper are passive for every draw (B > 0 always under a log-normal)
    assert cert.robust is not None and cert.robust.p_stable == 1.0
    assert cert.decision in ("GO", "MARGINAL"), cert.reasons
