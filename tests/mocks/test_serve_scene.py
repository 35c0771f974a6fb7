"""``hil mock serve SCENE``: a scene's simulated devices served on their own, reached by plain
clients from another process (subprocess tests) and cleaned up on exit.

The served devices run free on the wall clock (that is what ``hil mock serve`` is for), so these
tests wait for *states* (a report printed, a number of frames received, a reply), never for a
duration, and assert rates on the devices' own clocks (their timestamps), never on the wall clock:
a loaded machine only makes them slower. Their timeouts are bounds a loaded machine never reaches."""

from __future__ import annotations

import json
import os
import random
import select
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from hil.bench.serve import serve_scene
from hil.cli.main import main as hil_main
from hil.protocols.registry import open_device
from hil.protocols.serial_bota import FrameParser
from hil.scene.spec import load_scene


def _start(*args: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "hil.cli.main", "mock", "serve", *args]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _report(proc: subprocess.Popen) -> dict:
    """The JSON line the server prints once every device listens (waited for as long as the server
    lives: starting a Python process on a loaded machine takes what it takes)."""
    while not select.select([proc.stdout], [], [], 1.0)[0]:
        if proc.poll() is not None:
            break
    line = proc.stdout.readline()
    if not line:
        proc.wait(5)
        pytest.fail(f"server exited ({proc.returncode}): {proc.stderr.read()}")
    return json.loads(line)


def _finish(proc: subprocess.Popen, timeout: float) -> tuple[int, str]:
    try:
        _, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate(timeout=5)
        pytest.fail("the server did not exit by itself")
    return proc.returncode, err


def _by_name(report: dict) -> dict[str, dict]:
    return {d["name"]: d for d in report["devices"]}


@pytest.mark.timeout(300)
def test_sdea_bench_bota_pty_from_another_process():
    proc = _start("sdea_bench", "--duration", "600", "--json")  # stopped by SIGTERM below
    try:
        rep = _report(proc)
        devs = _by_name(rep)
        assert rep["scene"] == "sdea_bench" and rep["rate_hz"] == 2000 and rep["pid"] == proc.pid
        motor, ft = devs["motor"], devs["spring_ft"]
        assert motor["driver"] == "odrive_can" and motor["cross_process"] is False
        assert motor["params"] == {"interface": "virtual", "bitrate": 1000000, "channel": "hil0", "node_id": 3}
        assert any("virtual" in n and "udp_multicast" in n for n in rep["notes"])
        assert ft["driver"] == "bota_serial" and ft["params"]["url"].startswith("/dev/")
        assert ft["params"]["sinc_length"] == 51 and "period_s" not in ft["params"]  # 51200/51 = 1004 Hz

        # 1) a plain client: pyserial + the documented frame format, no adapter
        import serial

        with serial.serial_for_url(ft["params"]["url"], baudrate=460800, timeout=0.01) as port:
            port.reset_input_buffer()
            parser = FrameParser()
            frames = []
            while len(frames) < 100:
                frames += parser.feed(port.read(port.in_waiting or 1))
        # free-running at the sensor's rate: on its own clock (the frames' timestamps, us) the
        # samples are 51 / 51200 s = 996 us apart (sinc 51); a slow machine only skips some
        ts = np.array([f.timestamp for f in frames], dtype=np.int64)
        steps = np.diff(ts) / (51 / 51200 * 1e6)
        assert np.all(steps > 0.5) and np.allclose(steps, np.round(steps), atol=0.01)
        w = np.array([f.wrench for f in frames])
        assert np.all(np.isfinite(w))
        assert np.all(w[:, :5] == 0.0)  # only Tz (axes: [5]) carries the spring torque
        assert 1e-4 < np.std(w[:, 5]) < 0.01  # sensor noise 0.002 N.m around a plant at rest
        assert np.all(np.abs(w[:, 5]) < 0.05)

        # 2) the printed params open the project's adapter as they are
        with open_device(ft["driver"], **ft["params"]) as dev:
            a, b = dev.read(timeout=30.0), dev.read(timeout=30.0)
            assert b.seq == a.seq + 1 and abs(b.wrench[5]) < 0.05
        proc.send_signal(signal.SIGTERM)
    finally:
        rc, err = _finish(proc, timeout=60)
    assert rc == 0, err
    assert "stopped after" in err


@pytest.mark.timeout(300)
def test_dual_master_modbus_tcp_and_dynamixel_then_sigterm():
    from pymodbus.client import ModbusTcpClient

    proc = _start("dual_master_3dof", "--json")  # no --duration: runs until SIGTERM
    try:
        devs = _by_name(_report(proc))
        ft = devs["master2_ft"]
        assert ft["driver"] == "robotiq_ft300" and ft["params"]["url"].startswith("tcp://127.0.0.1:")
        host, port = ft["params"]["url"].removeprefix("tcp://").split(":")
        client = ModbusTcpClient(host, port=int(port), timeout=30.0, retries=0)
        try:
            assert client.connect()
            seen = []
            for _ in range(5):
                r = client.read_holding_registers(180, count=6, device_id=9)
                assert not r.isError()
                raw = np.array(r.registers, dtype=np.int64)
                seen.append(np.where(raw >= 0x8000, raw - 0x10000, raw) / np.array([100.0] * 3 + [1000.0] * 3))
                time.sleep(0.01)
            serial_regs = client.read_holding_registers(510, count=4, device_id=9).registers
        finally:
            client.close()
        seen = np.array(seen)
        # Tx, Ty (axes [3, 4]) = the operator's hand force on master 2 (at rest: noise of 0.01),
        # the other components unused
        assert np.all(seen[:, [0, 1, 2, 5]] == 0.0)
        assert np.all(np.abs(seen[:, [3, 4]]) < 0.1) and np.any(seen[:, [3, 4]] != 0.0)
        assert serial_regs[0] >> 8 == ord("S")
        slave = devs["slave"]
        assert slave["params"]["ids"] == [1, 2, 3]
        with open_device(slave["driver"], **slave["params"], timeout=30.0) as dxl:
            s = dxl.read(timeout=30.0)
            assert s.position.shape == (3,) and np.all(np.abs(s.position) < 0.01)
        proc.send_signal(signal.SIGTERM)
    finally:
        rc, err = _finish(proc, timeout=60)
    assert rc == 0, err
    assert "stopped after" in err


