"""``hil import``: convert a CSV or MATLAB .mat run into a run record (HDF5)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from hil.cli.common import UsageError
from hil.errors import EXIT_OK


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", help="CSV (header row) or .mat file")
    p.add_argument("--out", help="record path (default: FILE with .h5)")
    p.add_argument("--time", help="time column / variable (s); default t or time")
    p.add_argument("--map", action="append", metavar="CHANNEL=COL[,COL...]",
                   help="channel from one column or a vector from several (repeatable)")
    p.add_argument("--sidecar", help="YAML/JSON mapping file (default: found next to the CSV)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing record at --out")


def run(args: argparse.Namespace) -> int:
    from hil.record.importers import import_csv, import_mat
    from hil.record.outdir import check_out_file

    src = Path(args.file)
    if src.is_dir():
        raise UsageError(f"{src}: is a folder; give a .csv or .mat file")
    if not src.exists():
        raise UsageError(f"{src}: no such file")
    out = Path(args.out) if args.out else src.with_suffix(".h5")
    if out.resolve() == src.resolve():
        raise UsageError(f"--out {out}: would replace the input file")
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
            if not ch.strip() or not parts:
                raise UsageError(f"--map {item}: expects CHANNEL=COLUMN[,COLUMN...]")
            mapping[ch.strip()] = parts[0] if len(parts) == 1 else parts
        # without --time the importer takes the t/time column (hil.record.importers)
    suffix = src.suffix.lower()
    if suffix not in (".mat", ".csv", ".txt", ".tsv"):
        raise UsageError(f"{src}: expected a .csv or .mat file")
    if suffix == ".mat" and args.sidecar:
        raise UsageError("--sidecar applies to CSV files; for .mat give --map/--time or a sidecar next to the file")
    if args.sidecar and mapping is not None:
        raise UsageError("give --sidecar or --map/--time, not both")
    check_out_file(out, overwrite=args.overwrite)
    if suffix == ".mat":
        path = import_mat(src, out, mapping=mapping)
    else:
        path = import_csv(src, out, mapping=mapping, sidecar=args.sidecar)
    print(str(path))
    return EXIT_OK
