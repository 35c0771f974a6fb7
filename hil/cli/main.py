"""The ``hil`` command line.

Subcommands import what they need when they run, so ``hil stability`` never imports device
libraries and ``hil mock serve`` never imports the stability core.

Global options go before the subcommand, for every subcommand: ``hil --debug run ...``,
``hil --debug identify ...``, ``hil --debug mock serve ...`` (``--debug`` is also accepted after the
subcommand name of the argparse subcommands).

Errors: an expected failure (a :class:`~hil.errors.HilError`, an unreadable or unwritable file, a
file that is not UTF-8 text, a bad flag or value) prints exactly one line on stderr,
``hil <command>: error: <file or flag>: <what is wrong>``, and exits 2; anything else is a bug:
one line pointing at ``--debug`` and exit 1. ``--debug`` adds the traceback (and debug logs).
Output folders never overwrite: see :mod:`hil.record.outdir` (``--overwrite``).

Exit codes: one table, :class:`hil.errors.ExitCode` with :data:`hil.errors.EXIT_MEANINGS` (README.md
shows it; tests/test_exit_codes.py compares the two).
"""

from __future__ import annotations

import argparse
import contextlib
import difflib
import importlib
import json
import logging
import math
import os
import sys
import threading
import time
import traceback
import warnings
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, cast

from hil.errors import (  # the exit codes: one table in hil.errors (re-exported here for callers)
    DECISION_EXIT,
    EXIT_ERROR,
    EXIT_INTERNAL,
    EXIT_INTERRUPTED,
    EXIT_MARGINAL,
    EXIT_NOT_APPLICABLE,
    EXIT_NOT_HELD,
    EXIT_OK,
    EXIT_SAFETY_STOP,
    EXIT_UNSTABLE,
    EXIT_USAGE,
    VERDICT_EXIT,
    HilError,
    SafetyStop,
)
from hil.inputs import number_type, seed_type  # both are needed to build the parser of every command

# hil.bench.probe (its codecs, link budgets) is imported by _cmd_probe and by build_parser only for
# ``hil probe``: importing it here cost every command's start-up (issue 15, ``hil stability``).

__all__ = ["DECISION_EXIT", "EXIT_ERROR", "EXIT_INTERNAL", "EXIT_INTERRUPTED", "EXIT_MARGINAL", "EXIT_NOT_APPLICABLE",
           "EXIT_NOT_HELD", "EXIT_OK", "EXIT_SAFETY_STOP", "EXIT_UNSTABLE", "EXIT_USAGE", "VERDICT_EXIT",
           "OneLineArgumentParser", "UsageError", "build_parser", "main", "one_line"]

logger = logging.getLogger(__name__)


class UsageError(HilError):
    """A command-line mistake; reported in one line with exit code 2."""


def one_line(text: object) -> str:
    """``text`` with every run of white space (newlines too) collapsed to one space."""
    return " ".join(str(text).split())


class OneLineArgumentParser(argparse.ArgumentParser):
    """An :class:`argparse.ArgumentParser` whose errors are one line on stderr,
    ``<prog>: error: <message> (see '<prog> --help')``, with exit status 2 (``SystemExit``), instead
    of the usage block followed by the message. Subparsers inherit the class."""

    def error(self, message: str) -> Any:
        self.exit(2, f"{self.prog}: error: {one_line(message)} (see '{self.prog} --help')\n")


