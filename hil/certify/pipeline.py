"""``hil certify``: experiments -> identification -> network model over the posterior -> stability
criteria -> GO / MARGINAL / NO-GO (or ERROR) -> certificate record (and reports).

Stages (timed; ``Certificate.measurements`` records what each produced), each a function
``stage_<name>`` here taking the :class:`~hil.certify.stages.Context`, the
:class:`~hil.certify.stages.Sheet` it records on and the earlier stages' outputs, and returning
its own typed output (:mod:`hil.certify.stages`: the dataclasses and the measurements' declared
limits); :func:`certify_scene` composes them (decide runs before witness: the witness only adds
reasons). An exception escaping a stage makes the certificate ERROR with the stage and reason
recorded, never FAIL:

1. **run** the scene's experiments on its bench (mocked or real) -- records, energy evidence;
2. **identify** the parameters named in ``certification.identify`` from their records (emcee
   posterior); parameters listed in ``certification.uncertain`` are drawn log-normally instead;
3. **nominal**: the network model at the nominal values -- each parameter's median: the posterior
   median of an identified one, the stated value of an uncertain one -- (plus the scene's fixed
   parameters, e.g. controller gains) through the criterion, with margins and evidence;
4. **robust**: the criterion on every posterior draw (vectorized for the SDEA; per draw,
   verdict-only, for other networks), P(stable) with a Clopper-Pearson interval, the worst-case
   margin over the credible ellipsoid (optimized), the critical band (where the binding condition is
   within 10 % of its minimum; docs/CERTIFICATION.md "critical band"); P(stable) counts only
   independent draws: each emcee chain is thinned by its autocorrelation time first; the worst case
   minimizes the nominal margin's own function (the exact criterion's margin), so worst ≤ nominal;
   the reliability index β (FORM) with its design point, and, when plain Monte Carlo cannot reach
   the requirement, P(stable) by importance sampling around it (docs/CERTIFICATION.md);
5. **design** guidance for a free parameter (the largest value keeping the required probability),
   and for the SDEA's k22 the headroom at the nominal plant and over the posterior;
6. **witness**: when the nominal network is potentially unstable, a passive termination set that
   makes the operator-port impedance non-positive-real, simulated with the exact-ZOH engine (the
   coupled system diverges, or E_s(t) = ∫ F·V dt goes negative under a sinusoidal force);
7. **decide** with the policy; NaN or missing evidence gives ERROR, never GO.

The witness, the plots and the energy evidence are *optional* stages: a failure inside one never
stops the certification and is never swallowed either. It is logged and recorded in the
certificate's ``errors`` ("<stage> failed: <reason>", shown in the report's Errors section), and
it leaves the decision as the criterion made it (a NO-GO stays NO-GO; a NO-GO without its witness
says why in its reasons), with one conservative exception: a GO whose energy evidence could not be
read becomes MARGINAL.

Only what the scene uses is computed and reported: no identification section without identify
entries, no energy section without energy-injection experiments, no multi-port section for a
two-port with 1-DOF ports, no design section without a design parameter.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import logging
import math
import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Literal

import numpy as np

from hil.bench.stopflag import StopRequested
from hil.certify import friction as fr
from hil.certify.certificate import (
    Certificate,
    ConditionRow,
    DecisionStr,
    Design,
    EnergyEvidence,
    Identification,
    Measurement,
    MultiPort,
    Nominal,
    ParameterSummary,
    Robust,
    SceneInfo,
    Series,
    VerdictStr,
    Witness,
    seal,
)
from hil.certify.provenance import bench_info
from hil.certify.stages import (
    NOMINAL_MARGIN,
    Context,
    DesignOutput,
    NominalOutput,
    PosteriorDraws,
    RobustOutput,
    RunOutput,
    Sheet,
    Verdict,
    WitnessOutput,
    beta_spec,
    converged_spec,
    energy_spec,
    experiment_spec,
    headroom_spec,
    info_spec,
    nominal_verdict_spec,
    one_line,
    p_stable_is_spec,
    p_stable_spec,
    worst_case_spec,
)
from hil.certify.statistics import (
    Decision,
    Policy,
    decide,
    max_safe_parameter,
    probability_of_stability,
    worst_case_margin,
)
from hil.errors import HilError
from hil.models import build_network, model_params_from_scene

logger = logging.getLogger(__name__)

__all__ = ["build_network", "certify_scene", "model_params_from_scene"]

Progress = Callable[[str], None]


# ---------------------------------------------------------------------------------------------
# model parameters (each model's scene mapping is registered with it, hil.models)


def _criterion(model: str, cfg: str) -> str:
    from hil.models import get_model

    if cfg != "auto":
        return cfg
    return get_model(model).criterion


def _check(tm: Any, criterion: str, margins: bool = True) -> Any:
    from hil.stability.criteria import check

    if margins:
        return check(tm, criterion)
    from hil.stability import criteria as C

    if criterion == "passivity":
        return C.two_port_passivity(tm, margins=False) if tm.n_ports == 2 else C.positive_real(tm, margins=False)
    if criterion == "llewellyn":
        return C.llewellyn(tm, margins=False)
    return check(tm, criterion)


# ---------------------------------------------------------------------------------------------
# the pipeline: certify_scene = seal(compose(run, identify, nominal, robust, design, decide, witness))


def certify_scene(scene: Any, out_dir: str | Path, *, seed: int | None = None, progress: Progress | None = None,
                  run_experiments: bool = True, max_ticks: int | None = None,
                  outcomes: Mapping[str, Any] | None = None,
                  tick_progress: Callable[[str, int, int], None] | None = None) -> Certificate:
    """Run the whole pipeline for ``scene`` (see the module docstring). Never raises for bad
    evidence: problems become an ERROR certificate with their reasons (a scene without a
    ``certification`` section too, and a stage that raised: its name and reason). ``outcomes``
    (experiment name -> ExperimentOutcome) reuses runs already made instead of running the
    experiments again. ``tick_progress(record name, tick, ticks)`` follows each run (what ``hil
    certify`` shows while an experiment runs).

    The certificate comes back sealed: ``evidence`` holds the SHA-256 of the scene text (written
    to ``out_dir/scene.yaml``) and of every record it rests on (the records written under
    ``out_dir/records`` and any reused record it names), ``integrity.digest`` the digest of its
    content (see :mod:`hil.certify.certificate`)."""
    cert = _assess(scene, out_dir, seed=seed, progress=progress, run_experiments=run_experiments,
                   max_ticks=max_ticks, outcomes=outcomes, tick_progress=tick_progress)
    return _seal(cert, scene, Path(out_dir))


def _seal(cert: Certificate, scene: Any, out: Path) -> Certificate:
    """Evidence hashes (records are closed by now: runs and identification are done) and digest."""
    from hil.certify.verify import file_evidence

    scene_path = out / "scene.yaml"
    text = scene.source_text.encode("utf-8")
    try:
        out.mkdir(parents=True, exist_ok=True)
        if not (scene_path.is_file() and scene_path.read_bytes() == text):
            tmp = scene_path.with_name(f".scene.yaml.{os.getpid()}.tmp")
            tmp.write_bytes(text)
            os.replace(tmp, scene_path)
    except OSError as exc:
        raise HilError(f"{scene_path}: cannot write the scene copy: {exc.strerror or exc}") from None
    evidence = [file_evidence(out, scene_path, "scene")]
    records: list[Path] = sorted((out / "records").glob("*.h5")) if (out / "records").is_dir() else []
    named = [i.record for i in cert.identification or []] + [e.record for e in cert.energy or []]
    for r in named:
        p = Path(r) if Path(r).is_absolute() else out / r  # named relative to the certificate folder
        if not p.is_file():
            logger.warning("evidence: record %s named by the certificate is not a file; not hashed", r)
        elif all(p.resolve() != q.resolve() for q in records):
            records.append(p)
    evidence += [file_evidence(out, r, "record") for r in records]
    return seal(cert.model_copy(update={"evidence": evidence}))


def _relative(folder: Path, record: str) -> str:
    """A record path as the certificate names it: POSIX, relative to the certificate's folder (so a
    moved folder still finds its records), whatever the working directory was."""
    p = Path(record)
    if not p.is_absolute():
        p = Path.cwd() / p
    return Path(os.path.relpath(p.resolve(), Path(folder).resolve())).as_posix()


def _scene_info(scene: Any) -> SceneInfo:
    return SceneInfo(name=scene.name, sha256=scene.sha256, description=scene.description, source=scene.path,
                     units=scene.units)


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


def _assess(scene: Any, out_dir: str | Path, *, seed: int | None = None, progress: Progress | None = None,
            run_experiments: bool = True, max_ticks: int | None = None,
            outcomes: Mapping[str, Any] | None = None,
            tick_progress: Callable[[str, int, int], None] | None = None) -> Certificate:
    """The pipeline proper (:func:`certify_scene` adds the evidence and the digest): the stages in
    order, each a function of the context and the stages' outputs before it."""
    if scene.certification is None:
        return Certificate(created_utc=_now(), software=_versions(), scene=_scene_info(scene),
                           decision="ERROR", reasons=["the scene has no 'certification' section: nothing to certify"],
                           policy={}, measurements=[], errors=["no certification section"])
    cert = scene.certification
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    policy = Policy(cert.policy.required_probability, cert.policy.confidence, cert.policy.credible)
    # the scene's names and ranges (model, parameters, identify entries, design) were checked by
    # hil.scene.spec at load time
    ctx = Context(scene=scene, cert=cert, out=out, seed=int(scene.seed if seed is None else seed), policy=policy,
                  model=cert.model, criterion=_criterion(cert.model, cert.criterion),
                  params=model_params_from_scene(scene), say=progress or (lambda msg: logger.info(msg)))
    sheet = Sheet()
    stage = "run"
    try:
        run = stage_run(ctx, sheet, run_experiments=run_experiments, max_ticks=max_ticks, outcomes=outcomes,
                        tick_progress=tick_progress)
        stage = "identify"
        draws = stage_identify(ctx, sheet, run)
        stage = "nominal"
        nominal = stage_nominal(ctx, sheet, draws)
        stage = "robust"
        robust = stage_robust(ctx, sheet, draws, nominal)
        stage = "design"
        design = stage_design(ctx, sheet, draws, nominal)
        stage = "decide"
        verdict = stage_decide(ctx, sheet, run, draws, nominal, robust, design)
        stage = "witness"
        witness = stage_witness(ctx, sheet, nominal)
    except HilError:
        # one of ours, with its exit code (a device that cannot be opened, a record that cannot be
        # written, StopRequested: the person at the bench asked to stop): no certificate follows
        raise
    except Exception as exc:  # a defect in a stage: ERROR with its reason, never FAIL
        reason = one_line(exc)
        logger.error("certification stage %s failed: %s", stage, reason, exc_info=True)
        sheet.errors.append(f"stage {stage} failed: {reason}")
        return _certificate(ctx, sheet, Verdict(Decision.ERROR, (f"stage {stage} failed: {reason}",)))
    return _certificate(ctx, sheet, verdict, run=run, draws=draws, nominal=nominal, robust=robust, design=design,
                        witness=witness)


