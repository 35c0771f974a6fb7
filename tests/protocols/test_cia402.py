"""CiA 402 adapter (hil.protocols.cia402, over canopen) against the simulated drive
(hil.mocks.cia402_drive: canopen LocalNode + the shipped EDS) on a python-can virtual bus.

Specs followed: CiA 402 / IEC 61800-7-201 state machine (controlword 0x06/0x07/0x0F/0x02/0x80,
statusword masks), CiA 402 §6.5 torque objects (per mille of rated torque 0x6076), CiA 301 EMCY,
heartbeat and SDO abort codes. The adapter waits on simulated time (``tests/simtime``): no
receive thread, what the drive sends (in the sender's thread: ``sync=True``) is dispatched when the
adapter waits, and an answer that never comes times out without any wall-clock wait."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

pytest.importorskip("canopen")

from simtime import served

from hil.errors import DeviceFault, DeviceTimeout, ProtocolError
from hil.mocks.cia402_drive import SimCiA402
from hil.mocks.faults import FaultPlan
from hil.mocks.interfaces import FreeJoints
from hil.protocols.cia402 import CiA402Drive, parse_mode, state_of

pytestmark = pytest.mark.timeout(30)
_chan = itertools.count()
CPR = 131072
RATED = 500  # mN.m


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture
def rig(request):
    """FreeJoints (1e-2 kg.m^2) + simulated drive (sync replies) + adapter, gear ratio 2."""
    opts = getattr(request, "param", {})
    ch = f"test-cia402-{next(_chan)}"
    joints = FreeJoints(1, 0.01)
    clock = Clock()
    sim = SimCiA402(joints, ch, 7, sync=True, dt=0.001, gear_ratio=2.0, counts_per_rev=CPR,
                    rated_torque_mNm=RATED, faults=opts.get("faults"), quick_stop_option=opts.get("qso", 2))
    drv = CiA402Drive(7, ch, "virtual", waits=served(), gear_ratio=2.0, clock=clock, timeout=0.5,
                      mode=opts.get("mode", 4))

    def step(n: int = 1) -> None:
        for _ in range(n):
            joints.step(0.001)
            clock.t += 0.001
            sim.tick()

    yield sim, drv, joints, step, clock
    drv.close()
    sim.close()


def test_open_reaches_operation_enabled_and_reads_identity(rig):
    sim, drv, *_ = rig
    assert sim.nmt_state == "OPERATIONAL"
    assert sim.state == "OPERATION ENABLED"
    assert state_of(sim.statusword()) == "OPERATION ENABLED"
    assert sim.mode == 4
    # identity 0x1018 and 0x608F / 0x6076 as the drive holds them
    assert drv.info.extra["vendor_id"] == 0x0A1C and drv.info.extra["product_code"] == 0x402
    assert drv.counts_per_rev == CPR and drv.rated_torque_mNm == RATED
    # PDO mapping written by SDO into the drive's own dictionary: RPDO1 = 0x6040 + 0x6071
    store = sim.node.data_store
    assert int.from_bytes(store[0x1600][1], "little") == 0x60400010
    assert int.from_bytes(store[0x1600][2], "little") == 0x60710010
    assert int.from_bytes(store[0x1A00][2], "little") == 0x60640020


def test_pdo_values_in_si_units(rig):
    sim, drv, joints, step, _ = rig
    q, v = 0.731, -2.5  # rad, rad/s at the joint
    joints._x[:] = q
    joints._v[:] = v
    s = drv.read(0.5)
    # independent derivation: counts = round(q * gear * cpr / 2 pi); decode back with the same scale
    counts = round(q * 2.0 * CPR / (2 * math.pi))
    assert s.position[0] == pytest.approx(2 * math.pi * counts / (2.0 * CPR), abs=1e-15)
    assert abs(s.position[0] - q) <= math.pi / (2.0 * CPR) + 1e-15  # at most half a count
    assert abs(s.velocity[0] - v) <= math.pi / (2.0 * CPR) + 1e-15
    # torque: 0.1234 N.m at the joint = 0.0617 N.m at the motor = 123.4 per mille of 0.5 N.m -> 123
    drv.command_effort(np.array([0.1234]))
    assert sim.target_torque == 123
    assert sim.applied_joint_torque() == pytest.approx(2.0 * 0.123 * 0.5)
    step()
    s2 = drv.read(0.5)
    assert s2.effort[0] == pytest.approx(2.0 * 0.123 * 0.5)
    assert s2.seq == s.seq + 1
    # the simulated plant moved under that torque: a = tau / J over one 1 ms step
    assert joints.velocity()[0] == pytest.approx(v + 0.123 / 0.01 * 1e-3)


@pytest.mark.parametrize("rig", [{"mode": "cst"}], indirect=True)
def test_cyclic_synchronous_torque_applies_at_the_next_sync(rig):
    sim, drv, *_ = rig
    assert sim.mode == 10 and drv.sync_rpdo
    drv.command_effort(np.array([0.1]))
    assert sim.applied_per_mille() == 0  # RPDO transmission type 1: held until the SYNC
    drv.read(0.5)
    assert sim.applied_per_mille() == 100


def test_emcy_is_a_device_fault_and_fault_reset_recovers():
    ch = f"test-cia402-{next(_chan)}"
    joints = FreeJoints(1, 0.01)
    plan = FaultPlan(error_code=0x2310, error_at_tick=3, error_until_tick=6)
    clock = Clock()  # the heartbeat consumer runs on this clock: no heartbeat is missed while paused
    with SimCiA402(joints, ch, 4, sync=True, faults=plan) as sim, \
            CiA402Drive(4, ch, "virtual", waits=served(), timeout=0.5, clock=clock) as drv:
        drv.command_effort(np.array([0.3]))
        for _ in range(3):
            sim.tick()
        assert sim.state == "FAULT" and sim.applied_per_mille() == 0
        with pytest.raises(DeviceFault) as exc:
            drv.read(0.5)
        assert exc.value.code == 0x2310
        assert drv.counters()["emcy"] == 1
        with pytest.raises(DeviceFault):  # refused while the injected error is active
            drv.enable_operation()
        for _ in range(3):
            sim.tick()
        drv.enable_operation()  # fault reset (rising edge of bit 7), then to Operation enabled
        assert sim.state == "OPERATION ENABLED"
        drv.read(0.5)


def test_sdo_timeout_is_device_timeout():
    ch = f"test-cia402-{next(_chan)}"
    with pytest.raises(DeviceTimeout, match="no SDO answer"):
        CiA402Drive(9, ch, "virtual", waits=served(), timeout=0.05)  # nobody on the bus
    joints = FreeJoints(1)
    with SimCiA402(joints, ch, 9, sync=True, faults=FaultPlan(disconnect_at_tick=1)) as sim, \
            CiA402Drive(9, ch, "virtual", waits=served(), timeout=0.1, clock=Clock()) as drv:
        sim.tick()
        with pytest.raises(DeviceTimeout):
            drv.sdo_read(0x1000)
        with pytest.raises(DeviceTimeout, match="TPDO"):
            drv.read(0.05)
        assert drv.counters()["timeouts"] == 2


def test_safe_stop_quick_stop_ends_with_zero_torque(rig):
    sim, drv, joints, step, _ = rig
    drv.command_effort(np.array([0.4]))
    step()
    assert sim.applied_per_mille() == 400
    drv.safe_stop()
    assert sim.applied_per_mille() == 0 and joints._u[0] == 0.0
    assert sim.state == "SWITCH ON DISABLED"  # option code 2: quick stop, then switch on disabled
    assert drv.last_stop["torque_actual"] == 0
    with pytest.raises(DeviceFault, match="left OPERATION ENABLED"):
        drv.read(0.5)


@pytest.mark.parametrize("rig", [{"qso": 6}], indirect=True)
def test_quick_stop_option_6_stays_in_quick_stop_active(rig):
    sim, drv, *_ = rig
    drv.command_effort(np.array([0.2]))
    assert drv.quick_stop() == "QUICK STOP ACTIVE"
    assert sim.applied_per_mille() == 0
    drv.sdo_write(0x6040, 0x0F)  # transition 16: back to Operation enabled
    assert sim.state == "OPERATION ENABLED"
    drv.safe_stop()  # quick stop, then disable voltage
    assert sim.state == "SWITCH ON DISABLED" and drv.last_stop["state"] == "SWITCH ON DISABLED"


def test_lost_heartbeat_is_a_device_fault(rig):
    sim, drv, _, step, clock = rig
    step(150)  # heartbeats every 100 ticks = 100 ms of the simulated clock
    drv.read(0.5)
    assert drv.heartbeats >= 1
    sim.injector = type(sim.injector)(FaultPlan(disconnect_at_tick=0))
    clock.t += 0.31  # > 3 x 100 ms without a heartbeat
    with pytest.raises(DeviceFault, match="heartbeat lost"):
        drv.read(0.5)


def test_unsupported_mode_is_an_sdo_abort(rig):
    _, drv, *_ = rig
    with pytest.raises(ProtocolError, match="0x06090030"):
        drv.sdo_write(0x6060, 1)  # profile position: not supported by the simulated drive (0x6502)


def test_bad_parameters():
    with pytest.raises(ValueError):
        CiA402Drive(0, "x", "virtual")
    with pytest.raises(ValueError):
        parse_mode("velocity")
    for bad in (0.0, -1.0, math.nan):
        with pytest.raises(ValueError, match="state_timeout"):
            CiA402Drive(1, "x", "virtual", state_timeout=bad, enable=False)
    assert parse_mode("cyclic_synchronous_torque") == 10 and parse_mode(4) == 4


def test_scene_refuses_a_linear_cia402_axis():
    import yaml

    from hil.errors import SceneError
    from hil.scene.spec import load_scene, scene_from_dict

    d = yaml.safe_load(load_scene("cia402_bench").source_text)
    d["units"] = "linear"
    with pytest.raises(SceneError, match="one rotary actuator axis"):
        scene_from_dict(d, label="linear-cia402")


def test_effort_on_wire_is_what_the_drive_applies(rig):
    """The adapter's effort_on_wire (what hil.run.runner records as effort_cmd) is exactly the joint
    torque the drive applies: per mille of rated torque (CiA 402 §6.5.1), here 2 x 0.5 N.m / 1000 =
    1 mN.m steps at the joint, clamped by effort_limit before rounding."""
    sim, drv, *_ = rig
    for u in (0.1234, -0.0006, 0.0004999, 1e-9, -0.3):
        drv.command_effort(np.array([u]))
        # independent derivation: round(u / gear / rated[N.m] * 1000) per mille, decoded
        pm = round(u / 2.0 / 0.5 * 1000.0)
        assert sim.target_torque == pm
        assert drv.effort_on_wire(np.array([u]))[0] == sim.applied_joint_torque() == pytest.approx(pm * 1e-3)
    drv.effort_limit = 0.05
    assert drv.effort_on_wire(np.array([0.2]))[0] == pytest.approx(0.05)
    with pytest.raises(ValueError):
        drv.effort_on_wire(np.array([math.nan]))
