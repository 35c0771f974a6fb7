"""Channels of a scene are separate buses (issue 29, item 9): three ODrives at node 0 on three CAN
channels (legal on three physical buses) must not hear each other, in lockstep (python-can virtual
channels private to the bench), served free-running (``hil mock serve`` / SimulatedScene over
udp_multicast: each channel its own multicast group *and* UDP port, python-can binding a bus to its
port on every address) and in a realtime run (ProcessSimBench, the devices in another process);
``hil probe`` on channel B lists only channel B's devices.

The measure is a count, not a time: one RTR request on a channel is answered exactly once, one
Set_Axis_State arms exactly one drive; the wall-clock waits only bound how long a frame already on
its way may take."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

can = pytest.importorskip("can")

from hil.bench.runtime import Bench  # noqa: E402
from hil.scene.spec import load_scene  # noqa: E402

pytestmark = pytest.mark.timeout(120)
WAIT = 0.5  # s: bound for a frame already sent to arrive over loopback multicast

SCENE = """\
name: three_channels
description: ODrive axes at node 0 on three CAN channels (three buses) and one at node 5 on the second
seed: 0
rate_hz: 200
mode: lockstep
units: rotary
devices:
  - {name: a, role: actuator, driver: odrive_can, params: {interface: virtual, bitrate: 1000000, channel: hil0,
     node_id: 0}, dof: 1, body: ja, dofs: [0]}
  - {name: b, role: actuator, driver: odrive_can, params: {interface: virtual, bitrate: 1000000, channel: hil1,
     node_id: 0}, dof: 1, body: jb, dofs: [0]}
  - {name: c, role: actuator, driver: odrive_can, params: {interface: virtual, bitrate: 1000000, channel: hil2,
     node_id: 0}, dof: 1, body: jc, dofs: [0]}
  - {name: d, role: actuator, driver: odrive_can, params: {interface: virtual, bitrate: 1000000, channel: hil1,
     node_id: 5}, dof: 1, body: jd, dofs: [0]}
simulation:
  bodies:
    - {name: ja, M: 1.0, B: 1.0, K: 10.0}
    - {name: jb, M: 1.0, B: 1.0, K: 10.0}
    - {name: jc, M: 1.0, B: 1.0, K: 10.0}
    - {name: jd, M: 1.0, B: 1.0, K: 10.0}
