"""``hil export``: a run record as MCAP (Foxglove, PlotJuggler) or CSV (spreadsheets)."""

from __future__ import annotations

import argparse
from pathlib import Path

from hil.cli.common import UsageError
from hil.errors import EXIT_OK


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("record", help="run record (.h5) written by hil run or hil import")
    p.add_argument("--format", dest="fmt", choices=("mcap", "csv"), required=True,
                   help="mcap: channels per device, events, stop and device counters as JSON messages with "
                        "JSON schemas; csv: the channels, one row per sample")
    p.add_argument("--out", help="output file (default: RECORD with .mcap or .csv)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")


def run(args: argparse.Namespace) -> int:
    from hil.record.export import export_record
    from hil.record.outdir import check_out_file

    src = Path(args.record)
    if not src.is_file():
        raise UsageError(f"{src}: no such record file")
    out = Path(args.out) if args.out else src.with_suffix(f".{args.fmt}")
    if out.resolve() == src.resolve():
        raise UsageError(f"--out {out}: would replace the record")
    check_out_file(out, overwrite=args.overwrite)
    print(str(export_record(src, out, args.fmt)))
    return EXIT_OK
