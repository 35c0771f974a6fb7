"""Signal building blocks, computed from the tick index (exactly periodic in samples): raised-cosine
fades, chirps, Schroeder-phased multisines and their lines, crest factor."""

from __future__ import annotations

import math

import numpy as np

from hil.errors import SceneError


def raised_cosine_fade(n: int, n_fade: int) -> np.ndarray:
    """Window of ``n`` samples rising as ``(1 - cos(π i / n_fade))/2`` over the first ``n_fade``
    samples, 1 in the middle, mirrored at the end. ``n_fade = 0`` gives ones."""
    w = np.ones(n)
    if n_fade <= 0:
        return w
    n_fade = min(n_fade, n // 2)
    ramp = 0.5 * (1.0 - np.cos(np.pi * np.arange(n_fade) / n_fade))
    w[:n_fade] = ramp
    w[n - n_fade:] = ramp[::-1]
    return w


def chirp_signal(n: int, fs: float, f0: float, f1: float, sweep: str = "log") -> tuple[np.ndarray, np.ndarray]:
    """One sweep of ``n`` samples at ``fs`` Hz from ``f0`` to ``f1`` Hz, unit amplitude.

    Phase ``φ(τ)`` (``τ = i/fs``, sweep length ``P = n/fs``): linear
    ``2π (f0 τ + (f1 - f0) τ²/(2P))``, instantaneous frequency ``f0 + (f1 - f0) τ/P``; log
    ``2π f0 P (r^{τ/P} - 1)/ln r`` with ``r = f1/f0``, instantaneous frequency ``f0 r^{τ/P}``.
    Returns ``(sin φ, f_inst)``.
    """
    tau = np.arange(n) / fs
    P = n / fs
    if sweep == "linear":
        phase = 2 * np.pi * (f0 * tau + (f1 - f0) * tau**2 / (2 * P))
        finst = f0 + (f1 - f0) * tau / P
    elif sweep == "log":
        r = f1 / f0
        phase = 2 * np.pi * f0 * P * (np.power(r, tau / P) - 1.0) / math.log(r)
        finst = f0 * np.power(r, tau / P)
    else:
        raise SceneError(f"sweep: 'log' or 'linear', got {sweep!r}")
    return np.sin(phase), finst


def schroeder_phases(n_lines: int) -> np.ndarray:
    """Schroeder's low-crest-factor phases for ``n_lines`` equal-amplitude, equally spaced lines:
    ``φ_l = -π l (l - 1)/L``, ``l = 1..L`` (Schroeder 1970)."""
    ell = np.arange(1, n_lines + 1)
    return -np.pi * ell * (ell - 1) / n_lines


def multisine_lines(kmin: int, kmax: int, n_total: int, spacing: str = "linear") -> np.ndarray:
    """``n_total`` distinct harmonic indices spread over ``[kmin, kmax]`` (linear or log).
    Raises ValueError when they cannot be distinct."""
    if kmax < kmin or kmax - kmin + 1 < n_total:
        raise ValueError(f"only {max(kmax - kmin + 1, 0)} harmonics available, {n_total} needed")
    if spacing == "linear":
        idx = np.round(np.linspace(kmin, kmax, n_total)).astype(int)
    elif spacing == "log":
        idx = np.round(np.geomspace(max(kmin, 1), kmax, n_total)).astype(int)
    else:
        raise ValueError(f"spacing must be 'linear' or 'log', got {spacing!r}")
    if np.unique(idx).size != n_total:
        raise ValueError(f"{n_total} {spacing} lines collide on the harmonic grid [{kmin}, {kmax}]")
    return idx


def crest_factor(x: np.ndarray) -> float:
    """Peak over RMS."""
    x = np.asarray(x, dtype=float)
    return float(np.max(np.abs(x)) / np.sqrt(np.mean(x**2)))
