"""``hil design``: largest virtual-coupler stiffness k22 of the SDEA (002 Table II)."""

from __future__ import annotations

import argparse
import json
import math

from hil.cli.common import StepProgress, UsageError, one_line, parse_set
from hil.errors import EXIT_OK, HilError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--criterion", choices=["passivity", "absolute_stability"], default="passivity",
                   help="the condition the coupler must meet: two-port passivity (default) or Llewellyn's "
                        "absolute stability")
    p.add_argument("--alpha", type=float, help="feed-forward ratio alpha in [0, 1] (default 1)")
    p.add_argument("--optimize-alpha", action="store_true", help="also maximize over alpha")
    p.add_argument("--b22", type=float, help="fix the coupler damping instead of optimizing it")
    p.add_argument("--set", action="append", metavar="PARAM=VALUE", help="override an SDEA parameter")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")


def run(args: argparse.Namespace) -> int:
    from hil.models.design import DESIGN_FIXED, check_design_inputs, k22_max, optimize_coupler
    from hil.models.sdea import SDEA_TABLE1

    params = parse_set(args.set or [], {k: SDEA_TABLE1[k] for k in DESIGN_FIXED}, "the SDEA design")
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
    with StepProgress("hil design", enabled=True) as prog:
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
