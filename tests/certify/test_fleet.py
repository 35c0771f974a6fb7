"""Fleet certification: scheduling groups, the worst decision, the index, and fleet runs that
match the scenes' individual runs."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from hil.certify.fleet import DECISION_ORDER, FleetEntry, FleetResult, expand_scenes, transport_groups, write_index


def _hil(*args: str) -> subprocess.CompletedProcess:
    """``hil ARGS`` in a subprocess, waited for as long as it runs (the test's timeout guards a hang)."""
    return subprocess.run([sys.executable, "-m", "hil", *args], capture_output=True, text=True, check=False)


def _scene(sim: bool, *endpoints: str) -> SimpleNamespace:
    devs = [SimpleNamespace(params={"channel": e}) for e in endpoints]
    return SimpleNamespace(simulation=object() if sim else None, devices=devs)


def test_real_scenes_sharing_a_transport_run_in_series() -> None:
    scenes = [_scene(True, "vcan0"), _scene(False, "can0"), _scene(False, "can1"), _scene(False, "can0", "can2"),
              _scene(False, "can2"), _scene(True, "vcan0")]
    groups = transport_groups(scenes)
    # simulated scenes never share a group (their transports are private); 1, 3, 4 are linked by can0/can2
    assert sorted(map(sorted, groups)) == [[0], [1, 3, 4], [2], [5]]


def test_fleet_decision_is_the_worst(tmp_path) -> None:
    def e(name: str, d: str) -> FleetEntry:
        return FleetEntry(name, name, d, [f"{name} reason"], 0, str(tmp_path / name), 1.0)

    for worst in DECISION_ORDER:
        entries = [e("a", "GO"), e("b", worst), e("c", "GO")]
        res = FleetResult(entries, tmp_path)
        assert res.decision == worst
        assert res.exit_code == {"GO": 0, "MARGINAL": 10, "NO-GO": 11, "ERROR": 13}[worst]
    idx = write_index(FleetResult([e("a<b>", "NO-GO")], tmp_path))
    text = idx.read_text()
    assert "a&lt;b&gt;" in text and "NO-GO" in text  # names are escaped
    assert json.loads((tmp_path / "fleet.json").read_text())["decision"] == "NO-GO"


def test_expand_scenes_reads_folders(tmp_path) -> None:
    (tmp_path / "b.yaml").write_text("x")
    (tmp_path / "a.yml").write_text("x")
    (tmp_path / "notes.txt").write_text("x")
    assert expand_scenes([str(tmp_path), "sdea_bench"]) == [str(tmp_path / "a.yml"), str(tmp_path / "b.yaml"),
                                                            "sdea_bench"]
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ValueError, match="no scene files"):
        expand_scenes([str(empty)])


#: measurements of wall-clock time (the only ones that differ between two runs of a scene and seed)
WALL_CLOCK = {"run time"}


def _comparable(doc: dict) -> dict:
    """What must agree between two runs of the same scene and seed (not times or digests)."""
    return {"decision": doc["decision"], "reasons": doc["reasons"],
            "measurements": [(m["name"], m["value"], m["unit"], m["outcome"]) for m in doc["measurements"]
                             if m["name"] not in WALL_CLOCK]}


def _fleet_matches_individual(tmp_path: Path, scenes: list[str], extra: list[str]) -> None:
    solo = {}
    for s in scenes:
        p = _hil("certify", s, "--out", str(tmp_path / "solo" / s), "--seed", "7", "--json", *extra)
        solo[s] = (p.returncode, _comparable(json.loads(p.stdout)))
    p = _hil("certify", *scenes, "--out", str(tmp_path / "fleet"), "--seed", "7", "--workers", "2", "--json", *extra)
    fleet = json.loads(p.stdout)
    worst = max((solo[s][1]["decision"] for s in scenes), key=DECISION_ORDER.index)
    assert fleet["decision"] == worst
    assert p.returncode == max(code for code, _ in solo.values()) or fleet["decision"] == "ERROR"
    for entry in fleet["scenes"]:
        code, ref = solo[entry["scene"]]
        assert entry["exit_code"] == code
        doc = json.loads((Path(entry["out"]) / "certificate.json").read_text())
        assert _comparable(doc) == ref
        assert (Path(entry["out"]) / "report.html").exists()
    index = (tmp_path / "fleet" / "index.html").read_text()
    for s in scenes:
        assert f'href="{s}/report.html"' in index


def test_fleet_without_experiments_matches_individual_runs(tmp_path) -> None:
    _fleet_matches_individual(tmp_path, ["sdea_bench", "mbk_2dof_bench"], ["--no-experiments"])


@pytest.mark.slow
def test_fleet_of_built_in_scenes_matches_individual_runs(tmp_path) -> None:
    """Two mocked benches certified in parallel give the certificates they give alone (~40 s)."""
    _fleet_matches_individual(tmp_path, ["dual_master_3dof", "dynamixel_leader_follower"], [])


def test_fleet_refuses_bad_scene_before_running(tmp_path) -> None:
    p = _hil("certify", "sdea_bench", "no_such_scene", "--out", str(tmp_path / "f"))
    assert p.returncode == 2 and len(p.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "f").exists()
    p = _hil("certify", "sdea_bench", "sdea_bench", "--out", str(tmp_path / "g"))
    assert p.returncode == 2 and "share the name" in p.stderr


def test_sigint_stops_the_fleet_with_a_summary(tmp_path) -> None:
    """SIGINT to the fleet: no new scene starts, the index is written, exit 130."""
    import signal
    import time

    out = tmp_path / "f"
    proc = subprocess.Popen([sys.executable, "-m", "hil", "certify", "sdea_bench", "mbk_2dof_bench", "dual_master_3dof",
                             "--no-experiments", "--workers", "1", "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    while proc.poll() is None and not (out / "sdea_bench" / "certificate.json").exists() \
            and not (out / "mbk_2dof_bench" / "certificate.json").exists():  # a state, no deadline
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _o, err = proc.communicate()
    assert proc.returncode == 130, err
    assert "stopped: signal: SIGINT" in err
    doc = json.loads((out / "fleet.json").read_text())
    assert len(doc["scenes"]) == 3 and doc["decision"] == "ERROR"  # the scenes are all listed
    assert (out / "index.html").exists()