def _number(flag: str, name: str, text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise UsageError(f"{flag} {name}={text.strip()}: {name} must be a number") from None
    if not math.isfinite(v):
        raise UsageError(f"{flag} {name}={text.strip()}: {name} must be finite")
    return v


def _parse_set(items: Sequence[str], defaults: dict[str, Any] | None = None, what: str = "",
               flag: str = "--set") -> dict[str, Any]:
    """``NAME=VALUE`` items. With ``defaults``: names must be keys of it (did-you-mean otherwise);
    a name whose default is a string takes the text, every other name a finite number."""
    out: dict[str, Any] = {}
    for it in items:
        if "=" not in it:
            raise UsageError(f"{flag} expects NAME=VALUE, got {it!r}")
        k, v = it.split("=", 1)
        k = k.strip()
        if not k:
            raise UsageError(f"{flag} {it}: empty parameter name")
        if defaults is not None and k not in defaults:
            raise UsageError(f"{flag} {it}: {what} has no parameter {k!r}{_suggest(k, list(defaults))}")
        if defaults is not None and isinstance(defaults[k], str):
            out[k] = v.strip()
        else:
            out[k] = _number(flag, k, v)
    return out


def _suggest(name: str, known: Sequence[str]) -> str:
    close = difflib.get_close_matches(name, known, n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


# ---------------------------------------------------------------------------------------------
# hil stability


def _stability_tol(args: argparse.Namespace):
    """Tolerances for ``hil stability``: ``--rtol R`` (relative perturbation of the coefficients;
    then ``marginal`` means the verdict can flip within it, docs/VERDICTS.md)."""
    from hil.stability.criteria import Tolerances

    r = getattr(args, "rtol", None)
    if r is None:
        return Tolerances()
    if not math.isfinite(r) or r < 0 or r >= 1:
        raise UsageError(f"--rtol must be a number in [0, 1), got {r!r}")
    return Tolerances(rtol=float(r))


def _cmd_stability(args: argparse.Namespace) -> int:
    from hil.stability.criteria import check

    if args.list_models:
        from hil.models import get_model, model_names

        for n in model_names():
            m = get_model(n)
            print(f"{n:18s} {m.description}  [criterion: {m.criterion}]")
        return EXIT_OK
    if bool(args.file) == bool(args.model):
        raise UsageError("give either a network FILE or --model NAME (see --list-models)")
    if args.file:
        from hil.scene.netfile import load_network

        if args.set:
            raise UsageError("--set applies to built-in models (--model), not to files")
        source = str(args.file)
        with _Progress(f"hil stability {source}") as prog, _numeric_guard(source):
            prog.update("reading the network file")
            tm, crit = load_network(args.file)
        criterion = args.criterion or crit
    else:
        from hil.models import get_model, model_names

        try:
            m = get_model(args.model)
        except KeyError:
            raise UsageError(f"--model {args.model}: unknown model{_suggest(args.model, model_names())}; "
                             f"known: {', '.join(model_names())}") from None
        params = _parse_set(args.set or [], m.defaults, f"model {m.name}")
        source = f"--model {m.name}"
        try:
            m.check_params(params)
        except HilError as exc:
            raise UsageError(f"--set: {one_line(exc)}") from None
        try:
            with _numeric_guard(source):
                tm = m.build(**params)
        except TypeError as exc:
            raise UsageError(f"{source}: bad parameter: {exc}") from None
        except HilError as exc:
            raise UsageError(f"{source}: {one_line(exc)}") from None
        criterion = args.criterion or m.criterion
    with _Progress(f"hil stability {source}") as prog:
        prog.update(f"checking the {criterion} conditions")
        try:
            with _numeric_guard(source):
                result = check(tm, criterion, _stability_tol(args))
        except UsageError:
            raise
        except HilError as exc:
            raise UsageError(f"{source}: {one_line(exc)}") from None
    if args.json:
        print(json.dumps(result.to_dict(), indent=2, ensure_ascii=False))
    else:
        _print_result(result, args.verbose)
    return VERDICT_EXIT[str(result.verdict)]


def _print_result(result: Any, verbose: bool) -> None:
    from rich.console import Console
    from rich.table import Table

    con = Console(highlight=False, soft_wrap=True)
    colour = {"stable": "green", "marginal": "yellow", "potentially_unstable": "red", "not_applicable": "magenta"}
    v = str(result.verdict)
    title = f"{result.network.get('name') or 'network'} — {result.criterion}"
    con.print(f"[bold]{title}[/bold]")
    weak = " (weak: some conditions hold with equality)" if result.weak else ""
    con.print(f"verdict: [bold {colour[v]}]{v}[/]{weak}")
    if result.failed_condition:
        con.print(f"decided by: {result.failed_condition}")
    if result.reason:
        con.print(f"reason: {result.reason}")
    if not (isinstance(result.margin, float) and math.isnan(result.margin)):
        wf = result.worst_frequency
        wtxt = "" if wf is None else (" at ω → ∞" if math.isinf(wf) else f" at ω = {wf:.5g} rad/s")
        con.print(f"margin (normalized): {result.margin:.4g}{wtxt}")
    tab = Table(show_header=True, header_style="bold")
    for col in ("condition", "status", "margin", "ω [rad/s]"):  # names and values never wrap
        tab.add_column(col, no_wrap=True)
    tab.add_column("detail", min_width=20)  # prose: wraps between words
    shown = 0
    for c in result.conditions:
        if not verbose and c.status == "satisfied":
            continue
        shown += 1
        wf = "" if c.worst_frequency is None else ("∞" if math.isinf(c.worst_frequency) else f"{c.worst_frequency:.4g}")
        m = "" if isinstance(c.margin, float) and math.isnan(c.margin) else f"{c.margin:.3g}"
        st = c.status
        col = colour.get({"violated": "potentially_unstable", "satisfied": "stable"}.get(st, st), "white")
        tab.add_row(c.name, f"[{col}]{st}[/]", m, wf, c.detail)
    n_ok = sum(1 for c in result.conditions if c.status == "satisfied")
    if shown:
        con.print(tab)
    if not verbose:
        con.print(f"[dim]{n_ok} further condition(s) satisfied (use -v to list all)[/dim]")


# ---------------------------------------------------------------------------------------------
# hil design


def _cmd_design(args: argparse.Namespace) -> int:
    from hil.models.design import DESIGN_FIXED, check_design_inputs, k22_max, optimize_coupler
    from hil.models.sdea import SDEA_TABLE1

    params = _parse_set(args.set or [], {k: SDEA_TABLE1[k] for k in DESIGN_FIXED}, "the SDEA design")
    if args.b22 is not None and (not math.isfinite(args.b22) or args.b22 <= 0):
        raise UsageError(f"--b22 {args.b22:g}: the coupler damping must be a finite positive number [N.m.s/rad]")
    if args.alpha is not None and (not math.isfinite(args.alpha) or not 0.0 <= args.alpha <= 1.0):
        raise UsageError(f"--alpha {args.alpha:g}: the feed-forward ratio must lie in [0, 1]")
    if args.optimize_alpha and args.alpha is not None:
        raise UsageError("--alpha and --optimize-alpha exclude each other")
    if args.optimize_alpha and args.b22 is not None:
        raise UsageError("--b22 fixes the damping at the given alpha; drop --optimize-alpha or --b22")
    try:
        check_design_inputs(args.b22, args.alpha, args.criterion, params)
    except HilError as exc:
        raise UsageError(f"--set: {one_line(exc)}") from None
    with _Progress("hil design", enabled=True) as prog:
        if args.b22 is not None:
            r = k22_max(args.b22, args.alpha if args.alpha is not None else 1.0, args.criterion, params)
        else:
            alpha = None if args.optimize_alpha else (args.alpha if args.alpha is not None else 1.0)
            r = optimize_coupler(args.criterion, alpha, params, progress=prog.update)
    if args.json:
        print(json.dumps(r.to_dict(), indent=2))
    else:
        print(f"{args.criterion}: k22_max = {r.k22_max:.6g} N.m/rad at b22 = {r.b22:.6g} N.m.s/rad, "
              f"alpha = {r.alpha:.4g} ({r.evaluations} exact verdicts)")
    return EXIT_OK


# ---------------------------------------------------------------------------------------------
# hil sweep


def _cmd_sweep(args: argparse.Namespace) -> int:
    from hil.bench.stopflag import STOP, StopRequested
    from hil.certify.sweep import SweepSpec, iter_table, make_executor, parse_grid, plot_sweep, run_sweep, save_sweep
    from hil.models import get_model, model_names

    if bool(args.model) == bool(args.scene):
        raise UsageError("give either --model NAME or --scene SCENE (the network of its certification)")
    scene = None
    if args.scene:
        from hil.scene.spec import load_scene

        scene = load_scene(args.scene)
        if scene.certification is None:
            raise UsageError(f"--scene {args.scene}: the scene has no certification section (the network to sweep)")
        args.model = scene.certification.model
    try:
        m = get_model(args.model)
    except KeyError:
        raise UsageError(f"--model {args.model}: unknown model{_suggest(args.model, model_names())}; "
                         f"known: {', '.join(model_names())}") from None
    axes = [parse_grid(g) for g in args.grid]
    params = _parse_set(args.set or [], m.defaults, f"model {m.name}")
    posterior = None
    if args.posterior:
        from hil.certify.sweep import posterior_from_record

        path, _, name = args.posterior.partition(":")
        posterior = posterior_from_record(path, name or None, args.model)
    if args.required is not None and not 0 < args.required < 1:
        raise UsageError(f"--required {args.required:g}: a probability in (0, 1)")
    kw = {"refine": not args.no_refine, "boundary_tol": args.boundary_tol, "posterior": posterior,
          "n_draws": args.draws, "chunk": args.chunk}
    spec = (SweepSpec.from_scene(scene, axes, params, args.criterion, **kw) if scene is not None
            else SweepSpec(args.model, axes, params, args.criterion, **kw))
    spec.validate()
    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers {args.workers}: give at least 1")
    executor = "dask" if args.scheduler else args.executor
    cache = None if args.no_cache else (args.cache or ".hil-cache/sweep")
    out = _out_dir(args.out, f"reports/sweep-{scene.name if scene is not None else args.model}", args.overwrite)
    ex = make_executor(executor, args.workers, args.scheduler)
    bar = _SweepProgress(f"hil sweep {args.model}", enabled=not args.json)
    try:
        with STOP.install(), bar:
            res = run_sweep(spec, ex, cache, progress=bar.update, should_stop=STOP.check)
    except StopRequested as exc:
        raise StopRequested(f"{exc}: the finished tasks are cached in {cache}; run the same command "
                            "again to resume" if cache else f"{exc} (no cache: nothing kept)", exc.status) from None
    finally:
        ex.close()
    files = {"table": save_sweep(res, out / "sweep.h5")}
    if len(res.boundary["points"]):
        import numpy as np

        hdr = ",".join([*res.names, "axis", "stable_end", "unstable_end"])
        rows = np.column_stack([res.boundary["points"], res.boundary["axis"], res.boundary["bracket"]])
        np.savetxt(out / "boundary.csv", rows, delimiter=",", header=hdr, comments="", fmt="%.10g")
        files["boundary"] = out / "boundary.csv"
    from hil.protocols.registry import missing_extras

    if not args.no_plot and not missing_extras(report=True):
        files["map"] = plot_sweep(res, out / "sweep.png", args.required)
    counts = Counter(r["verdict"] for r in iter_table(res))
    if args.json:
        print(json.dumps({"model": args.model, "criterion": spec.criterion_name, "points": int(res.verdict.size),
                          "verdicts": dict(counts), "boundary_points": len(res.boundary["points"]),
                          "evaluations": res.evaluations, "cache_hits": res.cache_hits, "timings": res.timings,
                          "files": {k: str(v) for k, v in files.items()}}, indent=2))
    else:
        print(f"{args.model} ({spec.criterion_name}): {res.verdict.size} grid points, "
              + ", ".join(f"{v} {k}" for k, v in sorted(counts.items()))
              + f"; {len(res.boundary['points'])} boundary points refined; {res.evaluations} exact verdicts "
              f"({res.cache_hits} tasks from the cache) in {res.timings['total_s']:.1f} s")
        for k, v in files.items():
            print(f"{k}: {v}")
    return EXIT_OK


# ---------------------------------------------------------------------------------------------
# hil scenes / hil run / hil replay


def _cmd_scenes(args: argparse.Namespace) -> int:
    from hil.scene.spec import builtin_scenes

    rows = builtin_scenes()
    if args.json:
        print(json.dumps([{"name": n, "description": d} for n, d in rows], indent=2))
        return EXIT_OK
    from rich.console import Console
    from rich.table import Table

    tab = Table("scene", "description", title="built-in scenes (usable by name: hil run NAME)")
    for n, d in rows:
        tab.add_row(n, d)
    Console().print(tab)
    return EXIT_OK


def _cmd_run(args: argparse.Namespace) -> int:
    from hil.protocols.registry import extras_message
    from hil.run.runner import Runner
    from hil.scene.spec import check_seed, load_scene

    scene = load_scene(args.scene)
    if args.seed is not None:
        scene.seed = check_seed(args.seed)
    if need := extras_message(scene):  # a base install: say which extra, before anything is on disk
        print(f"hil run {args.scene}: {need}", file=sys.stderr)
        return EXIT_USAGE
    select = None
    if args.experiment:
        select = []
        for item in args.experiment:
            try:
                select.append(int(item))
            except ValueError:
                idx = [i for i, e in enumerate(scene.experiments) if getattr(e, "type", None) == item]
                if not idx:
                    names = [str(getattr(e, "type", "?")) for e in scene.experiments]
                    raise UsageError(f"--experiment {item}: no such experiment in scene {scene.name} "
                                     f"(indices 0-{len(names) - 1}, types: {', '.join(dict.fromkeys(names))})"
                                     ) from None
                select += idx
        bad = [i for i in select if not 0 <= i < len(scene.experiments)]
        if bad:
            raise UsageError(f"--experiment {bad[0]}: scene {scene.name} has experiments 0-"
                             f"{len(scene.experiments) - 1}")
    out = _out_dir(args.out, f"runs/{scene.name}", args.overwrite)
    realtime = True if args.realtime else (False if args.lockstep else None)
    progress_cb = None
    prog = None
    if not args.json and sys.stderr.isatty():
        from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

        prog = Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
                        TimeRemainingColumn(), transient=True)
        tasks: dict[str, Any] = {}

        def progress_cb(name: str, k: int, n: int) -> None:
            if name not in tasks:
                tasks[name] = prog.add_task(name, total=n)
            prog.update(tasks[name], completed=k)

    beat: Any = None
    if prog is None:  # not a terminal: a plain line every few seconds (_Progress)
        beat = _Progress(f"hil run {scene.name}")

        def progress_cb(name: str, k: int, n: int) -> None:
            beat.message = f"{name}: {k}/{n} ticks ({100.0 * k / max(n, 1):.0f} %)"

    from hil.bench.stopflag import STOP

    runner = Runner(scene, out, realtime=realtime, progress=progress_cb, overwrite=args.overwrite)
    with STOP.install():  # signals stay stop requests until the results are printed
        with prog if prog is not None else beat:
            outcomes = runner.run(select)
        code = _run_exit_code(outcomes, runner)
        _print_run(args, scene, out, outcomes, runner)
    return code


def _run_exit_code(outcomes: Sequence[Any], runner: Any) -> int:
    """130 if a run was interrupted (SIGINT), 20 for any other stop (limit, watchdog, device or record
    failure, SIGTERM/SIGHUP, error), 0 when every experiment completed."""
    statuses = [o.status for o in outcomes] + [getattr(runner, "stop_status", None)]
    if "interrupted" in statuses:
        return EXIT_INTERRUPTED
    if any(s in ("safety_stop", "error") for s in statuses):
        return EXIT_SAFETY_STOP
    return EXIT_OK


def _print_run(args: argparse.Namespace, scene: Any, out: Any, outcomes: Sequence[Any], runner: Any) -> None:
    stop = None
    if getattr(runner, "stop_status", None):
        stop = {"status": runner.stop_status, "reason": runner.stop_reason}
    if args.json:
        print(json.dumps({"scene": scene.name, "out": str(out), "stop": stop,
                          "experiments": [o.to_dict() for o in outcomes]}, indent=2, default=str), flush=True)
    else:
        from rich.console import Console
        from rich.table import Table

        con = Console(highlight=False, soft_wrap=True)
        tab = Table(title=f"hil run {scene.name}")
        tab.add_column("experiment", no_wrap=True)
        tab.add_column("status", no_wrap=True)
        tab.add_column("stop reason", min_width=12)
        tab.add_column("key results", min_width=24)
        for o in outcomes:
            scalars = [(k, v) for k, v in o.results.items() if not isinstance(v, dict | list)][:4]
            keys = ", ".join(f"{k}={_short(v)}" for k, v in scalars)  # wraps after a comma, never inside a value
            tab.add_row(o.name, o.status, o.stop_reason if o.status != "completed" else "", keys)
        con.print(tab)
        if stop is not None:
            con.print(f"run stopped: {stop['reason']}")
        con.print(f"records in {out}:")  # paths outside the table: never split across lines
        for o in outcomes:
            con.print(f"  {o.record}")


def _short(v: Any) -> str:
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, float | int) or hasattr(v, "dtype"):
        try:
            return f"{float(v):.4g}"
        except (TypeError, ValueError):
            pass
    return str(v)[:24]


