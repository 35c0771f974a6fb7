"""``hil replay``: inspect a run record (summary of channels, timing, stop reason)."""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("record")
    p.add_argument("--json", action="store_true")


def run(args: argparse.Namespace) -> int:
    from hil.record.hdf5 import replay

    return replay(args.record, as_json=args.json)
