"""``hil replay``: inspect a run record (summary of channels, timing, stop reason)."""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("record", help="a run record (.h5) written by hil run, hil certify or hil import")
    p.add_argument("--json", action="store_true", help="print one JSON object (channels, timing, lateness, "
                   "stop reason, device counters)")


def run(args: argparse.Namespace) -> int:
    from hil.record.hdf5 import replay

    return replay(args.record, as_json=args.json)
