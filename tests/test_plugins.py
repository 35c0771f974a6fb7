"""An experiment type, a controller, a network model and a criterion from another distribution,
through the entry-point groups of :mod:`hil.plugins` and :mod:`hil.stability.criteria`: one module
and one registration each, no edit of the suite (devices: tests/protocols/test_registry_entry_points.py).

The "distribution" is a ``*.dist-info`` folder (METADATA + entry_points.txt, what
:mod:`importlib.metadata` reads) and a module in a temporary directory on ``sys.path``.
"""

from __future__ import annotations

import importlib
import sys
import textwrap
from pathlib import Path

import pytest
import yaml

from hil import controllers, experiments, models, plugins
from hil.cli.main import main
from hil.errors import ExitCode, SceneError
from hil.run.runner import Runner
from hil.scene.spec import load_scene, refresh_schema, scene_from_dict
from hil.stability import criteria

pytestmark = pytest.mark.timeout(120)

PLUGIN_MODULE = '''
"""The outside package: one experiment type, one controller, one model, one criterion."""
from typing import Literal

import numpy as np

from hil.controllers import ControllerConfig, ControllerType
from hil.experiments import ExperimentType, StaticHold, StaticHoldExperiment
from hil.models import BuiltinModel
from hil.stability.criteria import Criterion, positive_real
from hil.stability.rational import TransferMatrix


class PluginHoldExperiment(StaticHoldExperiment):
    """A static hold under another type name."""
    type: Literal["plugin_hold"]


class JointSpringConfig(ControllerConfig):
    """A virtual spring on one actuator: effort = -k * position (N.m/rad)."""
    type: Literal["joint_spring"]
    device: str
    k: float


class JointSpring:
    name = "joint_spring"

    def __init__(self, cfg):
        self.device, self.k = cfg.device, float(cfg.k)

    def reset(self):
        pass

    def update(self, t, dt, meas):
        return {self.device: -self.k * np.asarray(meas[self.device].position, dtype=float)}


def rc_one_port(R=1.0, C=1.0):
    """Z(s) = R + 1/(C s): a resistor in series with a capacitor (impedance, ohm-like units)."""
    return TransferMatrix.from_coefficients([[{"num": [R * C, 1.0], "den": [C, 0.0]}]])


EXPERIMENT = ExperimentType("plugin_hold", PluginHoldExperiment, StaticHold)
CONTROLLER = ControllerType("joint_spring", JointSpringConfig, lambda cfg, where, scene: JointSpring(cfg))
MODEL = BuiltinModel("rc_one_port", "R + 1/(C s) (a plugin's model)", "pr_plugin", {"R": 1.0, "C": 1.0},
                     rc_one_port)
CRITERION = Criterion("pr_plugin", lambda tm, tol, margins: positive_real(tm, tol, margins),
                      "positive realness under a plugin's name")
'''

ENTRY_POINTS = """\
[hil_certify.experiments]
plugin_hold = hil_plugin_demo:EXPERIMENT
[hil_certify.controllers]
joint_spring = hil_plugin_demo:CONTROLLER
broken = hil_plugin_demo:NO_SUCH_NAME
[hil_certify.models]
rc_one_port = hil_plugin_demo:MODEL
[hil_certify.criteria]
pr_plugin = hil_plugin_demo:CRITERION
"""


