"""Synthetic chirp data for the identification tests (seeded, exact discretization).

The plants are simulated from their own state-space equations written here (independently of the
transfer functions in ``hil.identify.models``, so the tests also check those derivations).

Simulation: the input is the continuous chirp evaluated on a grid ``oversample`` times finer than
the measurement rate; the state-space model is discretized exactly for piecewise-linear inputs
(``scipy.signal.cont2discrete(method="foh")``) and filtered with second-order sections; the
outputs are then sampled at the measurement rate and white Gaussian noise is added. The sampled
input/output pairs then follow the continuous-time FRF up to an interpolation error of order
``(w T_fine)^2 / 12`` (< 1e-4 here), far below the noise. (A zero-order hold at the measurement
rate would add the DAC's half-sample delay and sinc droop, which the grey-box model would need as
a nuisance delay.)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy import signal

SDEA_TRUTH = {"K_f": 362.0, "B_f": 0.05, "M": 6.399e-4, "B": 0.169}

#: 2-DOF device with cross-coupled M, B, K (SI units, translational): modes near 10 and 25 Hz.
MBK_TRUTH = {
    "M": np.array([[1.0, 0.2], [0.2, 0.6]]),
    "B": np.array([[8.0, -2.0], [-2.0, 6.0]]),
    "K": np.array([[6000.0, -2500.0], [-2500.0, 9000.0]]),
}


@dataclass
class SimRecord:
    """One simulated experiment: ``t`` [s], ``u`` (n, n_in), ``y`` (n, n_out) noisy, noise std."""

    t: NDArray[np.float64]
    u: NDArray[np.float64]
    y: NDArray[np.float64]
    fs: float
    noise_std: NDArray[np.float64]


def sdea_locked_ss(K_f: float, B_f: float, M: float, B: float) -> tuple[NDArray, ...]:
    """State x = [angle, velocity]; M v' = tau - (B + B_f) v - K_f x; outputs [v, F = K_f x + B_f v]."""
    A = np.array([[0.0, 1.0], [-K_f / M, -(B + B_f) / M]])
    Bm = np.array([[0.0], [1.0 / M]])
    C = np.array([[0.0, 1.0], [K_f, B_f]])
    D = np.zeros((2, 1))
    return A, Bm, C, D


def mbk_ss(M: NDArray, B: NDArray, K: NDArray) -> tuple[NDArray, ...]:
    """State [q, q']; M q'' + B q' + K q = f; outputs q' (velocities)."""
    n = M.shape[0]
    Mi = np.linalg.inv(M)
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-Mi @ K, -Mi @ B]])
    Bm = np.vstack([np.zeros((n, n)), Mi])
    C = np.hstack([np.zeros((n, n)), np.eye(n)])
    return A, Bm, C, np.zeros((n, n))


def simulate(
    ss: Sequence[NDArray],
    u_fine: NDArray[np.float64],
    fs_fine: float,
    oversample: int,
) -> NDArray[np.float64]:
    """Noise-free outputs (n_fine, n_out) of the continuous system for the piecewise-linear input."""
    A, Bm, C, D = ss
    Ad, Bd, Cd, Dd, _ = signal.cont2discrete((A, Bm, C, D), 1.0 / fs_fine, method="foh")
    n_out, n_in = Cd.shape[0], Bd.shape[1]
    y = np.zeros((u_fine.shape[0], n_out))
    for i in range(n_in):
        if not np.any(u_fine[:, i]):
            continue
        for o in range(n_out):
            z, p, k = signal.ss2zpk(Ad, Bd, Cd[o : o + 1], Dd[o : o + 1], input=i)
            sos = signal.zpk2sos(np.atleast_1d(z).ravel(), p, float(np.atleast_1d(k).ravel()[0]))
            y[:, o] += signal.sosfilt(sos, u_fine[:, i])
    return y