def _cmd_plan(args: argparse.Namespace) -> int:
    """``hil plan SCENE``: predicted posterior sd and safety of the identification experiments (hil.run.plan)."""
    from hil.run.plan import plan_scene
    from hil.scene.spec import load_scene

    scene = load_scene(args.scene)
    precision = _parse_set(args.precision or [], None, flag="--precision")
    preds = plan_scene(scene, experiments=args.experiment, precision=precision)
    if args.json:
        print(json.dumps({"scene": scene.name, "experiments": [p.to_dict() for p in preds]}, indent=2, default=str))
        return EXIT_OK
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    con = Console(highlight=False, soft_wrap=True)
    for p in preds:
        c = p.config
        tab = Table(title=f"{escape(scene.name)}: {escape(p.name)} ({p.model}; {c['type']} {c['f0']:.4g}-"
                    f"{c['f1']:.4g} Hz, amplitude {c['amplitude']:.4g}, {c['duration']:.4g} s, "
                    f"{p.n_averages} averages)")
        for col in ("parameter", "nominal", "predicted sd", "rel sd", "requested", "info fraction"):
            tab.add_column(col, no_wrap=True)
        for n in p.names:
            req = p.requested.get(n)
            flag = " (not pinned)" if n in p.not_pinned else ""
            tab.add_row(n, f"{p.nominal[n]:.5g}", f"{p.sd[n]:.3g}", f"{p.rel_sd[n]:.3g}",
                        "" if req is None else f"{req:.3g}", f"{p.information_fraction[n]:.2f}{flag}")
        con.print(tab)
        lims = ", ".join(f"{k} {v['peak']:.4g} / {v['limit']:.4g}" for k, v in p.safety.items())
        con.print(f"safety (peak / limit): {lims}: " + ("[green]allowed[/]" if p.allowed else "[red]NOT allowed[/]"))
        if p.ok_precision is not None:
            con.print("requested precision: " + ("[green]met[/]" if p.ok_precision else "[red]not met[/]"))
        for note in p.proposal_notes:
            con.print(f"  proposal: {escape(note)}")
    return EXIT_OK


