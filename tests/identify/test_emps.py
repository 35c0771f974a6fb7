"""The EMPS benchmark (a real electro-mechanical positioning axis) through the documented user path:
``hil import DATA_EMPS.mat --map ... --scale motor.effort_cmd=35.15`` then ``hil identify --friction``.

Reference: the published IDIM-LS estimates (Janot, Gautier, Brunot 2019, EMPS_Description.pdf sec.
3.4; copied in ../shared/data/emps/SOURCE.txt): M 95.1089 kg, Fv 203.5034 N.s/m, Fc 20.3935 N, offset
-3.1648 N. The data are the one exception to "tests do not read ../shared": absent, the tests skip.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hil.cli.main import main as hil_main

DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "emps"
if not (DATA / "DATA_EMPS.mat").is_file():  # the worktree layout: /work/wt/<branch>/tests/identify
    DATA = Path("/work/shared/data/emps")
PUBLISHED = {"M": 95.1089, "B": 203.5034, "F_c": 20.3935, "F_0": -3.1648}
GTAU = 35.15065188  # N/V, the record's gtau

pytestmark = pytest.mark.skipif(not (DATA / "DATA_EMPS.mat").is_file(),
                                reason=f"EMPS benchmark data not found in {DATA} (../shared/data/emps)")


def _import(name: str, tmp: Path) -> Path:
    out = tmp / f"{name}.h5"
    rc = hil_main(["import", str(DATA / f"{name}.mat"), "--out", str(out), "--time", "t",
                   "--map", "motor.position=qm", "--map", "motor.effort_cmd=vir",
                   "--scale", f"motor.effort_cmd={GTAU}"])
    assert rc == 0
    return out


@pytest.fixture(scope="module")
def emps_json(tmp_path_factory: pytest.TempPathFactory) -> dict:
    tmp = tmp_path_factory.mktemp("emps")
    rec = _import("DATA_EMPS", tmp)
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = hil_main(["identify", str(rec), "--model", "mbk", "--friction", "coulomb,offset", "--json", "--seed", "1"])
    assert rc == 0, "a friction fit of EMPS passes its adequacy tests and converges"
    return json.loads(buf.getvalue())


@pytest.mark.slow
def test_idim_ls_reproduces_the_published_estimates(emps_json: dict) -> None:
    idim = emps_json["output_error_ml"]["idim_ls"]
    est = idim["estimate"]
    for k in ("M", "B", "F_c"):
        assert abs(est[k] / PUBLISHED[k] - 1) < 0.005, (k, est[k])
    assert abs(est["F_0"] - PUBLISHED["F_0"]) < 0.1
    # and its white-residual standard deviations are the published ones (0.1085, 1.1460, 0.1012, 0.0444)
    for k, sd in (("M", 0.1085), ("B", 1.1460), ("F_c", 0.1012), ("F_0", 0.0444)):
        assert abs(idim["std"][k] / sd - 1) < 0.05, (k, idim["std"][k])


@pytest.mark.slow
def test_posterior_estimates_and_units(emps_json: dict) -> None:
    par = emps_json["parameters"]
    assert set(par) == {"M", "B", "F_c", "F_0"}
    assert {k: par[k]["unit"] for k in par} == {"M": "kg", "B": "N.s/m", "F_c": "N", "F_0": "N"}
    for k, tol in (("M", 0.03), ("B", 0.03), ("F_c", 0.05)):
        assert abs(par[k]["median"] / PUBLISHED[k] - 1) < tol, (k, par[k]["median"])
    assert emps_json["converged"] and not emps_json["misfit"]
    # the intervals account for the coloured equation error: wider than the white-residual formula
    # (the published sd), by the sandwich factor of the residual's AR spectrum
    assert par["B"]["std"] > 2 * 1.1460
    assert par["M"]["q05"] < PUBLISHED["M"] < par["M"]["q95"]


@pytest.mark.slow
def test_pulses_record_model_choice(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Defect 5: the validation record is no longer refused with "check the actuator is enabled";
    the linear model is judged, and the friction models' simulation error is reported next to the
    linear model's, lower."""
    rec = _import("DATA_EMPS_PULSES", tmp_path)
    capsys.readouterr()
    rc = hil_main(["identify", str(rec), "--model", "mbk", "--no-store", "--max-seconds", "60"])
    out, err = capsys.readouterr()
    assert rc == 13
    assert "check the actuator is enabled" not in err
    rows = {ln.split(" " * 2)[0].strip(): ln for ln in out.splitlines() if "viscous" in ln}
    assert "the data support friction" in err
    lin = [ln for ln in out.splitlines() if ln.strip().startswith("linear (viscous only)")]
    cof = [ln for ln in out.splitlines() if ln.strip().startswith("viscous + coulomb + offset")]
    assert lin and cof, rows
    rms = {"lin": float(lin[0].split()[4]), "cof": float(cof[0].split()[6])}
    assert rms["cof"] < 0.5 * rms["lin"], rms


