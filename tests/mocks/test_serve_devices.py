"""``hil mock serve --device KIND``: one simulated device of every kind served on its own; the
printed endpoint connects the matching adapter (in process) or a plain client (another process).

Served devices run free on the wall clock: the tests wait for states (a report, a reply), and their
timeouts are bounds a loaded machine never reaches (a read returns with its answer)."""

from __future__ import annotations

import json
import select
import subprocess
import sys

import numpy as np
import pytest

from hil.bench.serve import MOCK_KINDS, serve, shutdown
from hil.cli.main import main as hil_main
from hil.protocols.registry import open_device

pytestmark = pytest.mark.timeout(60)

SPECS = [
    {"kind": "odrive", "channel": "serve-dev-od", "node_id": 3},
    {"kind": "cubemars", "channel": "serve-dev-cm", "motor_id": 2},
    {"kind": "cia402", "channel": "serve-dev-co", "node_id": 5},
    {"kind": "bota"},
    {"kind": "ft300", "slave": 9},
    {"kind": "ft300_stream", "slave": 9},
    {"kind": "dynamixel", "ids": [1, 2]},
]


def test_every_kind_has_a_spec_here():
    assert {s["kind"] for s in SPECS} == set(MOCK_KINDS)


@pytest.mark.parametrize("spec", SPECS, ids=[s["kind"] for s in SPECS])
def test_served_device_answers_its_adapter(spec):
    pytest.importorskip("can")
    if spec["kind"] == "cia402":
        pytest.importorskip("canopen")
    if spec["kind"] == "ft300":
        pytest.importorskip("pymodbus")
    if spec["kind"] == "dynamixel":
        pytest.importorskip("dynamixel_sdk")
    (ep,) = endpoints = serve([spec])
    try:
        assert ep.driver == MOCK_KINDS[spec["kind"]]
        extra = {"timeout": 30.0}
        with open_device(ep.driver, **ep.params, **extra) as dev:
            sample = dev.read(timeout=30.0)
            if hasattr(sample, "position"):
                assert sample.position.shape == (dev.dof,)
                assert np.all(np.isfinite(sample.position))
            else:
                assert np.all(np.isfinite(sample.wrench))
    finally:
        shutdown(endpoints)


def _start(*args: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "hil.cli.main", "mock", "serve", *args]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _report(proc: subprocess.Popen) -> dict:
    """The JSON line printed once the device listens (waited for as long as the server lives)."""
    while not select.select([proc.stdout], [], [], 1.0)[0]:
        if proc.poll() is not None:
            break
    line = proc.stdout.readline()
    if not line:
        proc.wait(5)
        pytest.fail(f"server exited ({proc.returncode}): {proc.stderr.read()}")
    return json.loads(line)


def test_dynamixel_served_alone_answers_a_raw_sdk_ping_from_another_process(monkeypatch):
    sdk = pytest.importorskip("dynamixel_sdk")
    import dynamixel_sdk.port_handler as ph_module

    # the stock SDK waits 2 x 16 ms (its USB latency timer) for a status packet: a bound the served
    # chain's thread may miss on a loaded machine; 2 x 1 s is one it does not (an answer ends it)
    monkeypatch.setattr(ph_module, "LATENCY_TIMER", 1000)
    proc = _start("--device", "dynamixel", "--pty", "--ids", "1,4", "--json", "--duration", "600")
    try:
        rep = _report(proc)
        (dev,) = rep["devices"]
        assert dev["driver"] == "dynamixel_x" and dev["params"]["ids"] == [1, 4]
        port = sdk.PortHandler(dev["params"]["port"])
        assert port.openPort()
        port.setBaudRate(57600)
        ph = sdk.PacketHandler(2.0)
        found = {}
        for dxl_id in (1, 2, 4):
            model, result, _ = ph.ping(port, dxl_id)
            if result == sdk.COMM_SUCCESS:
                found[dxl_id] = model
        port.closePort()
        assert sorted(found) == [1, 4]  # id 2 is not on this chain
        assert set(found.values()) == {1020}  # XM430-W350 model number (ROBOTIS e-Manual)
    finally:
        proc.terminate()
        proc.communicate(timeout=10)


def test_cia402_served_alone_over_udp_multicast_reaches_the_adapter_in_another_process():
    pytest.importorskip("canopen")
    pytest.importorskip("msgpack", reason="python-can's udp_multicast bus needs msgpack")
    group = "239.74.163.41"
    proc = _start("--device", "cia402", "--can-interface", "udp_multicast", "--can-channel", group,
                  "--node", "6", "--json", "--duration", "600")  # terminated below
    try:
        rep = _report(proc)
        (dev,) = rep["devices"]
        assert dev["params"] == {"interface": "udp_multicast", "channel": group, "node_id": 6, "gear_ratio": 1.0}
        with open_device("cia402", **dev["params"], timeout=30.0) as drv:
            drv.command_effort(np.array([0.05]))
            s = drv.read(timeout=30.0)
            assert s.effort[0] == pytest.approx(0.05)  # 50 per mille of the 1 N.m rated torque
            assert drv.info.extra["vendor_id"] == 0x0A1C
    finally:
        proc.terminate()
        proc.communicate(timeout=10)


@pytest.mark.parametrize(("argv", "needle"), [
    (["--device", "bota", "--node", "3"], "--device bota has no CAN node id"),
    (["--device", "odrive", "--can-channel", "hil0=vcan0"], "takes one CAN channel name"),
    (["--device", "cia402", "--node", "0"], "cia402 ids are 1..127"),
    (["--device", "ft300", "--ids", "1"], "only --device dynamixel has servo ids"),
    (["--device", "odrive", "--pty"], "does not serve on a pty"),
    (["sdea_bench", "--device", "odrive"], "give one of SCENE, --spec or --device"),
])
def test_bad_device_options_one_line(argv, needle, capsys):
    assert hil_main(["mock", "serve", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0], err
