"""``hil probe``: finds each simulated device family (served by hil.bench.serve, the same objects
``hil mock serve --device`` starts) with the identity the simulated device holds, and writes a
scene stub that loads; bad input is one line and nothing is overwritten."""

from __future__ import annotations

import itertools
import json

import pytest

pytest.importorskip("can")

from hil.bench.probe import probe_can, probe_modbus, probe_serial
from hil.bench.serve import serve, shutdown
from hil.cli.main import main
from hil.scene.spec import load_scene

pytestmark = pytest.mark.timeout(60)
_chan = itertools.count()


@pytest.fixture
def can_bench():
    pytest.importorskip("canopen")
    ch = f"probe-{next(_chan)}"
    eps = serve([
        # ODrive with an injected MISSING_INPUT (0x40) axis error, heartbeat every 100 ticks (100 ms)
        {"kind": "odrive", "channel": ch, "node_id": 3, "heartbeat_every": 100,
         "faults": {"error_code": 0x40, "error_at_tick": 0}},
        {"kind": "cia402", "channel": ch, "node_id": 5, "identity": {"serial": 4242, "product_code": 0x1234}},
        {"kind": "cubemars", "channel": ch, "motor_id": 2},
    ])
    yield ch, eps
    shutdown(eps)


def test_probe_can_finds_odrive_cia402_and_cubemars(can_bench):
    ch, _ = can_bench
    found = {f.family: f for f in probe_can(ch, "virtual", listen_s=0.5, cubemars_ids=[2], timeout=0.3)}
    assert set(found) == {"odrive", "cia402", "cubemars"}
    od = found["odrive"]
    assert od.params["node_id"] == 3 and od.details["axis_error"] == "0x00000040"
    assert od.details["errors"] == "MISSING_INPUT" and od.details["axis_state"] == "IDLE"
    co = found["cia402"]
    assert co.params["node_id"] == 5 and co.details["serial"] == 4242 and co.details["product_code"] == "0x00001234"
    assert co.details["profile"] == 402 and co.details["torque_modes"] == [4, 10]
    assert co.details["nmt_state"] == "PRE-OPERATIONAL"
    assert co.params["counts_per_rev"] == 131072 and co.params["rated_torque_mNm"] == 1000
    assert found["cubemars"].params["motor_id"] == 2 and found["cubemars"].details["error"] == 0


def test_probe_can_sends_only_to_nodes_that_announced_themselves(can_bench):
    import can

    ch, _ = can_bench
    spy = can.Bus(interface="virtual", channel=ch)
    found = {f.family for f in probe_can(ch, "virtual", listen_s=0.3, timeout=0.3)}
    from hil.bench.probe import _collect  # for a fixed time: the served ODrive's cyclic frames never pause

    seen = {(m.arbitration_id, m.is_remote_frame) for m in _collect(spy, 0.2)}
    spy.shutdown()
    assert "cubemars" not in found  # it only answers commands, and none was sent to it
    # devices' frames: ODrive 3 (factory cyclic) heartbeat 0x61, estimates 0x69 and Get_Version 0x60,
    # CiA node 5 heartbeat 0x705 and SDO answers 0x585; the probe's: RTR Get_Version to ODrive node 3
    # (0x60) and SDO requests to node 5 (0x605) only
    assert seen <= {(0x61, False), (0x69, False), (0x60, False), (0x705, False), (0x585, False), (0x60, True),
                    (0x605, False)}, seen
    assert (0x60, True) in seen and (0x605, False) in seen


def test_probe_cli_json_and_scene_stub(can_bench, tmp_path, capsys):
    ch, _ = can_bench
    out = tmp_path / "stub.yaml"
    argv = ["probe", "--can", ch, "--interface", "virtual", "--listen", "0.4", "--json", "--scene", str(out)]
    assert main(argv) == 0
    rep = json.loads(capsys.readouterr().out)
    assert {d["family"] for d in rep["devices"]} == {"odrive", "cia402"}
    sc = load_scene(out)
    assert sorted(d.driver for d in sc.devices) == ["cia402", "odrive_can"]
    assert {d.params["node_id"] for d in sc.devices} == {3, 5}
    text = out.read_text()
    assert main(argv) == 2  # no --overwrite: refused, file untouched
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "file exists" in err[0]
    assert out.read_text() == text


def test_probe_serial_dynamixel_broadcast_ping():
    pytest.importorskip("dynamixel_sdk")
    eps = serve([{"kind": "dynamixel", "ids": [1, 3]}])
    try:
        (f,) = probe_serial(eps[0].params["port"], baudrates=(57600,))
        assert f.family == "dynamixel" and f.params["ids"] == [1, 3]
        # XM430-W350: model number 1020 (ROBOTIS e-Manual control table, address 0)
        assert {s["model_number"] for s in f.details["servos"].values()} == {1020}
    finally:
        shutdown(eps)


def test_probe_serial_bota_stream():
    eps = serve([{"kind": "bota", "rate_hz": 1000}])
    try:
        (f,) = probe_serial(eps[0].params["url"], listen_s=0.3)
        assert f.family == "bota" and f.driver == "bota_serial"
        assert f.details["frame_period_us"] == pytest.approx(1000.0)  # the simulated 1 kHz timestamps
    finally:
        shutdown(eps)


def test_probe_ft300_modbus_tcp_and_rtu_on_a_serial_line():
    pytest.importorskip("pymodbus")
    eps = serve([{"kind": "ft300", "slave": 9}, {"kind": "ft300_stream", "slave": 9}])
    try:
        (tcp,) = probe_modbus(eps[0].params["url"], 9)
        assert tcp.details == {"firmware": "FTS-1.0.3", "serial": "SIM-0001"}
        assert probe_modbus(eps[0].params["url"], 10, timeout=0.2) == []  # nobody at unit 10
        (rtu,) = probe_serial(eps[1].params["url"], baudrates=(57600,), listen_s=0.1)
        assert rtu.driver == "robotiq_ft300" and rtu.details["serial"] == "SIM-0001"
    finally:
        shutdown(eps)


def test_probe_bad_input_one_line(capsys, tmp_path):
    assert main(["probe", "--can", "x", "--interface", "no_such_interface"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot open CAN bus" in err[0]
    assert main(["probe"]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