@pytest.fixture
def plugin_distribution(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """``hil-plugin-demo`` 0.1 on ``sys.path`` for this test only; every registry restored after."""
    root = tmp_path / "site"
    info = root / "hil_plugin_demo-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: hil-plugin-demo\nVersion: 0.1\n", encoding="utf-8")
    (info / "entry_points.txt").write_text(ENTRY_POINTS, encoding="utf-8")
    (root / "hil_plugin_demo.py").write_text(textwrap.dedent(PLUGIN_MODULE), encoding="utf-8")
    models.get_model("sdea")  # built-ins in place before the registry is copied
    monkeypatch.setattr(experiments, "EXPERIMENT_TYPES", dict(experiments.EXPERIMENT_TYPES))
    monkeypatch.setattr(controllers, "CONTROLLER_TYPES", dict(controllers.CONTROLLER_TYPES))
    monkeypatch.setattr(models, "BUILTIN_MODELS", dict(models.BUILTIN_MODELS))
    monkeypatch.setattr(criteria, "_REGISTRY", dict(criteria._REGISTRY))
    monkeypatch.setattr(criteria, "_entry_points_loaded", False)
    monkeypatch.setattr(plugins, "_loaded", set())
    monkeypatch.syspath_prepend(str(root))
    importlib.invalidate_caches()
    refresh_schema()  # composes the scene's unions again: reads the experiment/controller groups
    yield root
    monkeypatch.undo()
    refresh_schema()  # back to the built-in types
    sys.modules.pop("hil_plugin_demo", None)


def _scene(k: float) -> object:
    d = yaml.safe_load(load_scene("sdea_bench").source_text)
    d["controller"] = {"type": "joint_spring", "device": "motor", "k": k}
    # noise-free sensors: the static stiffness is checked to 1e-6 (the built-in scene's encoder noise,
    # 2e-4 rad, is 20 % of the 1.1e-3 rad the hold deflects)
    d["simulation"]["sensor_noise"] = {"force_std": 0.0, "velocity_std": 0.0, "position_std": 0.0}
    d["experiments"] = [{"name": "hold", "type": "plugin_hold", "controller": "scene", "variant": "locked",
                         "target": "motor", "effort": 0.5, "duration": 0.3, "settle": 0.1}]
    d.pop("certification", None)
    return scene_from_dict(d, label="plugin-sdea")


def test_registered_through_entry_points(plugin_distribution: Path) -> None:
    assert "plugin_hold" in experiments.EXPERIMENT_TYPES
    assert "joint_spring" in controllers.CONTROLLER_TYPES
    assert "broken" not in controllers.CONTROLLER_TYPES  # a broken entry point is skipped (logged)
    assert "rc_one_port" in models.model_names()
    assert criteria.is_criterion("pr_plugin") and "pr_plugin" in criteria.criterion_names()


def test_a_scene_runs_the_plugin_experiment_under_the_plugin_controller(plugin_distribution: Path,
                                                                       tmp_path: Path) -> None:
    """Locked SDEA under a constant motor effort F with the virtual spring k on the motor
    position: K_f x = F - k x at rest, so the static stiffness F/x the hold reports is K_f + k.
    (The transient decays with 2M/(B + B_f) = 5.8 ms; after the 0.1 s settle it is e^-17 of the
    step, so 1e-6 relative is ample.)"""
    k = 100.0
    sc = _scene(k)
    (out,) = Runner(sc, tmp_path / "run").run()
    assert out.status == "completed", out.stop_reason
    assert out.results["stiffness"][0] == pytest.approx(sc.simulation.sdea.K_f + k, rel=1e-6)


def test_unknown_plugin_key_is_refused_with_the_scene_path(plugin_distribution: Path) -> None:
    d = yaml.safe_load(load_scene("sdea_bench").source_text)
    d["controller"] = {"type": "joint_spring", "device": "motor", "k": 1.0, "kk": 2.0}
    with pytest.raises(SceneError, match=r"controller.*kk"):
        scene_from_dict(d, label="plugin-sdea")


@pytest.mark.parametrize(("R", "code", "verdict"),
                         [(1.0, ExitCode.OK, "stable"), (-1.0, ExitCode.UNSTABLE, "potentially_unstable")])
def test_plugin_model_under_the_plugin_criterion(plugin_distribution: Path, capsys: pytest.CaptureFixture[str],
                                                 R: float, code: ExitCode, verdict: str) -> None:
    """Re Z(jω) = R exactly: positive real iff R >= 0 (the pole at s = 0 has residue 1/C > 0)."""
    got = main(["stability", "--model", "rc_one_port", "--criterion", "pr_plugin", "--set", f"R={R}", "--json"])
    out = capsys.readouterr().out
    assert got == code, out
    assert f'"{verdict}"' in out