def _certificate(ctx: Context, sheet: Sheet, verdict: Verdict, *, run: RunOutput | None = None,
                 draws: PosteriorDraws | None = None, nominal: NominalOutput | None = None,
                 robust: RobustOutput | None = None, design: DesignOutput | None = None,
                 witness: WitnessOutput | None = None) -> Certificate:
    """The certificate record of the stages' outputs (those that ran)."""
    tm = None if nominal is None else nominal.network
    multiport = None
    if tm is not None and (tm.n_ports > 2 or max(tm.port_dofs) > 1):
        how = ("Theorem 1 of paper 000 (symmetrization conditions A, B checked)"
               if ctx.criterion == "absolute_stability" else
               f"{ctx.criterion} of the full {tm.n}x{tm.n} immittance matrix")
        multiport = MultiPort(ports=list(tm.port_dofs), dof_total=tm.n, symmetrization=how)
    sheet.add(info_spec("run time", "s").measure(sum(sheet.timings.values()), description=", ".join(
        f"{k} {v:.1f} s" for k, v in sheet.timings.items())))
    policy = ctx.policy
    reasons = list(verdict.reasons) + (list(witness.reasons) if witness is not None else [])
    idents = [i.model_copy(update={"record": _relative(ctx.out, i.record)}) for i in draws.identification] \
        if draws is not None else []
    energy = [e.model_copy(update={"record": _relative(ctx.out, e.record)}) for e in run.energy] \
        if run is not None else []
    return Certificate(
        created_utc=_now(), software=_versions(), scene=_scene_info(ctx.scene),
        decision=_DECISIONS[verdict.decision], reasons=reasons,
        policy={"required_probability": policy.required_probability, "confidence": policy.confidence,
                "credible": policy.credible},
        measurements=sheet.measurements, nominal=None if nominal is None else nominal.section,
        robust=None if robust is None else robust.section,
        identification=(idents or None) if draws is not None else None,
        design=None if design is None else design.design, witness=None if witness is None else witness.witness,
        energy=(energy or None) if run is not None else None, multiport=multiport,
        bench=bench_info(ctx.scene, None if run is None else run.outcomes), plots=sheet.plots,
        errors=sheet.errors + sheet.optional_errors)


# ---------------------------------------------------------------------------------------------
# 1. run


def stage_run(ctx: Context, sheet: Sheet, *, run_experiments: bool = True, max_ticks: int | None = None,
              outcomes: Mapping[str, Any] | None = None,
              tick_progress: Callable[[str, int, int], None] | None = None) -> RunOutput:
    """Run the scene's experiments (or take ``outcomes`` already made): one measurement per
    experiment, the energy evidence, fault counters and realtime loop timing."""
    scene, out = ctx.scene, ctx.out
    energy: list[EnergyEvidence] = []
    given = dict(outcomes or {})
    done: dict[str, Any] = {}
    if given:
        for i_name, o in given.items():
            done[i_name] = o
            _energy_stage(sheet, i_name, o, energy, sheet.measurements, sheet.plots)
        _fault_measurements(given, sheet.measurements)
    elif run_experiments and scene.experiments:
        from hil.run.runner import Runner

        configs = scene.experiment_configs()
        names = [e["name"] for e in configs]
        used = experiments_used(ctx.cert, configs)
        for n in names:
            if n not in used:  # `hil run` still runs it; certification never reads its record
                ctx.say(f"{scene.name}: experiment {n} skipped (not used by the certification)")
                sheet.add(info_spec(f"experiment {n}").measure(
                    "skipped", description="not used by the certification (no identify entry, not an energy "
                                           "injection); `hil run` runs it"))
        select = [i for i, n in enumerate(names) if n in used]
        with sheet.timed("run", ctx.say, scene.name) if select else contextlib.nullcontext():
            runner = Runner(scene, out / "records", max_ticks=max_ticks, progress=tick_progress)
            ran = [names[i] for i in select]
            for name, o in zip(ran, runner.run(select=select) if select else [], strict=False):
                done[name] = o
                ok = o.status == "completed"
                sheet.add(experiment_spec(name).measure(
                    o.status, description=o.stop_reason if not ok else f"record {getattr(o.record, 'name', o.record)}"))
                if o.status == "error":
                    sheet.errors.append(f"experiment {name}: {o.stop_reason}")
                _energy_stage(sheet, name, o, energy, sheet.measurements, sheet.plots)
            # (nothing selected: the runner never ran and has no stop to report)
            stop_reason = getattr(runner, "stop_reason", None) if select else None
            if stop_reason and all(o.status == "completed" for o in done.values()):
                sheet.errors.append(f"run stopped: {stop_reason}")  # e.g. a signal after the last experiment
            from hil.run.runner import bench_never_opened

            if select and (why := bench_never_opened(list(done.values()), runner)) is not None:
                from hil.errors import BenchUnavailable  # nothing ran: no certificate, exit 2 at the CLI

                raise BenchUnavailable(f"{scene.name}: the bench could not be opened, no experiment ran: {why}")
            if (stop_reason or "").startswith("signal"):
                # the person at the bench asked to stop: no identification or certificate follows
                kept = sorted((out / "records").glob("*.h5")) if (out / "records").is_dir() else []
                where = f"the records so far are in {out / 'records'}" if kept else "no record was written"
                raise StopRequested(f"{stop_reason}; {where}", runner.stop_status or "safety_stop")
            _fault_measurements(done, sheet.measurements)

    if any((getattr(o, "stats", {}) or {}).get("mode") == "realtime" for o in done.values()):
        # realtime runs only: loop lateness and sample timing rows (lockstep runs have none, and the
        # module's record and realtime imports are not loaded for them)
        from hil.certify.lateness import lateness_measurements

        sheet.measurements += lateness_measurements(done, scene)
    return RunOutput(outcomes=done, energy=tuple(energy))