@pytest.mark.timeout(300)
def test_can_devices_across_processes_over_udp_multicast():
    pytest.importorskip("msgpack", reason="python-can's udp_multicast bus needs msgpack")
    group = f"239.74.163.{random.randint(100, 250)}"
    proc = _start("sdea_bench", "--duration", "600", "--json", "--can-interface", "udp_multicast",
                  "--can-channel", f"hil0={group}")  # stopped by SIGTERM below
    try:
        motor = _by_name(_report(proc))["motor"]
        assert motor["cross_process"] is True
        # the channel's own UDP port (the first served channel: python-can's default 43113)
        assert motor["params"] == {"interface": "udp_multicast", "bitrate": 1000000, "channel": group, "node_id": 3,
                                   "port": 43113}
        with open_device(motor["driver"], **motor["params"], timeout=30.0) as dev:
            first = dev.read(timeout=30.0)
            moved = first
            while not moved.position[0] > first.position[0] + 1e-5:  # until the served plant moved
                dev.command_effort(np.array([0.05]), timeout=30.0)
                time.sleep(0.005)
                moved = dev.read(timeout=30.0)
            dev.safe_stop()
        proc.send_signal(signal.SIGTERM)
        # 0.05 N.m against the 362 N.m/rad spring: x -> 1.4e-4 rad (locked output: m_out is set,
        # so the free SDEA moves further); any motion proves the command reached the served plant
        assert moved.position[0] > first.position[0] + 1e-5
    finally:
        rc, err = _finish(proc, timeout=60)
    assert rc == 0, err


def _stream_scene(tmp_path: Path) -> Path:
    """sdea_bench with the spring torque measured by an FT-300 in stream mode."""
    data = yaml.safe_load(load_scene("sdea_bench").source_text)
    data["name"] = "sdea_ft300_stream"
    data["devices"][1].update(driver="robotiq_ft300_stream", params={"url": "/dev/ttyUSB0"})
    p = tmp_path / "sdea_ft300_stream.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def _fds() -> int:
    return len(os.listdir("/proc/self/fd"))


@pytest.mark.timeout(40)
def test_streaming_ft300_served_in_process_and_nothing_left(tmp_path):
    path = _stream_scene(tmp_path)
    threads0, fds0 = threading.active_count(), _fds()
    sim = serve_scene(str(path), stream_rate_hz=200.0)
    try:
        (ep,) = [e for e in sim.endpoints if e.driver == "robotiq_ft300_stream"]
        assert ep.params == {"url": ep.address}
        dev = open_device(ep.driver, **ep.params, timeout=30.0, stop_timeout=30.0)  # bounds, not a pace
        try:
            assert dev.info.extra["start"] == "handshake" and dev.info.serial == "SIM-0001"
            samples = [dev.read(timeout=30.0) for _ in range(10)]
            w = np.array([s.wrench for s in samples])
            assert np.all(w[:, :5] == 0.0) and np.all(np.abs(w[:, 5]) < 0.05)
            assert [s.seq for s in samples] == list(range(1, 11))
        finally:
            dev.close()
        assert dev.stream_stopped is True
        assert sim.ticks > 0
    finally:
        sim.close()
        sim.close()
    while threading.active_count() != threads0:  # threads that are ending (a state, not a duration)
        time.sleep(0.01)
    assert _fds() == fds0


@pytest.mark.timeout(30)
def test_main_in_process_prints_json_and_cleans_up(capsys):
    threads0, fds0 = threading.active_count(), _fds()
    assert hil_main(["mock", "serve", "sdea_bench", "--duration", "0.3", "--json"]) == 0  # returns
    out = capsys.readouterr()
    rep = json.loads(out.out.splitlines()[0])
    assert [d["name"] for d in rep["devices"]] == ["motor", "spring_ft"]
    assert "stopped after" in out.err
    assert threading.active_count() == threads0
    assert _fds() == fds0


@pytest.mark.timeout(30)
def test_main_text_output_and_errors(capsys):
    assert hil_main(["mock", "serve", "sdea_bench", "--duration", "0.1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("scene sdea_bench")
    motor = next(x for x in lines if x.startswith("motor"))
    assert "open_device('odrive_can', interface='virtual', bitrate=1000000, channel='hil0', node_id=3)" in motor
    assert "this process only" in motor
    spring = next(x for x in lines if x.startswith("spring_ft"))
    assert "open_device('bota_serial', url='/dev/" in spring
    assert hil_main(["mock", "serve", "sdea_bench", "--spec", "[]"]) == 2
    assert "give one of SCENE, --spec or --device" in capsys.readouterr().err
    assert hil_main(["mock", "serve", "no_such_scene", "--duration", "0"]) == 2  # a SceneError: one line
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("hil mock serve: error:") and "no_such_scene" in err[0]
