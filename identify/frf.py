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
  ``dof = 2 (n_d - n_inputs)`` (used by a Student-t likelihood in :mod:`posterior`); per bin
  (``dof_map``) only the inputs excited at that bin count.

Per-bin excited inputs: a bin where an input carries no power (below ``1e-12`` of that input's
peak) does not take part in the solve there: only the columns of the excited inputs are estimated
(the others are NaN, "not measured"). A zippered multisine -- every line driven by exactly one
input -- thus gives one column per line and the full MIMO FRF over the lines in ONE experiment.

Rounding floor (``resolution``). Recorded values are rounded (float32 on the device buses: ODrive
CANSimple, Bota; integer counts on others). On an exactly periodic excitation the simulated (or a
very quiet real) response repeats sample for sample, so its rounding errors repeat too: they do
NOT average out over the periods and the period-to-period residual ``Gvv`` misses them (it can be
exactly zero). They are added as a known floor with the variance of uniform rounding,
``q = mean(step^2)/12`` per sample (step = the float's spacing at each value, or a fixed
quantization step), on the outputs AND on the inputs (errors in variables: the drive applies a
rounded command, which reaches the output through ``H``)::

    Gvv_floor[k, o] = (2 / fs) (q_o + sum_i |H_oi|^2 q_i)      (white, one-sided density)
    var H_oi  =  (Gvv_o / n_avg + Gvv_floor_o / n_exp) [Gxx^-1]_ii   (n_exp: number of experiments)

and the per-bin degrees of freedom of that variance follow Welch-Satterthwaite
(``dof_map = dof * var^2 / var_random^2``: a known floor has infinitely many).

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
    "rounding_variance",
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
    dof_map: NDArray[np.float64] | None = None  # per-entry dof of sigma^2 (n_f, n_out, n_in); None: ``dof``

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
            dof_map=None if self.dof_map is None else self.dof_map[:, idx],
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
            dof_map=None if self.dof_map is None else self.dof_map[m],
        )

    @property
    def nu(self) -> NDArray[np.float64]:
        """Degrees of freedom of ``sigma^2`` per entry (n_f, n_out, n_in)."""
        if self.dof_map is not None:
            return self.dof_map
        return np.full(self.H.shape, float(self.dof))


#: spacing of the float formats, relative: variance of rounding computed from np.spacing
_FLOAT_FORMATS = {"float16": np.float16, "float32": np.float32, "float64": np.float64}

Resolution = str | float | None


def lattice_step(x: ArrayLike, *, min_ratio: float = 100.0) -> float | None:
    """The quantization step ``q`` of a signal recorded in whole units (a drive reporting velocity in
    encoder counts per second), or None: every value sits on a lattice of spacing ``q`` (within 1 % of
    ``q``; ``q`` from the smallest gaps between distinct values, refined over the whole span) and ``q``
    is at least ``min_ratio`` times the median float32 spacing of the signal (float32 values
    themselves are multiples of their smallest spacing: that is not a quantizer). Needs at least 8
    distinct values."""
    a = np.asarray(x, dtype=float).ravel()
    a = a[np.isfinite(a)]
    u = np.unique(a)
    if u.size >= 2:  # values equal up to float rounding (a derivative of counts: 1e-18 apart) are one level
        keep = np.concatenate([[True], np.diff(u) > 1e-9 * max(float(np.ptp(u)), 1e-300)])
        u = u[keep]
    if u.size < 8:
        return None
    d = np.diff(u)
    q0 = float(np.min(d))
    if not q0 > 0:
        return None
    # refine (values recorded as float32 sit within their spacing of the lattice): the adjacent gaps, then
    # the whole span over the count of steps (each gap's count is a small exact integer)
    q1 = float(np.median(d[d < 1.5 * q0]))
    n = np.round(d / q1)
    if np.any(n < 1):
        return None
    q = float(np.sum(d) / np.sum(n))
    k = (u - u[0]) / q
    if float(np.max(np.abs(k - np.round(k)))) > 1e-2:
        return None
    sp32 = float(np.median(np.spacing(np.abs(a).astype(np.float32)).astype(float)))
    return q if q >= min_ratio * sp32 else None


