"""Lockstep runs on simulated time (issue 26): the same records on an idle and on a loaded machine.

A mocked lockstep bench waits for its simulated devices by a barrier (:mod:`hil.protocols.waits`), so
neither how fast the machine runs a device nor the wall clock decides what a record holds:

* the records of a scene with devices on ptys (two DYNAMIXEL chains, a Bota sensor), on a virtual CAN
  bus (ODrive) and behind a Modbus/TCP server (FT-300) are the same, bit for bit, whether CPU-bound
  processes hold the machine or not; likewise the CANopen drive (canopen's SDO client, no receive
  thread) and a streaming FT-300 on a pty (slow set);
* a device slowed down on the wall clock (``delay_s``: it spends that long before each frame it
  sends) changes nothing in lockstep (same records as without it, no watchdog stop), while in
  realtime mode, where the devices run in another process on the wall clock, the same device ends
  the run in a watchdog stop;
* the lockstep waits themselves: a reply the simulated device does not send times out in simulated
  time (no wall-clock wait), one it sends is always there.

Nothing here asserts a wall-clock time; the CPU hogs are there to disturb, never measured.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from hil.scene.spec import load_scene, scene_from_dict

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_lockstep_records import _read_record, assert_same_record

pytestmark = pytest.mark.timeout(900)

#: lockstep ticks per run: covers the devices' opening handshakes, polls, streams and heartbeats
TICKS = 200
#: CPU-bound processes started beside the loaded run (the machine has 2 cores)
HOGS = 3


class CpuHogs:
    """``n`` busy-loop processes for the life of the ``with`` block (killed and reaped after)."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.procs: list[subprocess.Popen[bytes]] = []

    def __enter__(self) -> CpuHogs:
        self.procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(self.n)]
        return self

    def running(self) -> bool:
        return all(p.poll() is None for p in self.procs)

    def __exit__(self, *exc: object) -> None:
        for p in self.procs:
            p.kill()
        for p in self.procs:
            p.wait()


def _scene(name: str, edit: Any = None) -> Any:
    d = yaml.safe_load(load_scene(name).source_text)
    if edit is not None:
        edit(d)
    return scene_from_dict(d, label=f"{name}-simulated-time-test")


def _records(scene: Any, ticks: int = TICKS, experiments: list[int] | None = None) -> list[dict[str, Any]]:
    from hil.run.runner import Runner

    with tempfile.TemporaryDirectory() as d:
        outcomes = Runner(scene, d, realtime=False, max_ticks=ticks).run(select=experiments or [0])
        assert all(o.status == "completed" for o in outcomes), [(o.status, o.stop_reason) for o in outcomes]
        return [_read_record(p) for p in sorted(Path(d).rglob("*.h5"))]


def _same_under_load(scene: Any, idle: tuple[str, ...] = ()) -> None:
    """The scene's first experiment, :data:`TICKS` ticks, without and with :data:`HOGS` CPU hogs:
    identical records. Every device but ``idle`` (one the experiment leaves at rest) shows feedback
    that changes (so its answers did reach the record)."""
    quiet = _records(scene)
    with CpuHogs(HOGS) as hogs:
        loaded = _records(scene)
        assert hogs.running()  # the machine was held busy for the whole loaded run
    assert len(quiet) == len(loaded) == 1
    assert_same_record(loaded[0], quiet[0], f"{scene.name} under {HOGS} CPU hogs", exact=True)
    for dev in scene.devices:
        if dev.name in idle:
            continue
        chans = ("wrench",) if dev.role == "force_sensor" else ("position", "velocity", "effort")
        assert any(np.nanmax(np.ptp(quiet[0][f"channels/{dev.name}.{c}"], axis=0)) > 0 for c in chans), \
            f"{dev.name}: feedback constant over the run"


