"""Identification with friction: records -> IDIM-ML fit -> emcee posterior -> :class:`IdentificationResult`.

Entry point :func:`identify_friction_arrays` (one record as arrays) and the record dispatch used by
:func:`hil.identify.api.identify_record` when ``friction`` names at least one term. The estimator is
:mod:`hil.identify.inverse_ml` (start: IDIM-LS, :mod:`hil.identify.idim`); the parameters are named
``M``, ``B``, ``F_c``, ``F_s``/``v_s``, ``F_0`` with units (:data:`hil.identify.friction.PARAMETERS`).
Model choice (:func:`compare_friction_models`): each candidate is fitted on the estimation part and
judged by BIC (on the whitened equation error) and by the open-loop simulation error of the
position on a held-out part (the last third) or a second record.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from hil.identify.errors import DataQualityError, ModelSpecError
from hil.identify.friction import FrictionModel, describe_terms, normalize_friction
from hil.identify.inverse_ml import (
    InverseFit,
    InverseLogPosterior,
    check_inverse_fit,
    fit_inverse_ml,
    sandwich_adjust,
    summary_row,
)

logger = logging.getLogger(__name__)

__all__ = ["CANDIDATES", "compare_friction_models", "identify_friction_arrays", "identify_friction_record",
           "simulation_error"]

#: friction models tried by the model choice, simplest first
CANDIDATES: tuple[tuple[str, ...], ...] = ((), ("coulomb",), ("coulomb", "offset"), ("coulomb", "stribeck", "offset"))


def sample_rate(t: ArrayLike) -> float:
    """THE sample rate of a record [Hz]: ``1 / median(diff t)`` snapped to its short decimal form
    (:func:`hil.identify.records.nominal_rate`)."""
    from hil.identify.records import sample_rate as _sr

    return _sr(t)


def simulation_error(model: FrictionModel, theta: ArrayLike, u: ArrayLike, q: ArrayLike, fs: float) -> dict[str, float]:
    """Open-loop simulation of the position from the force over a record, from its measured start
    (position, filtered-derivative velocity): ``rms`` [m or rad] of ``q - q_sim`` and ``fit_pct =
    100 (1 - |q - q_sim| / |q - mean q|)`` (100 % = perfect)."""
    from hil.identify.friction import FrictionModel as _FM
    from hil.identify.idim import filtered_derivatives

    qq, uu = np.asarray(q, float), np.asarray(u, float)
    _, v, _ = filtered_derivatives(qq[: min(qq.size, 2000)], fs)
    m = _FM(model.terms, nominal={k: float(x) for k, x in zip(model.names, np.asarray(theta, float), strict=True)},
            units=model.units_kind, output="position", zoh_fs=fs, force_scale=float(np.max(np.abs(uu)) or 1.0))
    qs = m.simulate(np.asarray(theta, float), uu, x0=float(qq[0]), v0=float(v[0]))
    r = qq - qs
    if not np.all(np.isfinite(r)):
        raise DataQualityError("the simulation of the fitted model diverged")
    return {"rms": float(np.sqrt(np.mean(r**2))),
            "fit_pct": float(100 * (1 - np.linalg.norm(r) / max(float(np.linalg.norm(qq - qq.mean())), 1e-300)))}


def compare_friction_models(
    q: ArrayLike, u: ArrayLike, fs: float, *, candidates: Sequence[Sequence[str]] = CANDIDATES,
    validation: tuple[ArrayLike, ArrayLike] | None = None, units: str = "linear", holdout: float = 1 / 3,
) -> dict[str, Any]:
    """Fit every candidate friction model and report the evidence (module docstring).

    Without ``validation`` (``(q, u)`` of a second record) the last ``holdout`` of the record is held
    out: fitted on the rest, simulated on it. Returns ``{"rows": [...], "best": terms, "by": ...}``;
    each row: friction terms, parameters, ``bic``/``aic`` (on the full record, lower is better),
    ``simulation_rms`` [position unit] and ``simulation_fit_pct`` on the held-out data, ``misfit``.
    ``best``: the lowest BIC among the models whose adequacy tests pass (else the lowest BIC)."""
    qq, uu = np.asarray(q, float), np.asarray(u, float)
    if validation is None:
        cut = round(qq.size * (1 - holdout))
        est, val = (qq[:cut], uu[:cut]), (qq[cut:], uu[cut:])
        where = f"last {holdout:.0%} of the record (fitted on the rest)"
    else:
        est, val = (qq, uu), (np.asarray(validation[0], float), np.asarray(validation[1], float))
        where = "the validation record"
    rows = []
    for terms in candidates:
        terms = normalize_friction(terms)
        full = fit_inverse_ml([(qq, uu)], fs, terms, units=units)
        part = full if validation is not None else fit_inverse_ml([est], fs, terms, units=units)
        sim = simulation_error(part.model, part.theta, val[1], val[0], fs)
        row = summary_row(full)
        row.update(model=describe_terms(terms), simulation_rms=sim["rms"], simulation_fit_pct=sim["fit_pct"],
                   misfit=check_inverse_fit(full).misfit)
        rows.append(row)
    ok = [r for r in rows if not r["misfit"]] or rows
    best = min(ok, key=lambda r: r["bic"])
    return {"rows": rows, "best": best["friction"], "held_out": where,
            "by": "lowest BIC among the models that pass the adequacy tests"}


def _info(fit: InverseFit, post_kind: str) -> dict[str, Any]:
    return {"estimator": "inverse-dynamics maximum likelihood (IDIM-ML, hil.identify.inverse_ml)",
            "friction": list(fit.model.terms), "idim_ls": fit.idim.to_dict(),
            "noise_model": f"equation error: intervals from the sandwich with its smoothed periodogram; "
                           f"AR({fit.ar.order}) innovations (BIC) for the adequacy tests and the Cramer-Rao bound",
            "innovation_std": fit.ar.sigma, "bic": fit.bic, "aic": fit.aic, "n_equation_error": fit.n,
            "posterior": post_kind, "decimation": fit.idim.decimation, "filter_hz": fit.idim.f_filter}


def identify_friction_arrays(
    t: ArrayLike, u: ArrayLike, q: ArrayLike, friction: Sequence[str] | str, *, units: str = "linear",
    seed: int = 0, posterior: str = "emcee", n_walkers: int | None = None, max_steps: int = 20000,
    max_seconds: float | None = None, accept_misfit: bool = False, output: str = "position",
    record: Mapping[str, Any] | None = None, **_ignored: Any,
) -> Any:
    """Identify the 1-DOF model with ``friction`` from time ``t`` [s], force ``u`` and the measured
    ``output`` (``position`` [m or rad]; a ``velocity`` is integrated to a position). Returns an
    :class:`hil.identify.api.IdentificationResult` (``method = "idim-ml"``)."""
    from hil.identify.api import IdentificationResult
    from hil.identify.diagnostics import check_dead, check_finite, run_checks
    from hil.identify.fisher import IdentifiabilityReport
    from hil.identify.fit import LsResult
    from hil.identify.frf import estimate_frf
    from hil.identify.posterior import PosteriorResult, sample_posterior

    terms = normalize_friction(friction)
    t0 = time.perf_counter()
    tt = np.asarray(t, float)
    uu = np.asarray(u, float)
    yy = np.asarray(q, float)
    # the force gets every check; the position not the saturation one: an axis held by stiction sits
    # flat at one count, which is friction, not a clipped sensor
    report = run_checks(tt, {"force": uu}, {})
    report.diagnoses += check_finite({output: yy}) + check_dead({output: yy}, role={output: "output"})
    report.raise_if_failed()
    fs = sample_rate(tt)
    if output == "velocity":
        yy = np.concatenate([[0.0], np.cumsum(yy[:-1])]) / fs
    elif output != "position":
        raise ModelSpecError(f"friction models measure 'position' or 'velocity', got {output!r}")
    fit = fit_inverse_ml([(yy, uu)], fs, terms, units=units)
    timings = {"ml": time.perf_counter() - t0}
    adequacy = check_inverse_fit(fit)
    model = fit.model
    t1 = time.perf_counter()
    if posterior == "emcee":
        lp = InverseLogPosterior(fit)
        raw = sample_posterior(lp, fit.z, fit.cov_z, seed=seed, n_walkers=n_walkers, max_steps=max_steps,  # type: ignore[arg-type]
                               max_seconds=max_seconds)
        zs = sandwich_adjust(fit, model.to_z(raw.samples))
        lo, hi = model.z_bounds()
        zs = np.clip(zs, lo, hi)
        post = PosteriorResult(names=model.names, samples=model.from_z(zs), chain_z=raw.chain_z,
                               log_prob=raw.log_prob, diagnostics=raw.diagnostics, seed=seed, noise=lp.noise,
                               extra={"posterior": "emcee, sandwich-adjusted"})
    elif posterior == "laplace":
        from hil.identify.timedomain import laplace_posterior

        post = laplace_posterior(model, _as_ml(fit), seed=seed)
    else:
        raise ModelSpecError(f"posterior must be 'emcee' or 'laplace', got {posterior!r}")
    timings["posterior"] = time.perf_counter() - t1
    timings["total"] = time.perf_counter() - t0
    std = np.sqrt(np.clip(np.diag(fit.cov_theta), 0, None))
    ls = LsResult(names=model.names, theta=fit.theta, z=fit.z, cov_z=fit.cov_z, cov_theta=fit.cov_theta, std=std,
                  chi2=float(np.sum(fit.e**2) / fit.ar.sigma**2), dof=int(fit.n - fit.k), success=True,
                  message="IDIM-ML", n_starts=1)
    ev = np.asarray(np.linalg.eigvalsh(fit.fisher), dtype=np.float64)
    ident = IdentifiabilityReport(names=model.names, theta=fit.theta, fisher=fit.fisher, crb_cov_z=fit.cov_z,
                                  crb_std=fit.crb_std, crb_rel_std=fit.crb_std / np.maximum(np.abs(fit.theta), 1e-300),
                                  eigenvalues=ev, condition=float(ev[-1] / max(ev[0], 1e-300)),
                                  rank=int(np.sum(ev > 1e-12 * ev[-1])))
    n = yy.size
    est = estimate_frf([(uu[:, None], yy[:, None])], fs, nperseg=max(min(n // 8, 8192), 16),
                       input_names=model.input_names, output_names=model.output_names)
    res = IdentificationResult(model, est, ls, fit.crb_std, ident, post, report, timings, method="idim-ml",
                               adequacy=adequacy, misfit_accepted=bool(accept_misfit and adequacy.misfit),
                               ml=_info(fit, post.extra.get("posterior", posterior)))
    res.record = dict(record or {})
    return res


def _as_ml(fit: InverseFit) -> Any:
    """The fit as the :class:`hil.identify.timedomain.MlResult` fields the Laplace posterior reads."""
    from types import SimpleNamespace

    return SimpleNamespace(cov_z=fit.cov_z, z=fit.z)


def identify_friction_record(src: Any, overrides: Mapping[str, Any], friction: Sequence[str]) -> Any:
    """A run record (:class:`hil.identify.source.RecordSource`): the input is the target's effort
    command (or ``inputs``), the output its ``position`` (or ``outputs``: ``position``/``position_0``
    or ``velocity``/``velocity_0`` -> SIGNAL)."""
    from hil.identify.records import _pick_target, _vector_names, signal

    ov = {k: v for k, v in dict(overrides).items() if v is not None}
    model = str(ov.pop("model", "mbk") or "mbk").lower()
    if model != "mbk":
        raise ModelSpecError(f"friction is available for the 1-DOF mbk model (got --model {model})")
    data = src.to_identify_dict()
    sig = data["signals"]
    notes: list[str] = []
    target = ov.pop("target", None)
    inputs = ov.pop("inputs", None)
    if not inputs:
        target = target or _pick_target(sig, notes)
        names = _vector_names(sig, f"{target}.effort_cmd")
        if not names:
            raise ModelSpecError(f"the record has no channel {target}.effort_cmd: name the input with --input")
        inputs = names[:1]
    if len(inputs) != 1:
        raise ModelSpecError(f"friction models have one input (a 1-DOF joint), got {inputs}")
    outputs = dict(ov.pop("outputs", None) or {})
    output, name = "position", None
    for k, v in outputs.items():
        kind = k.split("_")[0]
        if kind not in ("position", "velocity"):
            raise ModelSpecError(f"--output {k}=...: friction models measure position (or velocity)")
        output, name = kind, v
    if name is None:
        tgt = target or inputs[0].split(".effort_cmd")[0]
        pos = _vector_names(sig, f"{tgt}.position")
        vel = _vector_names(sig, f"{tgt}.velocity")
        if pos:
            name = pos[0]
        elif vel:
            output, name = "velocity", vel[0]
        else:
            raise ModelSpecError("no position output: name it with --output position=SIGNAL")
    units = (getattr(getattr(src, "scene", None), "units", None) or dict(src.meta or {}).get("units") or "linear")
    kw = {k: ov[k] for k in ("seed", "posterior", "n_walkers", "max_steps", "max_seconds", "accept_misfit")
          if k in ov}
    res = identify_friction_arrays(np.asarray(data["t"], float), signal(sig, inputs[0]), signal(sig, name),
                                   friction, units=units if units in ("linear", "rotary") else "linear",
                                   output=output, **kw)
    res.record = {"path": str(src.path), "scene_sha256": src.scene_sha256,
                  "mapping": {"model": "mbk", "friction": list(normalize_friction(friction)), "inputs": list(inputs),
                              "outputs": {output: name}, "notes": notes}}
    return res