#: the certificate row that stands for the worst-case search and β on a nominal NO-GO
NOT_SEARCHED_ROW = "worst-case margin, β"


def experiments_used(cert: Any, configs: list[dict[str, Any]]) -> set[str]:
    """Names of the experiments whose records the certification reads: those named by a
    ``certification.identify`` entry (identification) and every energy-injection experiment (energy
    evidence). The others (e.g. a free-output chirp or a static hold) are left out of ``hil certify``."""
    used = {spec.experiment for spec in cert.identify}
    used.update(e["name"] for e in configs if e.get("type") == "energy_injection")
    return used


# ---------------------------------------------------------------------------------------------
# 2. identify


def stage_identify(ctx: Context, sheet: Sheet, run: RunOutput) -> PosteriorDraws:
    """Identify the parameters named in ``certification.identify`` from their records (independent
    draws of each thinned emcee chain), draw those in ``certification.uncertain`` log-normally,
    and subsample to ``certification.draws`` without replacement."""
    cert, scene, seed, errors = ctx.cert, ctx.scene, ctx.seed, sheet.errors
    draws: dict[str, np.ndarray] = {}
    thinning: list[str] = []  # how each identification's chain became independent draws
    idents: list[Identification] = []
    converged = True
    caps: list[str] = []  # reasons the decision can be at most MARGINAL (misfit plant, friction-masked energy)
    by_target: dict[str, Any] = {}  # experiment target -> identification result (dry friction of its port)
    targets = {c["name"]: c.get("target") for c in scene.experiment_configs()}
    if cert.identify:
        with sheet.timed("identify", ctx.say, scene.name):
            for spec in cert.identify:
                o = run.outcomes.get(spec.experiment)
                if o is None or o.record is None:
                    errors.append(f"identification: experiment {spec.experiment!r} has no record")
                    continue
                try:
                    from hil.identify.api import identify_record, store_result
                    from hil.record.identify_source import open_source  # the record as identification reads it

                    res = identify_record(open_source(o.record), seed=seed,
                                          **fr.identify_kwargs(spec, targets.get(spec.experiment)))
                    store_result(o.record, res)
                except HilError as exc:
                    errors.append(f"identification from {spec.experiment}: {exc}")
                    continue
                # a misfit plant model never feeds a GO (issue 12): its stability findings are evidence
                # about a model the data reject, so the decision is at most MARGINAL (issue 25)
                misfit = fr.misfit_reasons(res) or fr.linear_friction_screen(o.record, res, spec, scene.units)
                sheet.add(fr.adequacy_spec(spec.experiment).measure(
                    not misfit, description="; ".join(misfit) if misfit else fr.ADEQUACY_DESCRIPTION))
                if misfit:
                    caps.append(f"plant model misfit ({spec.experiment}): {'; '.join(misfit)}; a decision on a model "
                                "the data reject is at most MARGINAL")
                if targets.get(spec.experiment):
                    by_target[str(targets[spec.experiment])] = res
                converged = converged and res.converged
                summ = res.summary()
                units = dict(zip(res.model.names, res.model.units, strict=True))
                truth = {**_truth(scene), **friction_truth(scene, str(targets.get(spec.experiment) or ""))}
                idents.append(Identification(
                    model=res.model.name, record=str(o.record), converged=res.converged,
                    reason="; ".join(res.posterior.diagnostics.reasons) if not res.converged else "",
                    parameters=[ParameterSummary(name=k, unit=units.get(k, ""), truth=truth.get(k),
                                                 mean=v["mean"], median=v["median"], q05=v["q05"], q95=v["q95"],
                                                 std=v["std"], ls_std=v.get("ls_std"), crb_std=v.get("crb_std"))
                                for k, v in summ.items()],
                    diagnostics=res.posterior.diagnostics.to_dict(res.names)))
                samples, thin_note = _independent_samples(res)
                thinning.append(thin_note)
                # sampled parameters plus the model's derived quantities (e.g. the entries of M, B, K
                # of an MBK model sampled as Cholesky factors)
                available = {n: samples[:, i] for i, n in enumerate(res.names)}
                available.update({k: np.asarray(v) for k, (v, _u) in res.model.derived(samples).items()})
                mapping = spec.map or fr.default_map(res.names)
                sheet.measurements += fr.friction_rows(spec.experiment, res) if spec.friction else []
                for src, dst in mapping.items():
                    if src not in available:
                        errors.append(f"identification: parameter {src!r} not in model {res.model.name} "
                                      f"(have {sorted(available)})")
                        continue
                    draws[dst] = available[src]
                sheet.optional(f"plots (identification {spec.experiment})", _identification_plots, sheet.plots,
                               spec.experiment, res, seed, scene.units)
                sheet.add(converged_spec(res.model.name).measure(res.converged))
    rng = np.random.default_rng(seed)
    n_draws = cert.draws
    n_independent: int | None = None
    if draws:
        # independent posterior draws only (thinned chains), never resampled with replacement: with
        # fewer independent draws than requested, all of them are used and the certificate says so
        n_avail = min(len(v) for v in draws.values())
        n_independent = n_avail
        idx = rng.choice(n_avail, size=min(n_draws, n_avail), replace=False)
        draws = {k: np.asarray(v)[idx] for k, v in draws.items()}
        n_draws = idx.size
        if n_avail < cert.draws:
            thinning.append(f"only {n_avail} independent posterior draws exist: all used, fewer than the "
                            f"{cert.draws} requested")
        else:
            thinning.append(f"{n_draws} of them drawn without replacement")
    elif cert.uncertain:
        thinning.append(f"{n_draws} independent log-normal draws of the uncertain parameters")
    for k, u in cert.uncertain.items():
        draws[k] = u.value * np.exp(u.rel_std * rng.standard_normal(n_draws))
    for k, v in draws.items():
        if not np.all(np.isfinite(v)):
            errors.append(f"parameter {k}: non-finite posterior draws")
    # energy evidence without the dry friction's dissipation (docs/CERTIFICATION.md, "Friction")
    caps += sheet.optional("energy evidence (friction)", fr.friction_energy_evidence, scene, run.outcomes, by_target,
                           sheet.measurements, default=[])
    return PosteriorDraws(draws=draws, identification=tuple(idents), converged=converged,
                          n_independent=n_independent, sampling=tuple(thinning), caps=tuple(caps))


# ---------------------------------------------------------------------------------------------
# 3. nominal


def nominal_values(draws: Mapping[str, np.ndarray], uncertain: Mapping[str, Any]) -> dict[str, float]:
    """The nominal value of each drawn parameter: its **median** (docs/CERTIFICATION.md, "nominal"):
    the median of an identified parameter's independent posterior draws, and for a parameter of
    ``certification.uncertain`` its stated ``value``, the exact median of its log-normal draws
    value·exp(rel_std·z) (not a sample statistic: the scene's 2.0 stays 2.0)."""
    out = {}
    for k, v in draws.items():
        u = uncertain.get(k)
        out[k] = float(u.value) if u is not None else float(np.median(np.asarray(v, float)))
    return out


def stage_nominal(ctx: Context, sheet: Sheet, post: PosteriorDraws) -> NominalOutput:
    """The network at the nominal values (each parameter's median, :func:`nominal_values`; plus the
    fixed parameters) through the criterion: its
    verdict and margin as measurements, the decided condition's plot. A network that cannot be
    built is an evidence error (ERROR)."""
    nominal_params = dict(ctx.params)
    nominal_params.update(nominal_values(post.draws, ctx.cert.uncertain))
    with sheet.timed("nominal", ctx.say, ctx.scene.name):
        try:
            tm = build_network(ctx.model, nominal_params)
            nominal_res = _check(tm, ctx.criterion)
            section = _nominal_section(ctx.model, nominal_res, nominal_params)
            verdict = str(nominal_res.verdict)
            sheet.add(nominal_verdict_spec(nominal_res.criterion).measure(verdict, description=nominal_res.summary()))
            sheet.add(NOMINAL_MARGIN.measure(_f(nominal_res.margin), result=verdict))
            sheet.optional("plots (decided quantities)", _decided_plot, sheet.plots, tm, nominal_res)
        except HilError as exc:
            sheet.errors.append(f"nominal model: {exc}")
            return NominalOutput(params=nominal_params)
    return NominalOutput(params=nominal_params, network=tm, result=nominal_res, section=section)