def periodic_chirp(n_fine: int, fs_fine: float, f0: float, f1: float, amplitude: float, f_cut: float) -> NDArray:
    """One period (``n_fine`` samples) of a linear chirp f0 -> f1, band-limited below ``f_cut`` [Hz].

    The band limit (zeroing the DFT bins above ``f_cut``) makes the periodic signal smooth across the
    period wrap, so nothing aliases when it is sampled at the measurement rate.
    """
    period = n_fine / fs_fine
    t = np.arange(n_fine) / fs_fine
    x = amplitude * signal.chirp(t, f0, period, f1, method="linear", phi=-90)
    X = np.fft.rfft(x)
    X[np.fft.rfftfreq(n_fine, 1 / fs_fine) > f_cut] = 0.0
    return np.fft.irfft(X, n_fine)


def chirp_experiment(
    ss: Sequence[NDArray],
    *,
    n_in: int,
    excite: int,
    fs: float,
    period: float,
    n_periods: int,
    f0: float,
    f1: float,
    amplitude: float,
    noise_std: Sequence[float],
    rng: np.random.Generator,
    oversample: int = 16,
) -> SimRecord:
    """Periodic chirp on input ``excite`` (others zero), ``n_periods`` periods in steady state.

    One extra period is simulated first and dropped (the start-up transient), as a real experiment
    starts recording after the first period. Segments of one period then give leakage-free H1.
    """
    n_per = round(period * fs)
    fs_fine = fs * oversample
    one = periodic_chirp(n_per * oversample, fs_fine, f0, f1, amplitude, 0.45 * fs)
    u_fine = np.zeros(((n_periods + 1) * one.size, n_in))
    u_fine[:, excite] = np.tile(one, n_periods + 1)
    y_fine = simulate(ss, u_fine, fs_fine, oversample)
    keep = slice(one.size, None, oversample)
    u = u_fine[keep]
    y_clean = y_fine[keep]
    sd = np.asarray(noise_std, float)
    y = y_clean + rng.standard_normal(y_clean.shape) * sd
    t = np.arange(u.shape[0]) / fs
    return SimRecord(t, u, y, fs, sd)


# ---------------------------------------------------------------------------------------- standard setups
SDEA_SETUP = {
    "fs": 2000.0,
    "period": 0.5,  # s; Welch segment = one period (nperseg = period * fs)
    "n_periods": 16,
    "f0": 2.0,
    "f1": 450.0,
    "amplitude": 0.5,
    "noise_std": (0.05, 0.02),  # velocity [rad/s], spring torque [N.m]
    "nperseg": 1000,
    "band": (5.0, 400.0),
}

MBK_SETUP = {
    "fs": 500.0,
    "period": 5.0,
    "n_periods": 6,
    "f0": 0.5,
    "f1": 60.0,
    "amplitude": 20.0,
    "noise_std": (0.004, 0.004),  # velocities [m/s]
    "nperseg": 2500,
    "band": (2.0, 50.0),
}


def make_sdea_record(seed: int, **override: float) -> SimRecord:
    """Locked-output SDEA chirp record with motor velocity and spring force (truth: ``SDEA_TRUTH``)."""
    cfg = {**SDEA_SETUP, **override}
    rng = np.random.default_rng(seed)
    return chirp_experiment(
        sdea_locked_ss(**SDEA_TRUTH),
        n_in=1,
        excite=0,
        fs=cfg["fs"],
        period=cfg["period"],
        n_periods=int(cfg["n_periods"]),
        f0=cfg["f0"],
        f1=cfg["f1"],
        amplitude=cfg["amplitude"],
        noise_std=cfg["noise_std"],
        rng=rng,
    )