def _cmd_import(args: argparse.Namespace) -> int:
    from hil.record.importers import import_csv, import_mat
    from hil.record.outdir import check_out_file

    src = Path(args.file)
    if src.is_dir():
        raise UsageError(f"{src}: is a folder; give a .csv or .mat file")
    if not src.exists():
        raise UsageError(f"{src}: no such file")
    out = Path(args.out) if args.out else src.with_suffix(".h5")
    if out.resolve() == src.resolve():
        raise UsageError(f"--out {out}: would replace the input file")
    mapping: dict[str, Any] | None = None
    if args.map or args.time:
        mapping = {}
        if args.time:
            mapping["t"] = args.time
        for item in args.map or []:
            if "=" not in item:
                raise UsageError(f"--map expects CHANNEL=COLUMN[,COLUMN...], got {item!r}")
            ch, cols = item.split("=", 1)
            parts = [c.strip() for c in cols.split(",") if c.strip()]
            if not ch.strip() or not parts:
                raise UsageError(f"--map {item}: expects CHANNEL=COLUMN[,COLUMN...]")
            mapping[ch.strip()] = parts[0] if len(parts) == 1 else parts
        # without --time the importer takes the t/time column (hil.record.importers)
    suffix = src.suffix.lower()
    if suffix not in (".mat", ".csv", ".txt", ".tsv"):
        raise UsageError(f"{src}: expected a .csv or .mat file")
    if suffix == ".mat" and args.sidecar:
        raise UsageError("--sidecar applies to CSV files; for .mat give --map/--time or a sidecar next to the file")
    if args.sidecar and mapping is not None:
        raise UsageError("give --sidecar or --map/--time, not both")
    check_out_file(out, overwrite=args.overwrite)
    if suffix == ".mat":
        path = import_mat(src, out, mapping=mapping)
    else:
        path = import_csv(src, out, mapping=mapping, sidecar=args.sidecar)
    print(str(path))
    return EXIT_OK


def _cmd_certify(args: argparse.Namespace) -> int:
    from hil.certify.pipeline import certify_scene
    from hil.protocols.registry import extras_message
    from hil.scene.spec import check_seed, load_scene

    if len(args.scene) > 1 or (args.scene and Path(args.scene[0]).is_dir()):
        return _cmd_certify_fleet(args)
    if args.workers is not None or args.scheduler:
        raise UsageError("--workers and --scheduler apply to a fleet (several scenes or a folder)")
    args.scene = args.scene[0] if args.scene else None
    scene = load_scene(args.scene or "sdea_bench")
    if args.seed is not None:
        scene.seed = check_seed(args.seed)
    if need := extras_message(None if args.no_experiments else scene, report=True):  # before any folder
        print(f"hil certify {args.scene or 'sdea_bench'}: {need}", file=sys.stderr)
        return EXIT_USAGE
    key = None
    if args.sign:  # read the key (and check the extra) before anything runs or is written
        from hil.certify.signing import load_private_key

        key = load_private_key(args.sign)
    elif args.signer:
        raise UsageError("--signer names who signs: give the key with --sign KEY")
    out = _out_dir(args.out, f"reports/{scene.name}", args.overwrite)

    beat = _Progress(f"hil certify {scene.name}", enabled=not sys.stderr.isatty())  # stage lines on a terminal

    def say(msg: str) -> None:
        beat.message = f"{msg.removeprefix(scene.name + ': ')} (still running)"
        if not args.json:
            print(msg, file=sys.stderr)

    with beat:
        cert = certify_scene(scene, out, progress=say, run_experiments=not args.no_experiments)  # sealed
    from hil.report.render import build_reports

    integrity = None
    if key is not None:
        from hil.certify.signing import sign_certificate
        from hil.certify.verify import check_certificate

        cert = sign_certificate(cert, key, args.signer or "")
        integrity = check_certificate(cert, public_key=key.public(),
                                      verified_with="the signing key's public half, when signing")
    files = build_reports(cert, out, integrity=integrity)
    if args.json:
        print(json.dumps({"decision": cert.decision, "reasons": cert.reasons, "scene": scene.name,
                          "files": {k: str(v) for k, v in files.items()},
                          "digest": cert.integrity.digest if cert.integrity else None,
                          "signed": bool(cert.integrity and cert.integrity.signature),
                          "measurements": [m.model_dump() for m in cert.measurements]}, indent=2, default=str))
    else:
        from rich.console import Console
        from rich.markup import escape
        from rich.table import Table

        con = Console(highlight=False, soft_wrap=True)  # prose and paths are never broken by the console
        colour = {"GO": "green", "MARGINAL": "yellow", "NO-GO": "red", "ERROR": "magenta"}[cert.decision]
        con.print(f"[bold]{escape(scene.name)}[/bold]: [bold {colour}]{cert.decision}[/]")
        for r in cert.reasons:
            con.print(f"  - {escape(r)}")
        tab = Table()
        tab.add_column("measurement", min_width=16)  # a name: wraps between words if it must
        for col in ("value", "limits", "outcome"):  # values never wrap
            tab.add_column(col, no_wrap=True)
        for m in cert.measurements:
            lim = " ".join(x for x in (f"≥ {m.lower:g}" if m.lower is not None else "",
                                       f"≤ {m.upper:g}" if m.upper is not None else "") if x)
            tab.add_row(escape(m.name), escape(f"{_short_value(m.value)} {m.unit}".strip()), lim, m.outcome)
        con.print(tab)
        for k, v in files.items():
            con.print(f"{k}: {escape(str(v))}")
        if cert.integrity is not None:
            sig = cert.integrity.signature
            signed = f", signed with key {sig.public_key_sha256[:16]}…" if sig is not None else ""
            print(f"digest: {cert.integrity.digest}{signed}")
            print(f"check with: hil verify {out}")
    return DECISION_EXIT[cert.decision]