# ---------------------------------------------------------------------------------------------
# 4. robust


def stage_robust(ctx: Context, sheet: Sheet, post: PosteriorDraws, nominal: NominalOutput) -> RobustOutput:
    """The criterion over the posterior draws: P(stable) with its interval, the worst-case margin
    over the credible region, β (FORM) and, where Monte Carlo cannot reach the requirement,
    P(stable) by importance sampling; skipped without draws or after an evidence error."""
    draws, policy, params, seed, errors = post.draws, ctx.policy, ctx.params, ctx.seed, sheet.errors
    if not draws or errors:
        return RobustOutput()
    nominal_res, nominal_params, criterion = nominal.result, nominal.params, ctx.criterion
    with sheet.timed("robust", ctx.say, ctx.scene.name):
        stable_draws, proxy_fn, method, band, cmap = _robust_eval(ctx.model, criterion, params, draws)
        fast = method.startswith("vectorized")
        p, lo, hi = probability_of_stability(stable_draws, policy.confidence)
        names = sorted(draws)
        X = np.column_stack([draws[k] for k in names])
        # the nominal point exactly as the nominal stage built it (worst ≤ nominal by construction)
        centre = np.array([nominal_params[k] for k in names], float)
        exact_margin = _exact_margin_fn(ctx.model, criterion, params, names)
        wc, theta = (None, None)
        # a nominal NO-GO is decided: the worst case (≤ the nominal margin < 0) and β/importance
        # sampling cannot change it, so they are not searched (P(stable) is still counted: cheap, and
        # it says how much of the posterior is stable)
        nominal_unstable = nominal.verdict == "potentially_unstable"
        if X.shape[0] > X.shape[1] + 2 and not nominal_unstable:
            try:
                # the exact criterion's margin (the nominal margin's function) costs ~10-100 ms per
                # point: the vectorized proxy screens the draws, short local searches from the lowest
                wc_v, th = worst_case_margin(
                    exact_margin, X, credible=policy.credible, n_starts=4 if fast else 2, seed=seed,
                    maxiter=6 if fast else 4, axis_starts=True, centre=centre,
                    rank_fn=None if proxy_fn is None else
                    (lambda T: proxy_fn(dict(zip(names, T.T, strict=True)))),
                    n_screen=24, n_local=3 if fast else 1)
                wc, theta = _f(wc_v), {k: float(v) for k, v in zip(names, th, strict=True)}
                if nominal_res is not None and _f(nominal_res.margin) is not None and wc is not None and \
                        wc > float(nominal_res.margin):  # cannot happen: the centre is a candidate
                    errors.append(f"worst-case margin {wc} exceeds the nominal {nominal_res.margin}")
            except HilError as exc:
                logger.warning("worst-case search skipped: %s", exc)
        if band is None and nominal_res is not None:
            # the nominal binding condition's critical band (hil.stability.margins.critical_band,
            # docs/VERDICTS.md): it contains the violation and the region near the minimum
            from hil.stability.margins import critical_band

            cb = critical_band(nominal_res)
            band = None if cb is None else (cb[0], cb[1] if math.isfinite(cb[1]) else float(np.finfo(float).max))
        sampling = "; ".join(post.sampling)
        reliability, form_res, rare = None, None, None
        if X.shape[0] > X.shape[1] + 2 and not nominal_unstable:
            reliability, form_res, rare = _reliability_stage(ctx.model, criterion, params, names, X, centre,
                                                             stable_draws, policy, fast, seed, theta)
            if reliability is not None:
                sheet.optional("plots (design point)", _design_point_plot, sheet.plots, ctx.model, criterion,
                               params, names, X, centre, reliability, fast)
        p_method: Literal["monte_carlo", "importance_sampling"] = (
            "importance_sampling" if rare is not None and rare.reliable else "monte_carlo")
        robust = Robust(n_draws=int(stable_draws.size), p_stable=p, lower=lo, upper=hi,
                        confidence=policy.confidence, required=policy.required_probability,
                        credible=policy.credible, worst_case_margin=wc, worst_case_parameters=theta,
                        critical_band_rad_s=band, method=method, n_requested=int(ctx.cert.draws),
                        n_independent=post.n_independent, sampling=sampling,
                        worst_case_quantity=f"the exact criterion's margin, check(network(θ), {criterion!r})"
                                            ".margin, the nominal margin's function; the posterior centre is "
                                            "a candidate",
                        reliability=reliability, rare_event=rare, p_stable_method=p_method)
        sheet.add(p_stable_spec(policy).measure(
            lo, interval=(lo, hi), description=f"P̂ = {p:.4f} over {stable_draws.size} independent draws "
                                               f"({policy.confidence:.0%} Clopper-Pearson on the "
                                               f"thinned chain: {sampling})"))
        if rare is not None:
            sheet.add(p_stable_is_spec(policy).measure(
                rare.lower, interval=(rare.lower, rare.upper), invalid=not rare.reliable,
                description=f"P_f = {rare.p_failure:.3g} ± {rare.std_error:.2g} from {rare.n} samples "
                            f"({rare.n_fail} failing) of N(u*, I) around the FORM design point, Gaussian "
                            f"approximation of the posterior; {policy.confidence:.0%} normal interval"))
        if reliability is not None:
            sheet.add(beta_spec(reliability.required_beta).measure(
                reliability.beta,
                description=f"Φ(β) = {reliability.phi_beta:.6g} (sampled P̂ = {p:.4f}); distance in "
                            f"posterior-standardized coordinates to the nearest non-stable parameter set"
                            + (" (none within the search radius: β is at least this)" if reliability.censored
                               else "")))
        if wc is not None:
            sheet.add(worst_case_spec(policy).measure(wc))
        elif nominal_unstable:
            sheet.add(info_spec(NOT_SEARCHED_ROW).measure(
                "not searched", description="the nominal network is potentially unstable: NO-GO whatever the "
                                            "worst case over the credible region or β"))
        sheet.optional("plots (posterior Bode)", _bode_plot, sheet.plots, ctx.model, params, draws, seed,
                       ctx.scene.units, cmap)
        if fast and band is not None:
            sheet.optional("plots (critical band)", _critical_band_plot, sheet.plots, ctx.model, params, draws, band,
                           nominal_params)
    return RobustOutput(stable_draws=stable_draws, section=robust, form=form_res, rare=rare)


# ---------------------------------------------------------------------------------------------
# 5. design


def stage_design(ctx: Context, sheet: Sheet, post: PosteriorDraws, nominal: NominalOutput) -> DesignOutput:
    """Design guidance for ``certification.design``'s parameter: the largest value keeping the
    required probability, and its headroom at the nominal plant and over the posterior."""
    cert, policy = ctx.cert, ctx.policy
    if cert.design is None or not post.draws or sheet.errors:
        return DesignOutput()
    with sheet.timed("design", ctx.say, ctx.scene.name):
        design = _design(cert, ctx.params, post.draws, policy, nominal.params)
        if design is not None:
            sheet.add(info_spec(f"largest {design.parameter} at P ≥ {policy.required_probability}", design.unit)
                      .measure(design.max_value, description=design.note))
            for key, what in (("nominal_headroom", "at the nominal plant"),
                              ("posterior_headroom", f"over the posterior at P ≥ {policy.required_probability}")):
                h = getattr(design, key)
                if h is not None:
                    sheet.add(headroom_spec(design.parameter, what).measure(h))
            sheet.optional("plots (headroom)", _headroom_plot, sheet.plots, cert, ctx.params, post.draws, policy,
                           design)
    return DesignOutput(design)


# ---------------------------------------------------------------------------------------------
# 6. decide