def make_mbk_records(seed: int, **override: float) -> list[SimRecord]:
    """Two experiments on the 2-DOF device, one chirp per force input; both velocities measured."""
    cfg = {**MBK_SETUP, **override}
    rng = np.random.default_rng(seed)
    ss = mbk_ss(MBK_TRUTH["M"], MBK_TRUTH["B"], MBK_TRUTH["K"])
    return [
        chirp_experiment(
            ss,
            n_in=2,
            excite=i,
            fs=cfg["fs"],
            period=cfg["period"],
            n_periods=int(cfg["n_periods"]),
            f0=cfg["f0"],
            f1=cfg["f1"],
            amplitude=cfg["amplitude"],
            noise_std=cfg["noise_std"],
            rng=rng,
        )
        for i in range(2)
    ]


@pytest.fixture(scope="session")
def sdea_record() -> SimRecord:
    return make_sdea_record(seed=1234)


@pytest.fixture(scope="session")
def mbk_records() -> list[SimRecord]:
    return make_mbk_records(seed=4321)


# ------------------------------------------------------------------ non-periodic records (issue 12)
NONPERIODIC_SETUP = {
    "fs": 5000.0,
    "duration": 4.0,  # s of record
    "pre_roll": 0.1,  # s simulated before the record starts (the record begins mid-motion)
    "f0": 1.0,
    "f1": 400.0,  # log chirp f0 -> f1 over pre_roll + duration (not periodic, stops mid-sweep end)
    "amplitude": 0.5,  # N.m
    "band": (1.0, 1000.0),
}


def make_nonperiodic_record(
    ss: Sequence[NDArray],
    seed: int,
    noise: float,
    *,
    n_in: int = 1,
    **override: float,
) -> SimRecord:
    """One-shot (non-periodic) logarithmic chirp through the plant ``ss`` behind a zero-order hold at
    ``fs``, simulated with the suite's exact ZOH discretization (:mod:`hil.lti`, independent of
    the identification models' modal formulas). With ``n_in`` > 1 every input gets its own chirp
    (sweeps of different phase and direction, so the inputs are not collinear). ``noise``: white
    Gaussian noise std as a fraction of each noise-free output's RMS."""
    from hil.lti import StateSpace

    cfg = {**NONPERIODIC_SETUP, **override}
    rng = np.random.default_rng(seed)
    fs = float(cfg["fs"])
    n_pre = round(cfg["pre_roll"] * fs)
    n = round(cfg["duration"] * fs)
    t_all = np.arange(n_pre + n) / fs
    T = t_all[-1]
    cols = []
    for i in range(n_in):
        if i % 2 == 0:
            cols.append(cfg["amplitude"] * signal.chirp(t_all, cfg["f0"], T, cfg["f1"], method="logarithmic",
                                                        phi=-90 + 60 * i))
        else:  # downward sweep
            cols.append(cfg["amplitude"] * signal.chirp(T - t_all, cfg["f0"], T, cfg["f1"], method="logarithmic",
                                                        phi=30 * i))
    u_all = np.column_stack(cols)
    A, Bm, C, D = ss
    _, y_all = StateSpace(A, Bm, C, D).discretize(1.0 / fs, "zoh").simulate(u_all)
    u, y_clean = u_all[n_pre:], y_all[n_pre:]
    sd = noise * np.sqrt(np.mean(y_clean**2, axis=0))
    y = y_clean + rng.standard_normal(y_clean.shape) * sd
    return SimRecord(np.arange(n) / fs, u, y, fs, sd)