def test_pty_can_and_modbus_devices_give_the_same_records_under_cpu_hogs() -> None:
    """dual_master_3dof: DYNAMIXEL chains (2 and 3 servos) and a Bota sensor on ptys, an ODrive on
    virtual CAN, an FT-300 behind a pymodbus Modbus/TCP server on loopback."""
    sc = _scene("dual_master_3dof")
    drivers = {d.driver for d in sc.devices}
    assert drivers == {"dynamixel_x", "bota_serial", "odrive_can", "robotiq_ft300"}
    _same_under_load(sc, idle=("master2",))  # its operator pushes only in the second experiment


@pytest.mark.slow
def test_canopen_drive_gives_the_same_records_under_cpu_hogs() -> None:
    """cia402_bench: a CANopen drive (canopen's SDO client and PDOs; no receive thread in lockstep)."""
    _same_under_load(_scene("cia402_bench"))


def _ft300_stream(d: dict[str, Any]) -> None:
    """sdea_bench with its spring torque measured by an FT-300 streaming on a pty (Mz)."""
    ft = next(x for x in d["devices"] if x["name"] == "spring_ft")
    ft["driver"] = "robotiq_ft300_stream"
    ft["params"] = {"url": "/dev/ttyUSB0"}


def _ft300_rtu(d: dict[str, Any]) -> None:
    """dual_master_3dof with the FT-300 answering Modbus RTU frames over TCP."""
    ft = next(x for x in d["devices"] if x["name"] == "master2_ft")
    ft["params"] = {"url": "rtu-over-tcp://192.168.1.12:502"}
    ft["sim"] = {**ft.get("sim", {}), "framing": "rtu"}


@pytest.mark.slow
@pytest.mark.parametrize("edit", [_ft300_stream, _ft300_rtu], ids=["ft300_stream_pty", "ft300_modbus_rtu"])
def test_ft300_variants_give_the_same_records_under_cpu_hogs(edit: Any) -> None:
    if edit is _ft300_stream:
        _same_under_load(_scene("sdea_bench", edit))
    else:
        _same_under_load(_scene("dual_master_3dof", edit), idle=("master2",))


# ---------------------------------------------------------------------------------------------
# a device slowed down on the wall clock


#: the slowed device's wall-clock delay before each frame (s), and the scene's watchdog (ms)
DELAY_S = 0.02
WATCHDOG_MS = 5


def _slowed(delay_s: float) -> Any:
    def edit(d: dict[str, Any]) -> None:
        d["safety"]["watchdog_ms"] = WATCHDOG_MS
        d["experiments"] = d["experiments"][:1]
        d["experiments"][0]["duration"] = 0.5
        d.pop("certification", None)
        motor = next(x for x in d["devices"] if x["name"] == "motor")
        if delay_s:
            motor["sim"] = {"faults": {"delay_s": delay_s}}
    return _scene("sdea_bench", edit)


def test_a_slowed_device_changes_nothing_in_lockstep() -> None:
    """The ODrive spends 20 ms of wall time before each frame, four times the 5 ms watchdog: in
    lockstep the host waits for it (barrier), so the run completes with the records of the same
    scene without the delay."""
    ticks = 40
    slowed = _records(_slowed(DELAY_S), ticks)[0]
    plain = _records(_slowed(0.0), ticks)[0]
    assert_same_record(slowed, plain, "ODrive slowed by 20 ms a frame", exact=True)
    assert slowed["t"].shape == (ticks,)
    assert np.ptp(slowed["channels/motor.position"]) > 0


@pytest.mark.timeout(300)
def test_the_same_slowed_device_is_a_watchdog_stop_in_realtime() -> None:
    """In realtime mode the devices run in another process on the wall clock: answers 20 ms late
    exceed the 5 ms watchdog (``watchdog_ms`` is then every wait's timeout), and the run ends in a
    watchdog safe stop naming the device."""
    from hil.run.runner import Runner

    with tempfile.TemporaryDirectory() as d:
        out = Runner(_slowed(DELAY_S), d, realtime=True, rt_scheduling=False).run(select=[0])[0]
    assert out.status == "safety_stop", (out.status, out.stop_reason)
    assert out.stop_reason.startswith("watchdog:") and "motor" in out.stop_reason, out.stop_reason


# ---------------------------------------------------------------------------------------------
# the lockstep waits


