"""A sensor slower than the loop: ages, the hold filter A(ω) and the compensated FRF."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import csd, lfilter, welch

from hil.identify.sensor_hold import age_distribution, ages, compensate_frf, held_outputs, hold_response


def test_ages_count_ticks_since_the_last_new_value() -> None:
    y = np.array([1.0, 1.0, 2.0, 3.0, 3.0, 3.0, 4.0])
    np.testing.assert_array_equal(ages(y), [0, 1, 0, 0, 1, 2, 0])


def test_fresh_or_constant_channels_are_not_held() -> None:
    rng = np.random.default_rng(0)
    assert age_distribution(rng.standard_normal(1000)) is None  # no repeats
    assert age_distribution(np.ones(1000)) is None  # constant (idle)
    stalled = np.repeat(rng.standard_normal(10), 100)  # a stalled sensor, not a slower one
    assert age_distribution(stalled) is None


def _held(x: np.ndarray, ratio: float, phase: float = 0.3) -> np.ndarray:
    """x sampled by a sensor at fs·ratio (not phase-locked) and held until its next sample, the
    sample taken at the latest tick (the value the sensor reads at its instant)."""
    n = x.size
    t_sensor = (np.arange(int(n * ratio) + 2) + phase) / ratio  # sensor instants in ticks
    idx = np.floor(t_sensor).astype(int)
    idx = idx[idx < n]
    out = np.empty_like(x)
    j = 0
    for i in range(n):
        while j + 1 < idx.size and idx[j + 1] <= i:
            j += 1
        out[i] = x[idx[j]] if idx[0] <= i else x[0]
    return out


def test_hold_response_closed_form_at_half_rate() -> None:
    """p = (1/2, 1/2): A = (1 + e^{-jω/fs})/2 = cos(ω/2fs) e^{-jω/2fs}."""
    fs = 2000.0
    w = 2 * np.pi * np.array([10.0, 100.0, 200.0, 400.0])
    A = hold_response([0.5, 0.5], w, fs)
    np.testing.assert_allclose(A, np.cos(w / (2 * fs)) * np.exp(-1j * w / (2 * fs)), rtol=1e-12)
    rng = np.random.default_rng(1)
    y = _held(rng.standard_normal(20000), 1003.92 / 2000.0)
    p = age_distribution(y)
    assert p is not None and p.size == 2 and p[0] == pytest.approx(0.502, abs=0.005)


def test_compensated_frf_recovers_the_true_response() -> None:
    """A second-order filter's output through a 1004 Hz sensor at fs = 2 kHz: the H1 of the held
    output is biased by A(ω) (0.16 rad at 200 Hz); divided by A it matches the true response to
    the estimate's own scatter (1 % here)."""
    from dataclasses import dataclass

    fs = 2000.0
    rng = np.random.default_rng(2)
    u = rng.standard_normal(400_000)
    b, a = [0.02, 0.04, 0.02], [1.0, -1.56, 0.64]  # a resonant low-pass (digital, exact)
    y = lfilter(b, a, u)
    yh = _held(y, 1003.92 / fs)
    f, Puy = csd(u, yh, fs=fs, nperseg=2000)
    _, Puu = welch(u, fs=fs, nperseg=2000)
    H = Puy / Puu
    z = np.exp(1j * 2 * np.pi * f / fs)
    true = np.polyval(b[::-1], 1 / z) / np.polyval(a[::-1], 1 / z)
    band = (f > 5) & (f < 300)

    @dataclass
    class Est:
        f: np.ndarray
        H: np.ndarray
        sigma: np.ndarray
        output_names: tuple[str, ...] = ("force",)

    p = held_outputs([(u[:, None], yh[:, None])], ["force"])
    assert set(p) == {"force"}
    est = compensate_frf(Est(f, H[:, None, None], np.ones((f.size, 1, 1))), p, fs)
    raw_err = np.max(np.abs(H[band] / true[band] - 1))
    fixed_err = np.max(np.abs(est.H[band, 0, 0] / true[band] - 1))
    assert raw_err > 0.1  # the hold's bias is large
    assert fixed_err < 0.02, fixed_err