def stage_decide(ctx: Context, sheet: Sheet, run: RunOutput, post: PosteriorDraws, nominal: NominalOutput,
                 robust: RobustOutput, design: DesignOutput) -> Verdict:
    """The verdict policy (:func:`hil.certify.statistics.decide`) on the stages' findings; evidence errors
    give ERROR. A GO whose energy evidence went below its bound, or could not be read, becomes
    MARGINAL."""
    nominal_res, draws, d = nominal.result, post.draws, design.design
    rare = robust.rare
    dec, reasons, _prob = decide(nominal.verdict,
                                 robust.stable_draws if draws else (np.array([nominal_res.verdict == "stable"])
                                                                    if nominal_res is not None else None),
                                 ctx.policy, converged=post.converged, evidence_errors=sheet.errors or None,
                                 nominal_weak=bool(nominal_res is not None and nominal_res.weak),
                                 beta=None if robust.form is None else float(robust.form.beta),
                                 headroom_nominal=None if d is None else d.nominal_headroom,
                                 headroom_posterior=None if d is None else d.posterior_headroom,
                                 rare_event=(rare.lower, rare.upper) if rare is not None and rare.reliable else None,
                                 require_beta=bool(draws))
    if any(e.went_negative for e in run.energy) and dec == Decision.GO:
        dec = Decision.MARGINAL
        reasons.append("energy injection: E_s(t) went below its noise bound although the criterion passed")
    if post.caps and dec != Decision.ERROR:  # misfit plant model, friction-masked energy evidence
        if dec == Decision.GO:
            dec = Decision.MARGINAL
        reasons += list(post.caps)
    energy_failed = [k for k in sheet.failed if k.startswith("energy evidence")]
    if energy_failed and dec == Decision.GO:
        dec = Decision.MARGINAL
        reasons.append(f"energy injection evidence could not be read ({', '.join(energy_failed)}): not certified "
                       "GO without it")
    return Verdict(dec, tuple(reasons))


# ---------------------------------------------------------------------------------------------
# 7. witness


def stage_witness(ctx: Context, sheet: Sheet, nominal: NominalOutput) -> WitnessOutput:
    """When the nominal network is potentially unstable, a passive termination set that makes it
    deliver energy, simulated (optional: a failure is recorded, the decision stands)."""
    witness = None
    reasons: list[str] = []
    unstable = nominal.verdict == "potentially_unstable"
    if ctx.cert.witness and unstable and nominal.network is not None:
        with sheet.timed("witness", ctx.say, ctx.scene.name):
            witness = sheet.optional("witness", _witness, nominal.network, sheet.plots, sheet, ctx.scene)
        if witness is not None:
            reasons.append(_witness_reason(witness, ctx.scene.units))
        else:
            why = sheet.failed.get("witness")
            reasons.append(f"no destabilizing passive termination reported: the witness search failed ({why})"
                           if why is not None else
                           "no destabilizing passive termination found among the candidates searched (a finite "
                           "family: the criterion's verdict stands)")
    elif unstable and not ctx.cert.witness:
        reasons.append("no destabilizing passive termination reported: the scene disables the witness search "
                       "(certification.witness: false)")
    return WitnessOutput(witness, tuple(reasons))

def _witness_reason(w: Witness, units: str | None) -> str:
    """The witness in one plain sentence: which passive termination, what it does to the closed
    loop, and how soon the bench's first safety limit would be crossed (numbers as the witness
    section prints them)."""
    from hil.certify.numbers import fmt
    from hil.certify.units import termination_units

    terms = []
    for port, t in w.terminations.items():
        if isinstance(t, dict) and "params" in t:
            tu = termination_units(t["params"], w.units or units)
            where = f"port {int(port) + 1}" if str(port).isdigit() else f"port {port}"
            terms.append(f"a {t.get('kind', 'passive termination')} ("
                         + ", ".join(f"{k} = {fmt(v)} {tu.get(k, '')}".rstrip() for k, v in t["params"].items())
                         + f") at {where}")
    text = "for example " + (" and ".join(terms) or "a passive termination") + " makes it unstable"
    if w.growth_rate_1_s is not None and w.growth_rate_1_s > 0:
        text += f": the response grows as e^(σt) with σ = {fmt(w.growth_rate_1_s)} 1/s"
    if w.limit_exceeded is not None and w.time_to_limit_s is not None:
        text += (f", and the bench's {w.limit_exceeded.replace('_', ' ')} limit would be exceeded after "
                 f"{fmt(w.time_to_limit_s)} s")
    return text


# ---------------------------------------------------------------------------------------------
# helpers


def _f(v: Any) -> float | None:
    try:
        x = float(v)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _independent_samples(res: Any) -> tuple[np.ndarray, str]:
    """The identification's posterior samples thinned to independent draws: every walker of the
    kept emcee chain keeps one sample per ⌈τ⌉ steps, τ the largest integrated autocorrelation time
    over the parameters (``diagnostics.tau``, or estimated from the chain when missing). Returns the
    (n_independent, p) samples and one sentence saying how they were obtained."""
    from hil.certify.statistics import autocorrelation_time, thin_indices

    post = res.posterior
    samples = np.asarray(post.samples)[:, : len(res.names)]
    chain = np.asarray(post.chain_z)
    if chain.ndim != 3 or chain.shape[0] * chain.shape[1] != samples.shape[0]:
        return samples, (f"{res.model.name}: {samples.shape[0]} stored samples, chain layout unknown: "
                         "not thinned")
    n_steps, n_walkers = chain.shape[:2]
    tau_d = np.asarray(post.diagnostics.tau, float)
    tau = float(np.max(tau_d)) if tau_d.size and np.all(np.isfinite(tau_d)) else autocorrelation_time(chain)
    idx = thin_indices(n_steps, n_walkers, tau)
    note = (f"{res.model.name}: {samples.shape[0]} stored samples ({n_walkers} walkers × {n_steps} steps) "
            f"thinned every ⌈τ⌉ = {max(1, math.ceil(tau))} steps (τ = {tau:.1f}, the largest integrated "
            f"autocorrelation time): {idx.size} independent draws")
    return samples[idx], note


def friction_truth(scene: Any, device: str) -> dict[str, float]:
    """The simulated twin's friction of ``device`` (and a 1-DOF body's M and B), identification's names."""
    from hil.bench.mechanics import body_truth
    from hil.bench.mechanics import friction_truth as _ft

    return {**body_truth(scene, device), **_ft(scene, device)} if device else {}


def _truth(scene: Any) -> dict[str, float]:
    """Parameters of the simulated plant (known on a mocked bench; shown next to the estimates)."""
    sim = scene.simulation
    if sim is None or sim.sdea is None:
        return {}
    sd = sim.sdea
    return {"M": float(sd.M), "B": float(sd.B), "K_f": float(sd.K_f), "B_f": float(sd.B_f)}


def _versions() -> dict[str, str]:
    import platform

    import scipy

    import hil

    return {"hil": hil.__version__, "numpy": np.__version__, "scipy": scipy.__version__,
            "python": platform.python_version()}


_VERDICTS: dict[str, VerdictStr] = {"stable": "stable", "marginal": "marginal",
                                    "potentially_unstable": "potentially_unstable", "not_applicable": "not_applicable"}
_DECISIONS: dict[Decision, DecisionStr] = {Decision.GO: "GO", Decision.MARGINAL: "MARGINAL", Decision.NO_GO: "NO-GO",
                                           Decision.ERROR: "ERROR"}


def _nominal_section(model: str, r: Any, params: Mapping[str, Any]) -> Nominal:
    rows = [ConditionRow(name=c.name, label=c.label, status=c.status, margin=_f(c.margin),
                         worst_frequency=None if c.worst_frequency is None else (
                             "inf" if math.isinf(c.worst_frequency) else float(c.worst_frequency)), detail=c.detail)
            for c in r.conditions]
    wf = r.worst_frequency
    wf_out = None if wf is None else ("inf" if math.isinf(wf) else float(wf))
    return Nominal(network=r.network.get("name", model), criterion=r.criterion, verdict=_VERDICTS[str(r.verdict)],
                   margin=_f(r.margin), worst_frequency=wf_out,
                   failed_condition=r.failed_condition, weak=bool(r.weak),
                   parameters={k: float(v) for k, v in params.items() if isinstance(v, int | float)}, conditions=rows)


