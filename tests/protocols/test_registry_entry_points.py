"""A device kind from another distribution, through the ``hil_certify.devices`` entry-point group:
one module (adapter + simulated twin) and one registration, no edit of the suite.

The "distribution" is written into a temporary directory put on ``sys.path``: a ``*.dist-info``
folder with ``METADATA`` and ``entry_points.txt`` (what :mod:`importlib.metadata` reads) and the
module itself. A scene names the new driver, and a short simulated experiment runs through it.
"""

from __future__ import annotations

import importlib
import sys
import textwrap
from pathlib import Path

import pytest
import yaml

from hil.bench.runtime import Bench
from hil.protocols import registry
from hil.run.runner import Runner
from hil.scene.spec import load_scene, scene_from_dict

pytestmark = pytest.mark.timeout(120)

TOY_MODULE = '''
"""A toy actuator, its simulated twin and its registration (the outside package of the test)."""
import time

from hil.errors import DeviceDisconnected
from hil.mocks.twins import Twin
from hil.protocols.base import Actuator, DeviceInfo, JointSample
from hil.protocols.registry import DeviceKind

SERVED = {}  # "url" -> simulated motor: the toy's transport is a table in this process


class SimToyMotor:
    def __init__(self, point, url):
        self.point, self.url = point, url
        self.commands = self.ticks = 0
        SERVED[url] = self

    def tick(self):
        self.ticks += 1

    def close(self):
        SERVED.pop(self.url, None)


class ToyMotor(Actuator):
    dof = 1
    units = "rotary"

    def __init__(self, url, clock=time.monotonic, timeout=0.1):
        try:
            self._sim = SERVED[url]
        except KeyError:
            raise DeviceDisconnected(f"no toy motor at {url!r}") from None
        self.clock, self.timeout = clock, timeout
        self.info = DeviceInfo(driver="toy_motor", transport=f"toy:{url}")

    def _send_effort(self, effort, timeout):
        self._sim.point.apply_effort(effort)
        self._sim.commands += 1

    def _read_sample(self, timeout):
        p = self._sim.point
        return JointSample(t=self.clock(), seq=self._next_seq(), position=p.position(), velocity=p.velocity())

    def _release(self):
        self._sim = None


class ToyTwin(Twin):
    def start(self, ctx, params):
        url = f"toy-{ctx.index}-{id(ctx)}"
        params.update(url=url, clock=ctx.clock, timeout=ctx.timeout)
        return SimToyMotor(ctx.point, url), params

    def tick(self, sim):
        sim.tick()


TWIN = ToyTwin()
KIND = DeviceKind("toy_motor", "hil_toy_device:ToyMotor", "toy", "hil_toy_device:TWIN", "toy motor")
'''


@pytest.fixture
def toy_distribution(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """``hil-toy-device`` 0.1 installed on ``sys.path`` for this test only (registry restored after)."""
    root = tmp_path / "site"
    info = root / "hil_toy_device-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: hil-toy-device\nVersion: 0.1\n", encoding="utf-8")
    (info / "entry_points.txt").write_text("[hil_certify.devices]\ntoy_motor = hil_toy_device:KIND\n"
                                           "broken = hil_toy_device:NO_SUCH_NAME\n", encoding="utf-8")
    (root / "hil_toy_device.py").write_text(textwrap.dedent(TOY_MODULE), encoding="utf-8")
    for table in ("_KINDS", "_DRIVERS", "ADAPTER_REQUIRES", "SIMULATOR_REQUIRES", "DEVICE_LABELS"):
        monkeypatch.setattr(registry, table, dict(getattr(registry, table)))
    monkeypatch.setattr(registry, "_entry_points_loaded", False)
    monkeypatch.syspath_prepend(str(root))
    importlib.invalidate_caches()
    yield root
    sys.modules.pop("hil_toy_device", None)


def _toy_scene() -> object:
    """The SDEA bench with its ODrive replaced by the toy motor, one short static hold."""
    d = yaml.safe_load(load_scene("sdea_bench").source_text)
    d["devices"][0].update(driver="toy_motor", params={})
    # noise-free sensors: the static stiffness below is checked to 1e-6 (the built-in scene's encoder
    # noise, 2e-4 rad, is 20 % of the 1.4e-3 rad the hold deflects)
    d["simulation"]["sensor_noise"] = {"force_std": 0.0, "velocity_std": 0.0, "position_std": 0.0}
    d["experiments"] = [{"name": "hold", "type": "static_hold", "controller": "none", "variant": "locked",
                         "target": "motor", "effort": 0.5, "duration": 0.3, "settle": 0.1}]
    d.pop("certification", None)
    return scene_from_dict(d, label="toy-sdea")


def test_entry_point_registers_a_device_with_a_simulated_twin(toy_distribution: Path) -> None:
    assert "toy_motor" not in registry._KINDS
    assert "toy_motor" in registry.available_drivers()  # the entry point is read on first use
    assert "toy_motor" in registry.simulated_drivers()
    assert "broken" not in registry.available_drivers()  # a broken entry point is skipped, logged
    kind = registry.device_kind("toy_motor")
    assert kind.transport == "toy" and registry.resolve_driver("toy_motor").__name__ == "ToyMotor"


def test_a_scene_names_the_new_device_and_a_bench_ticks_its_twin(toy_distribution: Path) -> None:
    sc = _toy_scene()
    with Bench(sc, variant="locked") as bench:
        sim = bench._devs[0].sim
        for _ in range(5):
            bench.read()
            bench.command({"motor": [0.1]})
            bench.advance()
        assert type(sim).__name__ == "SimToyMotor"
        # published once at t = 0 (Twin.publish defaults to tick), then ticked once per period
        assert (sim.ticks, sim.commands) == (1 + 5, 5)
        assert bench.device_identities()["motor"]["driver"] == "toy_motor"
    assert sim.url not in sys.modules["hil_toy_device"].SERVED  # closed with the bench


def test_a_simulated_experiment_runs_through_the_new_device(toy_distribution: Path, tmp_path: Path) -> None:
    sc = _toy_scene()
    (out,) = Runner(sc, tmp_path / "run").run()
    assert out.status == "completed", out.stop_reason
    # locked SDEA: the static stiffness seen by a constant motor effort is the series spring K_f
    # (M x'' + (B + B_f) x' + K_f x = u settles with time constant 2 M / (B + B_f) = 5.8 ms; after
    # the 0.1 s settle the transient is e^-17 of the step, so 1e-6 relative is ample)
    k_f = sc.simulation.sdea.K_f
    assert out.results["stiffness"][0] == pytest.approx(k_f, rel=1e-6)
