"""``hil sweep``: stability map of a built-in model over 1-3 parameters, boundary refined by
bisection (docs/guide/certification.md, Stability maps)."""

from __future__ import annotations

import argparse
import json
from collections import Counter

from hil.cli.common import SweepProgress, UsageError, out_dir, parse_set, suggest
from hil.errors import EXIT_OK
from hil.stability.criteria import CriterionChoices  # the criterion names, from their registry


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", help="built-in model (hil stability --list-models)")
    p.add_argument("--scene", help="sweep the network a scene certifies (its model, gains and plant)")
    p.add_argument("--grid", action="append", required=True, metavar="NAME=LO:HI:N",
                   help="swept parameter (repeatable, 1-3; NAME=log:LO:HI:N for log spacing)")
    p.add_argument("--set", action="append", metavar="PARAM=VALUE", help="fix a model parameter (repeatable)")
    p.add_argument("--criterion", choices=CriterionChoices(auto=False),
                   help="criterion (default: the model's)")
    p.add_argument("--no-refine", action="store_true", help="grid only: no bisection of the boundary")
    p.add_argument("--boundary-tol", type=float, default=1e-4,
                   help="bisect each crossing to this fraction of the grid step (default 1e-4)")
    p.add_argument("--posterior", metavar="RECORD[:NAME]",
                   help="also P(stable) per point over a stored identification's posterior draws")
    p.add_argument("--draws", type=int, default=200, help="posterior draws per point (default 200)")
    p.add_argument("--required", type=float, help="draw the P(stable) contour at this probability")
    p.add_argument("--executor", choices=["process", "serial", "dask"], default="process",
                   help="where tasks run (default: a local process pool)")
    p.add_argument("--workers", type=int, help="processes (default: all cores)")
    p.add_argument("--scheduler", metavar="ADDR", help="Dask scheduler address (tcp://host:8786; extra 'dask')")
    p.add_argument("--chunk", type=int, default=64, help="grid points per task (default 64)")
    p.add_argument("--cache", metavar="DIR", help="task cache (default .hil-cache/sweep): a rerun resumes")
    p.add_argument("--no-cache", action="store_true", help="neither read nor write the task cache")
    p.add_argument("--out", help="output folder (default reports/sweep-<model>-<UTC time>-<id>)")
    p.add_argument("--overwrite", action="store_true", help="write into an existing non-empty --out")
    p.add_argument("--no-plot", action="store_true", help="no sweep.png")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def run(args: argparse.Namespace) -> int:
    from hil.bench.stopflag import STOP, StopRequested
    from hil.certify.sweep import (
        ExecutorLost,
        SweepError,
        SweepSpec,
        iter_table,
        make_executor,
        parse_grid,
        plot_sweep,
        run_sweep,
        save_sweep,
    )
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
        raise UsageError(f"--model {args.model}: unknown model{suggest(args.model, model_names())}; "
                         f"known: {', '.join(model_names())}") from None
    axes = [parse_grid(g) for g in args.grid]
    params = parse_set(args.set or [], m.defaults, f"model {m.name}")
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
    out = out_dir(args.out, f"reports/sweep-{scene.name if scene is not None else args.model}", args.overwrite)
    ex = make_executor(executor, args.workers, args.scheduler)
    bar = SweepProgress(f"hil sweep {args.model}", enabled=not args.json)
    try:
        with STOP.install(), bar:
            res = run_sweep(spec, ex, cache, progress=bar.update, should_stop=STOP.check)
    except ExecutorLost as exc:  # the scheduler or every worker is gone: the finished tasks are cached
        raise SweepError(f"{exc}; the finished tasks are cached in {cache}: rerun with --cache {cache} to resume"
                         if cache else f"{exc} (--no-cache: nothing kept; give --cache DIR to resume next time)"
                         ) from None
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
