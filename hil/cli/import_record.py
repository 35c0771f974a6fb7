"""``hil import``: convert a run recorded by another tool (CSV, MATLAB .mat, HDF5, TDMS, ROS bag, MCAP) into
a run record (HDF5), or list what a file holds (``--list``)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from hil.cli.common import UsageError, parse_number
from hil.errors import EXIT_OK

EPILOG = """\
sources (--map CHANNEL=SOURCE[,SOURCE...]):
  CSV        a column name                    --map motor.position=pos
  .mat       a variable or struct.field       --map motor.position=qm   (q[1]: column 1 of q)
  HDF5       a dataset path                   --map motor.position=/data/q[0]
  TDMS       group/channel                    --map motor.position="Untitled/Position"
  ROS bag,   /topic:field[joint or index]     --map motor.position=/joint_states:position[joint1]
  MCAP                                        --map spring_ft.wrench=/ft:wrench.force.z
'hil import FILE --list' shows the sources of a file. docs/guide/formats.md has one example per format."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = EPILOG
    p.add_argument("file", help="CSV/TXT/TSV, .mat (v4-v7.3), .h5/.hdf5, .tdms, .mcap, ROS 1 .bag or a ROS 2 bag "
                                "folder")
    p.add_argument("--out", help="record path (default: FILE with .h5)")
    p.add_argument("--list", action="store_true",
                   help="list what the file holds (columns, variables, datasets, channels, topics and fields, "
                        "rates, units) and write nothing")
    p.add_argument("--format", dest="fmt", metavar="FORMAT",
                   help="read as this format (csv, mat, hdf5, tdms, rosbag, mcap); default: from the file")
    p.add_argument("--time", help="time column / variable / dataset [s]; default t or time. Bags and MCAP: the "
                                  "topic whose stamps are the time base (default: the fastest mapped topic)")
    p.add_argument("--map", action="append", metavar="CHANNEL=SOURCE[,SOURCE...]",
                   help="channel from one source or a vector from several (repeatable; sources below)")
    p.add_argument("--scale", action="append", metavar="CHANNEL=FACTOR",
                   help="multiply a channel (or t) by FACTOR, e.g. motor.effort_cmd=35.15 for a force "
                        "recorded as a voltage (repeatable)")
    p.add_argument("--unit", action="append", metavar="CHANNEL=UNIT",
                   help="unit of a channel's (or t's) values in the file, e.g. t=ms, motor.position=mm: "
                        "converted to SI, the record states the SI unit (repeatable)")
    p.add_argument("--resample", type=float, metavar="HZ",
                   help="bags, MCAP, TDMS: put every channel onto a uniform grid at HZ (latest sample at or before "
                        "each grid time), for time stamps that jitter; default: the fastest topic's own stamps")
    p.add_argument("--sidecar", help="YAML/JSON mapping file (default: found next to the file)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing record at --out")


def _print_inventory(fmt: str, src: Path, rows: list[Any]) -> None:
    def num(v: float | None) -> str:
        return "" if v is None else f"{v:.6g}"

    table = [("source", "kind", "samples", "rate_Hz", "shape", "unit", "note")]
    table += [(r.source, r.kind, "" if r.samples is None else str(r.samples), num(r.rate_hz),
               "x".join(map(str, r.shape)) if r.shape else "", r.unit, r.note) for r in rows]
    widths = [max(len(row[i]) for row in table) for i in range(len(table[0]))]
    print(f"{src} ({fmt}): {len(rows)} source(s)")
    for row in table:
        print("  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip())


def run(args: argparse.Namespace) -> int:
    from hil.record.importers import describe, import_file
    from hil.record.outdir import check_out_file

    src = Path(args.file)
    if not src.exists():
        raise UsageError(f"{src}: no such file")
    if src.is_dir() and not (src / "metadata.yaml").is_file():
        raise UsageError(f"{src}: is a folder; give a file (or a ROS 2 bag: a folder with metadata.yaml)")
    if args.list:
        if args.map or args.time or args.scale or args.unit or args.sidecar or args.out or args.resample:
            raise UsageError("--list only lists the file: give it without --map/--time/--scale/--unit/--sidecar/"
                             "--resample/--out")
        fmt, rows = describe(src, args.fmt)
        _print_inventory(fmt, src, rows)
        return EXIT_OK
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
                raise UsageError(f"--map expects CHANNEL=SOURCE[,SOURCE...], got {item!r}")
            ch, cols = item.split("=", 1)
            parts = [c.strip() for c in cols.split(",") if c.strip()]
            if not ch.strip() or not parts:
                raise UsageError(f"--map {item}: expects CHANNEL=SOURCE[,SOURCE...]")
            mapping[ch.strip()] = parts[0] if len(parts) == 1 else parts
        # without --time the importer takes the t/time column (hil.record.importers)
    scale = {k: parse_number("--scale", k, str(v)) for k, v in _pairs("--scale", args.scale, "FACTOR").items()}
    units = _pairs("--unit", args.unit, "UNIT")
    if args.sidecar and mapping is not None:
        raise UsageError("give --sidecar or --map/--time, not both")
    check_out_file(out, overwrite=args.overwrite)
    path = import_file(src, out, mapping=mapping, sidecar=args.sidecar, scale=scale, units=units, fmt=args.fmt,
                       resample_hz=args.resample)
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
