"""identify/ takes arrays and records through a small interface (issue 13): no import of the suite's record,
scene or importer modules; any object with the :class:`hil.identify.source.RecordSource` members is a record;
files are opened by a registered backend (the suite's through its entry point)."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import SDEA_TRUTH, make_nonperiodic_record, sdea_locked_ss

from hil.identify.errors import ModelSpecError
from hil.identify.source import ENTRY_POINT_GROUP, RecordSource, as_source, backend_for

IDENTIFY = Path(__file__).resolve().parents[2] / "identify"
FORBIDDEN = ("hil.record.hdf5", "hil.scene.spec", "hil.record.importers")


def test_identify_imports_no_record_scene_or_importer_module() -> None:
    hits = []
    for path in sorted(IDENTIFY.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            hits += [f"{path.name}:{node.lineno} {n}" for n in names if n.startswith(FORBIDDEN)]
    assert not hits, hits
    # and at run time: importing every identify module (and identifying arrays) loads none of them
    code = ("import sys, numpy as np\n"
            "import hil.identify.api, hil.identify.records, hil.identify.held_ml, hil.identify.source\n"
            "t = np.arange(2000) / 1000.0; u = np.sin(2 * np.pi * 30 * t * t)\n"
            f"bad = [m for m in {FORBIDDEN!r} if m in sys.modules]\n"
            "print(bad); sys.exit(1 if bad else 0)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr


class _MemorySource:
    """A record held in memory: the RecordSource members and nothing else (no file, no scene)."""

    def __init__(self, rec) -> None:
        self.path = "memory://sdea"
        self.t = rec.t
        self.rate_hz = rec.fs
        self.meta: dict = {}
        self.results: dict = {}
        self.scene = None
        self.scene_sha256 = ""
        self._signals = {"motor.effort_cmd[0]": rec.u[:, 0], "motor.velocity[0]": rec.y[:, 0],
                         "ft.wrench[0]": rec.y[:, 1]}

    def to_identify_dict(self) -> dict:
        return {"t": self.t, "signals": dict(self._signals), "meta": {"rate_hz": self.rate_hz}}


def test_any_object_with_the_record_members_is_identified() -> None:
    from hil.identify.api import identify_record

    src = _MemorySource(make_nonperiodic_record(sdea_locked_ss(**SDEA_TRUTH), 11, 0.01, duration=1.0))
    assert isinstance(src, RecordSource) and as_source(src) is src
    res = identify_record(src, posterior="laplace")
    # inferred from channel names alone: target motor, the only wrench channel is the spring force
    assert res.model.name == "sdea_locked" and res.method == "ml"
    assert res.record["path"] == "memory://sdea"
    z = (res.ls.theta - res.model.vector(SDEA_TRUTH)) / res.crb_std
    assert np.all(np.abs(z) < 4), z  # an efficient estimator: p < 3e-4 per parameter


def test_files_are_opened_by_the_registered_backend(tmp_path) -> None:
    from importlib.metadata import entry_points

    from hil.identify.api import load_record

    assert any(ep.value == "hil.record.identify_source:BACKEND" for ep in entry_points(group=ENTRY_POINT_GROUP))
    b = backend_for("run.h5")
    assert ".h5" in b.suffixes and backend_for("run.csv") is b
    # a file that is not a record: the backend's error, one line naming the file
    p = tmp_path / "junk.h5"
    p.write_bytes(b"not hdf5")
    with pytest.raises(b.error) as ei:
        load_record(p)
    assert str(p) in str(ei.value) and "\n" not in str(ei.value)
    with pytest.raises(ModelSpecError, match="no such file"):
        load_record(tmp_path / "missing.npz")