def rounding_variance(x: ArrayLike, resolution: Resolution, *, grid: bool = True) -> float:
    """Mean per-sample variance of the rounding error of ``x`` at ``resolution``.

    ``"float32"`` (or ``float16``/``float64``): round to nearest in that format, error uniform over
    one spacing ``np.spacing(x)`` -> ``mean(spacing^2)/12``, or ``q^2/12`` when that is larger and
    the samples sit on a uniform grid of step ``q``
    (:func:`hil.identify.diagnostics.quantization_step`: an integer wire unit such as encoder
    counts/s or per-mille torque, decoded to SI before it was stored); a number: a fixed
    quantization step ``q`` -> ``q^2/12``; None/0: no rounding; ``"auto"``: the step of
    :func:`lattice_step` when the signal is quantized (``q^2/12``), else float32. ``grid=False``: no grid detection
    (the recorded input of a drive with integer units is the value it applies: hil.run.runner records
    the effort as encoded on the wire, so its grid is not a rounding error).
    """
    if resolution is None:
        return 0.0
    a = np.asarray(x, dtype=float)
    a = a[np.isfinite(a)]
    if resolution == "auto":
        q = lattice_step(a)
        return rounding_variance(a, "float32") if q is None else q**2 / 12.0
    if isinstance(resolution, str):
        fmt = _FLOAT_FORMATS.get(resolution)
        if fmt is None:
            raise DataQualityError(f"unknown resolution {resolution!r}: use float16/float32/float64 or a step")
        if a.size == 0:
            return 0.0
        with np.errstate(over="ignore"):
            sp = np.spacing(np.abs(a).astype(fmt)).astype(float)
        from hil.identify.diagnostics import quantization_step  # (diagnostics imports this module)

        step = quantization_step(a) if grid else 0.0
        return max(float(np.mean(sp**2) / 12.0), step**2 / 12.0)
    step = float(resolution)
    if not np.isfinite(step) or step < 0:
        raise DataQualityError(f"quantization step must be >= 0, got {resolution!r}")
    return step**2 / 12.0


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
    resolution: Resolution | Sequence[Resolution] = None,
    input_resolution: Resolution | Sequence[Resolution] = None,
    excited_tol: float = 1e-12,
) -> FrfEstimate:
    """MIMO H1 FRF from one or several experiments sharing the same inputs/outputs.

    ``experiments``: sequence of ``(u, y)`` with ``u`` (n, n_in) inputs and ``y`` (n, n_out) outputs
    sampled uniformly at ``fs`` [Hz] (1-D arrays mean one channel). Spectral matrices of each
    experiment are weighted by its number of Welch segments and summed, then ``H = Gyx Gxx^-1``
    per bin over the inputs excited there (module docstring). ``resolution`` / ``input_resolution``:
    rounding of the outputs / inputs (one spec for all or one per channel, see
    :func:`rounding_variance`) added to the FRF variance as a floor that periods do not average.
    """
    if noverlap is None:
        noverlap = nperseg // 2 if window != "boxcar" else 0
    acc_xx = acc_yx = acc_yy = None
    data: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []
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
        data.append((u, y))
        uT, yT = u.T, y.T
        kw = dict(fs=fs, window=window, nperseg=nperseg, noverlap=noverlap, detrend=detrend, axis=-1)
        f, Gxx = signal.csd(uT[None, :, :], uT[:, None, :], **kw)  # [i, j] = E[X_i conj(X_j)]
        _, Gyx = signal.csd(uT[None, :, :], yT[:, None, :], **kw)  # [o, i] = E[Y_o conj(X_i)]
        _, Gyy = signal.welch(yT, **kw)
        K, Ke = welch_effective_averages(u.shape[0], nperseg, noverlap, window)
        if acc_xx is None or acc_yx is None or acc_yy is None:
            acc_xx, acc_yx, acc_yy = K * Gxx, K * Gyx, K * Gyy
        else:
            assert acc_yx is not None and acc_yy is not None  # set together with acc_xx
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
    # Solve H Gxx = Gyx per frequency over the inputs excited there; guard singular input matrices.
    pw = np.real(np.diagonal(Gxx, axis1=1, axis2=2))  # (nf, ni) input power
    excited = pw > excited_tol * np.maximum(np.max(pw, axis=0), np.finfo(float).tiny)
    H = np.full(Gyx.shape, np.nan + 1j * np.nan)
    Ginv = np.full(Gxx.shape, np.nan + 1j * np.nan)
    explained = np.zeros(Gyy.shape)  # unexcited bins: nothing explained (coherence 0, H NaN)
    patterns = {tuple(row) for row in excited}
    for pat in patterns:
        sel = np.flatnonzero(pat)
        if sel.size == 0:
            continue
        rows = np.flatnonzero(np.all(excited == np.asarray(pat), axis=1))
        G = Gxx[np.ix_(rows, sel, sel)]
        scale = np.maximum(np.abs(np.trace(G, axis1=1, axis2=2)), np.finfo(float).tiny)
        good = rows[np.linalg.cond(G / scale[:, None, None]) < 1e10]
        if good.size == 0:
            continue
        Gi = np.linalg.inv(Gxx[np.ix_(good, sel, sel)])
        Hs = Gyx[np.ix_(good, np.arange(no), sel)] @ Gi
        H[np.ix_(good, np.arange(no), sel)] = Hs
        Ginv[np.ix_(good, sel, sel)] = Gi
        explained[good] = np.einsum("koi,kij,koj->ko", Hs, Gxx[np.ix_(good, sel, sel)], Hs.conj()).real
    Gvv = np.clip(Gyy - explained, 0.0, None) * K_eff / (K_eff - ni)
    with np.errstate(invalid="ignore", divide="ignore"):
        coh = np.clip(1.0 - (Gyy - explained) / Gyy, 0.0, 1.0)
    inv_diag = np.real(np.diagonal(Ginv, axis1=1, axis2=2))  # (nf, ni), NaN where not excited
    var_rand = Gvv[:, :, None] * inv_diag[:, None, :] / K_eff
    # rounding floor (module docstring): white, repeated in every period -> not averaged
    q_out = _per_channel(resolution, no, "resolution")
    q_in = _per_channel(input_resolution, ni, "input_resolution")
    qo = np.array([np.mean([rounding_variance(yy[:, o], q_out[o]) for _, yy in data]) for o in range(no)])
    qi = np.array([np.mean([rounding_variance(uu[:, i], q_in[i], grid=False) for uu, _ in data]) for i in range(ni)])
    floor = None
    if np.any(qo > 0) or np.any(qi > 0):
        Hz = np.nan_to_num(H)
        g_floor = (2.0 / fs) * (qo[None, :] + np.einsum("koi,i->ko", np.abs(Hz) ** 2, qi))  # (nf, no)
        floor = g_floor[:, :, None] * inv_diag[:, None, :] / len(data)
    var_complex = var_rand if floor is None else var_rand + floor
    sigma = np.sqrt(np.clip(var_complex / 2.0, 0.0, None))
    dof = 2.0 * (K_eff - ni)
    # per bin: the residual spends one complex dof per input EXCITED there (zippered lines: one)
    n_exc = np.maximum(np.sum(excited, axis=1), 1)
    dof_bins = np.broadcast_to((2.0 * (K_eff - n_exc))[:, None, None], H.shape).copy()
    if floor is not None:
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = np.minimum(var_complex / np.maximum(var_rand, 1e-300), 1e6)
            dof_bins = np.minimum(dof_bins * ratio**2, 1e6)
    dof_map = None if np.all(dof_bins == dof) else dof_bins
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
        dof=dof,
        fs=float(fs),
        nperseg=int(nperseg),
        input_names=ins,
        output_names=outs,
        meta={
            "window": window,
            "noverlap": noverlap,
            "n_segments": K_tot,
            "n_experiments": len(experiments),
            "rounding_variance": {"outputs": qo.tolist(), "inputs": qi.tolist()},
        },
        dof_map=dof_map,
    )


