"""Array-level and record-level entry points: data checks -> H1 FRF -> Fisher check -> LS -> emcee.

* :func:`identify_arrays` -- one experiment given as arrays.
* :func:`identify_experiments` -- several experiments (e.g. one chirp per input of an m-DOF device).
* :func:`identify_record` -- ``{"t": ..., "signals": {name: array}, "meta": {...}}`` (the future run
  record). ``meta`` keys: ``model`` (name), ``inputs`` / ``outputs`` (mapping model channel ->
  signal name, or list of signal names in model order), ``channels`` (measured model outputs),
  ``band`` [Hz], ``period`` [s] of the periodic chirp (sets the Welch segment), ``nperseg``,
  ``skip`` [s], ``seed``, ``model_options``, ``noise``.
* :func:`main` -- ``hil identify RECORD.npz [--model NAME] [--json]`` (to be wired into the CLI).

Pipeline order matters: the identifiability (Fisher rank) check runs BEFORE any fitting, at the
model's nominal parameters with the data's own FRF variance, and raises
:class:`~hil.identify.errors.NotIdentifiableError` with the fix; data problems raise
:class:`~hil.identify.errors.DataQualityError`. An unconverged posterior is returned flagged
(``result.converged`` False, ``reasons``) and :meth:`IdentificationResult.estimate` refuses it.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from hil.identify.diagnostics import DataReport, Diagnosis, check_excitation, run_checks
from hil.identify.errors import (
    ConvergenceError,
    DataQualityError,
    IdentificationError,
    ModelSpecError,
    NotIdentifiableError,
)
from hil.identify.fisher import IdentifiabilityReport, check_identifiability, crb, fisher_information
from hil.identify.fit import LsResult, fit_least_squares
from hil.identify.frf import FrfEstimate, estimate_frf
from hil.identify.models import GreyBoxModel, make_model
from hil.identify.posterior import LogPosterior, PosteriorResult, sample_posterior

logger = logging.getLogger(__name__)

__all__ = ["IdentificationResult", "identify_arrays", "identify_experiments", "identify_record", "main"]


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

    @property
    def names(self) -> tuple[str, ...]:
        return self.posterior.names

    @property
    def converged(self) -> bool:
        return self.posterior.converged

    def summary(self) -> dict[str, dict[str, float]]:
        """Per parameter: mean, median, q05, q95, std, ls, ls_std, crb_std (physical units)."""
        return self.posterior.summary(self.ls.std, self.crb_std, self.ls.theta)

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
            "convergence": self.posterior.diagnostics.to_dict(self.names),
            "noise_model": self.posterior.noise,
            "seed": self.posterior.seed,
            "least_squares": self.ls.to_dict(),
            "cramer_rao_std": dict(zip(self.model.names, map(float, self.crb_std), strict=True)),
            "identifiability": self.identifiability.to_dict(),
            "frf": {
                "f_min": float(self.frf.f[0]),
                "f_max": float(self.frf.f[-1]),
                "n_bins": self.frf.n_bins,
                "n_averages": self.frf.n_avg,
                "median_coherence": [float(c) for c in np.median(self.frf.coherence, axis=0)],
            },
            "data_checks": [d.to_dict() for d in self.data_report.diagnoses],
            "timings_s": self.timings,
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
) -> IdentificationResult:
    """Identify ``model`` from experiments ``[{"t": t, "inputs": ..., "outputs": ...}, ...]``.

    ``inputs``/``outputs``: mapping model channel -> (n,) array (or (n, k) arrays in model order).
    ``band`` [Hz]; ``period`` [s] of a periodic chirp sets ``nperseg = period * fs`` (recommended:
    leakage-free segments); otherwise ``nperseg`` defaults to 1/16 of the shortest record.
    ``skip`` [s] drops the start of each record (transient). ``seed`` drives LS restarts and the
    whole emcee run. Returns an :class:`IdentificationResult` (raise on data/identifiability errors).
    """
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    mdl = model if isinstance(model, GreyBoxModel) else make_model(model, channels, **dict(model_options or {}))
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
        fs = 1.0 / float(np.median(np.diff(t)))
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
    nps = int(nperseg) if nperseg else (round(period * fs) if period else max(n_min // 16, 16))
    est = estimate_frf(
        pairs, fs, nperseg=nps, window=window, input_names=mdl.input_names, output_names=mdl.output_names
    )
    est = est.band(*(band or (fs / nps, 0.45 * fs)))
    exc = check_excitation(est)
    report.diagnoses += exc
    report.raise_if_failed()
    timings["frf"] = time.perf_counter() - t0

    # --- identifiability BEFORE fitting: nominal parameters, data-derived FRF variance
    if isinstance(theta0, Mapping):
        th0 = mdl.vector(dict(theta0))
    else:
        th0 = mdl.nominal if theta0 is None else np.asarray(theta0, float)
    pre = check_identifiability(mdl, th0, w=est.w, sigma=est.sigma)
    pre.raise_if_not_identifiable()
    t1 = time.perf_counter()
    ls = fit_least_squares(mdl, est, x0=th0, n_starts=n_starts, seed=seed)
    timings["least_squares"] = time.perf_counter() - t1
    F = fisher_information(mdl, ls.theta, est.w, est.sigma)
    _, crb_std = crb(mdl, ls.theta, F)
    ident = check_identifiability(mdl, ls.theta, w=est.w, sigma=est.sigma)
    t2 = time.perf_counter()
    lp = LogPosterior(mdl, est, noise=noise)
    post = sample_posterior(
        lp, ls.z, ls.cov_z, seed=seed, n_walkers=n_walkers, max_steps=max_steps, max_seconds=max_seconds
    )
    timings["posterior"] = time.perf_counter() - t2
    timings["total"] = time.perf_counter() - t0
    res = IdentificationResult(mdl, est, ls, crb_std, ident, post, report, timings)
    if not res.converged:
        logger.warning(
            "identification of %s: posterior NOT converged (%s)", mdl.name, "; ".join(post.diagnostics.reasons)
        )
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
)


def identify_record(record: Mapping[str, Any], **overrides: Any) -> IdentificationResult:
    """Identify from ``{"t": ..., "signals": {name: array}, "meta": {...}}`` (see module docstring).

    ``meta["inputs"]``/``meta["outputs"]``: mapping model channel -> signal name (or a list of signal
    names in model order). ``overrides`` take precedence over ``meta``.
    """
    try:
        t = record["t"]
        sig = record["signals"]
    except (KeyError, TypeError) as exc:
        raise ModelSpecError("record needs 't' and 'signals'") from exc
    meta = dict(record.get("meta") or {})
    meta.update({k: v for k, v in overrides.items() if v is not None})
    model_name = meta.get("model", "sdea_locked")
    channels = meta.get("channels")
    mdl = make_model(model_name, channels, **dict(meta.get("model_options") or {}))

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


def main(argv: Sequence[str] | None = None) -> int:
    """``hil identify RECORD.npz [--model NAME] [--json]``. Exit codes: 0 ok, 2 data quality,
    3 posterior not converged, 4 not identifiable, 1 other identification error."""
    p = argparse.ArgumentParser(prog="hil identify", description="Identify a grey-box model from a chirp record")
    p.add_argument("record", help=".npz with arrays t, <signals>..., optional JSON string 'meta'")
    p.add_argument("--model", default=None, help="sdea_locked | sdea_free | mbk (default: meta or sdea_locked)")
    p.add_argument("--band", nargs=2, type=float, metavar=("F_MIN", "F_MAX"), default=None)
    p.add_argument("--period", type=float, default=None, help="chirp period [s] (Welch segment length)")
    p.add_argument("--seed", type=int, default=None)
    p.add_argument("--json", action="store_true", help="print the full result as JSON")
    a = p.parse_args(argv)
    rec = load_npz_record(a.record)
    try:
        res = identify_record(rec, model=a.model, band=a.band, period=a.period, seed=a.seed)
    except DataQualityError as exc:
        print(f"data quality: {exc}", file=sys.stderr)
        return 2
    except IdentificationError as exc:
        print(f"identification failed: {exc}", file=sys.stderr)
        return 4 if isinstance(exc, NotIdentifiableError) else 1
    if a.json:
        print(res.to_json())
    else:
        units = dict(zip(res.model.names, res.model.units, strict=True))
        print(f"model {res.model.name}; converged: {res.converged}")
        print(f"{'param':>10} {'median':>12} {'q05':>12} {'q95':>12} {'std':>10} {'ls_std':>10} {'crb_std':>10}  unit")
        for n, r in res.summary().items():
            print(
                f"{n:>10} {r['median']:12.5g} {r['q05']:12.5g} {r['q95']:12.5g} {r['std']:10.3g} "
                f"{r.get('ls_std', float('nan')):10.3g} {r.get('crb_std', float('nan')):10.3g}  {units.get(n, '')}"
            )
        if not res.converged:
            print("NOT CONVERGED: " + "; ".join(res.posterior.diagnostics.reasons))
    return 0 if res.converged else 3
