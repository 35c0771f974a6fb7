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
from numpy.typing import ArrayLike, NDArray

from hil.identify.errors import DataQualityError, ModelSpecError
from hil.identify.friction import FrictionModel, describe_terms, normalize_friction
from hil.identify.inverse_ml import (
    InverseFit,
    InverseLogPosterior,
    check_inverse_fit,
    fit_inverse,
    fit_inverse_ml,
    sandwich_adjust,
    summary_row,
)

logger = logging.getLogger(__name__)

__all__ = ["CANDIDATES", "UNSUPPORTED", "compare_friction_models", "dynamics_bandwidth", "identify_friction_arrays",
           "identify_friction_dict", "identify_friction_model", "identify_friction_record", "integrate_velocity",
           "refuse_unsupported", "simulation_error", "unhold_position"]

#: friction models tried by the model choice, simplest first
CANDIDATES: tuple[tuple[str, ...], ...] = ((), ("coulomb",), ("coulomb", "offset"), ("coulomb", "stribeck", "offset"))


def sample_rate(t: ArrayLike) -> float:
    """THE sample rate of a record [Hz]: ``1 / median(diff t)`` snapped to its short decimal form
    (:func:`hil.identify.records.nominal_rate`)."""
    from hil.identify.records import sample_rate as _sr

    return _sr(t)


