"""Experiment planning (hil.run.plan, ``hil plan``): predicted posterior sd against the sd the mocked bench
achieves, the safety prediction against the recorded peaks, proposals for a requested precision, CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from hil.cli.main import main
from hil.errors import SceneError
from hil.run.plan import SAFETY_MARGIN, PlanError, plan_scene, predict_experiment
from hil.scene.spec import load_scene, scene_from_dict


def _scene(velocity_std: float = 0.0, **chirp: object) -> object:
    """sdea_bench with only its locked-output chirp, shortened to 8 periods of 0.5 s (f0 = 2 Hz, one
    period's resolution), optional white velocity noise and chirp overrides."""
    d = yaml.safe_load(load_scene("sdea_bench").source_text)
    d["experiments"] = [d["experiments"][0]]
    d["experiments"][0].update({"duration": 4.0, "f0": 2.0, **chirp})
    d["simulation"]["sensor_noise"]["velocity_std"] = velocity_std
    return scene_from_dict(d, label="sdea_bench-short", source_text=yaml.safe_dump(d, sort_keys=False))


# --------------------------------------------------------------------- prediction vs the mocked bench


@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.parametrize("velocity_std", [0.0, 0.02])
def test_predicted_sd_matches_the_achieved_posterior_sd_on_the_mocked_bench(velocity_std, tmp_path) -> None:
    """The bench runs the planned chirp (ODrive on virtual CAN, Bota sensor, float32 feedback) and the
    record is identified as ``hil certify`` does. velocity_std 0: the velocity is known to its float32
    rounding (K_f, M to ~1e-9); 0.02 rad/s: white-noise limited (K_f to ~1e-3)."""
    from hil.identify.api import identify_record
    from hil.record.hdf5 import RunRecord
    from hil.run.runner import Runner

    sc = _scene(velocity_std)
    pred = predict_experiment(sc, sc.experiments[0])
    (out,) = Runner(sc, tmp_path).run()
    assert out.status == "completed", out.stop_reason
    res = identify_record(out.record, seed=0)
    assert res.converged
    summ = res.summary()
    for n in pred.names:
        ratio = summ[n]["std"] / pred.sd[n]
        # Factor 1.5 either way, as test_identify_from_mocks allows between posterior sd and the CRB of the
        # known noise: the Student-t likelihood with noise estimated from K = 7 periods widens the posterior
        # by sqrt(nu/(nu-2)) ~ 1.08, the sd of a few hundred independent MCMC draws scatters by ~5 %, and the
        # prediction uses the nominal response instead of the measured one. Measured: 1.02-1.05 (velocity_std
        # 0) and 0.94-1.02 (0.02).
        assert 1 / 1.5 < ratio < 1.5, (n, summ[n]["std"], pred.sd[n])
    rec = RunRecord.open(out.record)
    v = np.asarray(rec.channels["motor.velocity"]).ravel()
    # safety prediction: the nominal plant's peak velocity vs the recorded one. The mock integrates the same
    # plant with its own solver (1 %) and adds the sensor noise, which can only raise the recorded maximum, by
    # at most ~5 sd over 8000 samples (P(|n| > 5 sd) = 6e-7 per sample)
    peak = float(np.max(np.abs(v)))
    assert pred.safety["velocity"]["peak"] * 0.99 <= peak <= pred.safety["velocity"]["peak"] * 1.01 + 5 * velocity_std
    u = np.asarray(rec.channels["motor.effort_cmd"]).ravel()
    assert pred.safety["effort"]["peak"] == pytest.approx(float(np.max(np.abs(u))), rel=1e-6)


# ------------------------------------------------------------------------------ defining properties


def test_noise_limited_variance_falls_as_one_over_the_averages() -> None:
    """With white velocity noise dominating the float32 floor, sd^2 ~ 1/K: 4 -> 16 analysed periods halve
    every sd (to 1 %: the rounding floor, which does not average, is ~1e-6 of the noise)."""
    sa, sb = _scene(0.02, duration=2.5, periods=5), _scene(0.02, duration=8.5, periods=17)
    a, b = predict_experiment(sa, sa.experiments[0]), predict_experiment(sb, sb.experiments[0])
    assert (a.n_averages, b.n_averages) == (4, 16)
    for n in ("K_f", "M"):
        assert a.sd[n] / b.sd[n] == pytest.approx(2.0, rel=0.01)
    # and linear in 1/amplitude
    sc = _scene(0.02, duration=2.5, periods=5, amplitude=0.4)
    c = predict_experiment(sc, sc.experiments[0])
    for n in ("K_f", "M"):
        assert a.sd[n] / c.sd[n] == pytest.approx(2.0, rel=0.01)


def test_safety_prediction_and_proposal_stay_within_the_limits() -> None:
    d = yaml.safe_load(_scene().source_text)
    d["safety"]["max_velocity"] = 0.5  # below the chirp's 0.91 rad/s peak
    sc = scene_from_dict(d, label="tight", source_text=yaml.safe_dump(d))
    pred = predict_experiment(sc, sc.experiments[0])
    assert not pred.allowed and pred.safety["velocity"]["ratio"] > 1.0
    (prop,) = plan_scene(sc, precision={"B_f": 0.01})
    assert prop.allowed
    # linear plant: the proposal scales the amplitude so that the tightest peak is SAFETY_MARGIN of its limit
    assert max(v["ratio"] for v in prop.safety.values()) == pytest.approx(SAFETY_MARGIN, rel=1e-6)
    assert prop.config["amplitude"] < 0.2


def test_precision_proposal_meets_the_request() -> None:
    sc = _scene(0.02)
    base = predict_experiment(sc, sc.experiments[0])
    target = base.rel_sd["K_f"] / 20  # needs more amplitude AND more periods
    (prop,) = plan_scene(sc, precision={"K_f": target})
    assert prop.ok_precision and prop.rel_sd["K_f"] <= target and prop.allowed
    assert prop.config["amplitude"] > 0.2 and prop.config["periods"] > 8
    assert any("periods" in n for n in prop.proposal_notes)
    assert prop.to_dict()["parameters"]["K_f"]["requested_rel_sd"] == target


def test_narrow_band_plan_is_flagged_and_the_proposal_widens_it() -> None:
    # built-in noise (force 0.002 N.m, velocity float32-limited): 100-140 Hz carries 19 % / 18 % of the
    # information on K_f / M that the sweep extended over 12-900 Hz would (with 0.02 rad/s of velocity noise
    # the same band flags B and B_f instead: the fraction depends on which channel limits the precision)
    sc = _scene(0.0, f0=100.0, f1=140.0)
    pred = predict_experiment(sc, sc.experiments[0])
    assert {"K_f", "M"} <= set(pred.not_pinned)
    assert pred.information_fraction["K_f"] < 0.3 and pred.information_fraction["M"] < 0.3
    (prop,) = plan_scene(sc, precision={"K_f": 1.0})  # any precision: the band must pin K_f first
    assert prop.config["f0"] < 100.0 and prop.config["f1"] > 140.0 and not prop.not_pinned


# ------------------------------------------------------------------------------------------------- CLI


def test_cli_table_and_json(capsys) -> None:
    assert main(["plan", "sdea_bench", "--experiment", "chirp_locked"]) == 0
    out = capsys.readouterr().out
    assert "predicted sd" in out and "K_f" in out and "allowed" in out
    assert main(["plan", "sdea_bench", "--json", "--precision", "B_f=0.0002"]) == 0
    got = json.loads(capsys.readouterr().out)
    locked = next(e for e in got["experiments"] if e["experiment"] == "chirp_locked")
    assert locked["precision_met"] is True and locked["allowed"] is True
    assert locked["parameters"]["B_f"]["rel_sd"] <= 0.0002


@pytest.mark.parametrize(("argv", "needle"), [
    (["plan", "sdea_bench", "--precision", "nope=0.1"], "no planned experiment identifies it"),
    (["plan", "sdea_bench", "--precision", "B_f=-1"], "positive number"),
    (["plan", "sdea_bench", "--precision", "B_f=abc"], "must be a number"),
    (["plan", "sdea_bench", "--precision", "B_f"], "NAME=VALUE"),
    (["plan", "sdea_bench", "--experiment", "static_hold"], "no open-loop chirp/multisine experiment"),
    (["plan", "bilateral_2dof_A1"], "no open-loop"),
    (["plan", "no_such_scene.yaml"], "no_such_scene"),
])
def test_cli_bad_input_one_line_exit_2(argv, needle, capsys) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("hil plan: error:") and "\n" not in err and needle in err, err


def test_unsafe_amplitude_is_a_scene_error() -> None:
    sc = _scene()
    cfg = {**sc.experiments[0].model_dump(), "amplitude": 5.0}  # > safety.max_effort 2
    with pytest.raises(SceneError, match="max_effort"):
        predict_experiment(sc, cfg)
    with pytest.raises(PlanError, match="relative sd"):
        plan_scene(sc, precision={"K_f": float("nan")})


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_predicted_sd_matches_the_achieved_posterior_sd_on_the_mbk_2dof_bench(tmp_path) -> None:
    """The built-in mbk_2dof_bench as shipped (two ODrive axes on virtual CAN, cross-coupled 2-DOF body,
    0.002 m/s white velocity noise, zippered multisine of 6 periods): the record is identified as ``hil
    certify`` does and every parameter's posterior sd is compared with the plan's. The noise the plan
    assumes is the bench's: the recorded velocity scatters about its period mean by 0.00199 m/s (measured;
    the mock's only noise source is sensor_noise.velocity_std, the float32 feedback adds ~1e-8)."""
    from hil.identify.api import identify_record
    from hil.record.hdf5 import RunRecord
    from hil.run.runner import Runner

    sc = load_scene("mbk_2dof_bench")
    pred = predict_experiment(sc, sc.experiments[0])
    (out,) = Runner(sc, tmp_path).run()
    assert out.status == "completed", out.stop_reason
    res = identify_record(out.record, seed=0)
    assert res.converged and not res.misfit
    summ = res.summary()
    ratios = {n: summ[n]["std"] / pred.sd[n] for n in pred.names}
    # factor 1.5 either way, as for sdea_bench above (Student-t widening ~1.08 with K = 5 periods, ~5 % MCMC
    # scatter of a std, nominal instead of measured response). Measured: 1.04-1.22.
    assert all(1 / 1.5 < r < 1.5 for r in ratios.values()), ratios
    # the noise the plan assumes is the one recorded: velocity about its period mean, periods 2..6
    v = np.asarray(RunRecord.open(out.record).channels["device.velocity"], float)
    n = round(sc.experiments[0].duration / sc.experiments[0].periods * sc.rate_hz)
    per = v[n: n * sc.experiments[0].periods].reshape(sc.experiments[0].periods - 1, n, -1)
    k = per.shape[0]
    scatter = (per - per.mean(axis=0)).std(axis=(0, 1)) * np.sqrt(k / (k - 1))
    # 5 x 2000 samples per DOF: the sample std has a relative sd of 0.7 %; 5 % is > 7 sd
    np.testing.assert_allclose(scatter, [pred.noise["velocity_0"], pred.noise["velocity_1"]], rtol=0.05)


def test_cia402_velocity_quantization_is_in_the_plan(tmp_path) -> None:
    """A CiA 402 drive reports velocity in whole counts/s: the recorded velocity of the simulated drive lies on
    the lattice 2 pi / counts_per_rev rad/s that the plan takes as its velocity rounding floor (800 x the
    float32 spacing at 0.5 rad/s), which raises the predicted sd of the velocity-limited K_f and M."""
    pytest.importorskip("canopen")
    from hil.record.hdf5 import RunRecord
    from hil.run.plan import _velocity_steps
    from hil.run.runner import Runner

    d = yaml.safe_load(load_scene("cia402_bench").source_text)
    d["experiments"] = [dict(d["experiments"][0], duration=0.5, periods=1)]
    d["simulation"]["sensor_noise"]["velocity_std"] = 0.0  # the quantization alone (the built-in adds noise)
    sc = scene_from_dict(d, label="cia402-short", source_text=yaml.safe_dump(d, sort_keys=False))
    (step,) = _velocity_steps(sc, "motor")
    assert step == pytest.approx(2 * np.pi / 131072, rel=1e-12)
    (out,) = Runner(sc, tmp_path).run()
    v = np.asarray(RunRecord.open(out.record).channels["motor.velocity"], float).ravel()
    k = v / step
    assert np.ptp(k) > 100  # the chirp moves the motor over many counts/s
    np.testing.assert_allclose(k, np.round(k), atol=1e-3)  # whole counts (float32 recording: ~1e-3 of a count)
    pred = predict_experiment(sc, sc.experiments[0])
    d["devices"][0]["params"].pop("counts_per_rev")  # left to the drive: the plan cannot know the lattice
    sc2 = scene_from_dict(d, label="cia402-unknown-cpr", source_text=yaml.safe_dump(d, sort_keys=False))
    assert _velocity_steps(sc2, "motor") == []
    base = predict_experiment(sc2, sc2.experiments[0])
    assert pred.sd["K_f"] > 100 * base.sd["K_f"] and pred.sd["M"] > 100 * base.sd["M"]
    assert pred.sd["B_f"] == pytest.approx(base.sd["B_f"], rel=0.05)  # force-limited: unchanged
