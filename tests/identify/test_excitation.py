"""Excitation adequacy before fitting (hil.identify.excitation): the 100-140 Hz chirp is refused,
naming K_f and M and the excitation that would pin them; a 1-400 Hz chirp is accepted."""

from __future__ import annotations

import json

import numpy as np
import pytest
from sdea_synth import TRUTH, log_chirp_record

import hil.identify.api as api
from hil.identify.errors import ModelSpecError, NotIdentifiableError
from hil.identify.excitation import (
    MIN_FRACTION,
    check_excitation_adequacy,
    excitation_metrics,
    excited_band,
    reference_band,
)
from hil.identify.frf import estimate_frf
from hil.identify.models import SdeaLockedOutput

FS = 5000.0


def _est(f0: float, f1: float, band: tuple[float, float], seed: int = 1):
    c = log_chirp_record(seed, f0, f1)
    est = estimate_frf([(c.u[:, None], np.column_stack([c.v, c.f]))], FS, nperseg=c.u.size // 16,
                       output_names=("velocity", "force"))
    return est.band(*band)


def _no_fit(*a, **k):
    raise AssertionError("the fit must not run when the excitation cannot pin the parameters")


@pytest.mark.parametrize("seed", [1, 2])
def test_narrow_chirp_is_refused_before_fitting_naming_K_f_and_M(seed, monkeypatch) -> None:
    c = log_chirp_record(seed, 100.0, 140.0)
    monkeypatch.setattr(api, "fit_least_squares", _no_fit)
    with pytest.raises(NotIdentifiableError) as err:
        api.identify_arrays(c.t, {"torque": c.u}, {"velocity": c.v, "force": c.f}, band=(100.0, 140.0))
    msg = str(err.value)
    rep = err.value.report
    assert {"K_f", "M"} <= set(rep.not_pinned)
    assert "K_f is not pinned" in msg and "M is not pinned" in msg
    assert "mass line" in msg and "Hz" in msg  # what excitation would pin M
    for name in ("K_f", "M"):
        fix = rep.fixes[name]
        assert fix["up_to_hz"] is not None and fix["up_to_hz"] > 140.0  # extend the sweep upwards ...
        assert rep.information_fraction[rep.names.index(name)] < MIN_FRACTION


def test_broadband_chirp_is_accepted() -> None:
    rep = check_excitation_adequacy(SdeaLockedOutput(), _est(1.0, 400.0, (1.0, 400.0)), np.array(list(TRUTH.values())))
    assert rep.ok, rep.messages
    # measured 0.76-0.91: every parameter well above the 0.5 threshold
    assert np.all(rep.information_fraction > 0.7)
    assert np.all(rep.collinearity < 1.3)


def test_broadband_chirp_identifies_without_excitation_warnings() -> None:
    c = log_chirp_record(3, 1.0, 400.0)
    res = api.identify_arrays(c.t, {"torque": c.u}, {"velocity": c.v, "force": c.f}, band=(1.0, 400.0),
                              max_steps=150)
    assert "excitation" not in {d.kind for d in res.data_report.diagnoses}


def test_warn_mode_fits_and_keeps_the_flags_in_the_data_checks(caplog) -> None:
    c = log_chirp_record(1, 100.0, 140.0)
    res = api.identify_arrays(c.t, {"torque": c.u}, {"velocity": c.v, "force": c.f}, band=(100.0, 140.0),
                              max_steps=100, excitation="warn")
    flagged = {d.details["parameter"] for d in res.data_report.diagnoses if d.kind == "excitation"}
    assert {"K_f", "M"} <= flagged
    assert all(d.severity == "warning" for d in res.data_report.diagnoses if d.kind == "excitation")
    assert any("K_f is not pinned" in r.getMessage() for r in caplog.records)
    with pytest.raises(ModelSpecError, match="excitation must be"):
        api.identify_arrays(c.t, {"torque": c.u}, {"velocity": c.v, "force": c.f}, band=(100.0, 140.0),
                            excitation="maybe")


