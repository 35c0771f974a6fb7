"""End to end from the mocks: the runner plays the built-in identification experiments on the simulated
benches (SDEA of paper 002 behind an ODrive on virtual CAN + a Bota sensor; a cross-coupled 2-DOF device
on two grouped linear ODrive axes), the records are identified with everything inferred from the record
(model, channels, period, band, zero-order hold), and the posteriors are checked against the simulated
truth: 90 % intervals, posterior std vs the Cramér-Rao bound of the KNOWN noise, and the likelihood's
noise model vs the actual residuals at the truth (float32 rounding of the drive's feedback and command
included). Also: same estimates from a CSV export, the result stored in the record, CLI exit codes.

The non-slow tests run shortened copies of the built-in experiments (same periodic signals, fewer or
shorter periods); the built-in scenes at full length run under ``-m slow``.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from hil.cli.main import main as hil_main
from hil.identify.api import identify_record, load_identification, store_result
from hil.identify.fisher import crb, fisher_information
from hil.identify.frf import rounding_variance
from hil.record.hdf5 import RunRecord
from hil.run.runner import Runner
from hil.scene.spec import load_scene, scene_from_dict

SDEA_TRUTH = {"K_f": 362.0, "B_f": 0.05, "M": 6.399e-4, "B": 0.169}
M_OUT = 2.0e-3  # output inertia of the free variant (scene: simulation.sdea.m_out)
MBK_TRUTH = {
    "M": np.array([[1.0, 0.2], [0.2, 0.6]]),
    "B": np.array([[8.0, -2.0], [-2.0, 6.0]]),
    "K": np.array([[6000.0, -2500.0], [-2500.0, 9000.0]]),
}
# the built-in bench's simulated sensor noise (its scene: realistic sensors, not perfect ones)
_SN = load_scene("sdea_bench").simulation.sensor_noise
SDEA_NOISE = {"force": _SN.force_std, "velocity": _SN.velocity_std}
# Start the fits away from the truth (which is also the SDEA model's nominal, paper Table I).
THETA0 = {"K_f": 500.0, "B_f": 0.08, "M": 5e-4, "B": 0.12}
SET_ARGS = [a for k, v in THETA0.items() for a in ("--set", f"{k}={v}")]


def _modified(name: str, edit) -> object:
    """A built-in scene edited as a dict; the edited YAML is kept as the scene text (the record stores it)."""
    d = yaml.safe_load(load_scene(name).source_text)
    edit(d)
    return scene_from_dict(d, label=f"{name}-short", source_text=yaml.safe_dump(d, sort_keys=False))


def _short_sdea(d: dict) -> None:
    # 8 periods of 0.5 s instead of 2 s (f0 = 2 Hz = one period's resolution); static hold 0.5 s
    for e in d["experiments"][:2]:
        e.update(duration=4.0, f0=2.0)
    d["experiments"][2].update(duration=0.5, settle=0.2)


def _short_mbk(d: dict) -> None:
    # 6 periods of 1 s (1 Hz grid, 30 zippered lines per DOF) instead of 6 of 2 s
    d["experiments"][0].update(duration=6.0, periods=6, n_lines=30)


@pytest.fixture(scope="module")
def sdea_runs(tmp_path_factory) -> dict[str, Path]:
    outs = Runner(_modified("sdea_bench", _short_sdea), tmp_path_factory.mktemp("sdea")).run()
    assert [o.status for o in outs] == ["completed"] * 3, [o.stop_reason for o in outs]
    return {o.name.split("_", 1)[1]: o.record for o in outs}


@pytest.fixture(scope="module")
def mbk_run(tmp_path_factory) -> Path:
    (out,) = Runner(_modified("mbk_2dof_bench", _short_mbk), tmp_path_factory.mktemp("mbk")).run()
    assert out.status == "completed", out.stop_reason
    return out.record


@pytest.fixture(scope="module")
def locked_result(sdea_runs):
    return identify_record(sdea_runs["chirp_locked"], seed=0, theta0=THETA0)


# ------------------------------------------------------------------------------------------ helpers


def _known_noise_sigma(res, rec: RunRecord, noise_std: dict[str, float]) -> np.ndarray:
    """Per-bin FRF std of a SISO record from the KNOWN noise (not the data's estimate): white output noise
    of the scene's std averaged over the periods, plus the float32 rounding of the recorded outputs and
    of the applied command (repeated identically in every period: not averaged). A held output (a
    sensor slower than the loop, hil.identify.sensor_hold) carries only the fraction p_0 of new
    samples, so its white noise has 1/p_0 times the variance per FRF bin once the hold is divided
    out (the repeats add no information)."""
    from hil.identify.sensor_hold import age_distribution

    est, mdl = res.frf, res.model
    plan = res.record["mapping"]
    t = rec.t
    keep = t >= plan["settings"].get("skip", 0.0) - 1e-9
    sig = rec.to_identify_dict()["signals"]
    u = sig[plan["inputs"][0]][keep]
    q_u = rounding_variance(u, "float32")
    Gxx = est.Gxx[:, 0, 0].real
    out = np.empty(est.H.shape)
    for o, name in enumerate(mdl.output_names):
        y = sig[plan["outputs"][name]][keep]
        p = age_distribution(y)
        hold = 1.0 if p is None else 1.0 / p[0]
        q_y = rounding_variance(y, "float32")
        # |H1| in the input-rounding term: far more precise than that term needs
        g = (2.0 / est.fs) * (hold * noise_std.get(name, 0.0) ** 2 / est.n_avg + q_y
                              + np.abs(est.H[:, o, 0]) ** 2 * q_u)
        out[:, o, 0] = np.sqrt(g / Gxx / 2.0)
    return out


def _check_sdea(res, rec_path: Path, truth: dict[str, float], noise_std: dict[str, float]) -> dict[str, float]:
    assert res.converged, res.posterior.diagnostics.reasons
    summ = res.summary()
    mdl = res.model
    th = mdl.vector(truth)
    rec = RunRecord.open(rec_path)
    sigma = _known_noise_sigma(res, rec, noise_std)
    F = fisher_information(mdl, th, res.frf.w, sigma)
    _, crb_std = crb(mdl, th, F)
    ratios = {}
    for i, name in enumerate(mdl.names):
        row = summ[name]
        # One dataset, 4-5 parameters at 90 %: under perfect calibration a miss has probability ~10 % per
        # parameter; the records are deterministic (scene seed), the calibration itself is checked on
        # synthetic data by test_identify_calibration (slow).
        assert row["q05"] <= th[i] <= row["q95"], (name, row, th[i])
        ratios[name] = row["std"] / crb_std[i]
        assert 1 / 1.5 < ratios[name] < 1.5, (name, ratios[name], row["std"], crb_std[i])
    # The likelihood's noise model is honest: at the truth, |H1 - H|^2 / (2 sigma^2) averages ~1 per channel
    # (force: ~1.2 = nu/(nu-2) from the estimated variance with nu = 12; velocity: its sensor noise and
    # float32 rounding).
    H = mdl.frf(th, res.frf.w)
    z2 = np.abs(res.frf.H - H) ** 2 / (2 * res.frf.sigma**2)
    for o, name in enumerate(mdl.output_names):
        assert 0.6 < np.nanmean(z2[:, o, 0]) < 1.7, (name, np.nanmean(z2[:, o, 0]))
    return ratios


# --------------------------------------------------------------------------------------------- SDEA


def test_sdea_locked_record_inferred_and_truth_in_90pct_std_near_crb(sdea_runs, locked_result) -> None:
    res = locked_result
    m = res.record["mapping"]
    assert m["model"] == "sdea_locked" and m["model_options"]["zoh_fs"] == 2000.0
    assert m["inputs"] == ["motor.effort_cmd[0]"]
    assert m["outputs"] == {"velocity": "motor.velocity[0]", "force": "spring_ft.wrench[5]"}  # Tz, scene axes
    assert m["settings"]["period"] == 0.5 and m["settings"]["skip"] == 0.5
    assert tuple(m["settings"]["band"]) == (2.0, 200.0)
    ratios = _check_sdea(res, sdea_runs["chirp_locked"], SDEA_TRUTH, SDEA_NOISE)
    print("locked: posterior std / CRB", {k: round(v, 3) for k, v in ratios.items()})


def test_sdea_free_record_identifies_the_output_inertia_too(sdea_runs) -> None:
    res = identify_record(sdea_runs["chirp_free"], seed=0, theta0={**THETA0, "m_h": 3e-3})
    assert res.model.name == "sdea_free" and res.model.names == ("K_f", "B_f", "M", "B", "m_h")
    ratios = _check_sdea(res, sdea_runs["chirp_free"], {**SDEA_TRUTH, "m_h": M_OUT}, SDEA_NOISE)
    print("free: posterior std / CRB", {k: round(v, 3) for k, v in ratios.items()})


def test_velocity_only_locked_record_is_refused_before_fitting(sdea_runs, capsys) -> None:
    # The float32 velocity is precise to ~1e-8, yet B and B_f only enter as B + B_f: exact null direction.
    code = hil_main(["identify", str(sdea_runs["chirp_locked"]), "--output", "velocity=motor.velocity[0]",
                     "--no-store"])
    err = capsys.readouterr().err.strip()
    assert code == 13 and "NotIdentifiableError" in err and "B_f" in err and "\n" not in err


# ---------------------------------------------------------------------------------------------- MBK


def test_mbk_2dof_multisine_record_truth_in_90pct(mbk_run) -> None:
    res = identify_record(mbk_run, seed=0)
    m = res.record["mapping"]
    assert m["model"] == "mbk" and m["model_options"]["n_dof"] == 2
    assert m["inputs"] == ["device.effort_cmd[0]", "device.effort_cmd[1]"]  # the group's channels
    assert m["outputs"] == {"velocity_0": "device.velocity[0]", "velocity_1": "device.velocity[1]"}
    assert res.converged, res.posterior.diagnostics.reasons
    # zippered lines: every line gives one column of the 2x2 FRF, the other is "not measured"
    assert np.all(np.sum(np.isfinite(res.frf.H[:, 0, :]), axis=-1) == 1)
    der = res.derived_summary()
    for key, A in MBK_TRUTH.items():
        for i in range(2):
            for j in range(i, 2):
                row = der[f"{key}_{i}{j}"]
                assert row["q05"] <= A[i, j] <= row["q95"], (key, i, j, row)
    truth = res.model.theta_from_matrices(**MBK_TRUTH)
    summ = res.summary()
    for i, name in enumerate(res.model.names):  # the Cholesky factors too
        assert summ[name]["q05"] <= truth[i] <= summ[name]["q95"], (name, summ[name], truth[i])
        assert 1 / 1.5 < summ[name]["std"] / summ[name]["crb_std"] < 1.5


# ------------------------------------------------------------------------------ CSV, storage, CLI


def _export_csv(rec_path: Path, out: Path) -> Path:
    """The record's signals as a CSV another tool could have written (t + one column per signal)."""
    d = RunRecord.open(rec_path).to_identify_dict()
    names = ["motor.effort_cmd[0]", "motor.velocity[0]"] + [f"spring_ft.wrench[{i}]" for i in range(6)]
    cols = np.column_stack([d["t"]] + [d["signals"][n] for n in names])
    np.savetxt(out, cols, delimiter=",", header=",".join(["t", *names]), comments="", fmt="%.17g")
    return out


def test_csv_import_gives_the_same_estimates_as_the_native_record(sdea_runs, locked_result, tmp_path, capsys) -> None:
    csv = _export_csv(sdea_runs["chirp_locked"], tmp_path / "run.csv")
    # An imported CSV has no scene and no experiment meta: the model, force axis, period and band are given.
    code = hil_main(["identify", str(csv), "--json", "--seed", "0", "--model", "sdea_locked",
                     "--output", "velocity=motor.velocity[0]", "--output", "force=spring_ft.wrench[5]",
                     "--period", "0.5", "--skip", "0.5", "--band", "2", "200", "--accept-misfit", *SET_ARGS])
    # --accept-misfit: since one sample rate is used everywhere (issue 25 defect 1) the 2 Hz bin at the band's
    # lower edge is analysed (1/median(dt) = 1999.9999999999998 Hz put it at 1.9999999999999998 Hz, outside);
    # with it this seed's reduced chi^2 is 1.373 against the upper bound 1.37 (p = 1e-4), native and CSV alike.
    # What this test checks is that the CSV gives the native record's numbers.
    assert code == 0
    got = json.loads(capsys.readouterr().out)
    assert got["sampling"] == {"zoh_fs": 2000.0}
    for name, row in locked_result.summary().items():
        for k in ("median", "q05", "q95", "std"):
            assert got["parameters"][name][k] == pytest.approx(row[k], rel=1e-9, abs=0.0), (name, k)


def test_posterior_is_stored_in_the_record(sdea_runs, locked_result, tmp_path) -> None:
    path = tmp_path / "run.h5"
    shutil.copy(sdea_runs["chirp_locked"], path)
    assert store_result(path, locked_result) == "sdea_locked"
    store_result(path, locked_result)  # again: replaced, not duplicated
    got = load_identification(path, "sdea_locked")
    np.testing.assert_array_equal(got["samples"], locked_result.posterior.samples)
    s = got["summary"]
    assert s["converged"] is True and s["sample_names"] == ["K_f", "B_f", "M", "B"]
    assert s["parameters"]["K_f"]["median"] == locked_result.summary()["K_f"]["median"]
    assert {"tau", "split_rhat", "acceptance_fraction", "n_steps"} <= set(s["convergence"])
    rec = RunRecord.open(path)  # the run itself is untouched
    assert rec.status == "completed" and rec.t.size == RunRecord.open(sdea_runs["chirp_locked"]).t.size
    assert hil_main(["replay", str(path), "--json"]) == 0


def test_cli_exit_codes(sdea_runs, tmp_path, capsys) -> None:
    locked = tmp_path / "locked.h5"
    shutil.copy(sdea_runs["chirp_locked"], locked)

    def run(*argv: str) -> tuple[int, str]:
        code = hil_main(["identify", *argv])
        err = capsys.readouterr().err.strip()
        assert "Traceback" not in err
        return code, err

    # usage / input errors: 2
    assert run(str(tmp_path / "missing.h5"))[0] == 2
    assert run(str(locked), "--model", "nope")[0] == 2
    assert run(str(locked), "--output", "force=spring_ft.wrench[9]")[0] == 2
    # data quality (the static hold has no excitation): 13, one line
    code, err = run(str(sdea_runs["static_hold"]), "--model", "sdea_locked")
    assert code == 13 and err.startswith("hil identify: DataQualityError") and "\n" not in err
    # posterior not converged (time budget): 13, and the flagged result is still stored as evidence
    code, err = run(str(locked), "--max-seconds", "0.01", "--json", *SET_ARGS)
    assert code == 13 and "not converged" in err
    stored = load_identification(locked)
    assert stored["summary"]["converged"] is False and stored["samples"].shape[1] == 4


# --------------------------------------------------------------------------------- full length (slow)


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_builtin_scenes_full_length(tmp_path) -> None:
    outs = Runner(load_scene("sdea_bench"), tmp_path / "sdea").run(select=[0, 1])
    res = identify_record(outs[0].record, seed=1, theta0=THETA0)
    _check_sdea(res, outs[0].record, SDEA_TRUTH, SDEA_NOISE)
    res = identify_record(outs[1].record, seed=1, theta0={**THETA0, "m_h": 3e-3})
    _check_sdea(res, outs[1].record, {**SDEA_TRUTH, "m_h": M_OUT}, SDEA_NOISE)
    (out,) = Runner(load_scene("mbk_2dof_bench"), tmp_path / "mbk").run()
    res = identify_record(out.record, seed=1)
    assert res.converged
    for key, A in MBK_TRUTH.items():
        for i in range(2):
            for j in range(i, 2):
                row = res.derived_summary()[f"{key}_{i}{j}"]
                assert row["q05"] <= A[i, j] <= row["q95"], (key, i, j, row)
