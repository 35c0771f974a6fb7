"""Synthetic locked-output SDEA records with a NON-periodic (one-shot) log chirp, as another tool logs them.

Truth: paper 002 Table I (``TRUTH``). The plant ``M x'' = tau - (B + B_f) x' - K_f x`` with outputs
motor velocity ``x'`` and spring torque ``K_f x + B_f x'`` is written here from its equations
(independently of :mod:`hil.identify.models`), discretized exactly for a piecewise-linear input on a
grid ``oversample`` times finer than the record (``scipy.signal.cont2discrete(method="foh")``), and
sampled; white Gaussian noise of ``noise`` x each output's RMS is added.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import signal

TRUTH = {"K_f": 362.0, "B_f": 0.05, "M": 6.399e-4, "B": 0.169}


@dataclass
class Chirp:
    t: NDArray[np.float64]
    u: NDArray[np.float64]  # motor torque command [N.m]
    v: NDArray[np.float64]  # motor velocity [rad/s]
    f: NDArray[np.float64]  # spring torque [N.m]
    noise_std: tuple[float, float]  # (velocity, force)


def log_chirp_record(seed: int, f0: float, f1: float, *, fs: float = 5000.0, duration: float = 4.0,
                     amplitude: float = 0.5, noise: float = 0.01, oversample: int = 8) -> Chirp:
    """One-shot log chirp ``f0 -> f1`` [Hz] over ``duration`` [s], starting at rest (not periodic)."""
    K, Bf, M, B = (TRUTH[k] for k in ("K_f", "B_f", "M", "B"))
    A = np.array([[0.0, 1.0], [-K / M, -(B + Bf) / M]])
    Bm = np.array([[0.0], [1.0 / M]])
    C = np.array([[0.0, 1.0], [K, Bf]])
    fs_fine = fs * oversample
    tf = np.arange(round(duration * fs_fine)) / fs_fine
    u = amplitude * signal.chirp(tf, f0, duration, f1, method="logarithmic", phi=-90)
    Ad, Bd, Cd, Dd, _ = signal.cont2discrete((A, Bm, C, np.zeros((2, 1))), 1.0 / fs_fine, method="foh")
    y = np.zeros((u.size, 2))
    for o in range(2):  # filter form of the exact discretization (zero initial state: at rest)
        z, p, k = signal.ss2zpk(Ad, Bd, Cd[o : o + 1], Dd[o : o + 1])
        y[:, o] = signal.sosfilt(signal.zpk2sos(np.atleast_1d(z).ravel(), p, float(np.ravel(k)[0])), u)
    u, y = u[::oversample], y[::oversample]
    rng = np.random.default_rng(seed)
    sd = noise * np.sqrt(np.mean(y**2, axis=0))
    y = y + rng.standard_normal(y.shape) * sd
    return Chirp(np.arange(u.size) / fs, u, y[:, 0], y[:, 1], (float(sd[0]), float(sd[1])))
