"""``hil identify RECORD``: identify a grey-box model from a run record (:mod:`hil.identify.api`).

The suite's own records reach the identification through their backend
(:mod:`hil.record.identify_source`, imported here so it is registered). Exit codes: the one table
(:class:`hil.errors.ExitCode`).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

import hil.record.identify_source  # noqa: F401  (registers the backend of the suite's records)
from hil.cli.main import OneLineArgumentParser
from hil.errors import ExitCode, HilError
from hil.identify.api import IdentificationResult, identify_record, load_record, store_result
from hil.identify.errors import ConvergenceError, DataQualityError, ModelSpecError, NotIdentifiableError
from hil.identify.frf import Resolution
from hil.identify.source import backend_for
from hil.inputs import number_type, seed_type

__all__ = ["main"]

EXIT_OK, EXIT_USAGE, EXIT_ERROR = ExitCode.OK, ExitCode.USAGE, ExitCode.ERROR


def _kv(items: Sequence[str] | None, what: str) -> dict[str, str]:
    out: dict[str, str] = {}
    for it in items or []:
        if "=" not in it:
            raise ModelSpecError(f"{what} expects NAME=VALUE, got {it!r}")
        k, v = it.split("=", 1)
        if not k.strip() or not v.strip():
            raise ModelSpecError(f"{what} {it}: expects NAME=VALUE with both parts non-empty")
        out[k.strip()] = v.strip()
    return out


def _resolution_arg(v: str | None) -> Resolution | None:
    if v is None:
        return None
    if v in ("none", "0"):
        return None if v == "none" else 0.0
    if v in ("float16", "float32", "float64", "auto"):
        return v
    try:
        step = float(v)
    except ValueError:
        step = float("nan")
    if not np.isfinite(step) or step < 0:
        raise ModelSpecError(f"--resolution {v}: expected auto, float16, float32, float64, none, or a non-negative "
                             "quantization step")
    return step


def _theta0(items: Sequence[str] | None) -> dict[str, float] | None:
    out: dict[str, float] = {}
    for k, v in _kv(items, "--set").items():
        try:
            x = float(v)
        except ValueError:
            x = float("nan")
        if not np.isfinite(x):
            raise ModelSpecError(f"--set {k}={v}: the starting value of {k} must be a finite number")
        out[k] = x
    return out or None


def _print_table(res: IdentificationResult) -> None:
    units = dict(zip(res.model.names, res.model.units, strict=True))
    print(f"model {res.model.name}; method {res.method}; converged: {res.converged}; "
          f"misfit: {res.misfit}{' (accepted)' if res.misfit_accepted else ''}")
    for note in res.record.get("mapping", {}).get("notes", []):
        print(f"  {note}")
    print(f"{'param':>10} {'median':>12} {'q05':>12} {'q95':>12} {'std':>10} {'ls_std':>10} {'crb_std':>10}  unit")
    for n, r in res.summary().items():
        print(
            f"{n:>10} {r['median']:12.5g} {r['q05']:12.5g} {r['q95']:12.5g} {r['std']:10.3g} "
            f"{r.get('ls_std', float('nan')):10.3g} {r.get('crb_std', float('nan')):10.3g}  {units.get(n, '')}"
        )
    for n, d in res.derived_summary().items():
        print(f"{n:>10} {d['median']:12.5g} {d['q05']:12.5g} {d['q95']:12.5g} {d['std']:10.3g}  (derived)  {d['unit']}")
    if res.adequacy is not None:
        for t in res.adequacy.tests:
            rng = f" expected {t.expected[0]:.3g}..{t.expected[1]:.3g}" if t.expected else ""
            pv = f" p={t.p_value:.2g}" if t.p_value is not None else ""
            # the threshold the verdict used: p ≥ alpha passes (alpha Bonferroni-split over the tests)
            thr = f" (ok when p ≥ {t.alpha:.2g})" if t.p_value is not None else ""
            print(f"  adequacy {t.name} ({t.channel}): {t.statistic:.4g}{rng}{pv} "
                  f"{'ok' if t.passed else 'FAIL'}{thr}")


def _position_and_force(rec: Any, res: Any) -> tuple[np.ndarray, np.ndarray, float] | None:
    """(position, force, fs) of a 1-DOF record identified with mbk (velocity integrated), else None."""
    from hil.identify.records import sample_rate, signal

    mapping = res.record.get("mapping") or {}
    ins, outs = mapping.get("inputs") or [], mapping.get("outputs") or {}
    if res.model.name != "mbk" or len(ins) != 1 or len(outs) != 1 or isinstance(rec, Mapping):
        return None
    data = rec.to_identify_dict()
    (key, name), = outs.items()
    t = np.asarray(data["t"], float)
    fs = sample_rate(t)
    y = signal(data["signals"], name)
    q = y if key.startswith("position") else np.concatenate([[0.0], np.cumsum(y[:-1])]) / fs
    return q, signal(data["signals"], ins[0]), fs


def _mapping_only(rec: Any, kw: Mapping[str, Any]) -> Any:
    """An object with the ``model``/``record`` attributes :func:`_position_and_force` reads, from the
    record's inferred plan (the linear fit was refused before it had a result)."""
    from types import SimpleNamespace

    from hil.identify.records import plan_from_record

    keep = {k: v for k, v in kw.items() if k in ("model", "inputs", "outputs", "target", "experiment") and v}
    plan = plan_from_record(rec, rec.to_identify_dict()["signals"], keep)
    return SimpleNamespace(model=SimpleNamespace(name=plan.model, units_kind=plan.model_options.get("units")),
                           record={"mapping": plan.to_dict()})


