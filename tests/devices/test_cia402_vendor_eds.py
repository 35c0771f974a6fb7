"""The project's CiA 402 adapter against a drive that is not its twin: canopen's LocalNode built from
a vendor EDS (Technosoft iPOS, tests/devices/vendor_drive.py) with a delayed modes of operation
display, a holding brake, PDOs left valid at power-on and objects the EDS does not have (issue 29,
items 1-4).

Expected values come from CiA 301 / CiA 402 and the EDS itself, not from the adapter: the PDO
COB-IDs of the predefined connection set (0x180/0x280/0x200 + node, RPDO k / TPDO k at 0x1400 /
0x1800 + k - 1), the EDS's power-on PDO configuration, its missing objects (no 0x608F, no 0x6076),
the unit conversions of the adapter's docstring applied by hand to the drive's raw values."""

from __future__ import annotations

import itertools
import math
import struct

import pytest

can = pytest.importorskip("can")
canopen = pytest.importorskip("canopen")

from vendor_drive import VendorDrive  # noqa: E402

from hil.errors import DeviceFault, ProtocolError  # noqa: E402
from hil.protocols.cia402 import CiA402Drive  # noqa: E402

pytestmark = pytest.mark.timeout(60)
_chan = itertools.count()
NODE = 5
CPR, RATED = 4000, 1000  # what the bench knows of the motor (the EDS has no 0x608F / 0x6076)


@pytest.fixture
def drive(technosoft_eds, request):
    opts = getattr(request, "param", {})
    ch = f"vendor-402-{next(_chan)}"
    d = VendorDrive(ch, technosoft_eds, NODE, brake_release_s=opts.get("brake", 0.0))
    yield d, ch
    d.close()


def _open(ch: str, **kw) -> CiA402Drive:
    return CiA402Drive(NODE, ch, "virtual", **{"counts_per_rev": CPR, "rated_torque_mNm": RATED, **kw})


def _cob(d: VendorDrive, index: int) -> int:
    return struct.unpack("<I", d.node.get_data(index, 1))[0]


def test_the_vendor_drive_shows_the_mode_one_cycle_late(drive):
    """The drive itself (canopen master, raw SDO): the first 0x6061 read after a 0x6060 write still
    shows the old mode, the next the new one; this is what the adapter must wait for."""
    _, ch = drive
    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.05
    net.connect(interface="virtual", channel=ch)
    try:
        node = net.add_node(NODE, canopen.ObjectDictionary())
        node.sdo.download(0x6060, 0, struct.pack("<b", 4))
        first = struct.unpack("<b", node.sdo.upload(0x6061, 0))[0]
        second = struct.unpack("<b", node.sdo.upload(0x6061, 0))[0]
    finally:
        net.disconnect()
    assert (first, second) == (0, 4)


@pytest.mark.parametrize("eds", ["vendor", "shipped"])
def test_open_polls_the_mode_display_and_disables_leftover_pdos(drive, technosoft_eds, eds):
    d, ch = drive
    assert d.node.nmt.state == "PRE-OPERATIONAL"
    # power-on configuration: RPDO1..4 and TPDO1..3 valid (TPDO3 from a stored configuration)
    assert [_cob(d, 0x1400 + k) >> 31 for k in range(4)] == [0, 0, 0, 0]
    assert [_cob(d, 0x1800 + k) >> 31 for k in range(4)] == [0, 0, 0, 1]
    drv = _open(ch, eds=str(technosoft_eds) if eds == "vendor" else None)
    try:
        assert d.mode == 4 and d.state == "OPERATION ENABLED" and d.node.nmt.state == "OPERATIONAL"
        # every PDO that is not the adapter's is invalid, found in the drive whatever the adapter's EDS lists
        assert drv.pdos_disabled == ["RPDO2", "RPDO3", "RPDO4", "TPDO3"]
        assert [_cob(d, 0x1400 + k) >> 31 for k in range(4)] == [0, 1, 1, 1]
        assert [_cob(d, 0x1800 + k) >> 31 for k in range(4)] == [0, 0, 1, 1]
        before = sum(d.tpdo_frames.values())
        s = drv.read()
        # one SYNC: exactly TPDO1 (0x180 + node) and TPDO2 (0x280 + node), no TPDO3 (0x380 + node)
        assert d.syncs == 1 and sum(d.tpdo_frames.values()) - before == 2
        assert set(d.tpdo_frames) == {0x180 + NODE, 0x280 + NODE}
        assert s.position[0] == pytest.approx(2 * math.pi * d.position / CPR, rel=1e-12)
        assert s.velocity[0] == pytest.approx(2 * math.pi * d.velocity / CPR, rel=1e-12)
        assert s.effort[0] == pytest.approx(d.torque / 1000 * RATED / 1000, rel=1e-12)
    finally:
        drv.close()


def test_missing_objects_in_the_eds_are_one_line_errors(drive, technosoft_eds):
    d, ch = drive
    with pytest.raises(ProtocolError) as e:
        CiA402Drive(NODE, ch, "virtual", eds=str(technosoft_eds))
    msg = str(e.value)
    assert "\n" not in msg and "technosoft_iPOS.eds" in msg
    assert "0x608F" in msg and "position encoder resolution" in msg and "counts_per_rev" in msg
    assert "0x6076" in msg and "motor rated torque" in msg and "rated_torque_mNm" in msg
    assert d.sdo_requests == 0  # refused before anything was sent
    # with the two given, the same EDS opens (the documented fallback)
    _open(ch, eds=str(technosoft_eds)).close()


def test_an_object_the_drive_lacks_is_a_one_line_error_with_the_abort(drive):
    """The shipped dictionary lists 0x608F; the vendor drive answers SDO abort 0x06020000."""
    _, ch = drive
    with pytest.raises(ProtocolError) as e:
        CiA402Drive(NODE, ch, "virtual", rated_torque_mNm=RATED)
    msg = str(e.value)
    assert "\n" not in msg and "0x06020000" in msg and "the drive has no 0x608F" in msg and "counts_per_rev" in msg


@pytest.mark.parametrize("drive", [{"brake": 0.15}], indirect=True)
def test_a_150_ms_brake_release_is_within_the_default_state_timeout(drive):
    d, ch = drive
    drv = _open(ch)
    try:
        assert drv.state_timeout == pytest.approx(0.4) and d.state == "OPERATION ENABLED"
    finally:
        drv.close()


@pytest.mark.parametrize("drive", [{"brake": None}], indirect=True)
def test_a_brake_that_does_not_release_names_the_wait_that_ran_out(drive):
    _, ch = drive
    with pytest.raises(DeviceFault) as e:
        _open(ch, state_timeout=0.1)
    msg = str(e.value)
    assert "\n" not in msg
    assert "Enable operation" in msg and "OPERATION ENABLED" in msg and "0.100 s" in msg and "state_timeout" in msg
    assert "SWITCHED ON" in msg  # the state the drive was in