def test_cli_exit_13_one_line(tmp_path, capsys) -> None:
    from hil.cli.main import main

    c = log_chirp_record(1, 100.0, 140.0)
    np.savez(tmp_path / "narrow.npz", t=c.t, torque=c.u, velocity=c.v, force=c.f,
             meta=json.dumps({"model": "sdea_locked", "sampling": "continuous"}))
    code = main(["identify", str(tmp_path / "narrow.npz"), "--band", "100", "140"])
    err = capsys.readouterr().err.strip()
    assert code == 13
    assert err.startswith("hil identify: NotIdentifiableError:") and "\n" not in err
    assert "K_f is not pinned" in err and "M is not pinned" in err


# ------------------------------------------------------------------------------ defining properties


def _analytic_fisher(th: dict[str, float], f: np.ndarray, sig: np.ndarray) -> np.ndarray:
    """Fisher matrix in z = log(theta) of the locked SDEA from closed-form derivatives (independent of
    the module's finite differences): H_v = j w / D, H_F = (K + j B_f w) / D, D = K - M w^2 + j (B + B_f) w."""
    K, Bf, M, B = (th[k] for k in ("K_f", "B_f", "M", "B"))
    w = 2 * np.pi * f
    D = K - M * w**2 + 1j * (B + Bf) * w
    Hv, Hf = 1j * w / D, (K + 1j * Bf * w) / D
    dD = {"K_f": np.ones_like(w), "B_f": 1j * w, "M": -(w**2), "B": 1j * w}
    dN = {"K_f": np.ones_like(w), "B_f": 1j * w, "M": 0 * w, "B": 0 * w}
    cols = []
    for i, n in enumerate(("K_f", "B_f", "M", "B")):
        x = [K, Bf, M, B][i]  # d/dz = x d/dx
        dv = -Hv * dD[n] / D * x
        df_ = (dN[n] / D - Hf * dD[n] / D) * x
        cols.append(np.concatenate([dv / sig[:, 0], df_ / sig[:, 1]]))
    J = np.array(cols).T
    Jr = np.concatenate([J.real, J.imag])
    return Jr.T @ Jr


def test_information_fraction_is_the_crb_ratio_of_the_extended_test() -> None:
    m = SdeaLockedOutput()
    th = np.array(list(TRUTH.values()))
    df = 2.0
    f = np.arange(100.0, 140.0 + df / 2, df)
    sig = np.column_stack([np.full(f.size, 0.05), np.full(f.size, 0.02)])  # flat per-bin std
    ref = (10.0, 1000.0)
    got = excitation_metrics(m, th, f, sig[:, :, None], ref_band=ref, df=df)
    f_ref = np.arange(10.0, 1000.0 + df / 2, df)  # the extension has the edge std = the flat std here
    sig_ref = np.column_stack([np.full(f_ref.size, 0.05), np.full(f_ref.size, 0.02)])
    F_rec, F_ref = _analytic_fisher(TRUTH, f, sig), _analytic_fisher(TRUTH, f_ref, sig_ref)
    crb_rec, crb_ref = np.diag(np.linalg.inv(F_rec)), np.diag(np.linalg.inv(F_ref))
    # finite differences (4th order, step 1e-3 in z) vs closed form: agreement ~1e-8; 1e-6 leaves margin
    np.testing.assert_allclose(got["information_fraction"], crb_ref / crb_rec, rtol=1e-6)
    vif = crb_rec * np.diag(F_rec) / (crb_ref * np.diag(F_ref))
    np.testing.assert_allclose(got["collinearity"], vif, rtol=1e-6)
    assert np.all(got["information_fraction"] <= 1.0 + 1e-12)  # F_ref = F_rec + PSD term