def simulation_error(model: Any, theta: ArrayLike, u: ArrayLike, q: ArrayLike, fs: float) -> dict[str, float]:
    """Open-loop simulation of the position from the force over a record (``model``: the 1-DOF
    :class:`FrictionModel` of a fit, read for its terms and units), from its measured start
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


def _info(fit: InverseFit, post_kind: str, f_dyn: float) -> dict[str, Any]:
    orders = ", ".join(f"{eq.name} AR({ar.order})" for eq, ar in zip(fit.model.equations, fit.ars, strict=True))
    return {"estimator": "inverse-dynamics maximum likelihood (IDIM-ML, hil.identify.inverse_ml)",
            "friction": list(fit.model.terms), "idim_ls": fit.idim.to_dict(),
            "equations": [{"name": eq.name, "left_side": eq.lhs} for eq in fit.model.equations],
            "noise_model": f"equation error: intervals from the sandwich with its smoothed periodogram; "
                           f"{orders} innovations (BIC) for the adequacy tests and the Cramer-Rao bound",
            "innovation_std": fit.ar.sigma,
            "innovation_std_by_equation": {eq.name: ar.sigma for eq, ar in zip(fit.model.equations, fit.ars,
                                                                                 strict=True)},
            "bic": fit.bic, "aic": fit.aic, "n_equation_error": fit.n, "posterior": post_kind,
            "decimation": fit.problem.parts[0].r, "filter_hz": fit.problem.parts[0].motion.f_filter,
            "dynamics_bandwidth_hz": f_dyn}


def integrate_velocity(v: ArrayLike, fs: float) -> NDArray[np.float64]:
    """A position [m or rad] from velocity samples at ``fs`` [Hz], 0 at the first sample, by the
    trapezoidal rule (centred: its central difference is ``(v_k-1 + 2 v_k + v_k+1) / 4``, no lag)."""
    vv = np.asarray(v, float)
    return np.concatenate([np.zeros((1, *vv.shape[1:])), np.cumsum((vv[1:] + vv[:-1]) / 2.0, axis=0)]) / fs


def dynamics_bandwidth(u: ArrayLike, fs: float, band: Sequence[float] | None = None) -> float:
    """``f_dyn`` [Hz] of the inverse model (:mod:`hil.identify.inverse_design`): half the top of the
    analysis ``band`` (default: the band holding 99.8 % of the input power,
    :func:`hil.identify.excitation.excited_band`), at least the benchmark's 20 Hz
    (:data:`hil.identify.idim.F_DYN`), at most ``fs / 5``."""
    from hil.identify.excitation import excited_band
    from hil.identify.idim import F_DYN

    top = float(band[1]) if band is not None else float(excited_band(np.asarray(u, float), fs)[1])
    return float(min(max(F_DYN, top / 2.0), fs / 5.0))


def _builder(model: str, terms: tuple[str, ...], *, n_dof: int, units: str, fs: float, umax: float,
             force: bool) -> Any:
    """``make_model(nominal, scale)`` of a friction model by name (``mbk``, ``sdea_locked``, ``sdea_free``)."""
    from hil.identify.inverse_models import SdeaFrictionModel

    if model == "mbk":
        return lambda nom, sc: FrictionModel(terms, n_dof=n_dof, nominal=nom, scale=sc, units=units, output="position",
                                             zoh_fs=fs, force_scale=umax)
    if model in ("sdea_locked", "sdea_free"):
        variant = model.split("_")[1]
        SdeaFrictionModel(variant, terms, force=force, zoh_fs=fs)  # refuses an unidentifiable set-up early
        return lambda nom, sc: SdeaFrictionModel(variant, terms, force=force, nominal=nom, zoh_fs=fs, force_scale=umax)
    raise ModelSpecError(f"friction models: mbk, sdea_locked, sdea_free (got --model {model})")


def identify_friction_model(
    model: str, friction: Sequence[str] | str, t: ArrayLike, inputs: ArrayLike, positions: ArrayLike, *,
    force: ArrayLike | None = None, force_ages: ArrayLike | None = None,
    windows: Sequence[tuple[float, float]] | None = None, band: Sequence[float] | None = None, units: str = "linear",
    seed: int = 0, posterior: str = "emcee", n_walkers: int | None = None, max_steps: int = 20000,
    max_seconds: float | None = None, accept_misfit: bool = False, **_ignored: Any,
) -> Any:
    """Identify the friction model ``model`` (``mbk`` with ``n_dof`` = the inputs' columns, ``sdea_locked``,
    ``sdea_free``; :mod:`hil.identify.inverse_models`) from time ``t`` [s], actuator forces ``inputs``
    (n, n_in) [N or N.m], the measured ``positions`` (n, n_c) of the model's coordinates [m or rad] and,
    for an SDEA, the spring torque ``force`` (n,) [N.m] with the ``force_ages`` of a held sensor.
    ``windows``: [t0, t1) per experiment (one inverse-model record each; default the whole record);
    ``band`` [Hz]: the analysis band (sets the dynamics bandwidth, :func:`dynamics_bandwidth`). Returns an
    :class:`hil.identify.api.IdentificationResult` (``method = "idim-ml"``)."""
    from hil.identify.api import IdentificationResult
    from hil.identify.diagnostics import check_dead, check_finite, run_checks
    from hil.identify.fisher import IdentifiabilityReport
    from hil.identify.fit import LsResult
    from hil.identify.frf import estimate_frf
    from hil.identify.inverse_design import InverseRecord
    from hil.identify.posterior import PosteriorResult, sample_posterior

    terms = normalize_friction(friction)
    t0 = time.perf_counter()
    tt = np.asarray(t, float)
    U = np.asarray(inputs, float).reshape(tt.size, -1)
    Q = np.asarray(positions, float).reshape(tt.size, -1)
    F = None if force is None else np.asarray(force, float).ravel()
    fs = sample_rate(tt)
    build = _builder(model, terms, n_dof=U.shape[1], units=units, fs=fs, umax=float(np.max(np.abs(U)) or 1.0),
                     force=F is not None)
    m0 = build({}, {})
    # the forces get every check; the positions not the saturation one: an axis held by stiction sits
    # flat at one count, which is friction, not a clipped sensor
    report = run_checks(tt, dict(zip(m0.input_names, U.T, strict=True)), {})
    outs = dict(zip(m0.coordinates, Q.T, strict=True))
    report.diagnoses += check_finite(outs) + check_dead(outs, role={k: "output" for k in outs})
    if F is not None:
        report.diagnoses += check_finite({"force": F}) + check_dead({"force": F}, role={"force": "output"})
    report.raise_if_failed()
    n_e = len(m0.equations)
    Y = np.zeros((tt.size, n_e))
    ages: list[NDArray[np.int64] | None] = [None] * n_e
    for e, eq in enumerate(m0.equations):
        if eq.lhs == "input":
            Y[:, e] = U[:, int(eq.name.split("_")[1]) if "_" in eq.name else 0]
        elif eq.lhs == "measured" and F is not None:
            Y[:, e] = F
            ages[e] = None if force_ages is None else np.asarray(force_ages, int)
    masks = [np.ones(tt.size, bool)] if not windows else [(tt >= a - 1e-9) & (tt < b - 1e-9) for a, b in windows]
    recs = [InverseRecord(Q[mk], Y[mk], [None if a is None else a[mk] for a in ages]) for mk in masks if mk.sum() > 1]
    if not recs:
        raise DataQualityError(f"no samples in the experiment windows {windows}")
    f_dyn = dynamics_bandwidth(U, fs, band)
    start = None
    if model == "mbk" and U.shape[1] == 1:  # one joint: the benchmark's IDIM-LS is the start (and is reported)
        from hil.identify.idim import idim_ls

        start = idim_ls(np.concatenate([r.Q[:, 0] for r in recs]), np.concatenate([r.Y[:, 0] for r in recs]), fs,
                        terms)
    fit = fit_inverse(build, recs, fs, f_dyn=f_dyn, start=start)
    timings = {"ml": time.perf_counter() - t0}
    adequacy = check_inverse_fit(fit)
    mdl = fit.model
    t1 = time.perf_counter()
    if posterior == "emcee":
        lp = InverseLogPosterior(fit)
        raw = sample_posterior(lp, fit.z, fit.cov_z, seed=seed, n_walkers=n_walkers, max_steps=max_steps,  # type: ignore[arg-type]
                               max_seconds=max_seconds)
        lo, hi = mdl.z_bounds()
        zs = np.clip(sandwich_adjust(fit, mdl.to_z(raw.samples)), lo, hi)
        post = PosteriorResult(names=mdl.names, samples=mdl.from_z(zs), chain_z=raw.chain_z, log_prob=raw.log_prob,
                               diagnostics=raw.diagnostics, seed=seed, noise=lp.noise,
                               extra={"posterior": "emcee, sandwich-adjusted"})
    elif posterior == "laplace":
        from hil.identify.timedomain import laplace_posterior

        post = laplace_posterior(mdl, _as_ml(fit), seed=seed)
    else:
        raise ModelSpecError(f"posterior must be 'emcee' or 'laplace', got {posterior!r}")
    timings["posterior"] = time.perf_counter() - t1
    timings["total"] = time.perf_counter() - t0
    std = np.sqrt(np.clip(np.diag(fit.cov_theta), 0, None))
    ls = LsResult(names=mdl.names, theta=fit.theta, z=fit.z, cov_z=fit.cov_z, cov_theta=fit.cov_theta, std=std,
                  chi2=float(np.sum(fit.e**2)), dof=int(fit.e.size - fit.k), success=True, message="IDIM-ML",
                  n_starts=1)
    ev = np.asarray(np.linalg.eigvalsh(fit.fisher), dtype=np.float64)
    ident = IdentifiabilityReport(names=mdl.names, theta=fit.theta, fisher=fit.fisher, crb_cov_z=fit.cov_z,
                                  crb_std=fit.crb_std, crb_rel_std=fit.crb_std / np.maximum(np.abs(fit.theta), 1e-300),
                                  eigenvalues=ev, condition=float(ev[-1] / max(ev[0], 1e-300)),
                                  rank=int(np.sum(ev > 1e-12 * ev[-1])))
    Yo = Q if F is None else np.column_stack([Q, F])
    est = estimate_frf([(U, Yo)], fs, nperseg=max(min(tt.size // 8, 8192), 16), input_names=mdl.input_names,
                       output_names=mdl.output_names)
    res = IdentificationResult(mdl, est, ls, fit.crb_std, ident, post, report, timings, method="idim-ml",
                               adequacy=adequacy, misfit_accepted=bool(accept_misfit and adequacy.misfit),
                               ml=_info(fit, post.extra.get("posterior", posterior), f_dyn))
    return res


def identify_friction_arrays(
    t: ArrayLike, u: ArrayLike, q: ArrayLike, friction: Sequence[str] | str, *, units: str = "linear",
    output: str = "position", record: Mapping[str, Any] | None = None, **kw: Any,
) -> Any:
    """Identify the 1-DOF model with ``friction`` from time ``t`` [s], force ``u`` and the measured
    ``output`` (``position`` [m or rad]; a ``velocity`` is integrated to a position,
    :func:`integrate_velocity`); ``kw``: those of :func:`identify_friction_model`."""
    tt = np.asarray(t, float)
    yy = np.asarray(q, float)
    if output == "velocity":
        yy = integrate_velocity(yy, sample_rate(tt))
    elif output != "position":
        raise ModelSpecError(f"friction models measure 'position' or 'velocity', got {output!r}")
    res = identify_friction_model("mbk", friction, tt, np.asarray(u, float), yy, units=units, **kw)
    res.record = dict(record or {})
    return res


def _as_ml(fit: InverseFit) -> Any:
    """The fit as the :class:`hil.identify.timedomain.MlResult` fields the Laplace posterior reads."""
    from types import SimpleNamespace

    return SimpleNamespace(cov_z=fit.cov_z, z=fit.z)


_KW = ("seed", "posterior", "n_walkers", "max_steps", "max_seconds", "accept_misfit")

#: options of the linear models that have no meaning for the friction models -> why (a one-line refusal)
UNSUPPORTED: dict[str, str] = {
    "method": "the friction models are fitted by inverse-dynamics ML only (drop --method)",
    "sampling": "the friction models take the force held over each sample period (zoh) only",
    "noise": "the friction models' noise model is the equation error's AR model (drop --noise)",
    "theta0": "the friction models start from IDIM-LS, not from given values (drop --set)",
    "period": "the friction models are fitted in the time domain (drop --period)",
    "nperseg": "the friction models are fitted in the time domain (drop nperseg)",
}


def refuse_unsupported(options: Mapping[str, Any], terms: Sequence[str]) -> None:
    """Raise a one-line :class:`ModelSpecError` for a linear-model option given with friction
    (:data:`UNSUPPORTED`; ``method="auto"`` and ``sampling="zoh"`` are what the friction path does)."""
    for k, why in UNSUPPORTED.items():
        v = options.get(k)
        if v is None or (k, v) in (("method", "auto"), ("sampling", "zoh")):
            continue
        raise ModelSpecError(f"{k}={v!r} with friction {','.join(terms)}: {why}")


def unhold_position(q: ArrayLike, fs: float, rate: float | None) -> tuple[NDArray[np.float64], int]:
    """A position channel a record declares held (a slower encoder stream put on the record's time base
    by a zero-order hold, :func:`hil.identify.sensor_hold.declared_rate`) as the positions it measured:
    its new samples (age 0, :func:`hil.identify.sensor_hold.held_ages` with the declared ``rate`` [Hz])
    at the instants they appear, joined by a cubic spline (:class:`scipy.interpolate.CubicSpline`,
    not-a-knot) on every record sample. Differentiating the staircase itself would read each hold
    as a stop and each new value as a jump (velocity spikes of ``fs / rate`` times the mean, a
    delay of half a sensor period). Returns ``(positions, number of new samples)``."""
    from scipy.interpolate import CubicSpline

    from hil.identify.sensor_hold import held_ages

    qq = np.asarray(q, float)
    new = np.flatnonzero(held_ages(qq, fs, rate if rate is not None and np.isfinite(rate) else None) == 0)
    if new.size < 4:
        raise DataQualityError(f"a held position with {new.size} new samples cannot be differentiated")
    k = np.arange(qq.size, dtype=float)
    return np.asarray(CubicSpline(new.astype(float), qq[new])(k), float), int(new.size)


def _positions(sig: Mapping[str, Any], outputs: Mapping[str, str], keys: Sequence[str], fs: float,
               notes: list[str], meta: Mapping[str, Any] | None = None) -> NDArray[np.float64]:
    """The positions of coordinates ``keys`` (``position``, ``position_0``, ``output_position``) from the
    outputs mapping: a ``*position*`` signal as is, or, when the record's ``meta`` declares it held,
    its measured samples joined (:func:`unhold_position`); a ``*velocity*`` one: the record's position
    channel of the same device when it has one, else the velocity integrated (:func:`integrate_velocity`)."""
    from hil.identify.records import signal
    from hil.identify.sensor_hold import declared_rate

    cols = []
    for key in keys:
        vkey = key.replace("position", "velocity")
        if key in outputs:
            col = signal(sig, outputs[key])
            rate = declared_rate(meta or {}, outputs[key])
            if rate:  # declared held by the import (0.0: on the time base; None: nothing declared)
                col, n_new = unhold_position(col, fs, rate)
                notes.append(f"{key}: {outputs[key]} held (declared by the import, source {rate:g} Hz): its "
                             f"{n_new} measured samples joined by a cubic spline, not differentiated as held")
            cols.append(col)
        elif vkey in outputs:
            name = outputs[vkey]
            pos = name.replace(".velocity", ".position")
            if pos != name and pos.lstrip("-") in sig:
                cols.append(signal(sig, pos))
                notes.append(f"{key}: {pos} (the position channel of {name})")
            else:
                cols.append(integrate_velocity(signal(sig, name), fs))
                notes.append(f"{key}: {name} integrated (trapezoidal rule)")
        else:
            raise ModelSpecError(f"no position for {key}: name it with --output {key}=SIGNAL (or {vkey}=SIGNAL)")
    return np.column_stack(cols)


def identify_friction_record(src: Any, overrides: Mapping[str, Any], friction: Sequence[str]) -> Any:
    """A run record (:class:`hil.identify.source.RecordSource`): what it holds is read as for the linear
    models (:func:`hil.identify.records.plan_from_record`: model, target, inputs, outputs, windows, band;
    ``overrides`` win), then the positions are taken (:func:`_positions`), and for an SDEA the spring
    torque with, for a held sensor, its ages (:func:`hil.identify.sensor_hold.channel_ages`: the record's
    declaration of held channels first, else the repeats)."""
    from hil.identify.records import plan_from_record, signal
    from hil.identify.sensor_hold import channel_ages

    ov = {k: v for k, v in dict(overrides).items() if v is not None}
    refuse_unsupported(ov, friction)
    kw = {k: ov.pop(k) for k in _KW if k in ov}
    for k in ("sampling", "method", "noise", "resolution", "input_resolution", "excitation", "n_starts", "window",
              "theta0", "nperseg", "skip", "period"):
        ov.pop(k, None)
    if "model" in ov:
        ov["model"] = str(ov["model"]).lower().replace("-", "_")
    outputs_given = dict(ov.get("outputs") or {})
    if outputs_given:  # friction models name coordinates: position(_i), velocity(_i), output_*, force
        ov["outputs"] = {k: v for k, v in outputs_given.items() if not k.startswith("output_")}
    data = src.to_identify_dict()
    sig = data["signals"]
    plan = plan_from_record(src, sig, ov)
    t = np.asarray(data["t"], float)
    fs = sample_rate(t)
    notes = list(plan.notes)
    outs = {**plan.outputs, **outputs_given}
    U = np.column_stack([signal(sig, n) for n in plan.inputs])
    force = force_ages = None
    if plan.model == "mbk":
        n = len(plan.inputs)
        keys = ["position"] if n == 1 else [f"position_{i}" for i in range(n)]
        outs = {(k if n > 1 or "_" not in k or k.startswith("output") else k.split("_")[0]): v for k, v in outs.items()}
    elif plan.model in ("sdea_locked", "sdea_free"):
        keys = ["position"] + (["output_position"] if plan.model == "sdea_free" else [])
        if "force" in outs:
            force = signal(sig, outs["force"])
            force_ages, how = channel_ages(force, dict(getattr(src, "meta", {}) or {}), outs["force"], fs)
            if how:
                notes.append(f"force {outs['force']}: {how}")
    else:
        raise ModelSpecError(f"friction models: mbk, sdea_locked, sdea_free (got --model {plan.model})")
    Q = _positions(sig, outs, keys, fs, notes, dict(getattr(src, "meta", {}) or {}))
    units = plan.model_options.get("units") or "linear"
    res = identify_friction_model(plan.model, friction, t, U, Q, force=force, force_ages=force_ages,
                                  windows=plan.windows, band=plan.kwargs.get("band"),
                                  units=units if units in ("linear", "rotary") else "linear", **kw)
    res.record = {"path": str(src.path), "scene_sha256": src.scene_sha256,
                  "mapping": {"model": plan.model, "friction": list(normalize_friction(friction)),
                              "inputs": list(plan.inputs), "outputs": outs,
                              "windows_s": [list(w) for w in plan.windows], "notes": notes}}
    return res


def identify_friction_dict(record: Mapping[str, Any], overrides: Mapping[str, Any], friction: Sequence[str]) -> Any:
    """A record dict ``{"t", "signals", "meta"}`` (:func:`hil.identify.api.identify_record`): ``meta``
    (``overrides`` win) names the ``model`` (default ``mbk``), the ``inputs`` (force signals, one per
    joint) and the ``outputs`` (``{"position": sig}`` / ``position_i`` / ``velocity(_i)``; an SDEA's
    ``force`` and ``output_position``/``output_velocity``; a list: the positions in joint order)."""
    from hil.identify.records import signal
    from hil.identify.sensor_hold import channel_ages

    meta = {**dict(record.get("meta") or {}), **{k: v for k, v in dict(overrides).items() if v is not None}}
    refuse_unsupported({k: v for k, v in dict(overrides).items() if v is not None}, friction)
    try:
        t = np.asarray(record["t"], float)
        sig = record["signals"]
    except (KeyError, TypeError) as exc:
        raise ModelSpecError("record needs 't' and 'signals'") from exc
    ins, outs = meta.get("inputs"), meta.get("outputs")
    if not ins or not outs:
        raise ModelSpecError("a record dict with friction needs meta inputs [force signal(s)] and outputs "
                             "{'position': signal}")
    ins = list(ins.values()) if isinstance(ins, Mapping) else list(ins)
    model = str(meta.get("model") or "mbk").lower().replace("-", "_")
    n = len(ins)
    if not isinstance(outs, Mapping):
        outs = {("position" if n == 1 else f"position_{i}"): o for i, o in enumerate(outs)}
    outs = {str(k): str(v) for k, v in outs.items()}
    fs = sample_rate(t)
    notes: list[str] = []
    force = force_ages = None
    if model == "mbk":
        outs = {(k.split("_")[0] if n == 1 and k.split("_")[-1] == "0" else k): v for k, v in outs.items()}
        keys = ["position"] if n == 1 else [f"position_{i}" for i in range(n)]
    else:
        keys = ["position"] + (["output_position"] if model == "sdea_free" else [])
        if "force" in outs:
            force = signal(sig, outs["force"])
            force_ages, how = channel_ages(force, meta, outs["force"], fs)
            if how:
                notes.append(f"force {outs['force']}: {how}")
    Q = _positions(sig, outs, keys, fs, notes, meta)
    U = np.column_stack([signal(sig, s) for s in ins])
    kw = {k: meta[k] for k in (*_KW, "band", "units") if k in meta}
    res = identify_friction_model(model, friction, t, U, Q, force=force, force_ages=force_ages, **kw)
    res.record = {"mapping": {"model": model, "friction": list(normalize_friction(friction)), "inputs": ins,
                              "outputs": outs, "notes": notes}}
    return res
