"""Array-level and record-level entry points: data checks -> H1 FRF -> Fisher check -> LS -> emcee.

* :func:`identify_arrays` -- one experiment given as arrays.
* :func:`identify_experiments` -- several experiments (e.g. one chirp per input of an m-DOF device).
* :func:`identify_record` -- a run record (a :class:`hil.identify.source.RecordSource`, e.g. a
  :class:`hil.record.hdf5.RunRecord` adapted by its backend, or its path: ``.h5`` written by ``hil run`` or
  ``hil import``; ``.csv``/``.mat`` imported on the fly; ``.npz``), or the
  dict ``{"t": ..., "signals": {name: array}, "meta": {...}}``. For run records the model,
  channels, windows, Welch segment and band are inferred from the record's meta, results and scene
  (:mod:`hil.identify.records`); dict ``meta`` keys: ``model`` (name), ``inputs`` / ``outputs``
  (mapping model channel -> signal name, or list of signal names in model order), ``channels``
  (measured model outputs), ``band`` [Hz], ``period`` [s] of the periodic chirp (sets the Welch
  segment), ``nperseg``, ``skip`` [s], ``seed``, ``model_options``, ``noise``.
* :func:`store_result` -- posterior samples, summary and convergence diagnostics into the record
  (``/identification/<model>``, through the record backend: :func:`hil.record.hdf5.store_identification`);
  :func:`load_identification`.
* the command ``hil identify RECORD [--model NAME] [--json] ...`` is :func:`hil.cli.identify.main`.
  Exit codes (the CLI's): 0 ok;
  2 usage or input error (unreadable file, unknown model, missing channel); 13 the data cannot
  give a trustworthy estimate (data quality, not identifiable, posterior not converged, model misfit
  unless ``--accept-misfit``), with a one-line message; 1 only for bugs.

Estimator rule (``method="auto"``): a record with a known ``period`` whose input repeats with it keeps
the H1-FRF path (LS on the FRF, emcee on the FRF likelihood); every other record (one-shot chirps from
other tools, imported CSV/.mat) is identified by output-error maximum likelihood on the exact sampled
model with the record's transient estimated (:mod:`hil.identify.timedomain`), then emcee on the same
likelihood (or ``posterior="laplace"``). Both paths report the Cramér-Rao bound for the recorded
excitation under the fitted noise model (``crb_std``) and the adequacy tests of
:mod:`hil.identify.adequacy` (``result.misfit``).

Pipeline order matters: the identifiability (Fisher rank) check runs BEFORE any fitting, at the
model's nominal parameters with the data's own FRF variance, and raises
:class:`~hil.identify.errors.NotIdentifiableError` with the fix; data problems raise
:class:`~hil.identify.errors.DataQualityError`. An unconverged posterior is returned flagged
(``result.converged`` False, ``reasons``) and :meth:`IdentificationResult.estimate` refuses it.
"""

from __future__ import annotations

import json
import logging
import time
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np
from numpy.typing import ArrayLike

from hil.errors import HilError
from hil.identify.adequacy import AdequacyReport, check_frf_fit, check_ml_fit
from hil.identify.diagnostics import DataReport, Diagnosis, check_excitation, run_checks
from hil.identify.errors import (
    ConvergenceError,
    DataQualityError,
    ModelSpecError,
)
from hil.identify.fisher import IdentifiabilityReport, check_identifiability, crb
from hil.identify.fit import LsResult, fit_least_squares
from hil.identify.frf import FrfEstimate, Resolution, estimate_frf, lattice_step, lpm_frf
from hil.identify.models import GreyBoxModel, make_model
from hil.identify.posterior import LogPosterior, PosteriorResult, sample_posterior
from hil.identify.source import as_source, backend_for
from hil.identify.timedomain import (
    MlLogPosterior,
    dft_records,
    fisher_dft,
    fit_ml,
    is_periodic,
    laplace_posterior,
)

logger = logging.getLogger(__name__)

__all__ = [
    "IdentificationResult",
    "identify_arrays",
    "identify_experiments",
    "identify_record",
    "load_identification",
    "store_result",
]



