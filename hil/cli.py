"""The ``hil`` command line.

Subcommands import what they need when they run, so ``hil stability`` never imports device
libraries and ``hil mock serve`` never imports the stability core.

Exit codes (documented in README.md):

====  ==============================================================
0     stable (GO); ``hil verify``: the certificate and its evidence match
2     usage or input error (bad arguments, malformed file, unknown model): one-line message;
      ``hil verify`` / ``hil report``: the certificate does not match its digest, an evidence file
      or its signature (one line naming what)
10    marginal (MARGINAL)
11    potentially unstable (NO-GO)
12    criterion not applicable (e.g. Theorem 1's symmetrization fails)
13    evidence missing or broken (ERROR)
20    ``hil run``: an experiment ended in a safe stop (limit breach, watchdog, SIGTERM)
130   interrupted (Ctrl-C); the records keep every sample taken
1     unexpected internal error (a bug: please report it with the traceback from --debug)
====  ==============================================================
"""

from __future__ import annotations

import argparse
import difflib
import json
import logging
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hil.errors import HilError

EXIT_OK = 0
EXIT_INTERNAL = 1
EXIT_USAGE = 2
EXIT_MARGINAL = 10
EXIT_UNSTABLE = 11
EXIT_NOT_APPLICABLE = 12
EXIT_ERROR = 13
EXIT_SAFETY_STOP = 20
EXIT_INTERRUPTED = 130

VERDICT_EXIT = {"stable": EXIT_OK, "marginal": EXIT_MARGINAL, "potentially_unstable": EXIT_UNSTABLE,
                "not_applicable": EXIT_NOT_APPLICABLE}

log = logging.getLogger("hil")


class UsageError(HilError):
    """A command-line mistake; reported in one line with exit code 2."""