def _model_choice(rec: Any, res: Any, validate: str | None) -> dict[str, Any] | None:
    """Fit the friction models (hil.identify.friction_api.compare_friction_models) when the linear
    1-DOF fit is a misfit; the evidence table, or None when the record is not a 1-DOF position/velocity one."""
    from hil.identify.friction_api import compare_friction_models

    data = _position_and_force(rec, res)
    if data is None:
        return None
    q, u, fs = data
    val = None
    if validate:
        vrec = load_record(validate)
        vres_like = res  # same mapping (signal names) in the validation record
        vdata = _position_and_force(vrec, vres_like)
        if vdata is None:
            raise ModelSpecError(f"{validate}: no position/force signals named as in the record")
        val = (vdata[0], vdata[1])
    units = getattr(res.model, "units_kind", "linear")
    return compare_friction_models(q, u, fs, validation=val, units=units if units in ("linear", "rotary") else "linear")


def _print_choice(choice: Mapping[str, Any]) -> None:
    print(f"model choice (simulation error on {choice['held_out']}; best: {choice['by']}):")
    print(f"{'friction model':>38} {'BIC':>10} {'sim rms':>10} {'sim fit %':>9} {'AR':>3}  adequacy")
    for r in choice["rows"]:
        print(f"{r['model']:>38} {r['bic']:10.1f} {r['simulation_rms']:10.3g} {r['simulation_fit_pct']:9.2f} "
              f"{r['ar_order']:3d}  {'misfit' if r['misfit'] else 'ok'}")


