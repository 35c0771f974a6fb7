"""Bit-identity of lockstep records across speed-ups of the mocked bench (issue 15).

The lockstep path (python-can virtual bus, pty streams, simulated devices, plant) was optimised
without changing what goes over the transports; with a given seed the records must stay the same
bit for bit. The references were produced by the code *before* those optimisations (commit
715c158) and are stored in ``tests/data/lockstep_reference/``:

* ``sdea_bench.npz``: every experiment of ``sdea_bench`` (locked chirp, free chirp, static hold),
  :data:`TICKS` ticks each through the full :class:`hil.run.runner.Runner` in lockstep: ``/t`` and every
  ``/channels/*`` array, plus the record's ``device_counters``, ``events`` and ``status`` (JSON);
* ``digests.json``: the SHA-256 of ``/t`` and the channels of the first experiment of the other
  built-in scenes whose devices are ODrive (CAN) and Bota (pty) only, :data:`TICKS` ticks each;
  ``others.npz``: the same records' arrays;
* ``platform.json``: the floating-point platform the references were made on (:func:`platform_fingerprint`).

Bit-identity is a property of one floating-point platform: numpy's ``sin``/``power`` on arrays (the
chirp) and LAPACK (the ZOH matrices) dispatch on the CPU's SIMD features and change with the wheels, so
the same code gives records that differ in the last bit on another machine (an AVX-512 machine changed
``motor.excitation`` by 1 ULP on 11 of 240 ticks). Hence two comparisons:

* on the references' platform (same fingerprint): exact (NaN = NaN); any difference, even one ULP, is a
  change of behaviour of the mocked bench;
* elsewhere: integer arrays exact, float arrays within :data:`REL_TOL` of the channel's peak. ULP-level
  differences carried through 240 ticks of these stable closed loops stay at ~1e-14 of the peak
  (measured: 7e-16 on the excitation, 4e-15 on the motor velocity); any change of what goes over the
  transports (a frame lost, delayed by a tick, reordered) moves a sample by a tick's increment of the
  signal, ~1e-4 of the peak or more at 2 kHz. The digests are then not compared (they are exact).

Regenerate (only when a deliberate change elsewhere alters the records, and say so in the commit):
``python tests/bench/test_lockstep_records.py --regen``. The references in the repository were made from
the tree of 715c158 on a 2-core AMD EPYC (AVX-512) guest, numpy 2.4.6, scipy 1.17.1 (``platform.json``):
the current code gave the same records bit for bit there. Regenerated once since, deliberately, when the
built-in scenes got realistic simulated sensor noise (issue 28: velocity and position noise change every
measured channel), on a 2-core x86-64 guest whose numpy dispatches to X86_V3 (``platform.json``).
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
#: tolerance relative to a channel's peak |value| when the platform differs (see the module docstring)
REL_TOL = 1e-10
#: the other built-in scenes whose simulated devices are ODrive and Bota only (this module's scope)
DIGEST_SCENES = ("mbk_2dof_bench", "bilateral_2dof_A1", "bilateral_2dof_B", "mcet_trilateral")
_JSON_DATASETS = ("device_counters", "events", "status")


def platform_fingerprint() -> dict[str, Any]:
    """What the floating-point results of the lockstep run depend on besides the code: numpy and scipy
    versions, the CPU architecture, the C library, and the SIMD targets numpy dispatches to."""
    import platform

    import scipy

    try:
        simd = np.__config__.show(mode="dicts")["SIMD Extensions"]["found"]  # type: ignore[call-arg, index]
    except Exception:
        from numpy._core._multiarray_umath import __cpu_features__  # type: ignore[import-not-found]

        simd = sorted(k for k, v in __cpu_features__.items() if v)
    return {"numpy": np.__version__, "scipy": scipy.__version__, "machine": platform.machine(),
            "libc": " ".join(platform.libc_ver()), "numpy_simd": list(simd)}


def same_platform() -> bool:
    return bool(json.loads((DATA / "platform.json").read_text()) == platform_fingerprint())


def assert_same_record(rec: dict[str, Any], ref: dict[str, Any], what: str, *, exact: bool) -> None:
    """Every dataset of ``ref`` in ``rec``: JSON datasets equal; arrays equal bit for bit (``exact``) or,
    float arrays, within :data:`REL_TOL` of the channel's peak."""
    assert sorted(rec) == sorted(ref), f"{what}: record datasets differ"
    for k, v in ref.items():
        if k in _JSON_DATASETS:
            assert _comparable(k, rec[k]) == _comparable(k, v), f"{what}: {k} differs"
            continue
        got = rec[k]
        assert got.dtype == v.dtype and got.shape == v.shape, f"{what}: {k} dtype/shape"
        same = (got == v) | (np.isnan(got) & np.isnan(v))
        if not exact and np.issubdtype(v.dtype, np.floating):
            finite = np.isfinite(v)
            peak = float(np.max(np.abs(v[finite]))) if finite.any() else 0.0
            same |= np.abs(got - v) <= REL_TOL * max(peak, np.finfo(float).tiny)
        bad = np.flatnonzero(~same.reshape(len(got), -1).all(axis=1))
        assert bad.size == 0, (f"{what}: {k} differs from tick {bad[0]} on "
                               f"({'exact' if exact else f'rel. tol. {REL_TOL:g}'}): {got[bad[0]]!r} != {v[bad[0]]!r}")


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


