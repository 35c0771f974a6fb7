"""``hil report``: rebuild the HTML and PDF reports from a stored certificate.json."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hil.errors import EXIT_OK, EXIT_USAGE


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("path", help="certificate.json or the folder holding it")
    p.add_argument("--out", help="output folder (default: next to the certificate); another existing non-empty "
                   "folder is refused unless --overwrite")
    p.add_argument("--overwrite", action="store_true", help="write report.html / report.pdf into a non-empty --out")
    p.add_argument("--public-key", metavar="PUB", help="check the signature with this Ed25519 public key (PEM)")
    p.add_argument("--allow-modified", action="store_true",
                   help="render a certificate that does not match its digest, marked on every page "
                        "'MODIFIED: NOT A VALID CERTIFICATE'")


def run(args: argparse.Namespace) -> int:
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
