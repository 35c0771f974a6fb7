"""Driver registry: lazy imports, helpful errors."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

from hil.errors import DeviceError, HilError
from hil.protocols import registry
from hil.protocols.registry import UnknownDriverError, available_drivers, open_device

pytestmark = pytest.mark.timeout(20)


def test_available_drivers():
    names = available_drivers()
    for n in ("odrive_can", "cubemars_mit", "bota_serial", "robotiq_ft300", "dynamixel_x"):
        assert n in names
    assert names == sorted(names)


def test_unknown_driver_suggests():
    with pytest.raises(UnknownDriverError) as ei:
        open_device("odrive_cna")
    msg = str(ei.value)
    assert "did you mean 'odrive_can'" in msg.lower()
    assert "bota_serial" in msg  # lists known names
    assert isinstance(ei.value, KeyError) and isinstance(ei.value, DeviceError) and isinstance(ei.value, HilError)


def test_unknown_driver_without_close_match():
    with pytest.raises(UnknownDriverError) as ei:
        open_device("zzzzzz")
    assert "did you mean" not in str(ei.value).lower()


def isolate_registry(monkeypatch) -> None:
    """Registrations made by a test stay in it (copies of every registry table)."""
    for table in ("_KINDS", "_DRIVERS", "ADAPTER_REQUIRES", "SIMULATOR_REQUIRES", "DEVICE_LABELS"):
        monkeypatch.setattr(registry, table, dict(getattr(registry, table)))


def test_register_and_resolve(monkeypatch):
    isolate_registry(monkeypatch)
    registry.register_driver("fake", "collections:OrderedDict")
    assert open_device("fake", a=1) == {"a": 1}
    with pytest.raises(ValueError):
        registry.register_driver("fake", "collections:Counter")
    registry.register_driver("broken", "hil.no_such_module_xyz:Thing")
    with pytest.raises(DeviceError, match="failed to import"):
        open_device("broken")
    registry.register_driver("noclass", "collections:NoSuchClass")
    with pytest.raises(DeviceError, match="no class"):
        open_device("noclass")


def test_open_odrive_does_not_import_modbus_or_dynamixel():
    code = textwrap.dedent(
        """
        import sys
        from hil.mocks.can_devices import SimODrive
        from hil.mocks.interfaces import FreeJoints
        from hil.protocols.registry import open_device
        node = SimODrive(FreeJoints(), "reg-test", node_id=1, sync=True)
        dev = open_device("odrive_can", interface="virtual", channel="reg-test", node_id=1)
        dev.read(timeout=0.5)
        dev.close(); node.close()
        bad = [m for m in sys.modules if m.split(".")[0] in ("pymodbus", "dynamixel_sdk")]
        bad += [m for m in sys.modules if m in ("hil.protocols.modbus_robotiq", "hil.protocols.dynamixel_x")]
        print("LOADED", bad)
        assert not bad, bad
        """
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "LOADED []" in r.stdout


def test_open_bota_via_registry():
    from hil.mocks.interfaces import FreeJoints
    from hil.mocks.serial_devices import SimBota

    with SimBota(FreeJoints()) as sim, open_device("bota_serial", url=sim.path) as dev:
        sim.emit()
        assert dev.read().seq == 1


def test_mock_serve_endpoints_open_through_registry():
    import numpy as np

    from hil.bench.serve import serve, shutdown
    from hil.cli.main import main as hil_main

    eps = serve(
        [
            {"kind": "odrive", "channel": "serve-test", "node_id": 2, "faults": {"drop_prob": 0.0}},
            {"kind": "cubemars", "channel": "serve-test", "motor_id": 1},
            {"kind": "bota", "rate_hz": 500},
        ]
    )
    try:
        for ep in eps:
            with open_device(ep.driver, **ep.params) as dev:
                if hasattr(dev, "command_effort"):
                    dev.command_effort(np.array([0.1]))
                assert dev.read(timeout=1.0).seq == 1
    finally:
        shutdown(eps)
        shutdown(eps)
    with pytest.raises(ValueError, match="unknown mock kind"):
        serve([{"kind": "nope"}])
    assert hil_main(["mock", "serve", "--duration", "0.05", "--spec", '[{"kind": "bota"}]']) == 0
