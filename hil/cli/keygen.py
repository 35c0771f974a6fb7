"""``hil keygen``: write a new Ed25519 signing key pair (private 0600, public) into a folder."""

from __future__ import annotations

import argparse

from hil.errors import EXIT_OK


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, metavar="DIR", help="folder for the key files (never overwritten)")


def run(args: argparse.Namespace) -> int:
    from hil.certify.signing import generate_keypair, load_public_key

    priv, pub = generate_keypair(args.out)
    print(f"private key {priv} (mode 0600: keep it secret; hil certify --sign {priv})")
    print(f"public key  {pub} (fingerprint {load_public_key(pub).fingerprint}; hil verify DIR --public-key {pub})")
    return EXIT_OK