def _cmd_certify_fleet(args: argparse.Namespace) -> int:
    from hil.certify.fleet import certify_fleet, expand_scenes
    from hil.certify.sweep import make_executor
    from hil.protocols.registry import extras_message
    from hil.scene.spec import check_seed, load_scene

    if args.sign or args.signer:
        raise UsageError("--sign signs one certificate: sign the scenes of a fleet one by one")
    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers {args.workers}: give at least 1")
    scenes = expand_scenes(args.scene)
    seed = None if args.seed is None else check_seed(args.seed)
    for s in scenes:  # every scene loads and has its extras before anything runs or is written
        sc = load_scene(s)
        if need := extras_message(None if args.no_experiments else sc, report=True):
            print(f"hil certify {s}: {need}", file=sys.stderr)
            return EXIT_USAGE
    ex = make_executor("dask" if args.scheduler else "process", args.workers, args.scheduler)
    out = _out_dir(args.out, "reports/fleet", args.overwrite)
    extra = ["--no-experiments"] if args.no_experiments else []

    def said(done: int, total: int, e: Any) -> None:
        if not args.json:
            print(f"[{done}/{total}] {e.name}: {e.decision} ({e.seconds:.0f} s)", file=sys.stderr)

    from hil.bench.stopflag import STOP

    try:
        with STOP.install():
            res = certify_fleet(scenes, out, executor=ex, seed=seed, extra_args=extra, progress=said,
                                should_stop=lambda: STOP.requested)
    finally:
        ex.close()
    if args.json:
        print(json.dumps(res.to_dict(), indent=2))
    else:
        from rich.console import Console
        from rich.markup import escape
        from rich.table import Table

        con = Console(highlight=False, soft_wrap=True)
        colour = {"GO": "green", "MARGINAL": "yellow", "NO-GO": "red", "ERROR": "magenta"}
        tab = Table(title=f"fleet: {len(res.entries)} scene(s)")
        for col in ("scene", "decision", "bench", "time [s]"):
            tab.add_column(col, no_wrap=True)
        tab.add_column("first reason", min_width=20)
        for e in res.entries:
            tab.add_row(escape(e.name), f"[{colour[e.decision]}]{e.decision}[/]",
                        "simulated" if e.simulated else "real", f"{e.seconds:.1f}",
                        escape(e.reasons[0] if e.reasons else ""))
        con.print(tab)
        con.print(f"[bold]fleet decision: [{colour[res.decision]}]{res.decision}[/][/bold] (the worst scene)")
        con.print(f"index: {escape(str(out / 'index.html'))}")
    STOP.check()  # a signal stopped the fleet: exit 130 / 20 after the summary and the index
    return res.exit_code