def _robust_eval(model: str, criterion: str, params: Mapping[str, Any], draws: Mapping[str, np.ndarray]
                 ) -> tuple[np.ndarray, Callable[[Mapping[str, np.ndarray]], np.ndarray] | None, str,
                            tuple[float, float] | None, Any]:
    """Stability of every draw, a cheap vectorized proxy margin that ranks parameter sets from
    least to most stable (the model's vectorized criterion, e.g. the SDEA's closed-form margin; None
    on the general path), the method,
    the critical band (5 % quantile of the draws' lower edges to 95 % of their upper edges, see
    hil.models.batch) (None when the path does not provide it), and the general path's measured
    coefficient map (:func:`hil.models.batch_general.coefficient_map`, None when not affine or on
    the closed-form path). Without a closed-form batch, the
    exact criterion decides every draw that hil.models.batch_general's vectorized screen does not
    reject on a clearly violated necessary condition (the same per-draw verdicts, fewer exact runs)."""
    from hil.models import get_model

    n = len(next(iter(draws.values())))
    batch = get_model(model).vectorized(criterion)
    if batch is not None:
        fixed = {k: float(v) for k, v in params.items() if isinstance(v, int | float)}

        def margin(d: Mapping[str, np.ndarray]) -> np.ndarray:
            return batch(d, fixed=fixed, band=False)["margin"]

        res = batch(draws, fixed=fixed, band=True)
        # the critical band (hil.models.batch): per draw, where the coupler condition (c-ii) is
        # within 10 % of its minimum; over the draws, the 5 % quantile of the lower edges to the 95 %
        # quantile of the upper edges
        lo_e, hi_e = res["band_lo"], res["band_hi"]
        ok = np.isfinite(lo_e) & np.isfinite(hi_e) & (hi_e > lo_e)
        band = (float(np.quantile(lo_e[ok], 0.05)), float(np.quantile(hi_e[ok], 0.95))) if ok.any() else None
        return (res["passive"], margin, "vectorized closed form (Theorem 5), exact fallback near the boundary", band,
                None)
    from hil.models.batch_general import screened_stability

    def exact_one(q: Mapping[str, Any]) -> bool:
        return exactly_stable(model, criterion, q)

    # draws the vectorized screen rejects on a necessary condition (beyond its error bound) skip the
    # exact path; every other draw is decided exactly (hil.models.batch_general)
    # the certificate's method stays the exact criterion's: the screen only skips it where its
    # verdict is already determined, so every per-draw verdict is the exact criterion's
    res = screened_stability(model, criterion, params, draws, exact_one)
    assert res["stable"].shape == (n,)
    logger.info("robust draws: %s", res["method"])
    return res["stable"], None, "general exact criterion per draw", None, res.get("cmap")


def _exact_margin_fn(model: str, criterion: str, params: Mapping[str, Any],
                     names: list[str]) -> Callable[[np.ndarray], np.ndarray]:
    """θ rows (columns ``names``) → the exact criterion's margin, ``check(network(θ), criterion).margin``,
    the same function that gives the nominal margin at the posterior centre. A parameter set whose
    network cannot be built (HilError) or whose margin is not finite gets -1, the bottom of the
    normalized scale."""
    def fn(T: np.ndarray) -> np.ndarray:
        T = np.atleast_2d(T)
        out = np.empty(T.shape[0])
        for i, row in enumerate(T):
            q = dict(params)
            q.update({k: float(v) for k, v in zip(names, row, strict=True)})
            try:
                m = float(_check(build_network(model, q), criterion).margin)
            except HilError:
                m = -1.0
            out[i] = m if math.isfinite(m) else -1.0
        return out

    return fn


def _verdict_fn(model: str, criterion: str, params: Mapping[str, Any], names: list[str],
                fast: bool) -> Callable[[np.ndarray], np.ndarray]:
    """θ rows (columns ``names``) → stable (bool): the SDEA's vectorized closed-form verdict (its
    sign also within round-off of the boundary, where a bisection converges: the design point is
    then checked with the exact criterion) or the exact criterion per point (a network that cannot
    be built is not stable)."""
    from hil.models import get_model

    batch = get_model(model).vectorized(criterion) if fast else None
    if batch is not None:
        fixed = {k: float(v) for k, v in params.items() if isinstance(v, int | float)}

        def vec(T: np.ndarray) -> np.ndarray:
            T = np.atleast_2d(T)
            return batch(dict(zip(names, T.T, strict=True)), fixed=fixed, band=False,
                                        exact_fallback=False)["passive"]

        return vec

    def one(T: np.ndarray) -> np.ndarray:
        return np.array([exactly_stable(model, criterion, {**params, **dict(zip(names, map(float, row), strict=True))})
                         for row in np.atleast_2d(T)], dtype=bool)

    return one


def exactly_stable(model: str, criterion: str, params: Mapping[str, Any]) -> bool:
    """Whether the network of ``model`` at ``params`` is ``stable`` under the exact ``criterion``
    (verdict only, no margins); a network that cannot be built is not stable. The per-draw
    reference of every vectorized path."""
    try:
        return str(_check(build_network(model, params), criterion, margins=False).verdict) == "stable"
    except HilError:
        return False


#: the design point is checked with the exact criterion at (1 ∓ this)·u*
VERIFY_OFFSET = 0.05

#: importance-sampling sample sizes of the rare-event path (vectorized SDEA path, general path)
IS_SAMPLES = (20000, 300)


def _reliability_stage(model: str, criterion: str, params: Mapping[str, Any], names: list[str], X: np.ndarray,
                       centre: np.ndarray, stable_draws: np.ndarray, policy: Policy, fast: bool, seed: int,
                       worst_theta: Mapping[str, float] | None) -> tuple[Any, Any, Any]:
    """β by FORM in posterior-standardized coordinates (hil.stability.reliability) around the
    posterior centre (the nominal point), and, when plain Monte Carlo on the available draws
    cannot reach the requirement even with every draw stable, P(stable) by importance sampling
    around the design point. Returns (Reliability, FormResult, RareEvent) (None where not made)."""
    from scipy.special import ndtr  # Φ

    from hil.certify.certificate import RareEvent, Reliability
    from hil.certify.statistics import beta_required
    from hil.stability.reliability import Standardization, form, importance_sampling

    st = Standardization.from_draws(X)
    st = Standardization(centre, st.L)  # centred exactly on the nominal point
    verdict = _verdict_fn(model, criterion, params, names, fast)

    def stable_u(U: np.ndarray) -> np.ndarray:
        return verdict(st.to_theta(U))

    hints = []
    bad = ~np.asarray(stable_draws, bool)
    if bad.any():
        Ub = st.to_u(X[bad])
        hints += list(Ub[np.argsort(np.linalg.norm(Ub, axis=1))[:8]])
    if worst_theta is not None:
        hints.append(st.to_u(np.array([[worst_theta[k] for k in names]]))[0])
    b_req = beta_required(policy.required_probability)
    r_max = max(8.0, b_req + 3.0)
    d = len(names)
    kw: dict[str, Any] = {} if fast else {"n_random": 0, "n_grid": 6, "n_bisect": 7, "refine_iter": 1,
                                          "n_refine_starts": 1, "budget": 40 * d}
    if fast:  # cheap verdicts: a tight posterior's β is measured, not only bounded by r_max
        kw["r_limit"] = 8 ** 4 * r_max
    fr = form(stable_u, d, hints=hints, r_max=r_max, seed=seed, **kw)
    verified = None
    if not fr.censored:
        u = fr.design_point_u
        # the exact criterion on both sides of the design point (the search's verdict may be the
        # vectorized closed form, whose sign within ~1e-8 of the boundary is round-off), 5 % of β
        # inside and outside along its ray
        inner, outer = st.to_theta(u * (1 - VERIFY_OFFSET)), st.to_theta(u * (1 + VERIFY_OFFSET))
        def exact(T: np.ndarray) -> str:
            q = dict(params)
            q.update({k: float(v) for k, v in zip(names, np.atleast_2d(T)[0], strict=True)})
            try:
                return str(_check(build_network(model, q), criterion, margins=False).verdict)
            except HilError:
                return "potentially_unstable"

        centre_ok = fr.beta > 0
        vi, vo = exact(inner), exact(outer)
        # None: the exact criterion calls a side marginal (its rounding bound straddles zero there)
        verified = None if "marginal" in (vi, vo) else bool((vi == "stable") == centre_ok
                                                           and (vo == "stable") != centre_ok)
    theta_star = st.to_theta(fr.design_point_u)[0]
    rel = Reliability(beta=float(fr.beta), phi_beta=float(ndtr(fr.beta)), required_beta=b_req,
                      design_point={k: float(v) for k, v in zip(names, theta_star, strict=True)},
                      design_point_u=[float(v) for v in fr.design_point_u], censored=fr.censored,
                      bracket=(float(fr.bracket[0]), float(fr.bracket[1])) if math.isfinite(fr.bracket[1]) else None,
                      evaluations=fr.evaluations, verified=verified,
                      method=("FORM by verdict-only ray search (axes, random and hint directions; tangent-plane "
                              "refinement)" + ("" if fast else f", budget {40 * d} exact verdicts")))
    rare = None
    n = int(np.asarray(stable_draws).size)
    best_mc_lower = (0.5 * (1 - policy.confidence)) ** (1.0 / n)  # Clopper-Pearson lower bound when k = n
    if best_mc_lower < policy.required_probability and fr.beta > 0 and not fr.censored:
        isr = importance_sampling(stable_u, fr.design_point_u, n=IS_SAMPLES[0] if fast else IS_SAMPLES[1],
                                  confidence=policy.confidence, seed=seed + 7)
        rare = RareEvent(method="importance sampling, proposal N(u*, I) around the FORM design point, on the "
                                "Gaussian approximation N(μ, Σ) of the posterior; normal-approximation interval",
                         n=isr.n, n_fail=isr.n_fail, p_failure=isr.p_failure, std_error=isr.std_error,
                         p_stable=isr.p_stable, lower=1.0 - isr.upper, upper=1.0 - isr.lower,
                         confidence=isr.confidence, ess=isr.ess, reliable=isr.reliable)
    return rel, fr, rare


