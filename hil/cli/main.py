"""The ``hil`` command line: the command table, the parser, and the one place errors become exit codes.

One module per command (``hil/cli/<command>.py``: ``add_arguments(parser)`` and ``run(args)``;
:data:`COMMANDS` names it with its one-line help, so ``hil --help`` imports none of them and a
command imports only its own); what they share is in :mod:`hil.cli.common`.

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

Exit codes: one table, :class:`hil.errors.ExitCode` with :data:`hil.errors.EXIT_MEANINGS` (docs/guide/troubleshooting.md
shows it; tests/cli/test_exit_codes.py compares the two).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import os
import sys
import traceback
from collections.abc import Callable, Sequence
from typing import Any

from hil import __version__
from hil.cli.common import CREATED, OneLineArgumentParser, UsageError, cleanup_created, debug_parent, one_line
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

__all__ = ["COMMANDS", "DECISION_EXIT", "EXIT_ERROR", "EXIT_INTERNAL", "EXIT_INTERRUPTED", "EXIT_MARGINAL",
           "EXIT_NOT_APPLICABLE", "EXIT_NOT_HELD", "EXIT_OK", "EXIT_SAFETY_STOP", "EXIT_UNSTABLE", "EXIT_USAGE",
           "PASSTHROUGH", "VERDICT_EXIT", "OneLineArgumentParser", "UsageError", "build_parser", "main", "one_line"]

logger = logging.getLogger(__name__)

#: command -> (its module, one-line help). The module has ``add_arguments(parser)`` and
#: ``run(args) -> exit code``; a command in :data:`PASSTHROUGH` has ``main(argv)`` instead.
COMMANDS: dict[str, tuple[str, str]] = {
    "stability": ("hil.cli.stability", 'check passivity / absolute stability of a network (file or built-in model)'),
    "design": ("hil.cli.design", 'largest virtual-coupler stiffness k22 of the SDEA (002 Table II)'),
    "sweep": ("hil.cli.sweep",
        "stability map of a built-in model over 1-3 parameters, boundary refined by bisection (see "
        "docs/guide/certification.md, Stability maps)"),
    "scenes": ("hil.cli.scenes", 'list the built-in scenes'),
    "run": ("hil.cli.run", "run a scene's experiments (chirp, energy injection, static hold) and record them"),
    "plan": ("hil.cli.plan",
        "predict the posterior sd of each identification experiment (Cramér-Rao bound of the planned excitation) and "
        "its safety; --precision proposes amplitude, band, duration"),
    "certify": ("hil.cli.certify",
        "experiments -> identification -> criteria over the posterior -> GO / MARGINAL / NO-GO report (default: the "
        "mocked SDEA bench)"),
    "report": ("hil.cli.report", 'rebuild the HTML and PDF reports from a stored certificate.json'),
    "verify": ("hil.cli.verify",
        "check a certificate's digest, the SHA-256 of its records and scene, and (with --public-key) its signature; "
        "exit 0 or 2"),
    "keygen": ("hil.cli.keygen", 'write a new Ed25519 signing key pair (private 0600, public) into a folder'),
    "replay": ("hil.cli.replay", 'inspect a run record (summary of channels, timing, stop reason)'),
    "check-realtime": ("hil.cli.check_realtime",
        "the machine's wake-up latency (cyclictest's way) and the loop rates it holds"),
    "import": ("hil.cli.import_record",
               "convert a run from another tool (CSV, .mat, HDF5, TDMS, ROS bag, MCAP) into a run record"),
    "export": ("hil.cli.export", "write a run record as MCAP (Foxglove, PlotJuggler) or CSV (spreadsheets)"),
    "identify": ("hil.cli.identify", 'identify a grey-box model (M, B, K_f, B_f, ...) from a chirp record'),
    "probe": ("hil.cli.probe",
        "list what answers on a CAN channel, serial port or Modbus address (--scene writes a scene stub)"),
    "mock": ("hil.cli.mock", "simulated devices: 'hil mock serve SPEC' starts them and prints endpoints"),
}

#: commands that parse their own arguments (and --help): ``main(argv)`` of their module
PASSTHROUGH = frozenset({"identify"})


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser of ``hil``. With ``command`` (the subcommand about to run, as :func:`main` passes
    it) only that subcommand's module is imported and adds its arguments; the others are listed by
    name and help, which is all ``hil --help`` and the "invalid choice" error show (start-up time,
    issue 15: adding every command's arguments, and importing what they need, is work a single
    command never uses). ``command=None`` builds the whole parser (tests compare the two)."""
    p = OneLineArgumentParser(
        prog="hil", description="Hardware-in-the-loop identification and stability certification of haptic "
        "devices, teleoperators and series elastic actuators.",
        epilog="Global options go before the COMMAND: hil --debug COMMAND ... Exit codes: "
               "docs/guide/troubleshooting.md.")
    p.add_argument("--debug", action="store_true", help="show tracebacks and debug logs (before the COMMAND)")
    p.add_argument("--version", action="version", version=f"hil-certify {__version__}",
                   help="print the version and exit")
    common = debug_parent()
    sub = p.add_subparsers(dest="cmd", metavar="COMMAND", parser_class=OneLineArgumentParser)
    for name, (module, help_text) in COMMANDS.items():
        if command is not None and name != command:  # not the command that runs: listed, never parsed
            sub.add_parser(name, help=help_text, add_help=False)
            continue
        if name in PASSTHROUGH:  # parses its own arguments: everything after the name goes to it
            sp = sub.add_parser(name, help=help_text, add_help=False)
            sp.add_argument("rest", nargs=argparse.REMAINDER)
            continue
        sp = sub.add_parser(name, help=help_text, parents=[common])
        mod = importlib.import_module(module)
        mod.add_arguments(sp)
        sp.set_defaults(func=mod.run)
    return p


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
            cleanup_created()
        CREATED.clear()


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
    if argv and argv[0] in PASSTHROUGH:  # these subcommands own their argument parsing (and --help)
        cmd, rest = argv[0], argv[1:]
        if "--debug" in rest[: rest.index("--") if "--" in rest else len(rest)]:
            debug = True
            rest = [a for a in rest if a != "--debug"]
        _logging(debug)

        def passthrough() -> int:
            return int(importlib.import_module(COMMANDS[argv[0]][0]).main(rest) or 0)

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