def main(argv: Sequence[str] | None = None) -> int:
    """``hil identify RECORD [--model NAME] [--json] ...``. Exit codes: 0 ok; 2 usage or input error
    (file, record, model, channel); 13 no trustworthy estimate (data quality, not identifiable,
    posterior not converged; one-line message on stderr). 1 is left to bugs."""
    p = OneLineArgumentParser(
        prog="hil identify",
        description="Identify a grey-box model (SDEA: K_f, B_f, M, B; m-DOF: M, B, K) from a chirp/multisine run. "
        "The model, channels, period and band are inferred from the record; flags override them.",
    )
    p.add_argument("record", help="run record .h5 (hil run / hil import), .csv/.mat (imported on the fly), or .npz")
    p.add_argument("--model", default=None, help="sdea_locked | sdea_free | mbk (default: inferred)")
    p.add_argument("--friction", default=None, metavar="TERMS",
                   help="friction on every actuated joint: comma-separated coulomb, stribeck, offset (viscous B is "
                   "always in the model); mbk with 1 DOF (F_c, ...) or n DOF (F_c_0, F_c_1, ...), sdea_locked "
                   "(needs --output force=SIGNAL) or sdea_free (the motor's); identified from the positions by "
                   "inverse-dynamics ML")
    p.add_argument("--validate", default=None, metavar="RECORD",
                   help="second record (same signal names) for the simulation error of the model choice "
                   "(default: the last third of the record, the models fitted on the rest)")
    p.add_argument("--experiment", default=None, help="experiment name in the record (when it holds several)")
    p.add_argument("--target", default=None, help="actuator (device or group) whose effort command is the input")
    p.add_argument("--input", action="append", metavar="SIGNAL", help="input signal, repeatable (model order)")
    p.add_argument("--output", action="append", metavar="CHANNEL=SIGNAL",
                   help="model output from a signal, e.g. force=spring_ft.wrench[5] (a leading - negates)")
    p.add_argument("--band", nargs=2, type=number_type("nonnegative"), metavar=("F_MIN", "F_MAX"), default=None,
                   help="analysis band [Hz], 0 <= F_MIN < F_MAX")
    p.add_argument("--period", type=number_type("positive"), default=None,
                   help="excitation period [s] (Welch segment length)")
    p.add_argument("--skip", type=number_type("nonnegative"), default=None, help="start-up transient to drop [s]")
    p.add_argument("--sampling", choices=["zoh", "continuous"], default=None,
                   help="plant behind a zero-order hold at the record's rate (default for records) or continuous")
    p.add_argument("--resolution", default=None,
                   help="rounding of the recorded signals: float32 (default), auto (a whole-count quantizer "
                   "detected from the values, else float32), float64, none, or a step")
    p.add_argument("--noise", choices=["student", "gaussian", "scaled"], default=None,
                   help="likelihood of the FRF residuals: student (default: the variance estimated from the "
                        "coherence, Student-t), gaussian (variance known), scaled (gaussian with a fitted common "
                        "scale)")
    p.add_argument("--set", action="append", metavar="PARAM=VALUE", help="starting value of a parameter (theta0)")
    p.add_argument("--seed", type=seed_type, default=None, help="seed of the least-squares restarts and the "
                   "emcee sampler (default 0)")
    p.add_argument("--max-seconds", type=number_type("positive"), default=None, help="time budget of the sampler [s]")
    p.add_argument("--excitation", choices=["refuse", "warn"], default=None, help="a band that cannot pin a parameter: "
                   "refuse (default, exit 13) or warn and fit anyway (hil.identify.excitation)")
    p.add_argument("--method", choices=["auto", "frf", "ml"], default=None,
                   help="estimator: auto (H1 FRF for periodic records, output-error ML otherwise), frf, ml")
    p.add_argument("--posterior", choices=["emcee", "laplace"], default=None,
                   help="ML path: emcee on the ML likelihood (default) or its Laplace approximation (fast)")
    p.add_argument("--accept-misfit", action="store_true",
                   help="exit 0 although an adequacy test flags a model misfit (the result stays flagged)")
    p.add_argument("--json", action="store_true", help="print the full result as JSON")
    p.add_argument("--no-store", action="store_true", help="do not write the posterior into the record")
    p.add_argument("--out", default=None, help="for .csv/.mat input: keep the imported record (with the result) here")
    p.add_argument("--overwrite", action="store_true", help="replace an existing record at --out")
    a = p.parse_args(argv)
    if a.band is not None and not a.band[0] < a.band[1]:
        p.error(f"argument --band: F_MIN must be below F_MAX, got {a.band[0]:g} {a.band[1]:g}")
    try:
        outputs = _kv(a.output, "--output") or None
        theta0 = _theta0(a.set)
        res_spec = _resolution_arg(a.resolution)
        record_path = Path(a.record)
        target_path: Path | None = record_path
        suffix = record_path.suffix.lower()
        if record_path.is_dir():
            raise ModelSpecError(f"{record_path}: is a folder, not a record")
        if a.out and suffix not in (".csv", ".mat"):
            raise ModelSpecError(f"--out applies to .csv/.mat input (the result goes into {target_path} itself)")
        if suffix in (".csv", ".mat"):
            if a.out:  # the backend imports the file into a record kept at --out
                target_path = backend_for(record_path).import_to(record_path, a.out, overwrite=a.overwrite)
                rec: Any = load_record(target_path)
            else:
                rec, target_path = load_record(a.record), None
        elif suffix == ".npz":
            import zipfile

            try:
                rec = load_record(a.record)
            except HilError:
                raise
            except (ValueError, EOFError, zipfile.BadZipFile) as exc:  # garbage, pickled objects, truncated
                raise ModelSpecError(f"{a.record}: not a readable .npz record ({type(exc).__name__})") from None
            target_path = None
        else:
            rec = load_record(a.record)
        kw = {"model": a.model, "band": a.band, "period": a.period, "seed": a.seed, "skip": a.skip,
              "noise": a.noise, "max_seconds": a.max_seconds, "theta0": theta0, "sampling": a.sampling,
              "method": a.method, "posterior": a.posterior, "accept_misfit": a.accept_misfit or None}
        kw["excitation"] = a.excitation
        if a.friction is not None:
            from hil.identify.friction import normalize_friction

            kw["friction"] = normalize_friction(a.friction) or None
        if a.resolution is not None:
            kw["resolution"] = kw["input_resolution"] = res_spec
        if isinstance(rec, Mapping):  # .npz record dict
            if a.input or outputs:
                kw["inputs"], kw["outputs"] = a.input, outputs
            res = identify_record(rec, **kw)
        else:
            kw.update(experiment=a.experiment, target=a.target, inputs=a.input, outputs=outputs)
            res = identify_record(rec, **{k: v for k, v in kw.items() if v is not None})
    except (DataQualityError, NotIdentifiableError, ConvergenceError) as exc:
        hint = ""
        if not a.friction and not isinstance(rec, Mapping) and (a.model or "mbk") == "mbk":
            try:  # a 1-DOF axis the linear model cannot describe: show what the friction models say
                choice = _model_choice(rec, _mapping_only(rec, kw), a.validate)
            except (HilError, ValueError):
                choice = None
            if choice is not None:
                _print_choice(choice)
                best = choice["best"]
                hint = (f"; the data support friction {','.join(best)}: --model mbk --friction {','.join(best)}"
                        if best else "")
        print(f"hil identify: {type(exc).__name__}: {' '.join(str(exc).split())}{hint}", file=sys.stderr)
        return EXIT_ERROR
    except (HilError, OSError, UnicodeDecodeError) as exc:  # ModelSpecError, RecordError, SceneError: input
        msg = " ".join(str(exc).split())
        if isinstance(exc, OSError) and exc.filename is not None:
            msg = f"{exc.filename}: {exc.strerror or msg}"
        elif isinstance(exc, UnicodeDecodeError):
            msg = f"{a.record}: not UTF-8 text ({exc.reason} at byte {exc.start})"
        print(f"hil identify: error: {msg}", file=sys.stderr)
        return EXIT_USAGE
    if target_path is not None and not a.no_store:
        try:
            key = store_result(target_path, res)
            res.record["stored"] = f"{target_path}:/identification/{key}"
        except HilError as exc:
            print(f"hil identify: warning: result not stored: {exc}", file=sys.stderr)
    choice = None
    if res.misfit and not a.accept_misfit and not a.friction:
        try:
            choice = _model_choice(rec, res, a.validate)
        except HilError as exc:
            print(f"hil identify: warning: no friction model choice: {' '.join(str(exc).split())}", file=sys.stderr)
    if a.json:
        out = res.to_dict()
        if choice is not None:
            out["model_choice"] = choice
        print(json.dumps(out, indent=2))
    else:
        _print_table(res)
        if choice is not None:
            _print_choice(choice)
    if not res.converged:
        reasons = "; ".join(res.posterior.diagnostics.reasons)
        print(f"hil identify: ConvergenceError: posterior not converged: {reasons}", file=sys.stderr)
        return EXIT_ERROR
    if res.misfit and not a.accept_misfit:
        why = "; ".join(res.adequacy.reasons) if res.adequacy is not None else ""
        richer = "use a richer model"
        if choice is not None:
            best = choice["best"]
            richer = (f"the data support friction {','.join(best)}: hil identify {a.record} --model mbk --friction "
                      f"{','.join(best)}" if best else "no friction model fits better")
        print(f"hil identify: ModelMisfit: the model does not describe the data ({why}); "
              f"{richer}, or --accept-misfit", file=sys.stderr)
        return EXIT_ERROR
    return EXIT_OK