def _design_point_plot(plots: dict[str, Series], model: str, criterion: str, params: Mapping[str, Any],
                       names: list[str], X: np.ndarray, centre: np.ndarray, reliability: Any, fast: bool) -> None:
    """The design point in the posterior-standardized coordinates of :func:`_reliability_stage`
    with the limit state traced by the same verdict; see :func:`hil.certify.figures.design_point_plot`."""
    from hil.certify.figures import design_point_plot
    from hil.stability.reliability import Standardization

    st = Standardization(centre, Standardization.from_draws(X).L)
    verdict = _verdict_fn(model, criterion, params, names, fast)
    design_point_plot(plots, lambda U: verdict(st.to_theta(U)), reliability, names, model=model, fast=fast)


def _design(cert: Any, params: Mapping[str, Any], draws: Mapping[str, np.ndarray], policy: Policy,
            nominal_params: Mapping[str, Any] | None = None) -> Design | None:
    from hil.models import get_model

    d = cert.design
    m = get_model(cert.model)
    crit = _criterion(cert.model, cert.criterion)
    batch = m.vectorized(crit)
    if batch is None or d.parameter not in m.design:
        return Design(parameter=d.parameter, max_value=None, probability_at_max=None,
                      required=policy.required_probability,
                      note="design search is implemented for the SDEA coupler (k22, b22)")
    dp = m.design[d.parameter]

    fixed = {k: float(v) for k, v in params.items() if isinstance(v, int | float)}

    def stable(x: float) -> np.ndarray:
        dd = dict(draws)
        dd[d.parameter] = np.full(len(next(iter(draws.values()))), x)
        return batch(dd, fixed=fixed, band=False)["passive"]

    x, p = max_safe_parameter(stable, d.range[0], d.range[1], policy.required_probability, policy.confidence)
    unit = dp.unit
    head: dict[str, Any] = {}
    cur = fixed.get(d.parameter)
    if dp.headroom is not None and cur is not None and cur > 0:
        # parametric headroom (docs/CERTIFICATION.md): k22_max/k22 − 1 at the nominal plant, and the
        # posterior limit (lower bound of P(stable) = required) / k22 − 1
        from hil.certify.statistics import posterior_limit

        plant = {k: float(v) for k, v in (nominal_params or params).items()
                 if k in m.defaults and isinstance(v, int | float)}
        km, hn = dp.headroom(cur, plant)
        xl, kind = posterior_limit(stable, cur, policy.required_probability, policy.confidence)
        head = {"nominal_limit": km, "nominal_headroom": hn, "posterior_limit": xl, "posterior_limit_kind": kind,
                "posterior_headroom": xl / cur - 1.0}
    return Design(parameter=d.parameter, unit=unit, current=cur, max_value=_f(x),
                  probability_at_max=_f(p), required=policy.required_probability,
                  note=f"largest {d.parameter} in [{d.range[0]:g}, {d.range[1]:g}] whose lower "
                       f"{policy.confidence:.0%} bound of P(stable) stays ≥ {policy.required_probability}", **head)


def _witness(tm: Any, plots: dict[str, Series], opt: Sheet, scene: Any = None) -> Witness | None:
    """Search a passive termination set and simulate the driven, terminated one-port exactly
    (a failure of the simulation is recorded by ``opt``; the witness is kept without it). With the
    scene, the witness says what a reader needs: the closed-loop poles the termination creates,
    and when the response crosses the bench's safety limits (hil.certify.figures.witness_response)."""
    from hil.certify.figures import witness_response
    from hil.stability.witness import find_witness, termination_family

    port = 0
    cands = termination_family(max(tm.port_dofs))[::2]
    w = find_witness(tm, port, cands, first=True)
    if w is None:
        return None
    units = getattr(scene, "units", None)
    sim = opt.optional("witness simulation", _simulate_witness, w, plots, scene)
    if sim is None:
        sim = {"simulated": False, "reason": f"simulation failed: {opt.failed['witness simulation']}"}
    band = None if w.band_rad_s is None else (float(w.band_rad_s[0]),
                                             "inf" if math.isinf(w.band_rad_s[1]) else float(w.band_rad_s[1]))
    fields: tuple[str, ...] = witness_response.FIELDS  # type: ignore[attr-defined]  # set on the function there
    extra = {k: sim.pop(k) for k in list(sim) if k in fields}
    return Witness(terminations={str(k): v.to_dict() for k, v in w.terminations.items()},
                   drive_frequency_rad_s=w.drive_frequency, band_rad_s=band, margin=float(w.result.margin),
                   simulation=sim, units=units, **extra)

def _simulate_witness(w: Any, plots: dict[str, Series], scene: Any = None) -> dict[str, Any]:
    """Drive the terminated network's operator port with F(t) = F0 d sin(ωt) (d = the most
    non-passive direction, F0 = 1 N or N.m) and integrate E_s(t) = ∫ Fᵀ V dt, V = Y_in(s) F, with the
    exact-ZOH engine of hil.mocks (admittance state space from the exact rational Y_in = Z_in⁻¹),
    until the response crosses the scene's safety limits (or grows a thousandfold without a scene);
    see :func:`hil.certify.figures.witness_response`."""
    from hil.certify.figures import witness_response

    return witness_response(w, plots, scene)



# ---------------------------------------------------------------------------------------------
# plots (as data series; rendered by hil.report.render)


def _identification_plots(plots: dict[str, Series], name: str, res: Any, seed: int, units: str | None = None) -> None:
    """FRF evidence (measured H1 with its coherence-based confidence band, the posterior fit band,
    magnitude and phase, coherence and normalized residuals beneath) per output, and the corner
    plot of the posterior; see :func:`hil.certify.figures.identification_plots`."""
    from hil.certify.figures import identification_plots

    identification_plots(plots, name, res, seed, units)

def _fault_measurements(outcomes: Mapping[str, Any], measurements: list[Measurement]) -> None:
    """One INFO measurement per experiment whose devices report fault counters: the total count of
    faults the adapters tolerated during the run (CRC errors, resyncs, dropped, late and stale
    frames, retries, ...), each device's non-zero counters in the description. Evidence only: the
    decision does not use it (a fault the adapter could not tolerate is a safe stop, FAIL)."""
    for exp_name, o in outcomes.items():
        per = (getattr(o, "results", {}) or {}).get("device_counters", {})
        if not per:
            continue
        # "stale": a read with no new sample since the last tick -- expected, not a fault, for a
        # sensor slower than the loop (its samples are held; identification compensates the hold)
        faults = {dev: {k: int(v) for k, v in c.items() if k != "stale"} for dev, c in per.items()}
        total = sum(v for c in faults.values() for v in c.values())
        nonzero = [f"{dev}: " + ", ".join(f"{k}={v}" for k, v in sorted(c.items()) if v)
                   for dev, c in sorted(faults.items()) if any(c.values())]
        detail = "; ".join(nonzero) if nonzero else f"none on {len(per)} device(s)"
        held = {dev: int(c.get("stale", 0)) for dev, c in per.items() if int(c.get("stale", 0))}
        if held:
            detail += "; reads without a new sample (held, not counted): " + ", ".join(
                f"{dev}={n}" for dev, n in sorted(held.items()))
        measurements.append(info_spec(f"device faults tolerated ({exp_name})", "count").measure(
            float(total), description=f"adapter counters during the run: {detail}"))