def test_lockstep_waits_time_out_in_simulated_time_and_find_what_the_barrier_delivered() -> None:
    """LockstepWaits: a wait first runs the barrier; what the barrier delivered is found at once,
    a wait for what never comes lasts its timeout in simulated time (``monotonic`` moves by it)."""
    import os
    import select

    from hil.protocols.waits import WAIT_QUANTUM_S, LockstepWaits

    sim_t = {"t": 1.0}
    r, w = os.pipe()
    try:
        pending: list[bytes] = []
        barriers = []

        def barrier() -> None:  # a device answering what the host sent
            barriers.append(sim_t["t"])
            while pending:
                os.write(w, pending.pop(0))

        waits = LockstepWaits(lambda: sim_t["t"], barrier)
        assert waits.monotonic() == 1.0
        pending.append(b"reply")
        assert waits.readable(r, 0.5)  # delivered by the barrier: there at once, no time passes
        assert waits.monotonic() == 1.0 and os.read(r, 16) == b"reply"
        assert not waits.readable(r, 0.5)  # nothing comes: the whole timeout passes, simulated
        assert waits.monotonic() > 1.5 and waits.waited == pytest.approx(0.5, abs=2 * WAIT_QUANTUM_S)
        waits.sleep(0.25)
        assert waits.monotonic() == pytest.approx(1.75, abs=3 * WAIT_QUANTUM_S)
        sim_t["t"] = 2.0  # the simulation advanced: monotonic = simulated clock + time spent waiting
        assert waits.monotonic() == pytest.approx(2.75, abs=3 * WAIT_QUANTUM_S)
        assert waits.receive(lambda t: None, 0.1) is None
        assert waits.waited == pytest.approx(0.85, abs=4 * WAIT_QUANTUM_S)
        before = waits.waited
        assert waits.receive(lambda t: "frame", 0.1) == "frame" and waits.waited == before  # no time passes
        link = waits.link()  # one device's view: same time, own counters
        link.sent(2)
        link.received(7)
        assert link.monotonic() == waits.monotonic() and (link.tx_units, link.rx_bytes) == (2, 7)
        assert (waits.tx_units, waits.rx_bytes) == (0, 0)
        assert len(barriers) == waits.settles == 5  # every wait ran the barrier first
        assert not select.select([r], [], [], 0)[0]
    finally:
        os.close(r)
        os.close(w)


def test_lockstep_receive_waits_for_bytes_the_device_wrote_before_it_times_out() -> None:
    """A link whose device wrote bytes the host has not received yet (``device_tx > rx_bytes``: TCP
    delivery is asynchronous) keeps polling instead of timing out: what was sent arrives."""
    from hil.protocols.waits import LockstepWaits

    waits = LockstepWaits(lambda: 0.0, lambda: None).link()
    waits.device_tx = 10
    calls: list[float] = []

    def poll(t: float) -> bytes | None:  # delivered on the third look
        calls.append(t)
        return b"0123456789" if len(calls) == 3 else None

    got = waits.receive(poll, 1.0)
    assert got == b"0123456789" and waits.waited == 0.0
    assert calls[0] == 0.0 and len(calls) == 3
    waits.received(10)
    assert waits.receive(lambda t: None, 1.0) is None and waits.waited > 1.0  # nothing due: timed out


def test_a_deadline_loop_always_ends_in_simulated_time() -> None:
    """Every empty wait moves simulated time by at least WAIT_QUANTUM_S: a loop that waits until
    ``monotonic() > deadline`` (strictly, as dynamixel_sdk's packet timeout) or polls with timeout 0
    ends, whatever the rounding of the time left."""
    from hil.protocols.waits import LockstepWaits

    waits = LockstepWaits(lambda: 1e5, lambda: None)  # a large clock: coarse float rounding
    deadline = waits.monotonic() + 0.1
    n = 0
    while not waits.monotonic() > deadline:
        waits.receive(lambda t: None, min(0.005, deadline - waits.monotonic()))
        n += 1
        assert n < 100
    start = waits.monotonic()
    for _ in range(3):
        waits.receive(lambda t: None, 0.0)
    assert waits.monotonic() > start