def test_proposed_fix_pins_the_parameter() -> None:
    """The reported extension, added at the band edge's quality, lifts the parameter's information
    fraction to the threshold (checked here with the closed-form Fisher matrix)."""
    est = _est(100.0, 140.0, (100.0, 140.0))
    th = np.array(list(TRUTH.values()))
    rep = check_excitation_adequacy(SdeaLockedOutput(), est, th)
    assert not rep.ok
    m = excitation_metrics(SdeaLockedOutput(), th, est.f, est.sigma, ref_band=rep.reference_band,
                           df=est.fs / est.nperseg)
    s_hi = m["edge_sigma"][1][:, 0]
    df = est.fs / est.nperseg
    F_rec = _analytic_fisher(TRUTH, est.f, est.sigma[:, :, 0])
    crb_ref = m["crb_rel_ref"] ** 2
    for name in rep.not_pinned:
        i = rep.names.index(name)
        up = rep.fixes[name]["up_to_hz"]
        assert up is not None
        fx = np.arange(est.f[-1] + df, up + 1e-9, df)
        F = F_rec + _analytic_fisher(TRUTH, fx, np.tile(s_hi, (fx.size, 1)))
        assert crb_ref[i] / np.linalg.inv(F)[i, i] >= MIN_FRACTION * (1 - 1e-6)
        fx_short = fx[:-1]  # one bin less does not: the fix is the smallest extension on the bin grid
        F = F_rec + _analytic_fisher(TRUTH, fx_short, np.tile(s_hi, (fx_short.size, 1)))
        assert crb_ref[i] / np.linalg.inv(F)[i, i] < MIN_FRACTION


def test_reference_band_is_a_decade_around_the_resonance() -> None:
    m = SdeaLockedOutput()
    f_n = np.sqrt(TRUTH["K_f"] / TRUTH["M"]) / (2 * np.pi)  # |eigenvalue| of the complex pair = sqrt(K/M)
    lo, hi = reference_band(m, np.array(list(TRUTH.values())))
    assert lo == pytest.approx(f_n / 10, rel=1e-12) and hi == pytest.approx(10 * f_n, rel=1e-12)
    assert reference_band(m, np.array(list(TRUTH.values())), fs=2000.0)[1] == pytest.approx(900.0)


@pytest.mark.parametrize(("f0", "f1"), [(20.0, 300.0), (100.0, 140.0)])
def test_excited_band_brackets_the_sweep(f0, f1) -> None:
    t = np.arange(round(4 * FS)) / FS
    from scipy.signal import chirp

    u = chirp(t, f0, t[-1], f1, method="linear")
    lo, hi = excited_band(u, FS)
    # the abrupt start/stop leak a little power outside the sweep: the 99.8 % band is the sweep widened by
    # at most 25 % of its width at each end (measured: 20-300 Hz -> 17.8-304.8 Hz, 100-140 Hz -> 96.3-143.8 Hz)
    w = f1 - f0
    assert f0 - 0.25 * w <= lo <= f0 + 0.02 * w and f1 - 0.02 * w <= hi <= f1 + 0.25 * w
    with pytest.raises(ValueError, match="no input carries power"):
        excited_band(np.zeros(100), FS)


def test_cli_warn_fits_and_reports_the_flags(tmp_path, capsys) -> None:
    from hil.cli.main import main

    c = log_chirp_record(1, 100.0, 140.0)
    np.savez(tmp_path / "narrow.npz", t=c.t, torque=c.u, velocity=c.v, force=c.f,
             meta=json.dumps({"model": "sdea_locked", "sampling": "continuous"}))
    code = main(["identify", str(tmp_path / "narrow.npz"), "--band", "100", "140", "--excitation", "warn",
                 "--max-seconds", "1", "--json"])
    cap = capsys.readouterr()
    assert code in (0, 13) and "NotIdentifiableError" not in cap.err  # 13 only for an unconverged posterior
    checks = json.loads(cap.out)["data_checks"]
    assert {"K_f", "M"} <= {d["details"]["parameter"] for d in checks if d["kind"] == "excitation"}
