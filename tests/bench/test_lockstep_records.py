"""Bit-identity of lockstep records across speed-ups of the mocked bench (issue 15).

The lockstep path (python-can virtual bus, pty streams, simulated devices, plant) was optimised
without changing what goes over the transports; with a given seed the records must stay the same
bit for bit. The references were produced by the code *before* those optimisations (commit
715c158) and are stored in ``tests/data/lockstep_reference/``:

* ``sdea_bench.npz``: every experiment of ``sdea_bench`` (locked chirp, free chirp, static hold),
  :data:`TICKS` ticks each through the full :class:`hil.run.runner.Runner` in lockstep: ``/t`` and every
  ``/channels/*`` array, plus the record's ``device_counters``, ``events`` and ``status`` (JSON);
* ``digests.json``: the SHA-256 of ``/t`` and the channels of the first experiment of the other
  built-in scenes whose devices are ODrive (CAN) and Bota (pty) only, :data:`TICKS` ticks each.

Regenerate (only when a deliberate change elsewhere alters the records, and say so in the commit):
``python tests/bench/test_lockstep_records.py --regen``. The comparison is exact (``np.array_equal`` on
float64, NaN = NaN): any difference, even one ULP, is a change of behaviour of the mocked bench.
Bit-identity assumes the same numpy/scipy wheels (the ZOH matrices come from LAPACK once per run).
"""

from __future__ import annotations

import hashlib
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest

DATA = Path(__file__).resolve().parents[1] / "data" / "lockstep_reference"
#: ticks per experiment (0.12 s at 2 kHz: covers opening, Bota frames every other tick, heartbeats)
TICKS = 240
#: the other built-in scenes whose simulated devices are ODrive and Bota only (this module's scope)
DIGEST_SCENES = ("mbk_2dof_bench", "bilateral_2dof_A1", "bilateral_2dof_B", "mcet_trilateral")
_JSON_DATASETS = ("device_counters", "events", "status")


def _read_record(path: Path) -> dict[str, Any]:
    import h5py

    out: dict[str, Any] = {}
    with h5py.File(path, "r") as f:
        out["t"] = np.asarray(f["t"][()])
        for k in sorted(f["channels"]):
            out[f"channels/{k}"] = np.asarray(f["channels"][k][()])
        for k in _JSON_DATASETS:
            out[k] = bytes(np.asarray(f[k][()], dtype=np.uint8)).decode("utf-8")
    return out


def _comparable(name: str, text: str) -> Any:
    """A JSON dataset without its padding; the status without its wall-clock closing date."""
    text = text.rstrip("\x00 ")
    if name != "status":
        return text
    st = json.loads(text)
    st.pop("closed_utc", None)
    return st


def run_records(scene_name: str, select: list[int], ticks: int = TICKS) -> list[dict[str, Any]]:
    """Run experiments ``select`` of a built-in scene for ``ticks`` lockstep ticks each; return their
    records' arrays (see :func:`_read_record`), in order."""
    from hil.run.runner import Runner
    from hil.scene.spec import load_scene

    sc = load_scene(scene_name)
    with tempfile.TemporaryDirectory() as d:
        outcomes = Runner(sc, d, realtime=False, max_ticks=ticks).run(select=select)
        assert [o.status for o in outcomes] == ["completed"] * len(select) or scene_name == "bilateral_2dof_B"
        return [_read_record(p) for p in sorted(Path(d).rglob("*.h5"))]


def digest(rec: dict[str, Any]) -> str:
    """SHA-256 over ``/t`` and every channel (name, dtype, shape, bytes), as benchmarks/bench_lockstep.py."""
    h = hashlib.sha256()
    for n in ["t", *sorted(k for k in rec if k.startswith("channels/"))]:
        a = np.ascontiguousarray(rec[n])
        h.update(n.encode() + str(a.dtype).encode() + str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def regenerate() -> None:
    DATA.mkdir(parents=True, exist_ok=True)
    recs = run_records("sdea_bench", [0, 1, 2])
    arrays: dict[str, np.ndarray] = {}
    for i, rec in enumerate(recs):
        for k, v in rec.items():
            arrays[f"{i}:{k}"] = np.asarray(v) if not isinstance(v, str) else np.frombuffer(v.encode(), np.uint8)
    np.savez_compressed(DATA / "sdea_bench.npz", **arrays)
    digests = {name: digest(run_records(name, [0])[0]) for name in DIGEST_SCENES}
    (DATA / "digests.json").write_text(json.dumps({"ticks": TICKS, "digests": digests}, indent=1) + "\n")


def _reference() -> dict[int, dict[str, Any]]:
    ref: dict[int, dict[str, Any]] = {}
    with np.load(DATA / "sdea_bench.npz") as z:
        for key in z.files:
            i, name = key.split(":", 1)
            v = z[key]
            ref.setdefault(int(i), {})[name] = bytes(v).decode() if name in _JSON_DATASETS else v
    return ref


def test_sdea_bench_records_bit_identical_to_reference() -> None:
    ref = _reference()
    recs = run_records("sdea_bench", [0, 1, 2])
    assert len(recs) == len(ref) == 3
    for i, rec in enumerate(recs):
        assert sorted(rec) == sorted(ref[i]), f"experiment {i}: record datasets differ"
        assert rec["t"].shape == (TICKS,)
        for k, v in ref[i].items():
            if k in _JSON_DATASETS:
                assert _comparable(k, rec[k]) == _comparable(k, v), f"experiment {i}: {k} differs"
            else:
                got = rec[k]
                assert got.dtype == v.dtype and got.shape == v.shape, f"experiment {i}: {k} dtype/shape"
                bad = np.flatnonzero(~((got == v) | (np.isnan(got) & np.isnan(v))).reshape(len(got), -1).all(axis=1))
                assert bad.size == 0, (f"experiment {i}: {k} differs from tick {bad[0]} on: "
                                       f"{got[bad[0]]!r} != {v[bad[0]]!r}")
    # the reference is not trivial: the chirp moves the motor and the sensor sees the spring torque
    assert np.ptp(ref[0]["channels/motor.position"]) > 0
    assert np.ptp(ref[0]["channels/spring_ft.wrench"][:, 5]) > 0


@pytest.mark.slow
@pytest.mark.parametrize("scene_name", DIGEST_SCENES)
def test_other_can_pty_scenes_bit_identical(scene_name: str) -> None:
    ref = json.loads((DATA / "digests.json").read_text())
    assert ref["ticks"] == TICKS
    assert digest(run_records(scene_name, [0])[0]) == ref["digests"][scene_name]


if __name__ == "__main__":
    if sys.argv[1:] == ["--regen"]:
        regenerate()
        print(f"wrote {DATA}")
    else:
        print(__doc__)