def _save(path: Path, recs: dict[str, dict[str, Any]]) -> None:
    arrays: dict[str, np.ndarray] = {}
    for i, rec in recs.items():
        for k, v in rec.items():
            arrays[f"{i}:{k}"] = np.asarray(v) if not isinstance(v, str) else np.frombuffer(v.encode(), np.uint8)
    np.savez_compressed(path, **arrays)


def _load(path: Path) -> dict[str, dict[str, Any]]:
    ref: dict[str, dict[str, Any]] = {}
    with np.load(path) as z:
        for key in z.files:
            i, name = key.split(":", 1)
            v = z[key]
            ref.setdefault(i, {})[name] = bytes(v).decode() if name in _JSON_DATASETS else v
    return ref


def regenerate() -> None:
    DATA.mkdir(parents=True, exist_ok=True)
    _save(DATA / "sdea_bench.npz", {str(i): r for i, r in enumerate(run_records("sdea_bench", [0, 1, 2]))})
    others = {name: run_records(name, [0])[0] for name in DIGEST_SCENES}
    _save(DATA / "others.npz", others)
    digests = {name: digest(rec) for name, rec in others.items()}
    (DATA / "digests.json").write_text(json.dumps({"ticks": TICKS, "digests": digests}, indent=1) + "\n")
    (DATA / "platform.json").write_text(json.dumps(platform_fingerprint(), indent=1) + "\n")


def _reference() -> dict[int, dict[str, Any]]:
    return {int(i): r for i, r in _load(DATA / "sdea_bench.npz").items()}


def test_sdea_bench_records_bit_identical_to_reference() -> None:
    ref = _reference()
    recs = run_records("sdea_bench", [0, 1, 2])
    assert len(recs) == len(ref) == 3
    exact = same_platform()
    for i, rec in enumerate(recs):
        assert rec["t"].shape == (TICKS,)
        assert_same_record(rec, ref[i], f"experiment {i}", exact=exact)
    # the reference is not trivial: the chirp moves the motor and the sensor sees the spring torque
    assert np.ptp(ref[0]["channels/motor.position"]) > 0
    assert np.ptp(ref[0]["channels/spring_ft.wrench"][:, 5]) > 0


@pytest.mark.slow
@pytest.mark.parametrize("scene_name", DIGEST_SCENES)
def test_other_can_pty_scenes_bit_identical(scene_name: str) -> None:
    ref = json.loads((DATA / "digests.json").read_text())
    assert ref["ticks"] == TICKS
    rec = run_records(scene_name, [0])[0]
    if same_platform():
        assert digest(rec) == ref["digests"][scene_name]
    assert_same_record(rec, _load(DATA / "others.npz")[scene_name], scene_name, exact=same_platform())


def test_tolerance_catches_a_one_tick_delay_but_not_ulps() -> None:
    """The cross-platform comparison's defining property on the reference itself: a 1-ULP change on
    every sample passes, the same channel delayed by one tick (a frame one tick late) fails."""
    ref = _reference()[0]
    ulp = {k: (np.nextafter(v, np.inf) if np.issubdtype(v.dtype, np.floating) else v)
           if not isinstance(v, str) else v for k, v in ref.items()}
    assert_same_record(ulp, ref, "1 ULP", exact=False)
    with pytest.raises(AssertionError):
        assert_same_record(ulp, ref, "1 ULP", exact=True)
    for name in ("channels/motor.position", "channels/spring_ft.wrench", "channels/motor.effort_cmd"):
        late = dict(ref)
        late[name] = np.concatenate([ref[name][:1], ref[name][:-1]])
        with pytest.raises(AssertionError, match="differs from tick"):
            assert_same_record(late, ref, f"{name} one tick late", exact=False)


if __name__ == "__main__":
    if sys.argv[1:] == ["--regen"]:
        regenerate()
        print(f"wrote {DATA}")
    else:
        print(__doc__)