def _energy_stage(opt: Sheet, name: str, o: Any, energy: list[EnergyEvidence], measurements: list[Measurement],
                  plots: dict[str, Series]) -> None:
    """The optional energy-evidence stage of one experiment, and its plot."""
    if opt.optional(f"energy evidence ({name})", _energy_evidence, name, o, energy, measurements, default=False):
        opt.optional(f"plots (energy {name})", _energy_plot, plots, name, o)


def _energy_evidence(name: str, o: Any, energy: list[EnergyEvidence], measurements: list[Measurement]) -> bool:
    """Energy-injection results of an experiment as evidence and a measurement; True if it had some."""
    r = o.results
    if r.get("type") != "energy_injection" or "went_negative" not in r:
        return False
    bound = float(r.get("bound_at_min", 0.0))
    ev = EnergyEvidence(experiment=name, port=str(r.get("port")), record=str(o.record),
                        went_negative=bool(r["went_negative"]), min_energy=float(r["min_energy"]),
                        bound=bound, first_time=r.get("first_time"))
    m = energy_spec(name).measure(float(r["min_energy"]), result=bool(r["went_negative"]), lower=-bound)
    energy.append(ev)  # both or neither
    measurements.append(m)
    return True


def _energy_plot(plots: dict[str, Series], name: str, outcome: Any) -> None:
    from hil.record.hdf5 import RunRecord

    try:
        rec = RunRecord.open(outcome.record)
    except HilError:
        return
    port = outcome.results.get("port")
    key = f"{port}.energy"
    if key not in rec.channels:
        return
    e = rec.channels[key].reshape(-1)
    step = max(1, e.size // 1500)
    plots[f"energy_{name}"] = Series(title=f"Port energy E_s(t) at {port} ({name})", x=rec.t[::step].tolist(),
                                     x_label="t [s]", y_label="E_s [J]", lines={"E_s": e[::step].tolist()}, hline=0.0)


def _decided_plot(plots: dict[str, Series], tm: Any, r: Any) -> None:
    """The decisive condition against frequency (the failing one of a NO-GO, the one with the
    smallest margin otherwise), negative band shaded, worst frequency marked, and the imaginary-axis
    and infinity conditions as their residue margins; see :func:`hil.certify.figures.decided_plot`."""
    from hil.certify.figures import decided_plot

    decided_plot(plots, tm, r)

def _critical_band_plot(plots: dict[str, Series], model: str, params: Mapping[str, Any],
                        draws: Mapping[str, np.ndarray], band: tuple[float, float],
                        centre: Mapping[str, Any] | None = None) -> None:
    """The model's normalized band condition (the SDEA's coupler condition) g(ω) = t(ω²)/|t|(ω²)
    at the nominal point ``centre`` (the nominal stage's parameters) and its 5-95 % band over the
    draws, with the 10 % threshold of the nominal curve and the certificate's critical band (over the
    draws) marked; nothing for a model without one."""
    centre = dict(centre or {k: float(np.median(v)) for k, v in draws.items()})
    from hil.models import get_model
    from hil.models.batch import BAND_GRID_RAD_S, CRITICAL_BAND_FRACTION

    m = get_model(model)
    if m.band_condition is None:
        return
    condition = m.band_condition
    table = m.defaults  # the model's parameter table (Table I for the SDEA)
    base = {**table, **{k: float(v) for k, v in params.items() if isinstance(v, int | float)}}
    n = len(next(iter(draws.values())))
    sub = slice(None, None, max(1, n // 400))
    w = BAND_GRID_RAD_S
    x = (w * w)[:, None]

    def g_of(q: Mapping[str, np.ndarray]) -> np.ndarray:
        t0, t1, t2, t3 = condition(q)
        tv = ((t3 * x + t2) * x + t1) * x + t0
        tm = ((np.abs(t3) * x + np.abs(t2)) * x + np.abs(t1)) * x + np.abs(t0)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(tm > 0, tv / tm, np.nan)

    qd = {k: np.asarray(draws[k], float)[sub] if k in draws else np.full(len(range(n)[sub]), base[k])
          for k in table}
    gd = g_of(qd)
    gm = g_of({k: np.array([float(centre[k]) if k in centre else base[k]]) for k in table})[:, 0]
    q05, q95 = np.nanquantile(gd, [0.05, 0.95], axis=1)
    gmin = float(np.nanmin(gm))
    thr = gmin + CRITICAL_BAND_FRACTION * (1.0 - gmin)
    plots["critical_band"] = Series(
        title="Critical band: the coupler condition (c-ii) within 10 % of its minimum",
        x=w.tolist(), x_label="ω [rad/s]", y_label="g(ω) = t(ω²)/|t|(ω²) [1]", log_x=True,
        lines={"nominal (posterior median)": _clean(gm), "10 % threshold (nominal)": [thr] * w.size},
        bands={"5-95 % over the draws": (_clean(q05), _clean(q95))},
        points={"worst (nominal)": (float(w[int(np.nanargmin(gm))]), gmin),
                "critical band, low edge (over the draws)": (float(band[0]), thr),
                "critical band, high edge (over the draws)": (float(band[1]), thr)},
        hline=0.0)


def _clean(a: np.ndarray) -> list[float | None]:
    return [float(x) if math.isfinite(x) else None for x in np.asarray(a, float)]


def _bode_plot(plots: dict[str, Series], model: str, params: Mapping[str, Any], draws: Mapping[str, np.ndarray],
               seed: int, units: str | None = None, cmap: Any = None) -> None:
    """|entry (1,1)| of the network over the posterior: median and 90 % band (60 draws). With the
    robust stage's measured coefficient map ``cmap`` (general networks: coefficients affine in the
    drawn parameters, checked to 1e-9 relative at exact builds), the entry's coefficients of every
    draw come from the map instead of one exact network build per draw."""
    rng = np.random.default_rng(seed + 1)
    n = len(next(iter(draws.values())))
    pick = rng.choice(n, size=min(60, n), replace=False)
    try:
        tm0 = build_network(model, {**params, **{k: float(np.mean(v)) for k, v in draws.items()}})
    except HilError:
        return
    from hil.stability.criteria import _freq_range

    lo, hi = _freq_range(tm0.entries)
    w = np.geomspace(lo, hi, 300)
    mags = []
    if cmap is not None and set(cmap.names) == set(draws):
        X = np.column_stack([np.asarray(draws[k], float)[pick] for k in cmap.names])
        num, den = cmap.coefficients(X)  # (N, n, n, L), lowest degree first
        from numpy.polynomial.polynomial import polyval  # Horner, per draw: (N, n_w)

        mags = list(np.abs(polyval(1j * w, num[:, 0, 0].T) / polyval(1j * w, den[:, 0, 0].T)))
        pick = pick[:0]
    for i in pick:
        q = dict(params)
        q.update({k: float(v[i]) for k, v in draws.items()})
        try:
            mags.append(np.abs(build_network(model, q)[0, 0].freq(w)))
        except HilError:
            continue
    if not mags:
        return
    M = np.array(mags)
    q05, q50, q95 = np.quantile(M, [0.05, 0.5, 0.95], axis=0)
    db = lambda a: (20 * np.log10(np.maximum(a, 1e-300))).tolist()  # noqa: E731
    from hil.certify.figures import immittance_db_label

    plots["bode"] = Series(title=f"|{tm0.kind} entry (1,1)| over the posterior", x=w.tolist(), x_label="ω [rad/s]",
                           y_label=immittance_db_label(tm0.kind, units), log_x=True,
                           lines={"median": db(q50)},
                           bands={"90 % credible": (db(q05), db(q95))})


def _headroom_plot(plots: dict[str, Series], cert_cfg: Any, params: Mapping[str, Any],
                   draws: Mapping[str, np.ndarray], policy: Policy, design: Design) -> None:
    """P(stable) against the design parameter, requirement crossing marked; see
    :func:`hil.certify.figures.headroom_plot`."""
    from hil.certify.figures import headroom_plot

    headroom_plot(plots, cert_cfg, params, draws, policy, design)

