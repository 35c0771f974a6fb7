"""Identifiability before fitting (Fisher rank) and data diagnoses (noise-only, saturation, gaps)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SDEA_SETUP, make_sdea_record

import hil.identify.api as api
from hil.identify.errors import DataQualityError, NotIdentifiableError
from hil.identify.fisher import ExperimentPlan, check_identifiability
from hil.identify.models import SdeaFreeOutput, SdeaLockedOutput

PLAN = ExperimentPlan(
    band=SDEA_SETUP["band"],
    fs=SDEA_SETUP["fs"],
    duration=SDEA_SETUP["period"] * SDEA_SETUP["n_periods"],
    amplitude=SDEA_SETUP["amplitude"],
    noise_std=SDEA_SETUP["noise_std"][0],
    nperseg=SDEA_SETUP["nperseg"],
    chirp_band=(SDEA_SETUP["f0"], SDEA_SETUP["f1"]),
)


def test_velocity_only_locked_cannot_separate_B_and_B_f() -> None:
    rep = check_identifiability(SdeaLockedOutput(("velocity",)), plan=PLAN)
    assert not rep.ok and rep.rank == 3
    assert set(rep.unidentifiable) == {"B", "B_f"}
    msg = " ".join(rep.messages)
    assert "spring force" in msg and "free-output" in msg
    with pytest.raises(NotIdentifiableError):
        rep.raise_if_not_identifiable()


@pytest.mark.parametrize(
    "model", [SdeaLockedOutput(("velocity", "force")), SdeaFreeOutput(("velocity",)), SdeaFreeOutput(("force",))]
)
def test_fixes_make_it_identifiable(model) -> None:
    rep = check_identifiability(model, plan=PLAN)
    assert rep.ok, rep.messages
    assert np.all(np.isfinite(rep.crb_std)) and rep.condition < 1e8


def test_force_only_locked_lacks_the_scale() -> None:
    # F/tau = (B_f s + K_f)/(M s^2 + (B + B_f) s + K_f) only depends on ratios to K_f.
    rep = check_identifiability(SdeaLockedOutput(("force",)), plan=PLAN)
    assert not rep.ok and {"K_f", "M"} <= set(rep.unidentifiable)
    assert "motor velocity" in " ".join(rep.messages)


def test_gain_nuisance_with_one_channel_is_flagged() -> None:
    rep = check_identifiability(SdeaLockedOutput(("velocity", "force"), gain=True), plan=PLAN)
    assert not rep.ok and any("gain" in m for m in rep.messages)


def test_identify_refuses_velocity_only_before_fitting(sdea_record, monkeypatch) -> None:
    def _no_fit(*a, **k):
        raise AssertionError("fit must not run on a non-identifiable experiment")

    monkeypatch.setattr(api, "fit_least_squares", _no_fit)
    with pytest.raises(NotIdentifiableError, match="spring force"):
        api.identify_arrays(
            sdea_record.t,
            {"torque": sdea_record.u[:, 0]},
            {"velocity": sdea_record.y[:, 0]},
            model="sdea_locked",
            channels=("velocity",),
            band=SDEA_SETUP["band"],
            period=SDEA_SETUP["period"],
        )


def _run(t, u, y):
    return api.identify_arrays(
        t, {"torque": u}, {"velocity": y[:, 0], "force": y[:, 1]}, band=SDEA_SETUP["band"], period=0.5, max_steps=200
    )


def _kinds(exc: DataQualityError) -> set[str]:
    return {d.kind for d in exc.diagnoses}


def test_noise_only_data_is_diagnosed() -> None:
    rec = make_sdea_record(5)
    rng = np.random.default_rng(5)
    y_noise = rng.standard_normal(rec.y.shape) * np.array(SDEA_SETUP["noise_std"])  # sensors, no response
    with pytest.raises(DataQualityError) as ei:
        _run(rec.t, rec.u[:, 0], y_noise)
    assert _kinds(ei.value) == {"no_excitation"}
    assert "no response" in str(ei.value) or "no excitation" in str(ei.value)


def test_dead_input_is_diagnosed() -> None:
    rec = make_sdea_record(6)
    with pytest.raises(DataQualityError) as ei:
        _run(rec.t, np.zeros_like(rec.u[:, 0]), rec.y)
    assert "no_excitation" in _kinds(ei.value)


def test_saturated_run_is_diagnosed() -> None:
    rec = make_sdea_record(7)
    lim = 0.6 * np.max(np.abs(rec.u))
    with pytest.raises(DataQualityError) as ei:
        _run(rec.t, np.clip(rec.u[:, 0], -lim, lim), rec.y)
    assert _kinds(ei.value) == {"saturation"}
    assert "torque" in str(ei.value)


def test_record_with_dropped_samples_is_diagnosed() -> None:
    rec = make_sdea_record(8)
    keep = np.ones(rec.t.size, bool)
    keep[3000:3050] = False  # 50 dropped samples
    with pytest.raises(DataQualityError) as ei:
        _run(rec.t[keep], rec.u[keep, 0], rec.y[keep])
    assert _kinds(ei.value) == {"gaps"}
    assert ei.value.diagnoses[0].details["dropped_samples"] == 50


def test_record_with_nans_is_diagnosed() -> None:
    rec = make_sdea_record(9)
    y = rec.y.copy()
    y[100:110, 1] = np.nan
    with pytest.raises(DataQualityError) as ei:
        _run(rec.t, rec.u[:, 0], y)
    assert _kinds(ei.value) == {"non_finite"}


def test_jittered_timestamps_are_diagnosed() -> None:
    rec = make_sdea_record(9)
    t = rec.t + np.random.default_rng(0).uniform(-0.1, 0.1, rec.t.size) / rec.fs
    with pytest.raises(DataQualityError) as ei:
        _run(t, rec.u[:, 0], rec.y)
    assert _kinds(ei.value) == {"nonuniform_sampling"}
