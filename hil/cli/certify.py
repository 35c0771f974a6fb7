"""``hil certify``: experiments -> identification -> criteria over the posterior -> GO / MARGINAL /
NO-GO report (default: the mocked SDEA bench)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from hil.cli.common import StepProgress, UsageError, bench_opening_said_once, console, out_dir
from hil.errors import DECISION_EXIT, EXIT_USAGE


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", nargs="*", help="scene file, built-in name or folder of scenes (default "
                   "sdea_bench); several: a fleet certified in parallel (docs/guide/certification.md, Fleet "
                   "certification)")
    p.add_argument("--workers", type=int, help="fleet: parallel scenes (default: all cores)")
    p.add_argument("--scheduler", metavar="ADDR", help="fleet: run on a Dask scheduler (tcp://host:8786; "
                   "extra 'dask')")
    p.add_argument("--out", help="output folder (default reports/<scene>-<UTC time>-<id>); an existing "
                   "non-empty folder is refused unless --overwrite")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out folder, which must hold "
                   "only what hil certify writes, as a whole (built beside it, then swapped in)")
    p.add_argument("--seed", type=int, help="override the scene's seed (runs, posterior sampling, draws)")
    p.add_argument("--no-experiments", action="store_true", help="skip the runs (certify from the scene's priors)")
    p.add_argument("--sign", metavar="KEY", help="sign the certificate's digest with this Ed25519 private key "
                                                 "(PEM, see hil keygen; needs the 'sign' extra)")
    p.add_argument("--signer", metavar="NAME", help="who signs (recorded and signed with --sign)")
    p.add_argument("--json", action="store_true", help="print one JSON object (decision, reasons, bench, files, "
                   "digest, measurements) instead of the table; no progress lines")
    # a fleet's worker builds the folder in its own scratch space and the client writes it at this
    # path: the certificate and reports name the folder where it will be (not for people)
    p.add_argument("--named-as", help=argparse.SUPPRESS)


def run(args: argparse.Namespace) -> int:
    from hil.certify.fleet import CERTIFICATE_FOLDER  # what hil certify writes into its folder
    from hil.certify.pipeline import certify_scene
    from hil.protocols.registry import extras_message
    from hil.record.outdir import stage_out_dir
    from hil.scene.spec import check_seed, load_scene

    if len(args.scene) > 1 or (args.scene and Path(args.scene[0]).is_dir()):
        return run_fleet(args)
    if args.workers is not None or args.scheduler:
        raise UsageError("--workers and --scheduler apply to a fleet (several scenes or a folder)")
    args.scene = args.scene[0] if args.scene else None
    scene = load_scene(args.scene or "sdea_bench")
    if scene.certification is None:  # a usage error, not an ERROR certificate (nothing is written)
        raise UsageError(f"{args.scene or 'sdea_bench'}: the scene has no 'certification' section: nothing to "
                         "certify (hil run runs its experiments)")
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
    # the certificate folder is written as a unit: built in a sibling, moved into place at the end
    target = Path(args.out or f"reports/{scene.name}").absolute()
    fresh_parent = None if target.parent.exists() else target.parent  # made here: removed again if left empty
    staged = stage_out_dir(args.out, default_stem=f"reports/{scene.name}", overwrite=args.overwrite,
                           owned=CERTIFICATE_FOLDER)
    work = staged.path

    # stage lines, and between them a spinner (terminal) or a line every few seconds naming the stage,
    # the experiment running and its ticks
    beat = StepProgress(f"hil certify {scene.name}", enabled=not args.json)

    def say(msg: str) -> None:
        beat.update(f"{msg.removeprefix(scene.name + ': ')} (still running)")
        if not args.json:
            beat.say(msg)

    def ticks(name: str, k: int, n: int) -> None:  # which experiment runs, and how far it got
        beat.update(f"run {name}: {k}/{n} ticks ({100.0 * k / max(n, 1):.0f} %)")

    from hil.bench.stopflag import SignalInterrupt, StopRequested, signals_interrupt

    try:
        with signals_interrupt(), beat, bench_opening_said_once():  # SIGTERM/SIGHUP outside the bench: exit 20
            cert = certify_scene(scene, work, progress=say, run_experiments=not args.no_experiments,
                                 tick_progress=ticks)  # sealed
            cert = _renamed(cert, work, Path(args.named_as) if getattr(args, "named_as", None) else staged.final)
            say(f"{scene.name}: reports ...")
            from hil.report.render import build_reports

            integrity = None
            if key is not None:
                from hil.certify.signing import sign_certificate
                from hil.certify.verify import check_certificate

                cert = sign_certificate(cert, key, args.signer or "")
                integrity = check_certificate(cert, public_key=key.public(),
                                              verified_with="the signing key's public half, when signing")
            files = build_reports(cert, work, integrity=integrity)
        out = staged.commit()  # signals held for the few renames
    except BaseException as exc:
        kept = staged.abandon()  # partial records (a stopped run) stay, and the message says where
        if kept is None and fresh_parent is not None:
            from hil.record.outdir import remove_if_empty

            remove_if_empty(fresh_parent)
        if kept is not None and exc.args and isinstance(exc.args[0], str):
            exc.args = (exc.args[0].replace(str(work), str(kept)), *exc.args[1:])
        if isinstance(exc, SignalInterrupt):
            where = f"; the records so far are in {kept}" if kept is not None else "; nothing was written"
            raise StopRequested(f"signal: {exc.signame}{where}") from None
        raise
    files = {k: out / Path(v).relative_to(work) for k, v in files.items()}
    if args.json:
        print(json.dumps({"decision": cert.decision, "reasons": cert.reasons, "scene": scene.name,
                          "bench": None if cert.bench is None else cert.bench.model_dump(),
                          "files": {k: str(v) for k, v in files.items()},
                          "digest": cert.integrity.digest if cert.integrity else None,
                          "signed": bool(cert.integrity and cert.integrity.signature),
                          "measurements": [m.model_dump() for m in cert.measurements]}, indent=2, default=str))
    else:
        from rich.markup import escape
        from rich.table import Table

        con = console()  # prose and paths are never broken by the console
        colour = {"GO": "green", "MARGINAL": "yellow", "NO-GO": "red", "ERROR": "magenta"}[cert.decision]
        con.print(f"[bold]{escape(scene.name)}[/bold]: [bold {colour}]{cert.decision}[/]"
                  + (f" ({escape(cert.bench.label)})" if cert.bench is not None else ""))
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


def run_fleet(args: argparse.Namespace) -> int:
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
    out = out_dir(args.out, "reports/fleet", args.overwrite)
    extra = ["--no-experiments"] if args.no_experiments else []

    def said(done: int, total: int, e: Any) -> None:
        if not args.json:
            print(f"[{done}/{total}] {e.name}: {e.decision} ({e.seconds:.0f} s)", file=sys.stderr)

    from hil.bench.stopflag import STOP

    try:
        with STOP.install():
            res = certify_fleet(scenes, out, executor=ex, seed=seed, extra_args=extra, progress=said,
                                should_stop=lambda: STOP.requested, overwrite=args.overwrite)
    finally:
        ex.close()
    if args.json:
        print(json.dumps(res.to_dict(), indent=2))
    else:
        from rich.markup import escape
        from rich.table import Table

        con = console()
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

def _renamed(cert: Any, work: Path, final: Path) -> Any:
    """``cert`` with every mention of the staging folder (record paths, reasons) naming the final
    folder, sealed again (nothing is signed yet); unchanged when nothing mentions it."""
    from hil.certify.certificate import Certificate, seal

    old, new = str(work), str(final)
    if old not in cert.model_dump_json():
        return cert

    def swap(v: Any) -> Any:
        if isinstance(v, str):
            return v.replace(old, new)
        if isinstance(v, dict):
            return {k: swap(x) for k, x in v.items()}
        if isinstance(v, list | tuple):
            return type(v)(swap(x) for x in v)
        return v

    data = swap(cert.model_dump(exclude={"integrity"}))
    return seal(Certificate.model_validate(data))


def _short_value(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)
