"""Excitation adequacy: does the recorded (or planned) excitation pin every parameter separately?

The rank test of :mod:`hil.identify.fisher` only rejects experiments that are blind to a direction
of parameter space. An excitation can see every parameter and still pin some of them only
*jointly*: a chirp over 100-140 Hz around the 120 Hz resonance of the locked SDEA measures the
resonance (``K_f / M``, the damping, the peak gain) but neither the spring line (below the
resonance, where ``K_f`` acts alone) nor the mass line (above it, where ``M`` acts alone). The fit
then trades ``K_f`` against ``M`` along the resonance, and any small model or estimator error in the
band moves both together: "confident and wrong".

Rule (documented, per parameter ``i``), from the Fisher information ``F`` of the data actually
recorded (the FRF bins in the analysis band and their variance, as in
:func:`hil.identify.fisher.fisher_information`; z-space, i.e. relative for positive parameters):

* The *reference* is the same test with its sweep continued over the model's reference band: one
  decade below its lowest to one decade above its highest natural frequency (``|eigenvalue|/2 pi``
  of the state matrix at ``theta``), clipped to ``0.45 fs``. Bins are added on the record's grid
  (spacing ``fs / nperseg``) below and above the excited band, each with the FRF standard deviation
  of the nearest band edge (the median of its 3 outermost excited bins). Within a decade of a
  second-order corner the asymptotes (spring line, mass line) hold to 1 %: the reference sees every
  parameter where it acts alone. ``F_ref = F + (positive semidefinite)``.
* ``information_fraction_i = CRB_ii(reference) / CRB_ii(recorded)`` in (0, 1]: the share of the
  marginal information (1 / Cramér-Rao variance, the other parameters unknown) about ``z_i`` that
  the excited band delivers. A parameter is **not pinned** by the excitation when it is below
  ``min_fraction`` (default 0.5: its Cramér-Rao sd exceeds sqrt(2) x the extended test's). Measured
  on synthetic locked-SDEA data (Table I truth, 5 kHz, 1 % noise, 4 s log chirps, H1 with 16
  rectangular segments): a 100-140 Hz chirp analysed in 100-140 Hz gives K_f 0.35, B_f 0.33,
  M 0.31, B 0.37 (refused; the same in 6 of 6 seeds); a 80-160 Hz chirp about 0.8; 1-200 Hz
  (analysed from 4 Hz) 0.65-0.82; 1-400 Hz 0.76-0.91 (accepted, 6 seeds).
* ``collinearity_i = VIF_i(recorded) / VIF_i(reference)`` with ``VIF_i = (F^-1)_ii F_ii`` (the
  variance inflation factor: marginal over conditional Cramér-Rao variance) is reported to explain a
  refusal: above ~1.5 the band sees the parameter mostly through a combination with others (the
  100-140 Hz chirp: 2.0-2.1 for all four; the broadband chirps 1.1-1.2).

For every parameter that is not pinned, the fix is computed: the smallest extension of the
excited band downwards (to ``f_lo``) or upwards (to ``f_hi``), at the recorded per-bin quality,
that brings its information fraction to the threshold; the message names the parameter and those
frequencies (e.g. "K_f: excite down to ~60 Hz (where the spring line dominates) or up to ~210 Hz").

Refusal: :func:`check_excitation_adequacy` returns an :class:`ExcitationReport`;
:meth:`ExcitationReport.raise_if_inadequate` raises :class:`~hil.identify.errors.NotIdentifiableError`
(``hil identify`` exit 13). Identification refuses by default (``excitation="refuse"``): an
estimate whose interval rests on a correlation the data cannot resolve must not feed a
certificate; ``excitation="warn"`` keeps the fit and logs the same message (deliberate narrow-band
work with trusted priors).

:func:`excited_band` measures the band an input signal actually excites (used for the default band
of imported records, :mod:`hil.identify.records`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.identify.diagnostics import Diagnosis
from hil.identify.errors import ModelSpecError, NotIdentifiableError
from hil.identify.fisher import normalized_pinv, weighted_jacobian
from hil.identify.models import GreyBoxModel

logger = logging.getLogger(__name__)

__all__ = [
    "ExcitationReport",
    "check_excitation_adequacy",
    "excitation_metrics",
    "excited_band",
    "plan_adequacy",
    "reference_band",
]

#: default threshold on the information fraction (module docstring)
MIN_FRACTION = 0.5

#: what each SDEA parameter's asymptote is called, for the messages
_WHERE = {
    "K_f": ("down", "where the spring line dominates"),
    "M": ("up", "where the mass line dominates"),
}


def excited_band(u: ArrayLike, fs: float, *, power_fraction: float = 0.998) -> tuple[float, float]:
    """Band [Hz] holding ``power_fraction`` of the input power (mean removed), over all inputs.

    ``u``: (n,) or (n, n_in) input samples at ``fs`` [Hz]. From the periodogram of the whole record
    (rectangular window: no taper hides the start or the end of a sweep) of each input, the band runs
    from the frequency below which ``(1 - power_fraction)/2`` of the power lies to the one above which
    the same fraction lies (union over inputs). For a chirp that is its sweep, widened by the
    leakage of its abrupt start and stop (a log chirp 1-400 Hz over 4 s at 5 kHz: 0.25-402 Hz;
    100-140 Hz: 80-148 Hz).
    """
    a = np.asarray(u, float)
    a = a[:, None] if a.ndim == 1 else a
    if a.shape[0] < 8:
        raise ValueError(f"excited_band: need at least 8 samples, got {a.shape[0]}")
    lo, hi = np.inf, 0.0
    tail = (1.0 - power_fraction) / 2.0
    for col in a.T:
        col = col[np.isfinite(col)]
        if col.size < 8:
            continue
        p = np.abs(np.fft.rfft(col - np.mean(col))) ** 2
        f = np.fft.rfftfreq(col.size, 1.0 / fs)
        c = np.cumsum(p)
        if c[-1] <= 0:
            continue
        c = c / c[-1]
        i0 = int(np.searchsorted(c, tail))
        i1 = int(np.searchsorted(c, 1.0 - tail))
        lo, hi = min(lo, float(f[max(i0, 1)])), max(hi, float(f[min(i1, f.size - 1)]))
    if not np.isfinite(lo) or hi <= lo:
        raise ValueError("excited_band: no input carries power")
    return lo, hi


def reference_band(model: GreyBoxModel, theta: ArrayLike, fs: float | None = None) -> tuple[float, float]:
    """A decade below the lowest to a decade above the highest natural frequency [Hz] of ``model``
    at ``theta`` (``|eigenvalue| / 2 pi`` of its continuous state matrix, zero eigenvalues ignored),
    clipped to ``0.45 fs`` when ``fs`` is given."""
    A, _, _ = model.state_space(np.asarray(theta, float))
    lam = np.abs(np.linalg.eigvals(A))
    lam = lam[lam > 1e-9 * max(float(np.max(lam)), 1e-300)]
    if lam.size == 0:
        raise ValueError(f"{model.name}: no non-zero natural frequency for a reference band")
    f_n = lam / (2 * np.pi)
    lo, hi = float(np.min(f_n)) / 10.0, float(np.max(f_n)) * 10.0
    if fs is not None:
        hi = min(hi, 0.45 * float(fs))
    return lo, hi


def _fisher(model: GreyBoxModel, theta: NDArray[np.float64], f: NDArray[np.float64],
            sigma: NDArray[np.float64]) -> NDArray[np.float64]:
    J = weighted_jacobian(model, theta, 2 * np.pi * f, sigma)
    return J.T @ J


def _vif_and_var(F: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(VIF per parameter, marginal CRB variance in z) of a Fisher matrix."""
    cov = normalized_pinv(F)
    var = np.clip(np.diag(cov), 0, None)
    d = np.diag(F)
    with np.errstate(invalid="ignore", divide="ignore"):
        vif = np.where(d > 0, var * d, np.inf)
    return vif, var