def _short_value(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def _cmd_report(args: argparse.Namespace) -> int:
    from hil.protocols.registry import extras_message
    from hil.record.outdir import check_out_dir

    if need := extras_message(report=True):
        print(f"hil report {args.path}: {need}", file=sys.stderr)
        return EXIT_USAGE
    from hil.certify.verify import MODIFIED
    from hil.report.render import rebuild_reports

    if args.out:  # another folder than the certificate's must be new or empty (or --overwrite)
        src = Path(args.path)
        home = src if src.is_dir() else src.parent
        same = Path(args.out).exists() and home.exists() and Path(args.out).resolve() == home.resolve()
        check_out_dir(args.out, overwrite=args.overwrite or same)
    cert, st, paths = rebuild_reports(args.path, args.out, args.public_key, args.allow_modified)
    mark = f" [{MODIFIED}]" if not st.valid else ""
    print(f"{cert.decision} {cert.scene.name}{mark}: {paths['html']} {paths['pdf']}")
    return EXIT_OK


def _cmd_verify(args: argparse.Namespace) -> int:
    """``hil verify DIR [--public-key PUB]``: exit 0 and ``OK …`` on stdout, or 2 and one line on
    stderr saying what does not match (hil.certify.verify); a bad input raises (one line, exit 2)."""
    from hil.certify.verify import check_certificate, ok_summary
    from hil.report.render import _resolve, load_certificate

    where = _resolve(args.path)
    cert = load_certificate(args.path)
    key = None
    if args.public_key:
        from hil.certify.signing import load_public_key

        key = load_public_key(args.public_key)
    st = check_certificate(cert, where.parent, key)
    if key is not None and st.signature == "absent":
        st.signature, st.signature_detail = "invalid", "the certificate is not signed"
    if not st.valid:
        print(f"hil verify: {where}: NOT VALID: {st.reason()}", file=sys.stderr)
        return EXIT_USAGE
    print(f"OK {where}: {ok_summary(st)}")
    return EXIT_OK


def _cmd_keygen(args: argparse.Namespace) -> int:
    from hil.certify.signing import generate_keypair, load_public_key

    priv, pub = generate_keypair(args.out)
    print(f"private key {priv} (mode 0600: keep it secret; hil certify --sign {priv})")
    print(f"public key  {pub} (fingerprint {load_public_key(pub).fingerprint}; hil verify DIR --public-key {pub})")
    return EXIT_OK


def _cmd_check_realtime(args: argparse.Namespace) -> int:
    from hil.run.realtime import check_realtime

    return check_realtime(args.rate, args.seconds, rt=not args.no_rt, as_json=args.json)


def _cmd_replay(args: argparse.Namespace) -> int:
    from hil.record.hdf5 import replay

    return replay(args.record, as_json=args.json)


# ---------------------------------------------------------------------------------------------


class _Discard:
    """Stands in for the parser of a command that does not run (:func:`build_parser`): every
    argparse call on it (add_argument, set_defaults, groups, nested subparsers) is accepted and
    does nothing, so those commands' argument lists cost nothing at start-up."""

    def __getattr__(self, name: str) -> Callable[..., _Discard]:
        return lambda *a, **kw: self


_DISCARD = _Discard()


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser of ``hil``. With ``command`` (the subcommand about to run, as :func:`main` passes
    it) only that subcommand gets its arguments; the others are listed by name and help, which is
    all ``hil --help`` and the "invalid choice" error show (start-up time, issue 15: adding every
    command's arguments, and importing what they need, is work a single command never uses)."""
    from hil.stability.criteria import CriterionChoices  # the criterion names, from their registry

    p = OneLineArgumentParser(
        prog="hil", description="Hardware-in-the-loop identification and stability certification of haptic "
        "devices, teleoperators and series elastic actuators.",
        epilog="Global options go before the COMMAND: hil --debug COMMAND ... Exit codes: see the README.")
    p.add_argument("--debug", action="store_true", help="show tracebacks and debug logs (before the COMMAND)")
    common = OneLineArgumentParser(add_help=False)
    common.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    sub = p.add_subparsers(dest="cmd", metavar="COMMAND", parser_class=OneLineArgumentParser)

    def add(name: str, **kw: Any) -> argparse.ArgumentParser:  # every subcommand also takes --debug
        if command is not None and name != command:  # not the command that runs: listed, never parsed
            sub.add_parser(name, help=kw.get("help"), add_help=False)
            return cast(argparse.ArgumentParser, _DISCARD)  # its arguments go nowhere
        kw.setdefault("parents", [common])
        return sub.add_parser(name, **kw)

    s = add("stability", help="check passivity / absolute stability of a network (file or built-in model)")
    s.add_argument("file", nargs="?", help="network file (YAML or JSON): type, ports, matrix of {num, den}")
    s.add_argument("--model", help="built-in model name (see --list-models)")
    s.add_argument("--set", action="append", metavar="PARAM=VALUE", help="override a model parameter (repeatable)")
    s.add_argument("--criterion", choices=CriterionChoices(),
                   help="criterion to apply (default: the file's, or the model's, or auto)")
    s.add_argument("--json", action="store_true", help="print one JSON object")
    s.add_argument("--rtol", type=float, metavar="R",
                   help="relative tolerance on the coefficients: marginal = the verdict can flip within it "
                        "(default 0: the exact verdict for the given coefficients)")
    s.add_argument("-v", "--verbose", action="store_true", help="list every condition")
    s.add_argument("--list-models", action="store_true", help="list the built-in models and exit")
    s.set_defaults(func=_cmd_stability)

    d = add("design", help="largest virtual-coupler stiffness k22 of the SDEA (002 Table II)")
    d.add_argument("--criterion", choices=["passivity", "absolute_stability"], default="passivity")
    d.add_argument("--alpha", type=float, help="feed-forward ratio alpha in [0, 1] (default 1)")
    d.add_argument("--optimize-alpha", action="store_true", help="also maximize over alpha")
    d.add_argument("--b22", type=float, help="fix the coupler damping instead of optimizing it")
    d.add_argument("--set", action="append", metavar="PARAM=VALUE", help="override an SDEA parameter")
    d.add_argument("--json", action="store_true")
    d.set_defaults(func=_cmd_design)

    sw = add("sweep", help="stability map of a built-in model over 1-3 parameters, boundary refined "
                           "by bisection (see README, Stability maps)")
    sw.add_argument("--model", help="built-in model (hil stability --list-models)")
    sw.add_argument("--scene", help="sweep the network a scene certifies (its model, gains and plant)")
    sw.add_argument("--grid", action="append", required=True, metavar="NAME=LO:HI:N",
                    help="swept parameter (repeatable, 1-3; NAME=log:LO:HI:N for log spacing)")
    sw.add_argument("--set", action="append", metavar="PARAM=VALUE", help="fix a model parameter (repeatable)")
    sw.add_argument("--criterion", choices=CriterionChoices(auto=False),
                    help="criterion (default: the model's)")
    sw.add_argument("--no-refine", action="store_true", help="grid only: no bisection of the boundary")
    sw.add_argument("--boundary-tol", type=float, default=1e-4,
                    help="bisect each crossing to this fraction of the grid step (default 1e-4)")
    sw.add_argument("--posterior", metavar="RECORD[:NAME]",
                    help="also P(stable) per point over a stored identification's posterior draws")
    sw.add_argument("--draws", type=int, default=200, help="posterior draws per point (default 200)")
    sw.add_argument("--required", type=float, help="draw the P(stable) contour at this probability")
    sw.add_argument("--executor", choices=["process", "serial", "dask"], default="process",
                    help="where tasks run (default: a local process pool)")
    sw.add_argument("--workers", type=int, help="processes (default: all cores)")
    sw.add_argument("--scheduler", metavar="ADDR", help="Dask scheduler address (tcp://host:8786; extra 'dask')")
    sw.add_argument("--chunk", type=int, default=64, help="grid points per task (default 64)")
    sw.add_argument("--cache", metavar="DIR", help="task cache (default .hil-cache/sweep): a rerun resumes")
    sw.add_argument("--no-cache", action="store_true", help="neither read nor write the task cache")
    sw.add_argument("--out", help="output folder (default reports/sweep-<model>-<UTC time>-<id>)")
    sw.add_argument("--overwrite", action="store_true", help="write into an existing non-empty --out")
    sw.add_argument("--no-plot", action="store_true", help="no sweep.png")
    sw.add_argument("--json", action="store_true", help="print one JSON object")
    sw.set_defaults(func=_cmd_sweep)

    sc = add("scenes", help="list the built-in scenes")
    sc.add_argument("--json", action="store_true")
    sc.set_defaults(func=_cmd_scenes)

    r = add("run", help="run a scene's experiments (chirp, energy injection, static hold) and record them")
    r.add_argument("scene", help="scene YAML file or built-in scene name (see hil scenes)")
    r.add_argument("--out", help="output folder for the records (default runs/<scene>-<UTC time>-<id>); "
                   "an existing non-empty folder is refused unless --overwrite")
    r.add_argument("--overwrite", action="store_true", help="write into an existing --out folder, replacing "
                   "records of the same name")
    r.add_argument("--seed", type=int, help="override the scene's seed")
    r.add_argument("--experiment", action="append", help="run only this experiment (index or type; repeatable)")
    mode = r.add_mutually_exclusive_group()
    mode.add_argument("--realtime", action="store_true", help="fixed-rate loop on the wall clock")
    mode.add_argument("--lockstep", action="store_true",
                      help="as fast as possible; the plant advances one period per tick")
    r.add_argument("--json", action="store_true", help="print one JSON object")
    r.set_defaults(func=_cmd_run)

    pl = add("plan", help="predict the posterior sd of each identification experiment (Cramér-Rao bound of the "
                          "planned excitation) and its safety; --precision proposes amplitude, band, duration")
    pl.add_argument("scene", help="scene YAML file or built-in scene name (needs its simulation section)")
    pl.add_argument("--experiment", action="append", help="plan only this experiment (name; repeatable)")
    pl.add_argument("--precision", action="append", metavar="PARAM=REL",
                    help="requested relative sd of a parameter, e.g. B_f=0.001 (repeatable)")
    pl.add_argument("--json", action="store_true", help="print one JSON object")
    pl.set_defaults(func=_cmd_plan)

    ce = add("certify", help="experiments -> identification -> criteria over the posterior -> "
                                         "GO / MARGINAL / NO-GO report (default: the mocked SDEA bench)")
    ce.add_argument("scene", nargs="*", help="scene file, built-in name or folder of scenes (default "
                    "sdea_bench); several: a fleet certified in parallel (see README, Fleet certification)")
    ce.add_argument("--workers", type=int, help="fleet: parallel scenes (default: all cores)")
    ce.add_argument("--scheduler", metavar="ADDR", help="fleet: run on a Dask scheduler (tcp://host:8786; "
                    "extra 'dask')")
    ce.add_argument("--out", help="output folder (default reports/<scene>-<UTC time>-<id>); an existing "
                    "non-empty folder is refused unless --overwrite")
    ce.add_argument("--overwrite", action="store_true", help="write into an existing --out folder, replacing "
                    "files of the same name")
    ce.add_argument("--seed", type=int)
    ce.add_argument("--no-experiments", action="store_true", help="skip the runs (certify from the scene's priors)")
    ce.add_argument("--sign", metavar="KEY", help="sign the certificate's digest with this Ed25519 private key "
                                                  "(PEM, see hil keygen; needs the 'sign' extra)")
    ce.add_argument("--signer", metavar="NAME", help="who signs (recorded and signed with --sign)")
    ce.add_argument("--json", action="store_true")
    ce.set_defaults(func=_cmd_certify)

    rep = add("report", help="rebuild the HTML and PDF reports from a stored certificate.json")
    rep.add_argument("path", help="certificate.json or the folder holding it")
    rep.add_argument("--out", help="output folder (default: next to the certificate); another existing non-empty "
                     "folder is refused unless --overwrite")
    rep.add_argument("--overwrite", action="store_true", help="write report.html / report.pdf into a non-empty --out")
    rep.add_argument("--public-key", metavar="PUB", help="check the signature with this Ed25519 public key (PEM)")
    rep.add_argument("--allow-modified", action="store_true",
                     help="render a certificate that does not match its digest, marked on every page "
                          "'MODIFIED: NOT A VALID CERTIFICATE'")
    rep.set_defaults(func=_cmd_report)

    ve = add("verify", help="check a certificate's digest, the SHA-256 of its records and scene, "
                            "and (with --public-key) its signature; exit 0 or 2")
    ve.add_argument("path", metavar="DIR", help="the certificate folder (or its certificate.json)")
    ve.add_argument("--public-key", metavar="PUB", help="Ed25519 public key (PEM) the signature must verify with")
    ve.set_defaults(func=_cmd_verify)

    kg = add("keygen", help="write a new Ed25519 signing key pair (private 0600, public) into a folder")
    kg.add_argument("--out", required=True, metavar="DIR", help="folder for the key files (never overwritten)")
    kg.set_defaults(func=_cmd_keygen)

    rp = add("replay", help="inspect a run record (summary of channels, timing, stop reason)")
    rp.add_argument("record")
    rp.add_argument("--json", action="store_true")
    rp.set_defaults(func=_cmd_replay)

    cr = add("check-realtime", help="the machine's wake-up latency (cyclictest's way) and the loop rates it holds")
    cr.add_argument("--rate", type=number_type("positive"), default=2000.0, help="loop rate to check [Hz]")
    cr.add_argument("--seconds", type=number_type("positive"), default=5.0, help="seconds per measurement")
    cr.add_argument("--no-rt", action="store_true", help="without SCHED_FIFO / mlockall / CPU affinity")
    cr.add_argument("--json", action="store_true")
    cr.set_defaults(func=_cmd_check_realtime)

    im = add("import", help="convert a CSV or MATLAB .mat run into a run record (HDF5)")
    im.add_argument("file", help="CSV (header row) or .mat file")
    im.add_argument("--out", help="record path (default: FILE with .h5)")
    im.add_argument("--time", help="time column / variable (s); default t or time")
    im.add_argument("--map", action="append", metavar="CHANNEL=COL[,COL...]",
                    help="channel from one column or a vector from several (repeatable)")
    im.add_argument("--sidecar", help="YAML/JSON mapping file (default: found next to the CSV)")
    im.add_argument("--overwrite", action="store_true", help="replace an existing record at --out")
    im.set_defaults(func=_cmd_import)

    i = add("identify", help="identify a grey-box model (M, B, K_f, B_f, ...) from a chirp record",
                       add_help=False, parents=[])
    i.add_argument("rest", nargs=argparse.REMAINDER)

    pb = add("probe", help="list what answers on a CAN channel, serial port or Modbus address "
                           "(--scene writes a scene stub)")
    if command in (None, "probe"):  # lazy: start-up time of the other commands (see the imports above)
        from hil.bench.probe import add_arguments as _probe_arguments

        _probe_arguments(pb)
    pb.set_defaults(func=_cmd_probe)

    m = add("mock", help="simulated devices: 'hil mock serve SPEC' starts them and prints endpoints")
    msub = m.add_subparsers(dest="mock_cmd", metavar="serve", parser_class=OneLineArgumentParser, required=True)
    ms = msub.add_parser("serve", parents=[common], help="start simulated devices and print their endpoints",
                         description="Start a scene's simulated devices (or a spec's, or one --device) on their "
                                     "own and print where each one listens (hil.bench.serve).")
    _mock_serve_arguments(ms)
    ms.set_defaults(func=_cmd_mock_serve)
    return p


def _cmd_probe(args: argparse.Namespace) -> int:
    from hil.bench.probe import run as _probe_run  # lazy: start-up time of the other commands

    return _probe_run(args)


def _mock_serve_arguments(ap: argparse.ArgumentParser) -> None:
    """The options of ``hil mock serve`` (checked together by :func:`hil.bench.serve.run`)."""
    ap.add_argument("scene", nargs="?", help="scene file or built-in scene name (see 'hil scenes')")
    ap.add_argument("--spec", help="instead of a scene: JSON string or .json/.yaml file (see hil.bench.serve)")
    ap.add_argument("--duration", type=number_type("non-negative"), default=None,
                    help="seconds to run (default: until Ctrl-C/SIGTERM)")
    ap.add_argument("--json", action="store_true", help="print the endpoints as one JSON line")
    ap.add_argument("--seed", type=seed_type, default=None,
                    help="scene: seed of noise and faults (default: the scene's)")
    ap.add_argument("--variant", choices=["locked", "free"], default=None, help="scene: SDEA plant variant")
    ap.add_argument("--can-interface", default="virtual",
                    help="scene: python-can interface of the CAN devices (virtual | udp_multicast | socketcan ...)")
    ap.add_argument("--can-channel", action="append", default=[], metavar="SCENE_CH=CH",
                    help="scene: serve scene CAN channel SCENE_CH on channel CH (repeatable)")
    ap.add_argument("--stream-rate", type=number_type("positive"), default=100.0,
                    help="scene: frame rate of streaming FT-300 sensors [Hz] (the sensor's is 100)")
    ap.add_argument("--plant-rate", type=number_type("positive"), default=1000.0,
                    help="spec: FreeJoints step rate [Hz]")
    ap.add_argument("--device", default=None, metavar="KIND",
                    help="serve ONE simulated device of this kind (instead of a scene or --spec): odrive, "
                         "cubemars, cia402, bota, dynamixel, ft300, ft300_stream")
    ap.add_argument("--node", type=int, default=None,
                    help="device: CAN node id (odrive 0..63, cia402 1..127) or CubeMars motor id")
    ap.add_argument("--ids", default=None, help="device dynamixel: comma-separated servo ids (default 1)")
    ap.add_argument("--unit", type=int, default=None, help="device ft300 / ft300_stream: Modbus slave id (default 9)")
    ap.add_argument("--port", type=int, default=None, help="device ft300: TCP port on 127.0.0.1 (default: a free one)")
    ap.add_argument("--pty", action="store_true",
                    help="device bota / ft300_stream / dynamixel: serve on a pty (the default and only transport)")
    ap.add_argument("--rate", type=number_type("positive"), default=None,
                    help="device: tick / frame rate [Hz] (CAN cyclic frames, Bota frames; default 1000, "
                         "FT-300 stream 100)")


def _cmd_mock_serve(args: argparse.Namespace) -> int:
    from hil.bench.serve import run

    return run(args)


_PASSTHROUGH = {"identify": "hil.cli.identify"}  # identify owns its parser (hil.cli.identify.main)

# ---------------------------------------------------------------------------------------------
# output folders, progress, numeric guard, error mapping

#: output folders this process created (removed again when the command fails before writing a file)
_CREATED: list[Path] = []


def _out_dir(path: str | None, default_stem: str, overwrite: bool) -> Path:
    """:func:`hil.record.outdir.prepare_out_dir`, remembering a folder it created for clean-up on failure."""
    from hil.record.outdir import prepare_out_dir

    existed = path is not None and Path(path).exists()
    out = prepare_out_dir(path, default_stem=default_stem, overwrite=overwrite)
    if not existed:
        _CREATED.append(out)
    return out


def _cleanup_created() -> None:
    from hil.record.outdir import remove_if_empty

    while _CREATED:
        remove_if_empty(_CREATED.pop())


def _progress_interval() -> float:
    try:
        return max(0.05, float(os.environ.get("HIL_PROGRESS_SECONDS", "5")))
    except ValueError:
        return 5.0


class _Progress:
    """Progress of a long step on stderr. On a TTY a rich spinner with the latest message; otherwise
    a plain line ``<label>: <elapsed> s: <message>`` every ``HIL_PROGRESS_SECONDS`` (default 5) s,
    the first one only after that interval (a short step prints nothing)."""

    def __init__(self, label: str, enabled: bool = True, interval: float | None = None) -> None:
        self.label = label
        self.enabled = enabled
        self.interval = _progress_interval() if interval is None else interval
        self.message = "working"
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._status: Any = None
        self._t0 = time.monotonic()

    def update(self, message: str) -> None:
        self.message = message
        if self._status is not None:
            self._status.update(f"{self.label}: {message}")

    def _loop(self) -> None:
        while not self._stop.wait(self.interval):
            print(f"{self.label}: {time.monotonic() - self._t0:.0f} s: {self.message}", file=sys.stderr, flush=True)

    def __enter__(self) -> _Progress:
        self._t0 = time.monotonic()
        if not self.enabled:
            return self
        if sys.stderr.isatty():
            from rich.console import Console

            self._status = Console(stderr=True).status(f"{self.label}: {self.message}")
            self._status.__enter__()
        else:
            self._thread = threading.Thread(target=self._loop, name="hil-progress", daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if self._status is not None:
            self._status.__exit__(*exc)


@contextlib.contextmanager
def _numeric_guard(source: str) -> Iterator[None]:
    """Turn float overflow in the criteria (coefficients spanning too wide a range) into one
    :class:`UsageError` naming ``source`` instead of a RuntimeWarning or a traceback."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RuntimeWarning)
        try:
            yield
        except (FloatingPointError, OverflowError) as exc:
            raise UsageError(f"{source}: the arithmetic leaves float range ({one_line(exc)}): the coefficients "
                             "span too wide a range; rescale the units") from None
    bad = [w for w in caught if issubclass(w.category, RuntimeWarning)
           and any(k in str(w.message) for k in ("overflow", "invalid value"))]
    for w in caught:
        if w not in bad:
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    if bad:
        raise UsageError(f"{source}: the arithmetic leaves float range ({bad[0].message}): the result would not be "
                         "finite; rescale the units")


def _describe(exc: BaseException, cmd: str) -> tuple[int, str]:
    """(exit code, one-line message) for an exception that ended a command."""
    if isinstance(exc, SafetyStop):  # e.g. a signal during the runs of hil certify: 130 / 20
        status = getattr(exc, "status", "safety_stop")
        return (EXIT_INTERRUPTED if status == "interrupted" else EXIT_SAFETY_STOP), f"stopped: {one_line(exc)}"
    if isinstance(exc, HilError):
        return EXIT_USAGE, one_line(exc)
    if isinstance(exc, UnicodeDecodeError):
        return EXIT_USAGE, f"an input is not UTF-8 text ({exc.reason} at byte {exc.start})"
    if isinstance(exc, OSError):
        what = exc.strerror or one_line(exc) or type(exc).__name__
        if exc.filename is not None:
            two = f" -> {exc.filename2}" if exc.filename2 is not None else ""
            return EXIT_USAGE, f"{exc.filename}{two}: {what}"
        return EXIT_USAGE, one_line(exc) or type(exc).__name__
    if isinstance(exc, ValueError):  # bad values (pydantic ValidationError too)
        return EXIT_USAGE, one_line(exc) or type(exc).__name__
    return EXIT_INTERNAL, (f"internal error: {type(exc).__name__}: {one_line(exc)} (a bug: rerun as "
                           f"'hil --debug {cmd} ...' for the traceback and report it)")


def _guarded(cmd: str, debug: bool, fn: Callable[[], Any]) -> int:
    """Run one command; map every exception to its exit code and one stderr line (module docstring)."""
    failed = True
    try:
        code = int(fn() or 0)
        failed = False
        return code
    except SystemExit as exc:  # argparse: --help (0) or a one-line usage error (2)
        failed = exc.code not in (0, None)
        return exc.code if isinstance(exc.code, int) else (EXIT_USAGE if exc.code else EXIT_OK)
    except KeyboardInterrupt:
        print(f"hil {cmd}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # e.g. `hil stability ... --json | head`
        with contextlib.suppress(OSError):
            sys.stdout = open(os.devnull, "w")  # noqa: SIM115 (the interpreter's final flush must not fail)
        failed = False
        return EXIT_OK
    except Exception as exc:
        code, msg = _describe(exc, cmd)
        if debug:
            traceback.print_exc()
        print(f"hil {cmd}: error: {msg}", file=sys.stderr)
        return code
    finally:
        if failed:
            _cleanup_created()
        _CREATED.clear()


class _SweepProgress(_Progress):
    """Points done and time left: a rich bar on a TTY, otherwise a line every few seconds."""

    def __init__(self, label: str, enabled: bool = True) -> None:
        super().__init__(label, enabled=enabled and not sys.stderr.isatty())
        self._tty = enabled and sys.stderr.isatty()
        self._bar: Any = None
        self._task: Any = None
        self._t_phase = time.monotonic()
        self._last_total = -1
        self._n_phase = 0

    def update(self, done: int, total: int) -> None:  # type: ignore[override]
        if total != self._last_total:
            self._t_phase, self._last_total = time.monotonic(), total
            self._n_phase += 1
        el = time.monotonic() - self._t_phase
        left = (el / done * (total - done)) if done else float("nan")
        phase = "grid points" if self._n_phase <= 1 else "boundary segments"
        self.message = f"{done}/{total} {phase}, about {left:.0f} s left"
        if self._tty:
            if self._bar is None:
                from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeRemainingColumn

                self._bar = Progress("[progress.description]{task.description}", BarColumn(), MofNCompleteColumn(),
                                     TimeRemainingColumn(), transient=True)
                self._bar.start()
            if self._task is None or self._bar.tasks[-1].total != total:
                self._task = self._bar.add_task(f"{self.label} ({phase})", total=total)
            self._bar.update(self._task, completed=done)

    def __exit__(self, *exc: Any) -> None:
        if self._bar is not None:
            self._bar.stop()
        super().__exit__(*exc)


def _split_globals(argv: list[str]) -> tuple[bool, list[str]]:
    """Leading global options (``--debug``) and the rest."""
    debug = False
    while argv and argv[0] == "--debug":
        debug = True
        argv = argv[1:]
    return debug, argv


def main(argv: Sequence[str] | None = None) -> int:
    """The ``hil`` command (exit codes: module docstring)."""
    debug, argv = _split_globals(list(sys.argv[1:] if argv is None else argv))
    if argv and argv[0] in _PASSTHROUGH:  # these subcommands own their argument parsing (and --help)
        cmd, rest = argv[0], argv[1:]
        if "--debug" in rest[: rest.index("--") if "--" in rest else len(rest)]:
            debug = True
            rest = [a for a in rest if a != "--debug"]
        _logging(debug)

        def passthrough() -> int:
            return int(importlib.import_module(_PASSTHROUGH[argv[0]]).main(rest) or 0)

        return _guarded(cmd, debug, passthrough)
    parser = build_parser(argv[0] if argv and not argv[0].startswith("-") else None)
    try:
        args, extra = parser.parse_known_args(argv)
        if extra:  # named by the subcommand's parser: "hil report: error: unrecognized arguments: ..."
            _command_parser(parser, args).error(f"unrecognized arguments: {' '.join(extra)}")
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    debug = debug or bool(getattr(args, "debug", False))
    _logging(debug)
    if not getattr(args, "func", None):
        parser.print_help(sys.stderr)
        return EXIT_USAGE
    cmd = " ".join(x for x in (args.cmd, getattr(args, "mock_cmd", None)) if x)
    return _guarded(cmd, debug, lambda: args.func(args))


def _command_parser(parser: argparse.ArgumentParser, args: argparse.Namespace) -> argparse.ArgumentParser:
    """The (sub)parser of the command ``args`` were parsed for (``hil mock serve``: the nested one)."""
    for dest in ("cmd", "mock_cmd"):
        name = getattr(args, dest, None)
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if name is None or not subs:
            break
        parser = subs[0].choices[name]
    return parser


def _logging(debug: bool) -> None:
    """Warnings of every library; with ``--debug`` also the suite's own debug logs."""
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("hil").setLevel(logging.DEBUG if debug else logging.NOTSET)  # NOTSET: the root's WARNING


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