@dataclass
class IdentificationResult:
    """Everything an identification produced. ``to_json()`` for reports; check ``converged``."""

    model: GreyBoxModel
    frf: FrfEstimate
    ls: LsResult
    crb_std: np.ndarray
    identifiability: IdentifiabilityReport
    posterior: PosteriorResult
    data_report: DataReport
    timings: dict[str, float] = field(default_factory=dict)
    record: dict[str, Any] = field(default_factory=dict)  # where the data came from (records: channel mapping)
    #: "frf" (periodic H1 path) or "ml" (output-error ML on the exact sampled model); see api docstring
    method: str = "frf"
    #: residual whiteness, input-residual correlation, reduced chi^2 (:mod:`hil.identify.adequacy`)
    adequacy: AdequacyReport | None = None
    #: the misfit was accepted by the caller (``accept_misfit=True`` / ``--accept-misfit``)
    misfit_accepted: bool = False
    #: output-error ML details (noise std per output, transient), ``None`` on the FRF path
    ml: dict[str, Any] | None = None

    @property
    def misfit(self) -> bool:
        """True when an adequacy test failed: the model does not describe the data."""
        return bool(self.adequacy is not None and self.adequacy.misfit)

    @property
    def names(self) -> tuple[str, ...]:
        return self.posterior.names

    @property
    def converged(self) -> bool:
        return self.posterior.converged

    def summary(self) -> dict[str, dict[str, float]]:
        """Per parameter: mean, median, q05, q95, std (posterior); ``ls`` the point estimate (LS on the
        FRF, or the output-error ML); ``ls_std`` its std from the fit's curvature with the data's own
        noise estimate (FRF variance, or the ML residual variance); ``crb_std`` the Cramér-Rao bound:
        sqrt diag of the inverse Fisher information of the model under the fitted noise model, for
        the recorded excitation (:mod:`hil.identify.timedomain`). Physical units."""
        return self.posterior.summary(self.ls.std, self.crb_std, self.ls.theta)

    def derived_summary(self) -> dict[str, dict[str, float | str]]:
        """Model-specific derived quantities (e.g. the entries of M, B, K): mean, median, q05, q95, std, unit."""
        out: dict[str, dict[str, float | str]] = {}
        for name, (vals, unit) in self.model.derived(self.posterior.samples[:, : self.model.n_params]).items():
            q05, med, q95 = np.quantile(vals, [0.05, 0.5, 0.95])
            out[name] = {"mean": float(np.mean(vals)), "median": float(med), "q05": float(q05), "q95": float(q95),
                         "std": float(np.std(vals, ddof=1)), "unit": unit}
        return out

    def estimate(self, *, allow_unconverged: bool = False) -> dict[str, float]:
        """Posterior medians; raises :class:`ConvergenceError` if the sampler did not converge."""
        if not self.converged and not allow_unconverged:
            raise ConvergenceError(
                "posterior not converged: " + "; ".join(self.posterior.diagnostics.reasons), result=self
            )
        return {k: v["median"] for k, v in self.summary().items()}

    def to_dict(self) -> dict[str, Any]:
        units = dict(zip(self.model.names, self.model.units, strict=True))
        summ = self.summary()
        for k, row in summ.items():
            row["unit"] = units.get(k, "1")  # type: ignore[assignment]
        return {
            "model": self.model.name,
            "inputs": list(self.model.input_names),
            "outputs": list(self.model.output_names),
            "converged": self.converged,
            "parameters": summ,
            "derived": self.derived_summary(),
            "sample_names": list(self.posterior.names),
            "sampling": "continuous" if self.model.zoh_fs is None else {"zoh_fs": self.model.zoh_fs},
            "convergence": self.posterior.diagnostics.to_dict(self.names),
            "noise_model": self.posterior.noise,
            "seed": self.posterior.seed,
            "least_squares": self.ls.to_dict(),
            "cramer_rao_std": dict(zip(self.model.names, map(float, self.crb_std), strict=True)),
            "method": self.method,
            "misfit": self.misfit,
            "misfit_accepted": self.misfit_accepted,
            "adequacy": None if self.adequacy is None else self.adequacy.to_dict(),
            "output_error_ml": self.ml,
            "identifiability": self.identifiability.to_dict(),
            "frf": {
                "f_min": float(self.frf.f[0]),
                "f_max": float(self.frf.f[-1]),
                "n_bins": self.frf.n_bins,
                "n_averages": self.frf.n_avg,
                "median_coherence": [float(c) for c in np.median(self.frf.coherence, axis=0)],
                "rounding_variance": self.frf.meta.get("rounding_variance"),
            },
            "data_checks": [d.to_dict() for d in self.data_report.diagnoses],
            "timings_s": self.timings,
            "record": self.record,
        }

    def to_json(self, **kw: Any) -> str:
        return json.dumps(self.to_dict(), **{"indent": 2, **kw})