def _per_channel(spec: Resolution | Sequence[Resolution], n: int, what: str) -> list[Resolution]:
    if spec is None or isinstance(spec, str | int | float):
        return [spec] * n
    out = list(spec)
    if len(out) != n:
        raise DataQualityError(f"{what}: {len(out)} entries for {n} channels")
    return out


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


# ---------------------------------------------------------------------------------------------- LPM
def lpm_frf(
    U: ArrayLike, Y: ArrayLike, f: ArrayLike, *, order: int = 2, extra: int = 8
) -> tuple[NDArray[np.float64], NDArray[np.complex128], NDArray[np.float64]]:
    """Local polynomial method (Pintelon, Schoukens et al., MSSP 24 (2010) 573-595) on consecutive
    DFT bins of ONE record: ``U`` (m, n_in), ``Y`` (m, n_out), bin frequencies ``f`` (m,) [Hz].

    In disjoint windows of ``w = (n_in + 1)(order + 1) + extra`` bins (odd), ``Y_{k+r} = G_k U_{k+r} +
    T_k`` with ``G`` and the transient ``T`` polynomials of degree ``order`` in ``r``, solved by least
    squares for all outputs at once: the transient (leakage) of a non-periodic record is removed,
    not windowed. Returns the window-centre frequencies (n_w,), ``G`` (n_w, n_out, n_in) and the
    per-component (real/imag) std of ``G`` from the local residual variance (n_w, n_out, n_in)."""
    Ua = np.asarray(U, complex)
    Ya = np.asarray(Y, complex)
    ff = np.asarray(f, float)
    Ua = Ua[:, None] if Ua.ndim == 1 else Ua
    Ya = Ya[:, None] if Ya.ndim == 1 else Ya
    ni, no = Ua.shape[1], Ya.shape[1]
    w = (ni + 1) * (order + 1) + extra
    w += 1 - w % 2
    n_win = Ya.shape[0] // w
    r = np.arange(w) - w // 2
    P = (r[:, None] / max(w // 2, 1)) ** np.arange(order + 1)[None, :]
    fc = np.empty(n_win)
    G = np.full((n_win, no, ni), np.nan + 0j)
    sd = np.full((n_win, no, ni), np.nan)
    for k in range(n_win):
        sl = slice(k * w, (k + 1) * w)
        X = np.concatenate([Ua[sl, i : i + 1] * P for i in range(ni)] + [P.astype(complex)], axis=1)
        fc[k] = ff[k * w + w // 2]
        sol, _, rank, _ = np.linalg.lstsq(X, Ya[sl], rcond=1e-10)
        q = w - rank
        if rank < X.shape[1] or q <= 0:
            continue
        s2 = np.sum(np.abs(Ya[sl] - X @ sol) ** 2, axis=0) / q  # (no,) complex noise variance
        XtXi = np.linalg.inv(X.conj().T @ X)
        idx = [i * (order + 1) for i in range(ni)]  # the r^0 coefficient of each input's G polynomial
        G[k] = sol[idx].T
        sd[k] = np.sqrt(np.clip(s2[:, None] * np.real(np.diag(XtXi))[idx][None, :] / 2.0, 0, None))
    return fc, G, sd
