"""Frequency-response estimation from time series (chirp records): H1, coherence, FRF variance.

Conventions
-----------
* Spectra are one-sided densities from :func:`scipy.signal.csd` / :func:`scipy.signal.welch`;
  ``csd(x, y)`` is ``E[conj(X) Y]``.
* ``H[k, o, i]`` is the FRF from input ``i`` to output ``o`` at frequency ``f[k]`` [Hz].
* MIMO H1 (Bendat & Piersol, *Random Data*, 4th ed., ch. 7): with the input cross-spectral matrix
  ``Gxx[i, j] = E[X_i conj(X_j)]`` and ``Gyx[o, i] = E[Y_o conj(X_i)]``, ``H Gxx = Gyx``. Several
  experiments (e.g. one chirp per input) are stacked by summing their segment-weighted spectral
  matrices before solving, so each experiment may excite only one input.
* Residual (noise) spectrum ``Gvv_o = Gyy_oo - H_o Gxx H_o^H`` and multiple coherence
  ``gamma_o^2 = 1 - Gvv_o / Gyy_oo``.
* FRF variance (Bendat & Piersol, 4th ed., sec. 9.2.4/9.3: normalized random error of ``|H1|`` is
  ``sqrt(1 - gamma^2) / (|gamma| sqrt(2 n_d))``, i.e. ``var|H| ~ (1-gamma^2) / (2 n_d gamma^2) |H|^2``).
  In the MIMO form used here ``E|dH_oi|^2 = Gvv_o [Gxx^-1]_ii / n_d`` which reduces to the same
  expression for one input; the real and imaginary parts each carry half of it:
  ``sigma[k, o, i]`` is that per-component standard deviation. ``Gvv`` is corrected for the
  ``n_inputs`` complex degrees of freedom spent on ``H`` and its own uncertainty is summarized by
  ``dof = 2 (n_d - n_inputs)`` (used by a Student-t likelihood in :mod:`posterior`).

Default window: rectangular segments without overlap. With a burst/chirp input and segments much
longer than the impulse-response decay, the DFT bins of different segments and frequencies then
carry independent noise, so the per-bin variances above can be multiplied across bins in a
likelihood (Hann windows with overlap correlate neighbouring bins by ~2/3 and would overstate the
information by up to ~2x). Pass ``window="hann"`` for lightly damped systems with short records.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import signal

from hil.identify.errors import DataQualityError

logger = logging.getLogger(__name__)

__all__ = [
    "FrfEstimate",
    "LinearityReport",
    "compare_frfs",
    "estimate_frf",
    "harmonic_distortion",
    "welch_effective_averages",
]


@dataclass
class FrfEstimate:
    """An H1 FRF estimate with its coherence and per-bin uncertainty.

    Attributes: ``f`` [Hz] (n_f,), ``H`` (n_f, n_out, n_in) complex, ``coherence`` multiple coherence
    per output (n_f, n_out), ``sigma`` per-component (real/imag) std of ``H`` (n_f, n_out, n_in),
    ``Gxx`` input spectral matrix (n_f, n_in, n_in), ``Gyy`` output auto-spectra (n_f, n_out),
    ``Gvv`` residual noise spectra (n_f, n_out), ``n_avg`` effective number of averages,
    ``dof`` degrees of freedom of the variance estimate, ``fs`` [Hz], ``nperseg``.
    """

    f: NDArray[np.float64]
    H: NDArray[np.complex128]
    coherence: NDArray[np.float64]
    sigma: NDArray[np.float64]
    Gxx: NDArray[np.complex128]
    Gyy: NDArray[np.float64]
    Gvv: NDArray[np.float64]
    n_avg: float
    dof: float
    fs: float
    nperseg: int
    input_names: tuple[str, ...] = ()
    output_names: tuple[str, ...] = ()
    meta: dict[str, object] = field(default_factory=dict)

    @property
    def w(self) -> NDArray[np.float64]:
        """Angular frequencies [rad/s]."""
        return 2 * np.pi * self.f

    @property
    def n_bins(self) -> int:
        return int(self.f.size)

    def band(self, f_min: float | None = None, f_max: float | None = None) -> FrfEstimate:
        """Copy restricted to ``f_min <= f <= f_max`` [Hz] (DC always excluded)."""
        lo = 0.0 if f_min is None else f_min
        hi = np.inf if f_max is None else f_max
        m = (self.f >= lo) & (self.f <= hi) & (self.f > 0)
        if not np.any(m):
            raise DataQualityError(
                f"no frequency bin in band [{lo}, {hi}] Hz (resolution {self.fs / self.nperseg:g} Hz)"
            )
        return self._mask(m)

    def channels(self, outputs: Sequence[str]) -> FrfEstimate:
        """Copy restricted to the named outputs (in that order)."""
        idx = [self.output_names.index(o) for o in outputs]
        return replace(
            self,
            H=self.H[:, idx],
            coherence=self.coherence[:, idx],
            sigma=self.sigma[:, idx],
            Gyy=self.Gyy[:, idx],
            Gvv=self.Gvv[:, idx],
            output_names=tuple(outputs),
        )

    def _mask(self, m: NDArray[np.bool_]) -> FrfEstimate:
        return replace(
            self,
            f=self.f[m],
            H=self.H[m],
            coherence=self.coherence[m],
            sigma=self.sigma[m],
            Gxx=self.Gxx[m],
            Gyy=self.Gyy[m],
            Gvv=self.Gvv[m],
        )


def welch_effective_averages(
    n_samples: int, nperseg: int, noverlap: int, window: str | tuple = "boxcar"
) -> tuple[int, float]:
    """Number of Welch segments and the effective number of independent averages.

    For white noise the variance of Welch's average of ``K`` overlapping segments is
    ``(1/K) [1 + 2 sum_{j>=1} (1 - j/K) rho_j^2]`` (Welch 1967) with ``rho_j`` the window's overlap
    correlation at a shift of ``j`` steps. Returns ``(K, K_eff)``.
    """
    step = nperseg - noverlap
    K = max((n_samples - nperseg) // step + 1, 0)
    if K <= 1:
        return K, float(K)
    win = signal.get_window(window, nperseg)
    denom = float(np.sum(win**2))
    acc = 0.0
    for j in range(1, K):
        shift = j * step
        if shift >= nperseg:
            break
        rho = float(np.sum(win[: nperseg - shift] * win[shift:])) / denom
        acc += (1 - j / K) * rho**2
    return K, K / (1 + 2 * acc)


def _as_2d(x: ArrayLike) -> NDArray[np.float64]:
    a = np.asarray(x, dtype=float)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2:
        raise DataQualityError(f"signals must be (n_samples,) or (n_samples, n_channels), got shape {a.shape}")
    return a


def estimate_frf(
    experiments: Sequence[tuple[ArrayLike, ArrayLike]],
    fs: float,
    *,
    nperseg: int,
    noverlap: int | None = None,
    window: str | tuple = "boxcar",
    detrend: str | bool = "constant",
    input_names: Sequence[str] | None = None,
    output_names: Sequence[str] | None = None,
) -> FrfEstimate:
    """MIMO H1 FRF from one or several experiments sharing the same inputs/outputs.

    ``experiments``: sequence of ``(u, y)`` with ``u`` (n, n_in) inputs and ``y`` (n, n_out) outputs
    sampled uniformly at ``fs`` [Hz] (1-D arrays mean one channel). Spectral matrices of each
    experiment are weighted by its number of Welch segments and summed, then ``H = Gyx Gxx^-1``.
    """
    if noverlap is None:
        noverlap = nperseg // 2 if window != "boxcar" else 0
    acc_xx = acc_yx = acc_yy = None
    K_tot = 0
    K_eff = 0.0
    f = np.empty(0)
    for u_raw, y_raw in experiments:
        u = _as_2d(u_raw)
        y = _as_2d(y_raw)
        if u.shape[0] != y.shape[0]:
            raise DataQualityError(f"input and output lengths differ: {u.shape[0]} vs {y.shape[0]}")
        if u.shape[0] < nperseg:
            raise DataQualityError(f"record of {u.shape[0]} samples is shorter than nperseg={nperseg}")
        if not (np.all(np.isfinite(u)) and np.all(np.isfinite(y))):
            raise DataQualityError("non-finite samples in the record: run the diagnostics first")
        uT, yT = u.T, y.T
        kw = dict(fs=fs, window=window, nperseg=nperseg, noverlap=noverlap, detrend=detrend, axis=-1)
        f, Gxx = signal.csd(uT[None, :, :], uT[:, None, :], **kw)  # [i, j] = E[X_i conj(X_j)]
        _, Gyx = signal.csd(uT[None, :, :], yT[:, None, :], **kw)  # [o, i] = E[Y_o conj(X_i)]
        _, Gyy = signal.welch(yT, **kw)
        K, Ke = welch_effective_averages(u.shape[0], nperseg, noverlap, window)
        if acc_xx is None:
            acc_xx, acc_yx, acc_yy = K * Gxx, K * Gyx, K * Gyy
        else:
            if Gxx.shape != acc_xx.shape or Gyx.shape != acc_yx.shape:
                raise DataQualityError("experiments have different numbers of inputs/outputs")
            acc_xx, acc_yx, acc_yy = acc_xx + K * Gxx, acc_yx + K * Gyx, acc_yy + K * Gyy
        K_tot += K
        K_eff += Ke
    if acc_xx is None or acc_yx is None or acc_yy is None:
        raise DataQualityError("no experiment given")
    Gxx = np.moveaxis(acc_xx / K_tot, -1, 0)  # (nf, ni, ni)
    Gyx = np.moveaxis(acc_yx / K_tot, -1, 0)  # (nf, no, ni)
    Gyy = np.moveaxis(acc_yy / K_tot, -1, 0).real  # (nf, no)
    ni, no = Gxx.shape[1], Gyx.shape[1]
    if K_eff <= ni:
        raise DataQualityError(
            f"only {K_eff:.1f} effective averages for {ni} inputs: use a smaller nperseg or a longer record"
        )
    # Solve H Gxx = Gyx per frequency; guard bins where the input matrix is singular (DC, unexcited).
    scale = np.maximum(np.abs(np.trace(Gxx, axis1=1, axis2=2)), np.finfo(float).tiny)
    cond_ok = np.linalg.cond(Gxx / scale[:, None, None]) < 1e10
    H = np.full(Gyx.shape, np.nan + 1j * np.nan)
    Ginv = np.full(Gxx.shape, np.nan + 1j * np.nan)
    if np.any(cond_ok):
        Ginv[cond_ok] = np.linalg.inv(Gxx[cond_ok])
        H[cond_ok] = Gyx[cond_ok] @ Ginv[cond_ok]
    explained = np.einsum("koi,kij,koj->ko", H, Gxx, H.conj()).real
    Gvv = np.clip(Gyy - explained, 0.0, None) * K_eff / (K_eff - ni)
    with np.errstate(invalid="ignore", divide="ignore"):
        coh = np.clip(1.0 - (Gyy - explained) / Gyy, 0.0, 1.0)
    inv_diag = np.real(np.diagonal(Ginv, axis1=1, axis2=2))  # (nf, ni)
    var_complex = Gvv[:, :, None] * inv_diag[:, None, :] / K_eff
    sigma = np.sqrt(np.clip(var_complex / 2.0, 0.0, None))
    ins = tuple(input_names) if input_names is not None else tuple(f"u{i}" for i in range(ni))
    outs = tuple(output_names) if output_names is not None else tuple(f"y{o}" for o in range(no))
    logger.debug("H1 estimate: %d bins, K=%d segments, K_eff=%.1f, %d inputs, %d outputs", f.size, K_tot, K_eff, ni, no)
    return FrfEstimate(
        f=f,
        H=H,
        coherence=np.nan_to_num(coh),
        sigma=sigma,
        Gxx=Gxx,
        Gyy=Gyy,
        Gvv=Gvv,
        n_avg=K_eff,
        dof=2.0 * (K_eff - ni),
        fs=float(fs),
        nperseg=int(nperseg),
        input_names=ins,
        output_names=outs,
        meta={"window": window, "noverlap": noverlap, "n_segments": K_tot, "n_experiments": len(experiments)},
    )


# ---------------------------------------------------------------------------------------------- linearity
@dataclass
class LinearityReport:
    """Outcome of a linearity check: ``ok`` is False when the data look unfit for a linear model."""

    ok: bool
    statistic: float
    threshold: float
    message: str
    details: dict[str, float] = field(default_factory=dict)


def compare_frfs(a: FrfEstimate, b: FrfEstimate, *, threshold: float | None = None) -> LinearityReport:
    """Compare FRFs measured at two excitation amplitudes (same frequency grid).

    For a linear system both estimate the same ``H``; ``|Ha - Hb|^2 / (sa^2 + sb^2)`` is then
    ~chi^2 with 2 dof per bin (``s`` per-component std), so ``stat = mean(...)/2`` is ~1 (a bit more
    with estimated variances). A stat above ``threshold`` (default ``max(2, 1 + 6/sqrt(N))``) flags
    an amplitude-dependent response (friction, backlash, saturation, stiffening spring...).
    """
    if a.H.shape != b.H.shape or not np.allclose(a.f, b.f):
        raise DataQualityError("FRFs to compare must share the frequency grid and channels")
    var = a.sigma**2 + b.sigma**2
    m = np.isfinite(a.H) & np.isfinite(b.H) & (var > 0)
    z2 = np.abs(a.H - b.H)[m] ** 2 / var[m]
    n = int(z2.size)
    stat = float(np.mean(z2) / 2.0) if n else float("nan")
    thr = threshold if threshold is not None else max(2.0, 1.0 + 6.0 / np.sqrt(max(n, 1)))
    rel = float(np.median(np.abs(a.H - b.H)[m] / np.maximum(np.abs(a.H[m]), 1e-300))) if n else float("nan")
    ok = bool(np.isfinite(stat) and stat <= thr)
    msg = (
        "FRFs at both amplitudes agree within their uncertainty (linear)"
        if ok
        else (
            f"FRF changes with amplitude: normalized mismatch {stat:.2f} > {thr:.2f} (median relative "
            f"difference {rel:.1%}): the device is not linear at these amplitudes; a linear model would be biased"
        )
    )
    return LinearityReport(ok, stat, thr, msg, {"median_relative_difference": rel, "n_bins": float(n)})


def harmonic_distortion(
    y: ArrayLike, fs: float, f0: float, *, n_harmonics: int = 5, threshold: float = 0.05
) -> LinearityReport:
    """Harmonic distortion ratio of a steady sine response at ``f0`` [Hz].

    Least-squares projection of ``y`` on ``cos/sin(2 pi k f0 t)``, ``k = 1..n_harmonics`` (plus a
    constant). ``HDR = sqrt(sum_{k>=2} A_k^2) / A_1``; above ``threshold`` the response is flagged as
    nonlinear at that amplitude.
    """
    yy = np.asarray(y, float)
    t = np.arange(yy.size) / fs
    ks = [k for k in range(1, n_harmonics + 1) if k * f0 < fs / 2]
    cols = [np.ones_like(t)]
    for k in ks:
        cols += [np.cos(2 * np.pi * k * f0 * t), np.sin(2 * np.pi * k * f0 * t)]
    A = np.stack(cols, axis=1)
    coef, *_ = np.linalg.lstsq(A, yy, rcond=None)
    amps = np.hypot(coef[1::2], coef[2::2])
    hdr = float(np.sqrt(np.sum(amps[1:] ** 2)) / max(amps[0], 1e-300))
    ok = hdr <= threshold
    msg = (
        f"harmonic distortion {hdr:.2%} <= {threshold:.0%}"
        if ok
        else f"harmonic distortion {hdr:.2%} > {threshold:.0%} at {f0:g} Hz: response is not linear at this amplitude"
    )
    return LinearityReport(ok, hdr, threshold, msg, {f"A{k}": float(a) for k, a in zip(ks, amps, strict=True)})
