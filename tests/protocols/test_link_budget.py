"""Link budgets: scenes whose buses cannot carry their traffic are refused at load time, with
the numbers, in one line and exit 2 (issue 14, item 2; formulas in hil.protocols.link_budget)."""

from __future__ import annotations

import copy

import pytest
import yaml

from hil.cli.main import main
from hil.errors import SceneError
from hil.protocols import link_budget as lb
from hil.scene.spec import builtin_scenes, load_scene, scene_from_dict


def _data(name: str) -> dict:
    return yaml.safe_load(load_scene(name).source_text)


def _worst_case_bits(data_bytes: int) -> int:
    """Independent count of a classic CAN frame with an 11-bit id: 1 SOF + 11 id + RTR + IDE + r0
    + 4 DLC + 8 s data + 15 CRC = 34 + 8 s stuffable bits, at most one stuff bit per 4 after the
    first (ceil((n - 1) / 4) worst case, Davis et al. 2007), then CRC delimiter, ACK slot and
    delimiter, 7 EOF and 3 interframe bits = 13 fixed bits."""
    n = 34 + 8 * data_bytes
    return n + (n - 1) // 4 + 13


def test_can_worst_case_frame_bits():
    for s in range(9):
        assert lb.can_frame_bits(s) == _worst_case_bits(s) <= 55 + 10 * s
    assert lb.can_frame_bits(8) == 135 and lb.can_frame_bits(0) == 55


def test_serial_capacity_is_baud_over_10():
    assert lb.serial_capacity(460_800) == 46_080  # 8N1: 10 bit times per byte
    # the numbers: 37-byte frames, at most 1 245 frames/s at 460 800 baud
    assert int(lb.serial_capacity(460_800) / lb.BOTA_FRAME_BYTES) == 1245


def test_every_builtin_scene_fits_its_links():
    for name, _ in builtin_scenes():
        sc = load_scene(name)
        uses = lb.link_uses(sc.devices, sc.rate_hz)
        assert uses and all(u.need <= u.capacity for u in uses), name


def test_the_old_sdea_bench_bota_at_2_khz_is_refused_with_the_numbers():
    """The issue's case: the Bota at the 2 kHz loop rate (period 0.5 ms -> sinc 26, 1 969 Hz)."""
    d = _data("sdea_bench")
    d["devices"][1]["params"] = {"url": "/dev/ttyUSB0", "period_s": 0.0005}
    with pytest.raises(SceneError) as ei:
        scene_from_dict(d, label="old_sdea")
    msg = str(ei.value)
    need = 37 * 51200 / 26
    assert "\n" not in msg and "devices[1].params: link budget exceeded" in msg
    assert f"needs {need:,.0f} B/s" in msg and "at most 46,080 B/s" in msg and "(sinc 26)" in msg


@pytest.mark.parametrize(("scene", "edit", "expect"), [
    # 2 ODrives polled at 1 kHz: (Set_Input_Torque 8 bytes 135 + RTR 55 + answer 135) x 1000 + heartbeat
    # 135 x 10 = 326,350 bit/s each
    ("mbk_2dof_bench", lambda d: [x["params"].pop("bitrate") for x in d["devices"]],
     "CAN virtual:hil0 (axis_y, axis_z): needs 652,700 bit/s"),
    ("dynamixel_leader_follower", lambda d: [x["params"].pop("baudrate") for x in d["devices"]],
     "serial /dev/ttyUSB0 (leader, follower): needs 106,000 B/s"),
])
def test_factory_bus_rates_are_refused(scene, edit, expect):
    """Without the scene's bitrate/baudrate the factory rates apply: ODrive 250 kbit/s (two polled
    axes at 1 kHz need 2 x (95 + 55 + 135) x 1000 + 2 x 10 x 135 = 572 700 bit/s), a factory
    DYNAMIXEL at 57 600 bps (2 x (28 + 25) bytes per tick at 1 kHz = 106 000 B/s)."""
    d = copy.deepcopy(_data(scene))
    edit(d)
    with pytest.raises(SceneError, match="link budget exceeded") as ei:
        scene_from_dict(d, label=scene)
    assert expect in str(ei.value)


def test_cubemars_pair_at_2_khz_exceeds_1_mbit():
    class D:
        def __init__(self, name, motor):
            self.name, self.driver, self.dof = name, "cubemars_mit", 1
            self.params = {"channel": "can0", "motor_id": motor}

    over = lb.over_budget([D("a", 1), D("b", 2)], 2000.0)
    assert len(over) == 1 and over[0].need == 2 * 2 * 135 * 2000 and over[0].capacity == 1_000_000


def test_hil_run_refuses_an_over_budget_scene_in_one_line(tmp_path, capsys):
    d = _data("sdea_bench")
    d["devices"][1]["params"] = {"url": "/dev/ttyUSB0", "sinc_length": 25}
    f = tmp_path / "over.yaml"
    f.write_text(yaml.safe_dump(d, sort_keys=False))
    code = main(["run", str(f), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert "link budget exceeded" in err and "75,776 B/s" in err and "46,080 B/s" in err
    assert not (tmp_path / "out").exists()