@pytest.mark.slow
def test_linear_fit_is_a_misfit_that_names_the_model(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Defect 3: position output for mbk from the CLI; the linear fit of EMPS is flagged and the message
    names the friction model the data support."""
    rec = _import("DATA_EMPS", tmp_path)
    capsys.readouterr()
    rc = hil_main(["identify", str(rec), "--model", "mbk", "--no-store", "--max-seconds", "60", "--json"])
    out, err = capsys.readouterr()
    assert rc == 13
    res = json.loads(out)
    assert res["outputs"] == ["position_0"] and res["misfit"]
    choice = res["model_choice"]
    assert choice["best"] and "coulomb" in choice["best"]
    by = {tuple(r["friction"]): r for r in choice["rows"]}
    assert by[()]["misfit"] and not by[("coulomb", "offset")]["misfit"]
    assert by[("coulomb", "offset")]["bic"] < by[()]["bic"]
    assert "--friction coulomb" in err


def test_sample_rate_is_one_definition() -> None:
    """Defect 1: the jittered EMPS time column (steps 0.99998..1.00002 ms) and an exact k * 1 ms column
    give the same 1000 Hz, and 1/median(dt) does not (what the plan once used for the model)."""
    import scipy.io as sio

    from hil.identify.records import sample_rate

    t = sio.loadmat(DATA / "DATA_EMPS.mat")["t"].ravel()
    assert sample_rate(t) == 1000.0
    assert sample_rate(np.arange(t.size) * 1e-3) == 1000.0
    assert abs(1 / np.median(np.diff(t)) - 1000.0) > 1e-3  # the old definition was off


def test_import_scale_gives_the_force_in_newtons(tmp_path: Path) -> None:
    """Defect 4 (h30's hil import --scale, as the EMPS recipe uses it): the record's effort command is
    gtau * vir in N, not vir in V."""
    import scipy.io as sio

    from hil.record.hdf5 import RunRecord

    rec = _import("DATA_EMPS", tmp_path)
    vir = sio.loadmat(DATA / "DATA_EMPS.mat")["vir"].ravel()
    sig = RunRecord.open(rec).to_identify_dict()["signals"]
    np.testing.assert_allclose(sig["motor.effort_cmd"], GTAU * vir, rtol=1e-12)


@pytest.mark.slow
def test_encoder_velocity_is_not_taken_for_a_held_sensor(tmp_path: Path) -> None:
    """Defects 2 and 6: a velocity differentiated from the EMPS encoder (what a user without position
    support computed) repeats values in 17 % of the samples; it is not treated as a slower sensor, so
    the ML path is not the held-output likelihood (which cost ~0.45 s per emcee step on this record)."""
    import scipy.io as sio

    from hil.identify.api import identify_record

    d = sio.loadmat(DATA / "DATA_EMPS.mat")
    q, t = d["qm"].ravel(), np.arange(d["qm"].size) * 1e-3
    v = np.gradient(q, 1e-3)
    assert np.mean(v[1:] == v[:-1]) > 0.1
    rec = {"t": t, "signals": {"f": GTAU * d["vir"].ravel(), "v": v},
           "meta": {"model": "mbk", "model_options": {"n_dof": 1}, "inputs": ["f"], "outputs": ["v"],
                    "sampling": "zoh", "posterior": "laplace", "excitation": "warn"}}
    res = identify_record(rec, seed=0)
    assert not any(dg.kind == "sample_and_hold" for dg in res.data_report.diagnoses)
    assert "held_outputs" not in (res.ml or {})