def _ordered(
    signals: Mapping[str, ArrayLike] | ArrayLike, names: Sequence[str], what: str
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Signals as a {name: array} dict and an (n, len(names)) matrix in model order."""
    if isinstance(signals, Mapping):
        if all(n in signals for n in names):
            d = {n: np.asarray(signals[n], float) for n in names}
        elif len(signals) == len(names):
            d = {k: np.asarray(v, float) for k, v in signals.items()}
            logger.info("%s %s taken in the given order as model channels %s", what, list(signals), list(names))
        else:
            raise ModelSpecError(f"{what} {list(signals)} do not match model channels {list(names)}")
    else:
        a = np.asarray(signals, float)
        a = a[:, None] if a.ndim == 1 else a
        if a.shape[1] != len(names):
            raise ModelSpecError(f"{what}: {a.shape[1]} columns for model channels {list(names)}")
        d = {n: a[:, i] for i, n in enumerate(names)}
    return d, np.column_stack(list(d.values()))


def identify_experiments(
    experiments: Sequence[Mapping[str, Any]],
    *,
    model: str | GreyBoxModel = "sdea_locked",
    channels: Sequence[str] | None = None,
    band: tuple[float, float] | None = None,
    nperseg: int | None = None,
    period: float | None = None,
    skip: float = 0.0,
    window: str = "boxcar",
    seed: int = 0,
    noise: str = "student",
    model_options: Mapping[str, Any] | None = None,
    theta0: ArrayLike | Mapping[str, float] | None = None,
    n_walkers: int | None = None,
    max_steps: int = 20000,
    max_seconds: float | None = None,
    n_starts: int = 4,
    resolution: Resolution | Sequence[Resolution] = "float32",
    input_resolution: Resolution | Sequence[Resolution] = "float32",
    sampling: str = "continuous",
    excitation: str = "refuse",
    method: str = "auto",
    posterior: str = "emcee",
    accept_misfit: bool = False,
) -> IdentificationResult:
    """Identify ``model`` from experiments ``[{"t": t, "inputs": ..., "outputs": ...}, ...]``.

    ``inputs``/``outputs``: mapping model channel -> (n,) array (or (n, k) arrays in model order).
    ``band`` [Hz]; ``period`` [s] of a periodic chirp sets ``nperseg = period * fs`` (recommended:
    leakage-free segments); otherwise ``nperseg`` defaults to 1/16 of the shortest record.
    ``skip`` [s] drops the start of each record (transient). ``seed`` drives LS restarts and the
    whole emcee run. ``resolution``/``input_resolution``: rounding of the recorded outputs/inputs
    (default float32, what device buses carry; ``auto``: float32, or the step of a whole-count
    quantizer found in the values, :func:`hil.identify.frf.lattice_step`), a noise floor that periodic
    averaging does not remove (:mod:`hil.identify.frf`). ``sampling``: ``continuous`` (H(jw)) or ``zoh`` (the exact
    response of the plant behind a zero-order hold at the data's rate: digital benches; a model
    instance must then have been built with ``zoh_fs``). ``theta0`` (default: the model's
    data-derived :meth:`~hil.identify.models.GreyBoxModel.initial_guess`, else its nominal values)
    is where the identifiability check runs and the LS fit starts.
    ``excitation``: ``refuse`` (default) or ``warn`` when the band cannot pin a parameter (hil.identify.excitation).
    ``method``: ``auto`` (default: the H1-FRF path for periodic records -- a ``period`` is given and the
    input repeats with it -- else output-error ML, :mod:`hil.identify.timedomain`), ``frf`` or ``ml``.
    ``posterior`` (ML path): ``emcee`` on the ML likelihood, or ``laplace`` (Gaussian at the ML
    estimate with the inverse Fisher covariance; fast). The fit's adequacy is always tested
    (:mod:`hil.identify.adequacy`): ``result.misfit``; ``accept_misfit`` only records that the caller
    accepts it (``result.misfit_accepted``).
    Returns an :class:`IdentificationResult` (raise on data/identifiability errors).
    """
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    if sampling not in ("continuous", "zoh"):
        raise ModelSpecError(f"sampling must be 'continuous' or 'zoh', got {sampling!r}")
    from hil.identify.records import sample_rate  # the one sample-rate definition

    fs_first = sample_rate(experiments[0]["t"]) if experiments else 1.0
    if isinstance(model, GreyBoxModel):
        mdl = model
        if sampling == "zoh" and (mdl.zoh_fs is None or abs(mdl.zoh_fs / fs_first - 1) > 1e-6):
            raise ModelSpecError(f"sampling 'zoh': build the model with zoh_fs={fs_first:g} (the data's rate)")
    else:
        opts = dict(model_options or {})
        if sampling == "zoh":
            opts.setdefault("zoh_fs", fs_first)
        mdl = make_model(model, channels, **opts)
    diags: list[Diagnosis] = []
    pairs = []
    fs_all = []
    for e in experiments:
        t = np.asarray(e["t"], float)
        ins, U = _ordered(e["inputs"], mdl.input_names, "inputs")
        outs, Y = _ordered(e["outputs"], mdl.output_names, "outputs")
        rep = run_checks(t, ins, outs, allow_idle_inputs=len(experiments) > 1)
        diags += rep.diagnoses
        if not rep.ok:
            continue
        fs = sample_rate(t)
        k0 = round(skip * fs)
        pairs.append((U[k0:], Y[k0:]))
        fs_all.append(fs)
    idle = [d.channel for d in diags if d.kind == "no_excitation" and d.severity == "info"]
    for name in mdl.input_names:
        if idle.count(name) == len(experiments):
            diags.append(
                Diagnosis(
                    "no_excitation", "error", f"input {name} is idle in every experiment: no excitation", channel=name
                )
            )
    report = DataReport(diags)
    report.raise_if_failed()
    if not pairs:
        raise DataQualityError("no experiment given")
    fs = float(np.median(fs_all))
    if max(fs_all) / min(fs_all) - 1 > 1e-6:
        raise DataQualityError(f"experiments sampled at different rates {fs_all}")
    n_min = min(p[0].shape[0] for p in pairs)
    chosen = _choose_method(method, pairs, period, fs)
    # Welch segment: the period; else n/16 (FRF path), or n/4 on the ML path, where the H1 FRF only
    # feeds the data checks and the start: its first bin fs/nps must sit below the excitation's lowest
    # frequency (a 3 s record: 1.3 Hz, not 5.3 Hz) for the checks to see the band that is analysed; a
    # period given with a record that does not repeat it still sets the segment, but never fewer than 4
    if nperseg:
        nps = int(nperseg)
    elif chosen == "ml":
        nps = max(min(round(period * fs) if period else n_min, n_min // 4), 16)
    else:
        nps = round(period * fs) if period else max(n_min // 16, 16)
    est = estimate_frf(
        pairs,
        fs,
        nperseg=nps,
        window=window,
        input_names=mdl.input_names,
        output_names=mdl.output_names,
        resolution=resolution,
        input_resolution=input_resolution,
    )
    if isinstance(resolution, str) and resolution == "auto":
        for o, name in enumerate(mdl.output_names):
            q = lattice_step(np.concatenate([y[:, o] for _, y in pairs]))
            if q is not None:
                report.diagnoses.append(Diagnosis(
                    "quantized", "info", f"output {name} takes whole multiples of {q:.4g} (a sensor or drive "
                    "reporting whole counts): its rounding floor q^2/12 is in the noise model", channel=name))
    from hil.identify.sensor_hold import compensate_frf, held_outputs  # outputs of a slower sensor

    held = held_outputs(pairs, mdl.output_names)
    # the ML path models the hold in its likelihood (hil.identify.held_ml) on the exact ZOH model
    held_ml = bool(held) and chosen == "ml" and mdl.zoh_fs is not None and not mdl.has_delay
    if held:
        est = compensate_frf(est, held, fs)  # FRF path: the estimate; ML path: its checks and start
    for name in held:
        how = ("the FRF is compensated for the hold" if chosen == "frf" else
               "the likelihood observes it at its new samples only (hold modelled)" if held_ml else
               "the ML path models the hold only with the zero-order-hold model without delay (sampling 'zoh')")
        report.diagnoses.append(Diagnosis(
            "sample_and_hold", "info" if chosen == "frf" or held_ml else "warning",
            f"output {name} repeats its previous value in {100 * (1 - held[name][0]):.0f} % of the samples "
            f"(a sensor slower than the {fs:g} Hz loop): " + how, channel=name))
    if band is None and chosen == "ml":
        band = _record_band(pairs, fs)
        logger.info("analysis band %.3g..%.3g Hz: where the recorded input carries power", *band)
    est = est.band(*(band or (fs / nps, 0.45 * fs)))
    exc = check_excitation(est)
    if chosen == "ml" and getattr(mdl, "output", None) == "position":
        for d in exc:  # an encoder axis: low LINEAR coherence is no proof of "no response"
            if d.kind == "no_excitation":
                d.severity = "warning"
                d.message = (f"{d.channel}: low linear coherence with the input (median "
                             f"{d.details.get('median_coherence', float('nan')):.2f}) although the position is "
                             "measured: a free axis integrates its force, and closed-loop control or friction make "
                             "the response nonlinear; the fit proceeds and its adequacy tests judge it (friction: "
                             "--friction coulomb,offset)")
    report.diagnoses += exc
    report.raise_if_failed()
    timings["frf"] = time.perf_counter() - t0

    # --- identifiability BEFORE fitting: nominal parameters, data-derived FRF variance
    if isinstance(theta0, Mapping):
        th0 = mdl.vector(dict(theta0))
    elif theta0 is not None:
        th0 = np.asarray(theta0, float)
    else:
        guess = mdl.initial_guess(est)  # equation error on the (many) H1 bins
        th0 = mdl.nominal if guess is None else guess
    # at the initial guess: its messages are in the error it may raise; the check at the fit below warns
    pre = check_identifiability(mdl, th0, w=est.w, sigma=est.sigma, log_level=logging.DEBUG)
    pre.raise_if_not_identifiable()
    from hil.identify.excitation import check_excitation_adequacy  # does the band pin every parameter?

    report.diagnoses += check_excitation_adequacy(mdl, est, th0, mode=excitation).diagnoses()  # "refuse": raises
    t1 = time.perf_counter()
    ls = fit_least_squares(mdl, est, x0=th0, n_starts=n_starts, seed=seed)
    timings["least_squares"] = time.perf_counter() - t1
    ident = check_identifiability(mdl, ls.theta, w=est.w, sigma=est.sigma)
    if chosen == "ml":
        return _identify_ml(mdl, pairs, fs, band or (fs / nps, 0.45 * fs), est, ls, ident, report, timings, t0,
                            seed=seed, posterior=posterior, n_walkers=n_walkers, max_steps=max_steps,
                            max_seconds=max_seconds, accept_misfit=accept_misfit, held=held if held_ml else None,
                            alt_start=lambda: _lpm_start(mdl, pairs, fs, band or (fs / nps, 0.45 * fs), th0))
    crb_std = _frf_path_crb(mdl, ls.theta, pairs, fs, est)
    adequacy = check_frf_fit(mdl, est, ls.theta)
    t2 = time.perf_counter()
    lp = LogPosterior(mdl, est, noise=noise)
    post = sample_posterior(
        lp, ls.z, ls.cov_z, seed=seed, n_walkers=n_walkers, max_steps=max_steps, max_seconds=max_seconds
    )
    timings["posterior"] = time.perf_counter() - t2
    timings["total"] = time.perf_counter() - t0
    res = IdentificationResult(mdl, est, ls, crb_std, ident, post, report, timings, method="frf",
                               adequacy=adequacy, misfit_accepted=bool(accept_misfit and adequacy.misfit))
    if not res.converged:
        logger.warning(
            "identification of %s: posterior NOT converged (%s)", mdl.name, "; ".join(post.diagnostics.reasons)
        )
    return res


def _choose_method(method: str, pairs: Sequence[tuple[np.ndarray, np.ndarray]], period: float | None,
                   fs: float) -> str:
    """The documented rule (:mod:`hil.identify.timedomain`): ``auto`` -> ``frf`` when a ``period`` is
    known and every experiment's input repeats with it over >= 2 periods, else ``ml``."""
    if method not in ("auto", "frf", "ml"):
        raise ModelSpecError(f"method must be 'auto', 'frf' or 'ml', got {method!r}")
    if method != "auto":
        return method
    if period and all(is_periodic(u, round(period * fs)) for u, _ in pairs):
        return "frf"
    logger.info("non-periodic record%s: output-error ML on the exact sampled model",
                "" if period is None else f" (input does not repeat with period {period:g} s)")
    return "ml"


def _record_band(pairs: Sequence[tuple[np.ndarray, np.ndarray]], fs: float) -> tuple[float, float]:
    """Default band [Hz] of the ML path: the union over the records of the band holding 99.8 % of the
    input power in the periodogram of the whole record (:func:`hil.identify.excitation.excited_band`:
    full record resolution, so a sweep or multisine starting at 0.5 Hz is analysed from 0.5 Hz, not from
    the first Welch bin), capped at 0.45 fs. Idle records (one DOF after the other) are skipped."""
    from hil.identify.excitation import excited_band

    lo, hi = np.inf, 0.0
    for u, _ in pairs:
        try:
            b = excited_band(u, fs)
        except ValueError:
            continue
        lo, hi = min(lo, b[0]), max(hi, b[1])
    if not np.isfinite(lo) or hi <= lo:
        raise DataQualityError("no input carries power: no excitation")
    return float(lo), float(min(hi, 0.45 * fs))


def _excited_band(est: FrfEstimate, rel: float = 1e-4) -> tuple[float, float]:
    """Frequencies [Hz] between the first and last bin where some input's power is at least ``rel``
    of its peak (DC excluded): the range the excitation actually covers."""
    pw = np.real(np.diagonal(est.Gxx, axis1=1, axis2=2))  # (nf, ni)
    on = np.any(pw >= rel * np.maximum(np.max(pw, axis=0), 1e-300), axis=1) & (est.f > 0)
    if not np.any(on):
        return float(est.f[1]), float(est.f[-1])
    f_on = est.f[on]
    return float(f_on[0]), float(f_on[-1])


def _lpm_estimate(mdl: GreyBoxModel, pairs: Sequence[tuple[np.ndarray, np.ndarray]], fs: float,
                  band: tuple[float, float]) -> FrfEstimate | None:
    """Local-polynomial FRF (:func:`hil.identify.frf.lpm_frf`) of every record on ``band``, pooled and
    sorted by frequency, as an :class:`FrfEstimate` for the start of the ML fit; None when a record
    leaves an input idle (the LPM needs every input in every record) or too few bins remain."""
    fs_l, G_l, sd_l = [], [], []
    for r in dft_records(pairs, fs, band):
        if np.any(np.sum(np.abs(r.U) ** 2, axis=0) <= 0):
            return None
        fc, G, sd = lpm_frf(r.U, r.Y, r.f)
        fs_l.append(fc)
        G_l.append(G)
        sd_l.append(sd)
    f = np.concatenate(fs_l)
    G = np.concatenate(G_l)
    sd = np.concatenate(sd_l)
    ok = np.all(np.isfinite(G), axis=(1, 2)) & np.all(sd > 0, axis=(1, 2))
    if 2 * ok.sum() * len(mdl.output_names) * len(mdl.input_names) < 4 * mdl.n_params:
        return None
    o = np.argsort(f[ok])
    n, no, ni = int(ok.sum()), len(mdl.output_names), len(mdl.input_names)
    return FrfEstimate(f=f[ok][o], H=G[ok][o], coherence=np.ones((n, no)), sigma=sd[ok][o],
                       Gxx=np.zeros((n, ni, ni), complex), Gyy=np.zeros((n, no)), Gvv=np.zeros((n, no)), n_avg=1.0,
                       dof=8.0, fs=fs, nperseg=int(pairs[0][0].shape[0]), input_names=mdl.input_names,
                       output_names=mdl.output_names, meta={"estimator": "local polynomial method"})


def _lpm_start(mdl: GreyBoxModel, pairs: Sequence[tuple[np.ndarray, np.ndarray]], fs: float,
               band: tuple[float, float], x0: np.ndarray) -> np.ndarray | None:
    """LS fit on the local-polynomial FRF from ``x0``: the second ML start (None without an LPM FRF)."""
    lest = _lpm_estimate(mdl, pairs, fs, band)
    return None if lest is None else fit_least_squares(mdl, lest, x0=x0, n_starts=4, seed=0).theta


def _frf_path_crb(mdl: GreyBoxModel, theta: np.ndarray, pairs: Sequence[tuple[np.ndarray, np.ndarray]],
                  fs: float, est: FrfEstimate) -> np.ndarray:
    """Cramér-Rao std of the periodic path: Fisher information of the DFT of the records themselves
    (actual excitation), steady state, noise model = the H1 residual spectrum ``Gvv`` (a one-sided
    density: ``E|V_k|^2 = N fs Gvv / 2``) plus the known rounding floor of the outputs (and of the
    inputs through ``|H|^2``), on the analysis band."""
    recs = dft_records(pairs, fs, (float(est.f[0]), float(est.f[-1])))
    rv = cast(dict[str, Any], est.meta.get("rounding_variance") or {})
    qo = np.asarray(rv.get("outputs", np.zeros(len(mdl.output_names))), dtype=np.float64)
    qi = np.asarray(rv.get("inputs", np.zeros(len(mdl.input_names))), dtype=np.float64)
    noise_var = []
    for r in recs:
        gvv = np.column_stack([np.interp(r.f, est.f, est.Gvv[:, o]) for o in range(est.Gvv.shape[1])])
        H = mdl.frf(theta, r.w)
        floor = qo[None, :] + np.einsum("koi,i->ko", np.abs(H) ** 2, qi)
        v = r.n * (fs * gvv / 2.0 + floor)
        noise_var.append(np.maximum(v, 1e-300))
    F = fisher_dft(mdl, recs, theta, noise_var, transient=False)
    return crb(mdl, theta, F)[1]


def _identify_ml(
    mdl: GreyBoxModel,
    pairs: Sequence[tuple[np.ndarray, np.ndarray]],
    fs: float,
    band: tuple[float, float],
    est: FrfEstimate,
    ls0: LsResult,
    ident: IdentifiabilityReport,
    report: DataReport,
    timings: dict[str, float],
    t0: float,
    *,
    seed: int,
    posterior: str,
    n_walkers: int | None,
    max_steps: int,
    max_seconds: float | None,
    accept_misfit: bool,
    alt_start: Any = None,
    held: Mapping[str, Any] | None = None,
) -> IdentificationResult:
    """Output-error ML from the H1-LS start, adequacy tests, then the posterior (emcee on the same
    likelihood, or its Laplace approximation). ``held``: outputs of a slower sensor (name -> age
    distribution): the time-domain likelihood with the hold modelled (:mod:`hil.identify.held_ml`)."""
    t1 = time.perf_counter()
    start = "H1"
    recs = dft_records(pairs, fs, band)
    prob = None
    if held:
        from hil.identify.held_ml import check_held_fit, fit_held_ml, held_records

        ml, prob = fit_held_ml(mdl, held_records(pairs, mdl.output_names, held), ls0.theta)
        adequacy = check_held_fit(prob, ml.theta, ml.sigma)
        alt_start = None  # the time-domain problem has its own start (the hold-compensated H1 fit)
    else:
        ml = fit_ml(mdl, recs, ls0.theta)
        adequacy = check_ml_fit(mdl, recs, ml.theta, ml.sigma)
    if adequacy.misfit and alt_start is not None:
        # a local optimum also fails the adequacy tests: refit from an LS fit on the transient-free
        # local-polynomial FRF, keep the likelier fit
        # (profile likelihood -sum_o m_o log RSS_o; every output has the same number of bins)
        try:
            x2 = alt_start()
            ml2 = fit_ml(mdl, recs, x2) if x2 is not None else None
        except HilError as exc:
            ml2 = None
            logger.debug("second ML start failed: %s", exc)
        if ml2 is not None and np.sum(np.log(ml2.sigma)) < np.sum(np.log(ml.sigma)):
            ml, start = ml2, "local-polynomial"
            adequacy = check_ml_fit(mdl, recs, ml.theta, ml.sigma)
    timings["ml"] = time.perf_counter() - t1
    ls = LsResult(names=mdl.names, theta=ml.theta, z=ml.z, cov_z=ml.cov_z, cov_theta=ml.cov_theta, std=ml.crb_std,
                  chi2=ml.chi2, dof=ml.dof, success=ml.success, message=ml.message, n_starts=1)
    t2 = time.perf_counter()
    if posterior == "laplace":
        post = laplace_posterior(mdl, ml, seed=seed)
    elif posterior == "emcee":
        lp = MlLogPosterior(mdl, recs, ml.sigma, prob=prob)
        post = sample_posterior(lp, ml.z, ml.cov_z, seed=seed, n_walkers=n_walkers, max_steps=max_steps,  # type: ignore[arg-type]
                                max_seconds=max_seconds)
    else:
        raise ModelSpecError(f"posterior must be 'emcee' or 'laplace', got {posterior!r}")
    timings["posterior"] = time.perf_counter() - t2
    timings["total"] = time.perf_counter() - t0
    info = {"noise_std": dict(zip(mdl.output_names, map(float, ml.sigma), strict=True)), "band_hz": list(band),
            "n_bins": ml.n_bins, "posterior": posterior,
            "start": f"least squares on the {start} FRF"}
    if held:
        info.update(likelihood="time domain, held outputs observed at their new samples",
                    held_outputs=sorted(held), band_hz=None)
    res = IdentificationResult(mdl, est, ls, ml.crb_std, ident, post, report, timings, method="ml",
                               adequacy=adequacy, misfit_accepted=bool(accept_misfit and adequacy.misfit), ml=info)
    if not res.converged:
        logger.warning("identification of %s: posterior NOT converged (%s)", mdl.name,
                       "; ".join(post.diagnostics.reasons))
    return res


def identify_arrays(
    t: ArrayLike,
    inputs: Mapping[str, ArrayLike] | ArrayLike,
    outputs: Mapping[str, ArrayLike] | ArrayLike,
    model: str | GreyBoxModel = "sdea_locked",
    channels: Sequence[str] | None = None,
    seed: int = 0,
    **kw: Any,
) -> IdentificationResult:
    """One experiment: ``t`` [s], ``inputs``/``outputs`` (see :func:`identify_experiments`)."""
    return identify_experiments(
        [{"t": t, "inputs": inputs, "outputs": outputs}], model=model, channels=channels, seed=seed, **kw
    )


_META_KW = (
    "band",
    "nperseg",
    "period",
    "skip",
    "window",
    "seed",
    "noise",
    "model_options",
    "theta0",
    "n_walkers",
    "max_steps",
    "max_seconds",
    "n_starts",
    "resolution",
    "input_resolution",
    "sampling",
    "excitation",
    "method",
    "posterior",
    "accept_misfit",
)


def identify_record(record: Any, **overrides: Any) -> IdentificationResult:
    """Identify from a run record or a record dict (module docstring).

    ``record``: a :class:`~hil.identify.source.RecordSource` (or an object a registered record backend
    adapts to one, e.g. a :class:`hil.record.hdf5.RunRecord`), a path (``.npz``; ``.h5`` run record,
    ``.csv``/``.mat`` imported with the importers' defaults, through the registered backend,
    :mod:`hil.identify.source`), or ``{"t", "signals", "meta"}``.
    Run records: everything is inferred (:func:`hil.identify.records.plan_from_record`) and
    ``overrides`` (``model``, ``inputs``, ``outputs``, ``target``, ``experiment``, ``period``,
    ``skip``, ``band``, ``sampling``, ... and any keyword of :func:`identify_experiments`) win.
    ``friction``: a sequence of terms from ``{"coulomb", "stribeck", "offset"}`` (or ``"coulomb,offset"``);
    empty or None: the linear models as before. With friction the 1-DOF ``mbk`` model with friction is
    identified by inverse-dynamics ML from the position (:mod:`hil.identify.friction_api`); parameters
    ``M``, ``B`` (viscous), ``F_c``, ``F_s``/``v_s``, ``F_0`` with units, ``result.method == "idim-ml"``.
    Dicts: ``meta["inputs"]``/``meta["outputs"]`` map model channels to signal names (or list signal
    names in model order); ``overrides`` take precedence over ``meta``.
    """
    from hil.identify.friction import normalize_friction

    terms = normalize_friction(overrides.pop("friction", None))
    if isinstance(record, str | Path):
        record = load_record(record)
    src = as_source(record)
    if terms:  # a plant with friction: the inverse-dynamics ML path (hil.identify.friction_api)
        from hil.identify.friction_api import identify_friction_arrays, identify_friction_record

        if src is not None:
            return identify_friction_record(src, overrides, terms)
        meta = {**dict(record.get("meta") or {}), **{k: v for k, v in overrides.items() if v is not None}}
        sig = record["signals"]
        ins, outs = meta.get("inputs"), meta.get("outputs")
        if not ins or not outs:
            raise ModelSpecError("a record dict with friction needs meta inputs [force signal] and outputs "
                                 "{'position': signal}")
        (okey, oname), = dict(outs).items() if isinstance(outs, Mapping) else [("position", outs[0])]
        kw = {k: meta[k] for k in ("seed", "posterior", "n_walkers", "max_steps", "max_seconds", "accept_misfit")
              if k in meta}
        return identify_friction_arrays(record["t"], np.asarray(sig[next(iter(ins))], float),
                                        np.asarray(sig[oname], float), terms, output=okey.split("_")[0], **kw)
    if src is not None:
        return _identify_run_record(src, overrides)
    return _identify_dict(record, **overrides)


def load_record(path: str | Path) -> Any:
    """A :class:`~hil.identify.source.RecordSource` opened by the record backend registered for the
    file's suffix (the suite's: ``.h5``; ``.csv``/``.mat`` imported into a temporary record with the
    importers' defaults) or a record dict (``.npz``, read here). Raises the backend's error (RecordError)
    or ModelSpecError, one line naming the file."""
    p = Path(path)
    if p.suffix.lower() == ".npz":
        try:
            if not p.is_file():
                raise ModelSpecError(f"{p}: no such file")
            return load_npz_record(str(p))
        except HilError:
            raise
        except (OSError, EOFError, ValueError, KeyError, zipfile.BadZipFile) as exc:
            raise ModelSpecError(f"{p}: not a readable .npz record ({' '.join(str(exc).split())[:200]})") from None
    return backend_for(p).open(p)


def _identify_run_record(rec: Any, overrides: Mapping[str, Any]) -> IdentificationResult:
    from hil.identify.records import plan_from_record, signal, window_mask

    data = rec.to_identify_dict()
    sig = data["signals"]
    plan = plan_from_record(rec, sig, overrides)
    mdl = make_model(plan.model, plan.channels, **plan.model_options)
    if len(plan.inputs) != len(mdl.input_names):
        raise ModelSpecError(f"{len(plan.inputs)} inputs {plan.inputs} for model inputs {list(mdl.input_names)}")
    missing = [c for c in mdl.output_names if c not in plan.outputs]
    if missing:
        raise ModelSpecError(f"no signal for model outputs {missing}: pass --output {missing[0]}=SIGNAL")
    t = np.asarray(data["t"], float)
    exps = []
    for w in plan.windows:
        m = window_mask(t, w)
        if not np.any(m):
            continue
        ins = {c: signal(sig, n)[m] for c, n in zip(mdl.input_names, plan.inputs, strict=True)}
        outs = {c: signal(sig, plan.outputs[c])[m] for c in mdl.output_names}
        exps.append({"t": t[m], "inputs": ins, "outputs": outs})
    if not exps:
        raise DataQualityError(f"no samples in the experiment windows {plan.windows}")
    kw = dict(plan.kwargs)
    unknown = sorted(set(kw) - set(_META_KW))
    if unknown:
        raise ModelSpecError(f"unknown identification settings {unknown}")
    if "band" in kw:
        kw["band"] = tuple(kw["band"])
    kw.setdefault("sampling", "zoh" if mdl.zoh_fs is not None else "continuous")
    res = identify_experiments(exps, model=mdl, **kw)
    res.record = {"path": str(rec.path), "scene_sha256": rec.scene_sha256, "mapping": plan.to_dict()}
    return res


def _identify_dict(record: Mapping[str, Any], **overrides: Any) -> IdentificationResult:
    """Identify from ``{"t": ..., "signals": {name: array}, "meta": {...}}`` (see module docstring)."""
    try:
        t = record["t"]
        sig = record["signals"]
    except (KeyError, TypeError) as exc:
        raise ModelSpecError("record needs 't' and 'signals'") from exc
    meta = dict(record.get("meta") or {})
    meta.update({k: v for k, v in overrides.items() if v is not None})
    model_name = meta.get("model", "sdea_locked")
    channels = meta.get("channels")
    opts = dict(meta.get("model_options") or {})
    if meta.get("sampling") == "zoh":
        tt = np.asarray(t, float)
        if tt.size < 2:
            raise ModelSpecError("record needs at least 2 samples")
        from hil.identify.records import sample_rate

        opts.setdefault("zoh_fs", sample_rate(tt))
    mdl = make_model(model_name, channels, **opts)

    def pick(spec: Any, names: Sequence[str], what: str) -> dict[str, Any]:
        if spec is None:
            spec = {n: n for n in names}
        if isinstance(spec, Mapping):
            mapping = dict(spec)
        else:
            if len(spec) != len(names):
                raise ModelSpecError(f"meta {what} {spec} does not match model channels {list(names)}")
            mapping = dict(zip(names, spec, strict=True))
        missing = [s for s in mapping.values() if s not in sig]
        if missing:
            raise ModelSpecError(f"signals {missing} named in meta {what} are not in the record ({list(sig)})")
        return {n: sig[mapping[n]] for n in names}

    ins = pick(meta.get("inputs"), mdl.input_names, "inputs")
    outs = pick(meta.get("outputs"), mdl.output_names, "outputs")
    kw = {k: meta[k] for k in _META_KW if k in meta and k != "model_options"}
    if "band" in kw:
        kw["band"] = tuple(kw["band"])
    return identify_experiments([{"t": t, "inputs": ins, "outputs": outs}], model=mdl, **kw)


def load_npz_record(path: str) -> dict[str, Any]:
    """Load ``t``, signals and an optional JSON ``meta`` string from a ``.npz`` file."""
    with np.load(path, allow_pickle=False) as z:
        meta = json.loads(str(z["meta"])) if "meta" in z.files else {}
        signals = {k: z[k] for k in z.files if k not in ("t", "meta")}
        return {"t": z["t"], "signals": signals, "meta": meta}


def store_result(path: str | Path, res: IdentificationResult, name: str | None = None) -> str:
    """Write ``res`` into the run record at ``path`` as ``/identification/<name>`` (default: the
    model name): the posterior samples (physical units, columns ``sample_names``) and the full
    summary (:meth:`IdentificationResult.to_dict`: per-parameter summary, convergence diagnostics,
    noise model, LS, CRB, data checks, channel mapping). Returns the group name."""
    key = name or res.model.name
    backend_for(path).store(path, key, res.posterior.samples, res.to_dict())
    return key


def load_identification(path: str | Path, name: str | None = None) -> dict[str, Any]:
    """``{"samples": (n, p) array, "summary": dict}`` of ``/identification/<name>`` in a record (the
    only one when ``name`` is None). Raises RecordError."""
    import h5py

    try:
        error: type[Exception] = backend_for(path).error
    except ModelSpecError:
        error = ModelSpecError
    try:
        with h5py.File(path, "r") as f:
            g = f.get("identification")
            names = sorted(g) if g is not None else []
            if name is None and len(names) == 1:
                name = names[0]
            if name not in names:
                raise error(f"{path}: no identification {name!r} (have {names})")
            grp = g[name]
            return {"samples": np.array(grp["samples"]), "summary": json.loads(grp["summary"][()])}
    except OSError as exc:
        raise error(f"{path}: cannot read: {exc}") from None
