"""``hil verify``: check a certificate's digest, the SHA-256 of its records and scene, and (with
--public-key) its signature; exit 0 or 2."""

from __future__ import annotations

import argparse
import sys

from hil.errors import EXIT_OK, EXIT_USAGE


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("path", metavar="DIR", help="the certificate folder (or its certificate.json)")
    p.add_argument("--public-key", metavar="PUB", help="Ed25519 public key (PEM) the signature must verify with")


def run(args: argparse.Namespace) -> int:
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
    if not st.valid:
        print(f"hil verify: {where}: NOT VALID: {st.reason()}", file=sys.stderr)
        return EXIT_USAGE
    from hil.report.render import bench_banner

    print(f"OK {where}: {ok_summary(st)}; bench: {bench_banner(cert)[0]}")
    return EXIT_OK
