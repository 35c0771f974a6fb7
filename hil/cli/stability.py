"""``hil stability``: check passivity / absolute stability of a network (file or built-in model)."""

from __future__ import annotations

import argparse
import json
import math
from typing import Any

from hil.cli.common import StepProgress, UsageError, console, numeric_guard, one_line, parse_set, suggest
from hil.errors import EXIT_OK, VERDICT_EXIT, HilError
from hil.stability.criteria import CriterionChoices  # the criterion names, from their registry


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", nargs="?", help="network file (YAML or JSON): type, ports, matrix of {num, den}")
    p.add_argument("--model", help="built-in model name (see --list-models)")
    p.add_argument("--set", action="append", metavar="PARAM=VALUE", help="override a model parameter (repeatable)")
    # metavar: argparse would list the choices when the option is added, which reads the criteria's
    # entry points (importlib.metadata: ~17 ms of start-up); %(choices)s lists them in --help only
    p.add_argument("--criterion", choices=CriterionChoices(), metavar="NAME",
                   help="criterion to apply: %(choices)s (default: the file's, or the model's, or auto)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--rtol", type=float, metavar="R",
                   help="relative tolerance on the coefficients: marginal = the verdict can flip within it "
                        "(default 0: the exact verdict for the given coefficients)")
    p.add_argument("-v", "--verbose", action="store_true", help="list every condition")
    p.add_argument("--list-models", action="store_true", help="list the built-in models and exit")


def run(args: argparse.Namespace) -> int:
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
        with StepProgress(f"hil stability {source}") as prog, numeric_guard(source):
            prog.update("reading the network file")
            tm, crit = load_network(args.file)
        criterion = args.criterion or crit
    else:
        from hil.models import get_model, model_names

        try:
            m = get_model(args.model)
        except KeyError:
            raise UsageError(f"--model {args.model}: unknown model{suggest(args.model, model_names())}; "
                             f"known: {', '.join(model_names())}") from None
        params = parse_set(args.set or [], m.defaults, f"model {m.name}")
        source = f"--model {m.name}"
        try:
            m.check_params(params)
        except HilError as exc:
            raise UsageError(f"--set: {one_line(exc)}") from None
        try:
            with numeric_guard(source):
                tm = m.build(**params)
        except TypeError as exc:
            raise UsageError(f"{source}: bad parameter: {exc}") from None
        except HilError as exc:
            raise UsageError(f"{source}: {one_line(exc)}") from None
        criterion = args.criterion or m.criterion
    with StepProgress(f"hil stability {source}") as prog:
        prog.update(f"checking the {criterion} conditions")
        try:
            with numeric_guard(source):
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

def _print_result(result: Any, verbose: bool) -> None:
    from rich.table import Table

    con = console()
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