def make_multisine_record(
    ss: Sequence[NDArray],
    seed: int,
    noise: float,
    *,
    fs: float = 500.0,
    duration: float = 3.0,
    period: float = 1.7,
    pre_roll: float = 0.5,
    f0: float = 0.5,
    f1: float = 80.0,
    rms: float = 20.0,
    n_in: int = 2,
    phase_seed: int = 0,
) -> SimRecord:
    """A random-phase multisine through the plant ``ss`` behind a zero-order hold at ``fs`` (the suite's
    exact ZOH discretization), NOT periodic in the record: the multisine's period ``period`` does not
    divide ``duration`` and the record starts ``pre_roll`` s into the motion, so every DFT bin of the
    record carries leakage and a transient. Inputs take zippered lines of the ``1/period`` grid in
    ``[f0, f1]`` (input i every ``n_in``-th line from line i), so they are never collinear; each input
    has RMS ``rms``. The phases come from ``phase_seed`` (the same excitation for every noise seed);
    ``noise`` is white Gaussian noise std as a fraction of each noise-free output's RMS (``seed``)."""
    from hil.lti import StateSpace

    rng_p = np.random.default_rng(phase_seed)
    n_pre, n = round(pre_roll * fs), round(duration * fs)
    t_all = np.arange(n_pre + n) / fs
    lines = np.arange(max(1, int(np.ceil(f0 * period))), int(np.floor(f1 * period)) + 1) / period
    cols = []
    for i in range(n_in):
        f = lines[i::n_in]
        ph = rng_p.uniform(0, 2 * np.pi, f.size)
        x = np.cos(2 * np.pi * np.outer(t_all, f) + ph).sum(axis=1)
        cols.append(rms * x / np.sqrt(np.mean(x**2)))
    u_all = np.column_stack(cols)
    A, Bm, C, D = ss
    _, y_all = StateSpace(A, Bm, C, D).discretize(1.0 / fs, "zoh").simulate(u_all)
    u, y_clean = u_all[n_pre:], y_all[n_pre:]
    sd = noise * np.sqrt(np.mean(y_clean**2, axis=0))
    y = y_clean + np.random.default_rng(seed).standard_normal(y_clean.shape) * sd
    return SimRecord(np.arange(n) / fs, u, y, fs, sd)


def sample_and_hold(y: NDArray[np.float64], fs: float, rate: float, phase: float = 0.37) -> NDArray[np.float64]:
    """``y`` (n,) as a sensor streaming at ``rate`` < ``fs`` [Hz] leaves it in a record taken at ``fs``: the
    value is new at the ticks where a sensor sample fell since the previous tick (the sensor's clock runs
    free: at 1004 Hz in a 2 kHz loop the ages are mostly 0,1 with a 0,0 every ~250 ticks) and equals the
    signal at that tick; elsewhere the previous value is held (noise included)."""
    i = np.arange(y.size)
    new = np.ones(y.size, dtype=bool)
    new[1:] = np.floor(i[1:] * rate / fs + phase) > np.floor((i[1:] - 1) * rate / fs + phase)
    last = np.maximum.accumulate(np.where(new, i, 0))
    return y[last]


def sdea_compliant_mount_ss(
    K_f: float, B_f: float, M: float, B: float, *, m_e: float = 2e-3, f_e: float = 300.0, zeta: float = 0.02
) -> tuple[NDArray, ...]:
    """The "locked" SDEA whose end-effector is in fact held by a compliant mount: an end mass ``m_e``
    on a spring to ground resonating at ``f_e`` [Hz] with damping ratio ``zeta`` -- a resonance the
    locked-output model does not have. State [x_motor, x_end, v_motor, v_end]; outputs [v_motor,
    F = K_f (x_m - x_e) + B_f (v_m - v_e)]."""
    k_e = m_e * (2 * np.pi * f_e) ** 2
    b_e = 2 * zeta * np.sqrt(k_e * m_e)
    A = np.zeros((4, 4))
    A[0, 2] = A[1, 3] = 1.0
    A[2] = [-K_f / M, K_f / M, -(B + B_f) / M, B_f / M]
    A[3] = [K_f / m_e, -(K_f + k_e) / m_e, B_f / m_e, -(B_f + b_e) / m_e]
    Bm = np.array([[0.0], [0.0], [1.0 / M], [0.0]])
    C = np.array([[0.0, 0.0, 1.0, 0.0], [K_f, -K_f, B_f, -B_f]])
    return A, Bm, C, np.zeros((2, 1))