def _parse_set(items: Sequence[str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for it in items:
        if "=" not in it:
            raise UsageError(f"--set expects NAME=VALUE, got {it!r}")
        k, v = it.split("=", 1)
        k = k.strip()
        try:
            out[k] = float(v)
        except ValueError:
            out[k] = v.strip()
    return out


def _suggest(name: str, known: Sequence[str]) -> str:
    close = difflib.get_close_matches(name, known, n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


# ---------------------------------------------------------------------------------------------
# hil stability


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
        from hil.netfile import load_network

        if args.set:
            raise UsageError("--set applies to built-in models (--model), not to files")
        tm, crit = load_network(args.file)
        criterion = args.criterion or crit
    else:
        from hil.models import get_model, model_names

        try:
            m = get_model(args.model)
        except KeyError:
            raise UsageError(f"unknown model {args.model!r}{_suggest(args.model, model_names())}; "
                             f"known: {', '.join(model_names())}") from None
        params = _parse_set(args.set or [])
        for k in params:
            if k not in m.defaults:
                raise UsageError(f"model {m.name} has no parameter {k!r}{_suggest(k, list(m.defaults))}")
        try:
            tm = m.build(**params)
        except TypeError as exc:
            raise UsageError(f"bad parameter for {m.name}: {exc}") from None
        criterion = args.criterion or m.criterion
    result = check(tm, criterion)
    if args.json:
        print(json.dumps(result.to_dict(), indent=2, ensure_ascii=False))
    else:
        _print_result(result, args.verbose)
    return VERDICT_EXIT[str(result.verdict)]


def _print_result(result: Any, verbose: bool) -> None:
    from rich.console import Console
    from rich.table import Table

    con = Console()
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
    for col in ("condition", "status", "margin", "ω [rad/s]", "detail"):
        tab.add_column(col)
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
    from hil.stability.design import k22_max, optimize_coupler

    params = _parse_set(args.set or [])
    if args.b22 is not None:
        r = k22_max(args.b22, args.alpha if args.alpha is not None else 1.0, args.criterion, params)
    else:
        alpha = None if args.optimize_alpha else (args.alpha if args.alpha is not None else 1.0)
        r = optimize_coupler(args.criterion, alpha, params)
    if args.json:
        print(json.dumps(r.to_dict(), indent=2))
    else:
        print(f"{args.criterion}: k22_max = {r.k22_max:.6g} N.m/rad at b22 = {r.b22:.6g} N.m.s/rad, "
              f"alpha = {r.alpha:.4g} ({r.evaluations} exact verdicts)")
    return EXIT_OK


# ---------------------------------------------------------------------------------------------
# hil scenes / hil run / hil replay


def _cmd_scenes(args: argparse.Namespace) -> int:
    from hil.scene import builtin_scenes

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
    import datetime as dt

    from hil.runner import Runner
    from hil.scene import load_scene

    scene = load_scene(args.scene)
    if args.seed is not None:
        scene.seed = args.seed
    stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    out = args.out or f"runs/{scene.name}-{stamp}"
    select = None
    if args.experiment:
        select = []
        for item in args.experiment:
            try:
                select.append(int(item))
            except ValueError:
                idx = [i for i, e in enumerate(scene.experiments) if getattr(e, "type", None) == item]
                if not idx:
                    raise UsageError(f"no experiment {item!r} in scene {scene.name}") from None
                select += idx
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

    runner = Runner(scene, out, realtime=realtime, progress=progress_cb)
    if prog is not None:
        with prog:
            outcomes = runner.run(select)
    else:
        outcomes = runner.run(select)
    if args.json:
        print(json.dumps({"scene": scene.name, "out": str(out), "experiments": [o.to_dict() for o in outcomes]},
                         indent=2, default=str))
    else:
        from rich.console import Console
        from rich.table import Table

        tab = Table("experiment", "status", "stop reason", "record", "key results", title=f"hil run {scene.name}")
        for o in outcomes:
            scalars = [(k, v) for k, v in o.results.items() if not isinstance(v, dict | list)][:4]
            keys = ", ".join(f"{k}={_short(v)}" for k, v in scalars)
            tab.add_row(o.name, o.status, o.stop_reason if o.status != "completed" else "", str(o.record), keys)
        Console().print(tab)
    if any(o.status == "interrupted" for o in outcomes):
        return EXIT_INTERRUPTED
    if any(o.status in ("safety_stop", "error") for o in outcomes):
        return EXIT_SAFETY_STOP
    return EXIT_OK


def _short(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)[:24]


def _cmd_import(args: argparse.Namespace) -> int:
    from hil.importers import import_csv, import_mat

    src = Path(args.file)
    out = Path(args.out) if args.out else src.with_suffix(".h5")
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
            mapping[ch.strip()] = parts[0] if len(parts) == 1 else parts
    suffix = src.suffix.lower()
    if suffix == ".mat":
        if args.sidecar:
            raise UsageError("--sidecar applies to CSV files; for .mat give --map/--time or a sidecar next to the file")
        path = import_mat(src, out, mapping=mapping)
    elif suffix in (".csv", ".txt", ".tsv"):
        path = import_csv(src, out, mapping=mapping, sidecar=args.sidecar)
    else:
        raise UsageError(f"{src}: expected a .csv or .mat file")
    print(str(path))
    return EXIT_OK


DECISION_EXIT = {"GO": EXIT_OK, "MARGINAL": EXIT_MARGINAL, "NO-GO": EXIT_UNSTABLE, "ERROR": EXIT_ERROR}


def _cmd_certify(args: argparse.Namespace) -> int:
    import datetime as dt

    from hil.pipeline import certify_scene
    from hil.scene import load_scene

    scene = load_scene(args.scene or "sdea_bench")
    if args.seed is not None:
        scene.seed = args.seed
    key = None
    if args.sign:  # read the key (and check the extra) before anything runs or is written
        from hil.signing import load_private_key

        key = load_private_key(args.sign)
    elif args.signer:
        raise UsageError("--signer names who signs: give the key with --sign KEY")
    stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    out = Path(args.out or f"reports/{scene.name}-{stamp}")

    def say(msg: str) -> None:
        if not args.json:
            print(msg, file=sys.stderr)

    cert = certify_scene(scene, out, progress=say, run_experiments=not args.no_experiments)  # sealed
    from hil.report import build_reports

    integrity = None
    if key is not None:
        from hil.signing import sign_certificate
        from hil.verify import check_certificate

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
        from rich.table import Table

        con = Console()
        colour = {"GO": "green", "MARGINAL": "yellow", "NO-GO": "red", "ERROR": "magenta"}[cert.decision]
        con.print(f"[bold]{scene.name}[/bold]: [bold {colour}]{cert.decision}[/]")
        for r in cert.reasons:
            con.print(f"  - {r}")
        tab = Table("measurement", "value", "limits", "outcome")
        for m in cert.measurements:
            lim = " ".join(x for x in (f"≥ {m.lower:g}" if m.lower is not None else "",
                                       f"≤ {m.upper:g}" if m.upper is not None else "") if x)
            v = f"{m.value:.4g}" if isinstance(m.value, float) else str(m.value)
            tab.add_row(m.name, f"{v} {m.unit}".strip(), lim, m.outcome)
        con.print(tab)
        for k, v in files.items():
            con.print(f"{k}: {v}")
        if cert.integrity is not None:
            sig = cert.integrity.signature
            signed = f", signed with key {sig.public_key_sha256[:16]}…" if sig is not None else ""
            print(f"digest: {cert.integrity.digest}{signed} (check with: hil verify {out})")
    return DECISION_EXIT[cert.decision]


def _cmd_report(args: argparse.Namespace) -> int:
    from hil.report import report_main

    argv = [args.path] + (["--out", args.out] if args.out else []) + (
        ["--public-key", args.public_key] if args.public_key else []) + (
        ["--allow-modified"] if args.allow_modified else [])
    return int(report_main(argv) or 0)


def _cmd_verify(args: argparse.Namespace) -> int:
    from hil.verify import verify_main

    return int(verify_main([args.path] + (["--public-key", args.public_key] if args.public_key else [])) or 0)


def _cmd_keygen(args: argparse.Namespace) -> int:
    from hil.signing import generate_keypair, load_public_key

    priv, pub = generate_keypair(args.out)
    print(f"private key {priv} (mode 0600: keep it secret; hil certify --sign {priv})")
    print(f"public key  {pub} (fingerprint {load_public_key(pub).fingerprint}; hil verify DIR --public-key {pub})")
    return EXIT_OK


def _cmd_replay(args: argparse.Namespace) -> int:
    from hil.record import replay_main

    return int(replay_main([args.record] + (["--json"] if args.json else [])) or 0)


# ---------------------------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="hil", description="Hardware-in-the-loop identification and stability "
                                "certification of haptic devices, teleoperators and series elastic actuators.")
    p.add_argument("--debug", action="store_true", help="show tracebacks and debug logs")
    sub = p.add_subparsers(dest="cmd", metavar="COMMAND")

    s = sub.add_parser("stability", help="check passivity / absolute stability of a network (file or built-in model)")
    s.add_argument("file", nargs="?", help="network file (YAML or JSON): type, ports, matrix of {num, den}")
    s.add_argument("--model", help="built-in model name (see --list-models)")
    s.add_argument("--set", action="append", metavar="PARAM=VALUE", help="override a model parameter (repeatable)")
    s.add_argument("--criterion", choices=["auto", "positive_real", "passivity", "llewellyn", "absolute_stability"],
                   help="criterion to apply (default: the file's, or the model's, or auto)")
    s.add_argument("--json", action="store_true", help="print one JSON object")
    s.add_argument("-v", "--verbose", action="store_true", help="list every condition")
    s.add_argument("--list-models", action="store_true", help="list the built-in models and exit")
    s.set_defaults(func=_cmd_stability)

    d = sub.add_parser("design", help="largest virtual-coupler stiffness k22 of the SDEA (002 Table II)")
    d.add_argument("--criterion", choices=["passivity", "absolute_stability"], default="passivity")
    d.add_argument("--alpha", type=float, help="feed-forward ratio alpha in [0, 1] (default 1)")
    d.add_argument("--optimize-alpha", action="store_true", help="also maximize over alpha")
    d.add_argument("--b22", type=float, help="fix the coupler damping instead of optimizing it")
    d.add_argument("--set", action="append", metavar="PARAM=VALUE", help="override an SDEA parameter")
    d.add_argument("--json", action="store_true")
    d.set_defaults(func=_cmd_design)

    sc = sub.add_parser("scenes", help="list the built-in scenes")
    sc.add_argument("--json", action="store_true")
    sc.set_defaults(func=_cmd_scenes)

    r = sub.add_parser("run", help="run a scene's experiments (chirp, energy injection, static hold) and record them")
    r.add_argument("scene", help="scene YAML file or built-in scene name (see hil scenes)")
    r.add_argument("--out", help="output folder for the records (default runs/<scene>-<UTC time>)")
    r.add_argument("--seed", type=int, help="override the scene's seed")
    r.add_argument("--experiment", action="append", help="run only this experiment (index or type; repeatable)")
    mode = r.add_mutually_exclusive_group()
    mode.add_argument("--realtime", action="store_true", help="fixed-rate loop on the wall clock")
    mode.add_argument("--lockstep", action="store_true",
                      help="as fast as possible; the plant advances one period per tick")
    r.add_argument("--json", action="store_true", help="print one JSON object")
    r.set_defaults(func=_cmd_run)

    ce = sub.add_parser("certify", help="experiments -> identification -> criteria over the posterior -> "
                                         "GO / MARGINAL / NO-GO report (default: the mocked SDEA bench)")
    ce.add_argument("scene", nargs="?", help="scene file or built-in name (default sdea_bench)")
    ce.add_argument("--out", help="output folder (default reports/<scene>-<UTC time>)")
    ce.add_argument("--seed", type=int)
    ce.add_argument("--no-experiments", action="store_true", help="skip the runs (certify from the scene's priors)")
    ce.add_argument("--sign", metavar="KEY", help="sign the certificate's digest with this Ed25519 private key "
                                                  "(PEM, see hil keygen; needs the 'sign' extra)")
    ce.add_argument("--signer", metavar="NAME", help="who signs (recorded and signed with --sign)")
    ce.add_argument("--json", action="store_true")
    ce.set_defaults(func=_cmd_certify)

    rep = sub.add_parser("report", help="rebuild the HTML and PDF reports from a stored certificate.json")
    rep.add_argument("path", help="certificate.json or the folder holding it")
    rep.add_argument("--out", help="output folder (default: next to the certificate)")
    rep.add_argument("--public-key", metavar="PUB", help="check the signature with this Ed25519 public key (PEM)")
    rep.add_argument("--allow-modified", action="store_true",
                     help="render a certificate that does not match its digest, marked on every page "
                          "'MODIFIED: NOT A VALID CERTIFICATE'")
    rep.set_defaults(func=_cmd_report)

    ve = sub.add_parser("verify", help="check a certificate's digest, the SHA-256 of its records and scene, "
                                       "and (with --public-key) its signature; exit 0 or 2")
    ve.add_argument("path", metavar="DIR", help="the certificate folder (or its certificate.json)")
    ve.add_argument("--public-key", metavar="PUB", help="Ed25519 public key (PEM) the signature must verify with")
    ve.set_defaults(func=_cmd_verify)

    kg = sub.add_parser("keygen", help="write a new Ed25519 signing key pair (private 0600, public) into a folder")
    kg.add_argument("--out", required=True, metavar="DIR", help="folder for the key files (never overwritten)")
    kg.set_defaults(func=_cmd_keygen)

    rp = sub.add_parser("replay", help="inspect a run record (summary of channels, timing, stop reason)")
    rp.add_argument("record")
    rp.add_argument("--json", action="store_true")
    rp.set_defaults(func=_cmd_replay)

    im = sub.add_parser("import", help="convert a CSV or MATLAB .mat run into a run record (HDF5)")
    im.add_argument("file", help="CSV (header row) or .mat file")
    im.add_argument("--out", help="record path (default: FILE with .h5)")
    im.add_argument("--time", help="time column / variable (s); default t or time")
    im.add_argument("--map", action="append", metavar="CHANNEL=COL[,COL...]",
                    help="channel from one column or a vector from several (repeatable)")
    im.add_argument("--sidecar", help="YAML/JSON mapping file (default: found next to the CSV)")
    im.set_defaults(func=_cmd_import)

    i = sub.add_parser("identify", help="identify a grey-box model (M, B, K_f, B_f, ...) from a chirp record",
                       add_help=False)
    i.add_argument("rest", nargs=argparse.REMAINDER)

    m = sub.add_parser("mock", help="simulated devices: 'hil mock serve SPEC' starts them and prints endpoints")
    m.add_argument("rest", nargs=argparse.REMAINDER)
    return p


_PASSTHROUGH = {"identify": "hil.identify.api", "mock": "hil.mocks.serve"}


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in _PASSTHROUGH:  # these subcommands own their argument parsing (and --help)
        import importlib

        rest = argv[1:]
        if argv[0] == "mock":
            if not rest or rest[0] != "serve":
                print("usage: hil mock serve SCENE [--duration SECONDS] [--json] [--can-interface udp_multicast] "
                      "| hil mock serve --spec SPEC", file=sys.stderr)
                return EXIT_USAGE
            rest = rest[1:]
        try:
            return int(importlib.import_module(_PASSTHROUGH[argv[0]]).main(rest) or 0)
        except HilError as exc:
            print(f"hil {argv[0]}: error: {exc}", file=sys.stderr)
            return EXIT_USAGE
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.debug else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    if not getattr(args, "func", None):
        parser.print_help()
        return EXIT_USAGE
    try:
        return args.func(args)
    except (UsageError, HilError) as exc:
        if args.debug:
            raise
        print(f"hil {args.cmd}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # e.g. `hil stability ... --json | head`
        sys.stderr.close()
        return EXIT_OK


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
