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
    EnergyEvidence,
    Identification,
    MultiPort,
    ParameterSummary,
    Robust,
    SceneInfo,
    Witness,
    seal,
)
from hil.certify.evaluation import (
    _DECISIONS,
    _check,
    _criterion,
    _design,
    _design_point_plot,
    _exact_margin_fn,
    _f,
    _independent_samples,
    _nominal_section,
    _reliability_stage,
    _robust_eval,
    _truth,
    _versions,
    _witness,
    friction_truth,
)
from hil.certify.evidence import (
    _bode_plot,
    _critical_band_plot,
    _decided_plot,
    _energy_stage,
    _fault_measurements,
    _headroom_plot,
    _identification_plots,
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
    probability_of_stability,
    worst_case_margin,
)
from hil.errors import HilError
from hil.models import build_network, model_params_from_scene

logger = logging.getLogger(__name__)

__all__ = ["build_network", "certify_scene", "model_params_from_scene"]

Progress = Callable[[str], None]


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
