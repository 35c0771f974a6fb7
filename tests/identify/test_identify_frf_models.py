"""Model transfer functions, H1 estimation, FRF variance and linearity checks on synthetic data."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import (
    MBK_TRUTH,
    SDEA_SETUP,
    SDEA_TRUTH,
    make_sdea_record,
    mbk_ss,
    sdea_locked_ss,
)
from scipy import signal

from hil.identify.frf import compare_frfs, estimate_frf, harmonic_distortion
from hil.identify.models import MbkModel, SdeaFreeOutput, SdeaLockedOutput

W = 2 * np.pi * np.logspace(0, 2.7, 50)


def _ss_frf(ss: tuple, w: np.ndarray) -> np.ndarray:
    """(nf, no, ni) FRF of a state-space model, C (jwI - A)^-1 B + D, independently of the models."""
    A, B, C, D = ss
    n = A.shape[0]
    return np.stack([C @ np.linalg.solve(1j * wk * np.eye(n) - A, B) + D for wk in w])


def test_sdea_locked_matches_state_space() -> None:
    m = SdeaLockedOutput(("velocity", "force"))
    H = m.frf(m.vector(SDEA_TRUTH), W)
    np.testing.assert_allclose(H, _ss_frf(sdea_locked_ss(**SDEA_TRUTH), W), rtol=1e-10)


def test_sdea_free_matches_state_space() -> None:
    K, Bf, M, B, mh = 362.0, 0.05, 6.399e-4, 0.169, 2e-3
    # state [x1, x2, v1, v2]; spring torque F = K (x1 - x2) + Bf (v1 - v2)
    A = np.array(
        [[0, 0, 1, 0], [0, 0, 0, 1], [-K / M, K / M, -(B + Bf) / M, Bf / M], [K / mh, -K / mh, Bf / mh, -Bf / mh]]
    )
    Bm = np.array([[0], [0], [1 / M], [0]])
    C = np.array([[0, 0, 1, 0], [K, -K, Bf, -Bf], [0, 0, 0, 1]])
    m = SdeaFreeOutput(("velocity", "force", "output_velocity"), m_h=None)
    H = m.frf(m.vector({**SDEA_TRUTH, "m_h": mh}), W)
    np.testing.assert_allclose(H, _ss_frf((A, Bm, C, np.zeros((3, 1))), W), rtol=1e-9)


def test_mbk_matches_state_space_and_batches() -> None:
    m = MbkModel(2, M=MBK_TRUTH["M"], B=MBK_TRUTH["B"], K=MBK_TRUTH["K"])
    th = m.theta_from_matrices(MBK_TRUTH["M"], MBK_TRUTH["B"], MBK_TRUTH["K"])
    np.testing.assert_allclose(m.frf(th, W), _ss_frf(mbk_ss(**MBK_TRUTH), W), rtol=1e-10)
    Mm, Bm, Km = m.matrices(th)
    np.testing.assert_allclose(Mm, MBK_TRUTH["M"], rtol=1e-12)
    np.testing.assert_allclose(Bm, MBK_TRUTH["B"], rtol=1e-12)
    np.testing.assert_allclose(Km, MBK_TRUTH["K"], rtol=1e-12)
    batch = np.stack([th, th * 1.01, th * 0.99])
    Hb = m.frf(batch, W)
    assert Hb.shape == (3, W.size, 2, 2)
    np.testing.assert_allclose(Hb[1], m.frf(th * 1.01, W))


def test_gain_and_delay_nuisance() -> None:
    m = SdeaLockedOutput(("velocity",), gain=True, delay=True)
    th = m.vector({**SDEA_TRUTH, "gain_velocity": 2.0, "delay": 1e-3})
    base = SdeaLockedOutput(("velocity",)).frf(m.vector(SDEA_TRUTH)[:4], W)
    np.testing.assert_allclose(m.frf(th, W), 2.0 * base * np.exp(-1j * W * 1e-3)[:, None, None], rtol=1e-12)


def _est(rec, nperseg=SDEA_SETUP["nperseg"]):
    return estimate_frf([(rec.u, rec.y)], rec.fs, nperseg=nperseg, output_names=("velocity", "force")).band(
        *SDEA_SETUP["band"]
    )


def test_h1_noise_free_matches_model() -> None:
    rec = make_sdea_record(0, noise_std=(1e-9, 1e-9))
    est = _est(rec)
    Hm = SdeaLockedOutput().frf(SdeaLockedOutput().vector(SDEA_TRUTH), est.w)
    # Leakage-free periodic segments + 16x-oversampled FOH simulation: only the (w T_fine)^2/12 interpolation
    # error (< 1e-4) and the band-limiting of the chirp remain.
    np.testing.assert_allclose(est.H, Hm, rtol=2e-3)


def test_frf_variance_from_coherence_is_calibrated(sdea_record) -> None:
    est = _est(sdea_record)
    Hm = SdeaLockedOutput().frf(SdeaLockedOutput().vector(SDEA_TRUTH), est.w)
    z = (est.H - Hm) / est.sigma
    zz = np.concatenate([z.real.ravel(), z.imag.ravel()])
    # ~800 standardized errors; with sigma estimated from dof=30 the errors are Student-t (std 1.035).
    # The sample std of 800 values has a relative sd of ~2.5 % (plus t tails): accept 0.9..1.2.
    assert 0.9 < np.std(zz) < 1.2
    assert abs(np.mean(zz)) < 0.15  # 4 standard errors of the mean (1/sqrt(800) = 0.035)


def test_mimo_h1_from_two_experiments(mbk_records) -> None:
    est = estimate_frf([(r.u, r.y) for r in mbk_records], 500.0, nperseg=2500).band(2, 50)
    m = MbkModel(2)
    Hm = m.frf(m.theta_from_matrices(**MBK_TRUTH), est.w)
    z = (est.H - Hm) / est.sigma
    assert est.H.shape[1:] == (2, 2)
    assert 0.85 < np.std(np.concatenate([z.real.ravel(), z.imag.ravel()])) < 1.25


def test_linearity_check_passes_linear_and_flags_nonlinear() -> None:
    low = _est(make_sdea_record(10, amplitude=0.25))
    high = _est(make_sdea_record(11, amplitude=0.5))
    assert compare_frfs(low, high).ok
    # Sensor/plant nonlinearity: a cubic stiffening of the measured output (5 % at the peak of the high run).
    rec = make_sdea_record(12, amplitude=0.5)
    peak = np.max(np.abs(rec.y), axis=0)
    rec.y = rec.y + 0.05 * rec.y**3 / peak**2
    rep = compare_frfs(low, _est(rec))
    assert not rep.ok and "not linear" in rep.message


def test_harmonic_distortion_of_a_clipped_sine() -> None:
    fs, f0 = 1000.0, 10.0
    t = np.arange(4000) / fs
    y = np.sin(2 * np.pi * f0 * t)
    assert harmonic_distortion(y, fs, f0).ok
    bad = harmonic_distortion(np.clip(y, -0.6, 0.6), fs, f0)
    assert not bad.ok and bad.statistic > 0.05


@pytest.mark.parametrize("window", ["boxcar", "hann"])
def test_welch_windows_run(window: str) -> None:
    rec = make_sdea_record(3)
    est = estimate_frf([(rec.u, rec.y)], rec.fs, nperseg=1000, window=window)
    assert np.all(est.coherence >= 0) and np.all(est.coherence <= 1)
    assert est.n_avg > 1 and est.dof > 0
    _ = signal  # scipy.signal used by the generators in conftest


def test_lattice_step_finds_a_whole_count_quantizer_and_nothing_else() -> None:
    """A velocity reported in whole encoder counts per second (CiA 402: 2 pi / 131072 rad/s per count) lies on
    a lattice; float32 samples of a smooth signal (every float32 is a multiple of its smallest spacing) and
    noisy floats do not count. ``resolution="auto"`` then takes q^2/12 as the rounding floor."""
    from hil.identify.frf import lattice_step, rounding_variance

    q = 2 * np.pi / 131072
    t = np.arange(4000) / 2000.0
    v = 0.9 * np.sin(2 * np.pi * 3 * t)
    counts = np.round(v / q) * q
    assert lattice_step(counts) == pytest.approx(q, rel=1e-9)
    assert lattice_step(counts.astype(np.float32)) == pytest.approx(q, rel=1e-6)  # recorded as float32
    assert lattice_step(v.astype(np.float32)) is None
    assert lattice_step(v + 1e-3 * np.random.default_rng(0).standard_normal(v.size)) is None
    assert rounding_variance(counts, "auto") == pytest.approx(q**2 / 12, rel=1e-9)
    assert rounding_variance(v, "auto") == rounding_variance(v, "float32")
