"""docs/guide/formats.md runs as written: its Python block makes the example files, each `hil` command in its
bash blocks exits 0, and every imported record holds the same samples."""

from __future__ import annotations

import os
import re
import shlex
from pathlib import Path

import numpy as np
import pytest

from hil.record.hdf5 import RunRecord

GUIDE = Path(__file__).resolve().parents[2] / "docs" / "guide" / "formats.md"


def _blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", GUIDE.read_text(encoding="utf-8"), flags=re.S)


@pytest.mark.timeout(300)
def test_the_formats_guide_runs_as_written(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    for mod in ("nptdms", "rosbags", "mcap", "pint"):
        pytest.importorskip(mod, reason="the guide's formats need the 'formats' and 'ros' extras")
    from hil.cli.main import main

    monkeypatch.chdir(tmp_path)
    (code,) = _blocks("python")
    exec(compile(code, str(GUIDE), "exec"), {"__name__": "formats_guide"})  # the guide's own code
    commands = [ln for block in _blocks("bash") for ln in block.splitlines() if ln.startswith("hil ")]
    assert len(commands) >= 9
    for line in commands:
        args = shlex.split(line)[1:]
        assert main(args) == 0, (line, capsys.readouterr().err)
    out = capsys.readouterr().out
    assert "/joint_states:position[carriage]" in out and "/load_cell:wrench.force.x" in out  # the --list lines

    recs = {name: RunRecord.open(f"{name}.h5") for name in ("csv", "mat", "h5", "tdms", "bag", "mcap")}
    ref = recs["csv"]
    assert ref.t.size == 5000 and ref.units == {"motor.position": "m", "motor.effort_cmd": "N"}
    for name, rec in recs.items():
        np.testing.assert_allclose(rec.t, ref.t, rtol=0, atol=1e-12, err_msg=name)
        # mm -> m in the HDF5 file: the one conversion that is not exact
        np.testing.assert_allclose(rec.channels["motor.position"].reshape(-1), ref.channels["motor.position"],
                                   rtol=1e-15 if name == "h5" else 0, atol=0, err_msg=name)
        np.testing.assert_array_equal(rec.channels["motor.effort_cmd"].reshape(-1), ref.channels["motor.effort_cmd"],
                                      err_msg=name)
    for name in ("tdms", "bag"):
        assert recs[name].meta["held_channels"] == ["spring_ft.wrench"], name
    assert recs["h5"].units["motor.position"] == "m"
    assert os.path.getsize("csv_view.mcap") > 0 and Path("csv_sheet.csv").read_text().count("\n") == 5003