def _grid(lo: float, hi: float, df: float) -> NDArray[np.float64]:
    k0 = max(int(np.ceil(lo / df - 1e-9)), 1)
    return np.asarray(np.arange(k0, int(np.floor(hi / df + 1e-9)) + 1) * df, float)


def _edge_sigma(f: NDArray[np.float64], sig: NDArray[np.float64], excited: NDArray[np.bool_],
                n_edge: int = 3) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per-(output, input) median std of the ``n_edge`` excited bins at each end of the band."""
    idx = np.flatnonzero(excited)
    if idx.size == 0:
        idx = np.arange(f.size)
    out = []
    for part in (idx[:n_edge], idx[-n_edge:]):
        s = sig[part]
        ok = np.isfinite(s) & (s > 0)
        out.append(np.array([[np.median(s[:, o, i][ok[:, o, i]]) if np.any(ok[:, o, i]) else np.inf
                              for i in range(s.shape[2])] for o in range(s.shape[1])]))
    return out[0], out[1]


def excitation_metrics(
    model: GreyBoxModel,
    theta: ArrayLike,
    f: ArrayLike,
    sigma: ArrayLike,
    *,
    ref_band: tuple[float, float],
    df: float,
    excited: ArrayLike | None = None,
) -> dict[str, Any]:
    """VIF, information fraction and collinearity (module docstring) of FRF data ``(f [Hz], sigma)``.

    The broadband reference is the same data plus bins of spacing ``df`` [Hz] extending the excited
    band (``excited``: mask of the excited bins, default all finite ones) down and up to ``ref_band``,
    each at the per-bin std of the nearest band edge (median of its 3 outermost excited bins): the
    same experiment, its sweep continued at its edge quality. Its Fisher matrix is the recorded one
    plus a positive semidefinite term, so ``information_fraction <= 1``."""
    th = np.asarray(theta, float)
    ff = np.asarray(f, float)
    sig = np.asarray(sigma, float)
    exc = np.any(np.isfinite(sig) & (sig > 0), axis=(1, 2)) if excited is None else np.asarray(excited, bool)
    fe = ff[exc] if np.any(exc) else ff
    s_lo, s_hi = _edge_sigma(ff, sig, exc)
    f_dn = _grid(ref_band[0], fe[0] - df / 2, df)
    f_up = _grid(fe[-1] + df / 2, ref_band[1], df)
    F_rec = _fisher(model, th, ff, sig)
    F_ext = np.zeros_like(F_rec)
    for fx, sx in ((f_dn, s_lo), (f_up, s_hi)):
        if fx.size:
            F_ext += _fisher(model, th, fx, np.broadcast_to(sx, (fx.size, *sx.shape)))
    vif, var = _vif_and_var(F_rec)
    vif_ref, var_ref = _vif_and_var(F_rec + F_ext)
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(var > 0, var_ref / var, 0.0)
    return {"vif": vif, "vif_ref": vif_ref, "collinearity": vif / vif_ref, "information_fraction": frac,
            "crb_rel": np.sqrt(var), "crb_rel_ref": np.sqrt(var_ref), "band": (float(fe[0]), float(fe[-1])),
            "edge_sigma": (s_lo, s_hi), "F": F_rec}


@dataclass
class ExcitationReport:
    """Result of :func:`check_excitation_adequacy` (per parameter, in model order)."""

    names: tuple[str, ...]
    excited_band: tuple[float, float]
    reference_band: tuple[float, float]
    collinearity: NDArray[np.float64]
    information_fraction: NDArray[np.float64]
    vif: NDArray[np.float64]
    crb_rel: NDArray[np.float64]
    min_fraction: float
    not_pinned: list[str] = field(default_factory=list)
    fixes: dict[str, dict[str, float | None]] = field(default_factory=dict)
    messages: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """True when the excitation pins every parameter (information fraction >= ``min_fraction``)."""
        return not self.not_pinned

    @property
    def message(self) -> str:
        return "; ".join(self.messages)

    def raise_if_inadequate(self) -> None:
        """:class:`NotIdentifiableError` naming the parameters and the excitation that would pin them."""
        if not self.ok:
            raise NotIdentifiableError(self.message, report=self)

    def diagnoses(self) -> list[Diagnosis]:
        """One ``excitation`` warning per parameter that is not pinned (for the data checks of a result)."""
        return [Diagnosis("excitation", "warning", msg, channel=None, details={"parameter": n, **self.fixes[n]})
                for n, msg in zip(self.not_pinned, self.messages, strict=True)]

    def to_dict(self) -> dict[str, Any]:
        per = {n: {"collinearity": float(self.collinearity[i]), "information_fraction":
                   float(self.information_fraction[i]), "vif": float(self.vif[i]),
                   "crb_rel_std": float(self.crb_rel[i])} for i, n in enumerate(self.names)}
        return {"ok": self.ok, "excited_band_hz": list(self.excited_band),
                "reference_band_hz": list(self.reference_band), "min_fraction": self.min_fraction,
                "parameters": per, "not_pinned": self.not_pinned, "fixes_hz": self.fixes, "messages": self.messages}


def _extension(model: GreyBoxModel, th: NDArray[np.float64], F_rec: NDArray[np.float64],
               band: tuple[float, float], edge: NDArray[np.float64], ref: tuple[float, float], df: float,
               var_ref: NDArray[np.float64], idx: int, thr: float, direction: str) -> float | None:
    """Smallest extension of the excited band (down to f_lo or up to f_hi [Hz], on the bin grid, at the
    edge's per-bin std ``edge``) that brings parameter ``idx``'s information fraction to ``thr``; None
    if extending to the reference band edge does not. Bisection over the added bins: the fraction
    grows monotonically with them (each adds a positive semidefinite term to F)."""
    fx = _grid(ref[0], band[0] - df / 2, df)[::-1] if direction == "down" else _grid(band[1] + df / 2, ref[1], df)
    if fx.size == 0:
        return None

    def pins(k: int) -> bool:  # the first k added bins
        part = fx[:k]
        _, var = _vif_and_var(F_rec + _fisher(model, th, part, np.broadcast_to(edge, (part.size, *edge.shape))))
        return bool(var[idx] <= 0 or var_ref[idx] / var[idx] >= thr)

    if not pins(fx.size):
        return None
    lo, hi = 0, fx.size  # pins(hi) holds; pins(0) does not (the caller flagged idx)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if pins(mid) else (mid, hi)
    return float(fx[hi - 1])


def _assess(model: GreyBoxModel, th: NDArray[np.float64], f: NDArray[np.float64], sig: NDArray[np.float64],
            excited: NDArray[np.bool_], fs: float, df: float, min_fraction: float) -> ExcitationReport:
    try:
        ref = reference_band(model, th, fs)
    except (NotImplementedError, ValueError):  # no state space: nothing to extend to
        ref = (float(f[0]), float(f[-1]))
    fe = f[excited] if np.any(excited) else f
    ref = (min(ref[0], float(fe[0])), max(ref[1], float(fe[-1])))
    m = excitation_metrics(model, th, f, sig, ref_band=ref, df=df, excited=excited)
    band = m["band"]
    col = m["collinearity"]
    frac = m["information_fraction"]
    names = model.names
    bad = [i for i in range(len(names)) if frac[i] < min_fraction]
    var_ref = m["crb_rel_ref"] ** 2
    fixes: dict[str, dict[str, float | None]] = {}
    messages: list[str] = []
    s_lo, s_hi = m["edge_sigma"]
    for i in bad:
        down = _extension(model, th, m["F"], band, s_lo, ref, df, var_ref, i, min_fraction, "down")
        up = _extension(model, th, m["F"], band, s_hi, ref, df, var_ref, i, min_fraction, "up")
        fixes[names[i]] = {"down_to_hz": down, "up_to_hz": up}
        pref, where = _WHERE.get(names[i], (None, ""))
        opts = [(d, f"excite {d} to ~{e:.3g} Hz" + (f" ({where})" if d == pref else ""))
                for d, e in (("down", down), ("up", up)) if e is not None]
        opts.sort(key=lambda o: o[0] != pref)
        fix = " or ".join(t for _, t in opts) if opts else f"excite the whole band {ref[0]:.3g}-{ref[1]:.3g} Hz"
        joint = f", seen only jointly with other parameters (collinearity {col[i]:.2g})" if col[i] > 1.5 else ""
        messages.append(f"{names[i]} is not pinned by the excitation {band[0]:.4g}-{band[1]:.4g} Hz: it carries "
                        f"{frac[i]:.0%} of the information the same test extended to {ref[0]:.3g}-{ref[1]:.3g} Hz "
                        f"gives (need {min_fraction:.0%}){joint}; {fix}")
    return ExcitationReport(
        names=names, excited_band=band, reference_band=ref, collinearity=col,
        information_fraction=frac, vif=m["vif"], crb_rel=m["crb_rel"],
        min_fraction=float(min_fraction), not_pinned=[names[i] for i in bad], fixes=fixes,
        messages=messages)


def check_excitation_adequacy(
    model: GreyBoxModel,
    est: Any,
    theta: ArrayLike | None = None,
    *,
    mode: str | None = None,
    min_fraction: float = MIN_FRACTION,
    log_level: int = logging.WARNING,
) -> ExcitationReport:
    """Excitation adequacy (module docstring) of an FRF estimate ``est``
    (:class:`~hil.identify.frf.FrfEstimate`, already restricted to the analysis band) at ``theta``
    (default: the model's nominal values). Excited bins: some input's power ``Gxx_ii`` is at least
    1e-3 of its peak in the band. ``mode``: None (report only; messages logged at ``log_level``),
    ``"refuse"`` (raise :class:`NotIdentifiableError` when a parameter is not pinned) or ``"warn"``
    (log the messages as warnings and return the report)."""
    if mode not in (None, "refuse", "warn"):
        raise ModelSpecError(f"excitation must be 'refuse' or 'warn', got {mode!r}")
    th = model.nominal if theta is None else np.asarray(theta, float)
    f = np.asarray(est.f, float)
    sig = np.asarray(est.sigma, float)
    pw = np.real(np.diagonal(np.asarray(est.Gxx), axis1=1, axis2=2))  # (nf, ni)
    excited = np.any(pw >= 1e-3 * np.max(pw, axis=0, keepdims=True), axis=1)
    excited &= np.any(np.isfinite(sig) & (sig > 0), axis=(1, 2))
    rep = _assess(model, th, f, sig, excited, float(est.fs), float(est.fs) / float(est.nperseg), min_fraction)
    level = {"refuse": logging.DEBUG, "warn": logging.WARNING}.get(mode or "", log_level)
    for msg in rep.messages:
        logger.log(level, "excitation: %s", msg)
    if mode == "refuse":
        rep.raise_if_inadequate()
    return rep


def plan_adequacy(model: GreyBoxModel, theta: ArrayLike, f: ArrayLike, sigma: ArrayLike, fs: float, df: float,
                  *, min_fraction: float = MIN_FRACTION) -> ExcitationReport:
    """The same assessment for a PLANNED experiment (bins ``f`` [Hz] inside its sweep, predicted
    per-component std ``sigma`` (n_f, n_out, n_in), e.g. :meth:`hil.identify.fisher.ExperimentPlan.frf_sigma`)."""
    ff = np.asarray(f, float)
    sig = np.asarray(sigma, float)
    excited = np.any(np.isfinite(sig) & (sig > 0), axis=(1, 2))
    return _assess(model, np.asarray(theta, float), ff, sig, excited, fs, df, min_fraction)