controller: {type: none}
safety: {max_effort: 5.0, max_velocity: 5.0, position_limits: [-1.0, 1.0], max_energy: 10.0, watchdog_ms: 50}
experiments: []
"""


@pytest.fixture
def scene(tmp_path):
    p = tmp_path / "three_channels.yaml"
    p.write_text(SCENE, encoding="utf-8")
    return load_scene(str(p))


def _answers(bus, arb_id: int, wait: float = WAIT) -> int:
    """Data frames with ``arb_id`` received within ``wait`` s."""
    n, end = 0, time.monotonic() + wait
    while (left := end - time.monotonic()) > 0:
        m = bus.recv(left)
        if m is not None and m.arbitration_id == arb_id and not m.is_remote_frame:
            n += 1
    return n


def _rtr(bus, arb_id: int) -> None:
    bus.send(can.Message(arbitration_id=arb_id, is_remote_frame=True, dlc=8, is_extended_id=False))


def test_lockstep_channels_are_private_to_their_devices(scene):
    """Each adapter talks to the drive of its own channel: torques land only there, the private
    virtual channels differ, one request on a channel is answered once."""
    with Bench(scene) as b:
        sims = {d.name: d.sim for d in b._devs}
        chans = {name: sim.channel for name, sim in sims.items()}
        assert len({chans["a"], chans["b"], chans["c"]}) == 3 and chans["b"] == chans["d"]
        b.command({"a": np.array([0.1]), "b": np.array([0.2]), "c": np.array([0.3]), "d": np.array([0.4])})
        b.advance()
        assert [sims[k].input_torque for k in "abcd"] == pytest.approx([0.1, 0.2, 0.3, 0.4])
        assert all(len({tau for _, tau in sims[k].commands}) == 1 for k in "abcd")
        spy = can.Bus(interface="virtual", channel=chans["a"])
        try:
            _rtr(spy, 0x09)  # node 0 Get_Encoder_Estimates on channel a: the drives of b and c stay silent
            assert _answers(spy, 0x09, 0.05) == 1
        finally:
            spy.shutdown()


def _served(scene, **kw):
    from hil.bench.serve import serve_scene

    pytest.importorskip("msgpack", reason="python-can's udp_multicast bus needs msgpack")
    return serve_scene(scene, can_interface="udp_multicast", **kw)


def _bus(params):
    return can.Bus(interface="udp_multicast", channel=params["channel"], port=params["port"])


def test_served_channels_have_their_own_group_and_port_and_do_not_cross_talk(scene):
    sim = _served(scene)
    try:
        eps = {ep.name: ep.params for ep in sim.endpoints}
        assert len({(eps[k]["channel"], eps[k]["port"]) for k in "abc"}) == 3
        assert len({eps[k]["port"] for k in "abc"}) == 3 and eps["b"]["port"] == eps["d"]["port"]
        sims = {d.name: d.sim for d in sim._devs}
        bus_a = _bus(eps["a"])
        try:
            time.sleep(0.05)  # the group is joined
            _rtr(bus_a, 0x09)
            assert _answers(bus_a, 0x09) == 1  # before: 3 (every channel on one port)
            bus_a.send(can.Message(arbitration_id=0x0B, data=bytes([1, 0, 0, 0, 1, 0, 0, 0]), is_extended_id=False))
            bus_a.send(can.Message(arbitration_id=0x07, data=(8).to_bytes(4, "little").ljust(8, b"\0"),
                                   is_extended_id=False))
            end = time.monotonic() + WAIT
            while sims["a"].axis_state != 8 and time.monotonic() < end:
                time.sleep(0.01)
            time.sleep(0.05)  # any frame that crossed would have arrived by now
            assert [sims[k].axis_state for k in "abcd"] == [8, 1, 1, 1]  # arming one arms one
        finally:
            bus_a.shutdown()
    finally:
        sim.close()


def test_probe_on_channel_b_lists_only_channel_b(scene, capsys):
    from hil.bench.probe import add_arguments, probe_can, run

    sim = _served(scene)
    try:
        eps = {ep.name: ep.params for ep in sim.endpoints}
        b = eps["b"]
        found = probe_can(b["channel"], "udp_multicast", port=b["port"], listen_s=0.4, timeout=0.2)
        assert sorted(f.params["node_id"] for f in found) == [0, 5]  # b and d, not a nor c
        assert all(f.params["port"] == b["port"] and f.params["channel"] == b["channel"] for f in found)
        import argparse

        p = argparse.ArgumentParser()
        add_arguments(p)
        args = p.parse_args(["--can", eps["c"]["channel"], "--interface", "udp_multicast", "--can-port",
                             str(eps["c"]["port"]), "--listen", "0.4", "--json"])
        assert run(args) == 0
        out = json.loads(capsys.readouterr().out)
        assert [d["params"]["node_id"] for d in out["devices"]] == [0]
        assert out["probed"].endswith(f"port {eps['c']['port']}")
    finally:
        sim.close()


def test_realtime_process_bench_channels_are_isolated(scene):
    """ProcessSimBench (realtime runs): the devices' process serves each scene channel on its own
    group and port; the adapters open them; a request on one channel is answered once."""
    from hil.bench.runtime import ProcessSimBench

    pytest.importorskip("msgpack", reason="python-can's udp_multicast bus needs msgpack")
    with ProcessSimBench(scene, timeout=2.0) as b:
        assert len(set(b.can_ports.values())) == 3
        eps = {name: params for name, (_, params) in b._endpoint_params.items()}
        assert {eps[k]["port"] for k in "abc"} == set(b.can_ports.values())
        b.command({"a": np.array([0.1]), "b": np.array([-0.1]), "c": np.array([0.0]), "d": np.array([0.0])})
        bus = _bus(eps["c"])
        try:
            time.sleep(0.05)
            _rtr(bus, 0x09)
            assert _answers(bus, 0x09) == 1
        finally:
            bus.shutdown()


@pytest.mark.parametrize("bad", ["hil0", "hil0=port", "hil0=0", "hil0=70000"])
def test_a_bad_can_port_is_one_line_and_exit_2(scene, bad, capsys):
    from hil.cli.main import main

    rc = main(["mock", "serve", scene.path, "--can-interface", "udp_multicast", "--can-port", bad, "--duration", "0"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "--can-port" in err and len(err.splitlines()) == 1
