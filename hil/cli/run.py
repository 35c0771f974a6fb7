"""``hil run``: run a scene's experiments (chirp, energy injection, static hold) and record them."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from typing import Any

from hil.cli.common import StepProgress, UsageError, bench_opening_said_once, cleanup_created, console, out_dir
from hil.errors import EXIT_INTERRUPTED, EXIT_OK, EXIT_SAFETY_STOP, EXIT_USAGE


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", help="scene YAML file or built-in scene name (see hil scenes)")
    p.add_argument("--out", help="output folder for the records (default runs/<scene>-<UTC time>-<id>); "
                   "an existing non-empty folder is refused unless --overwrite")
    p.add_argument("--overwrite", action="store_true", help="write into an existing --out folder, replacing "
                   "records of the same name")
    p.add_argument("--seed", type=int, help="override the scene's seed")
    p.add_argument("--experiment", action="append", metavar="NAME",
                   help="run only this experiment, by its name in the scene (repeatable; hil plan and the "
                        "certification name experiments the same way)")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--realtime", action="store_true", help="fixed-rate loop on the wall clock")
    mode.add_argument("--lockstep", action="store_true",
                      help="as fast as possible; the plant advances one period per tick")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--live", nargs="?", type=int, const=8765, metavar="PORT",
                   help="stream the channels, safety state and events over the Foxglove WebSocket protocol on "
                        "ws://127.0.0.1:PORT (default 8765) while the run goes on; needs the 'live' extra")


def run(args: argparse.Namespace) -> int:
    from hil.errors import BenchUnavailable
    from hil.protocols.registry import extras_message
    from hil.run.runner import Runner, bench_never_opened
    from hil.scene.spec import check_seed, load_scene

    scene = load_scene(args.scene)
    if not scene.experiments:
        raise UsageError(f"{args.scene}: the scene has no experiments: nothing to run")
    if args.seed is not None:
        scene.seed = check_seed(args.seed)
    if need := extras_message(scene):  # a base install: say which extra, before anything is on disk
        print(f"hil run {args.scene}: {need}", file=sys.stderr)
        return EXIT_USAGE
    select = None
    if args.experiment:
        select = select_experiments(scene, args.experiment)
    out = out_dir(args.out, f"runs/{scene.name}", args.overwrite)
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
    if prog is None:  # not a terminal: a plain line every few seconds (StepProgress)
        beat = StepProgress(f"hil run {scene.name}")

        def progress_cb(name: str, k: int, n: int) -> None:
            beat.message = f"{name}: {k}/{n} ticks ({100.0 * k / max(n, 1):.0f} %)"

    from hil.bench.stopflag import STOP

    live = _start_live(args.live, scene, realtime)
    runner = Runner(scene, out, realtime=realtime, progress=progress_cb, overwrite=args.overwrite, live=live)
    with STOP.install():  # signals stay stop requests until the results are printed
        try:
            with prog if prog is not None else beat, bench_opening_said_once():
                outcomes = runner.run(select)
        finally:
            if live is not None:
                live.close()
        if (why := bench_never_opened(outcomes, runner)) is not None:  # nothing ran, nothing recorded
            raise BenchUnavailable(f"{args.scene}: the bench could not be opened, no experiment ran: {why}")
        code = run_exit_code(outcomes, runner)
        _print_run(args, scene, out, outcomes, runner)
    if not any(o.record is not None for o in outcomes):
        cleanup_created()  # nothing recorded: the folder this command made is removed again (when empty)
    return code


def select_experiments(scene: Any, items: Sequence[str]) -> list[int]:
    """The indices of the experiments named in ``items``, by name (``experiments[].name``, default
    ``<type>`` or ``<type>_<variant>``, as the records and the certification name them); for scripts
    written before names, an index or a type is still accepted when no name matches."""
    names = [str(e["name"]) for e in scene.experiment_configs()]
    types = [str(getattr(e, "type", "")) for e in scene.experiments]
    out: list[int] = []
    for item in items:
        if item in names:
            out.append(names.index(item))
        elif item.isdigit() and int(item) < len(names):
            out.append(int(item))
        elif item in types:
            out += [i for i, t in enumerate(types) if t == item]
        else:
            raise UsageError(f"--experiment {item}: no experiment named {item!r} in scene {scene.name} "
                             f"(names: {', '.join(names) or 'none'})")
    return list(dict.fromkeys(out))


def _start_live(port: int | None, scene: Any, realtime: bool | None) -> Any:
    """The live view of ``hil run --live [PORT]`` (None without the flag); realtime runs host it in a
    separate process and offer it at most :data:`hil.run.live.REALTIME_RATE_HZ` samples per second."""
    if port is None:
        return None
    from hil.run.live import REALTIME_RATE_HZ, LiveError, LiveView

    if not 0 <= port <= 65535:
        raise UsageError(f"--live {port}: a TCP port is 0-65535")
    mode = getattr(scene, "mode", None) or ("lockstep" if getattr(scene, "simulation", None) else "realtime")
    rt = (mode == "realtime") if realtime is None else realtime
    try:
        live = LiveView(port, process=rt, max_rate_hz=REALTIME_RATE_HZ if rt else None).start()
    except LiveError as exc:
        raise UsageError(str(exc)) from None
    print(f"live view: ws://127.0.0.1:{live.port} (Foxglove: open connection, Foxglove WebSocket)", file=sys.stderr)
    return live


def run_exit_code(outcomes: Sequence[Any], runner: Any) -> int:
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
        from rich.table import Table

        con = console()
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
        written = [o.record for o in outcomes if o.record is not None]
        if not written:  # e.g. a stop while the first bench opened
            con.print("no record was written (the run stopped before its first sample)")
            return
        con.print(f"records in {out}:")  # paths outside the table: never split across lines
        for r in written:
            con.print(f"  {r}")

def _short(v: Any) -> str:
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, float | int) or hasattr(v, "dtype"):
        try:
            return f"{float(v):.4g}"
        except (TypeError, ValueError):
            pass
    return str(v)[:24]
