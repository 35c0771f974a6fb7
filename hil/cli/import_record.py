"""``hil import``: convert a CSV or MATLAB .mat run into a run record (HDF5)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from hil.cli.common import UsageError, parse_number
from hil.errors import EXIT_OK


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", help="CSV (header row) or .mat file")
    p.add_argument("--out", help="record path (default: FILE with .h5)")
    p.add_argument("--time", help="time column / variable (s); default t or time")
    p.add_argument("--map", action="append", metavar="CHANNEL=COL[,COL...]",
                   help="channel from one column or a vector from several (repeatable)")
    p.add_argument("--scale", action="append", metavar="CHANNEL=FACTOR",
                   help="multiply a channel (or t) by FACTOR, e.g. motor.effort_cmd=35.15 for a force "
                        "recorded as a voltage (repeatable)")
    p.add_argument("--unit", action="append", metavar="CHANNEL=UNIT",
                   help="unit of a channel's (or t's) values in the file, e.g. t=ms, motor.position=mm: "
                        "converted to SI, the record states the SI unit (repeatable)")
    p.add_argument("--sidecar", help="YAML/JSON mapping file (default: found next to the file)")
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
    scale = {k: parse_number("--scale", k, str(v)) for k, v in _pairs("--scale", args.scale, "FACTOR").items()}
    units = _pairs("--unit", args.unit, "UNIT")
    suffix = src.suffix.lower()
    if suffix not in (".mat", ".csv", ".txt", ".tsv"):
        raise UsageError(f"{src}: expected a .csv or .mat file")
    if args.sidecar and mapping is not None:
        raise UsageError("give --sidecar or --map/--time, not both")
    check_out_file(out, overwrite=args.overwrite)
    importer = import_mat if suffix == ".mat" else import_csv
    path = importer(src, out, mapping=mapping, sidecar=args.sidecar, scale=scale, units=units)
    print(str(path))
    return EXIT_OK


def _pairs(flag: str, items: list[str] | None, what: str) -> dict[str, str]:
    """``NAME=VALUE`` items of a repeatable flag; a name given twice is refused."""
    out: dict[str, str] = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        if not sep or not name.strip() or not value.strip():
            raise UsageError(f"{flag} expects CHANNEL={what}, got {item!r}")
        if name.strip() in out:
            raise UsageError(f"{flag} {name.strip()}: given twice")
        out[name.strip()] = value.strip()
    return out
