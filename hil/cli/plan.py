"""``hil plan``: predict the posterior sd of each identification experiment (Cramér-Rao bound of the
planned excitation) and its safety; --precision proposes amplitude, band, duration."""

from __future__ import annotations

import argparse
import json

from hil.cli.common import console, parse_set
from hil.errors import EXIT_OK


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", help="scene YAML file or built-in scene name (needs its simulation section)")
    p.add_argument("--experiment", action="append", help="plan only this experiment (name; repeatable)")
    p.add_argument("--precision", action="append", metavar="PARAM=REL",
                   help="requested relative sd of a parameter, e.g. B_f=0.001 (repeatable)")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def run(args: argparse.Namespace) -> int:
    """``hil plan SCENE``: predicted posterior sd and safety of the identification experiments (hil.run.plan)."""
    from hil.run.plan import plan_scene
    from hil.scene.spec import load_scene

    scene = load_scene(args.scene)
    precision = parse_set(args.precision or [], None, flag="--precision")
    preds = plan_scene(scene, experiments=args.experiment, precision=precision)
    if args.json:
        print(json.dumps({"scene": scene.name, "experiments": [p.to_dict() for p in preds]}, indent=2, default=str))
        return EXIT_OK
    from rich.markup import escape
    from rich.table import Table

    con = console()
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
