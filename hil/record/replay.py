"""``hil replay RECORD [--json]``: a run record's summary (:meth:`hil.record.reader.RunRecord.summary`)
printed as a table, or as strict JSON."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from hil.record.format import _jsonable
from hil.record.reader import RunRecord, _fmt_s

__all__ = ["replay"]



def _fmt(v: Any) -> str:
    if v is None:
        return "—"
    if isinstance(v, list):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.5g}"
    return str(v)


def _print_summary(s: Mapping[str, Any]) -> None:
    from rich.console import Console  # lazy: only to print (the runner and workers import records)
    from rich.markup import escape
    from rich.table import Table

    con = Console()
    con.print(f"[bold]{s['path']}[/bold]")
    if s["closed"]:
        colour = "green" if s["status"] == "ok" else "red"
        con.print(f"status: [bold {colour}]{s['status']}[/] — stop reason: {s['stop_reason']}")
    else:
        con.print("status: [bold yellow]not closed[/] (killed or still running; samples up to the last flush)")
    rate = s["measured_rate_hz"]
    con.print(f"samples: {s['samples']}  duration: {s['duration_s']:.6g} s  rate: {_fmt(s['rate_hz'])} Hz "
              f"(measured {_fmt(rate)} Hz)")
    if s["experiments"]:
        con.print("results: " + ", ".join(s["experiments"]))
    kinds = ", ".join(f"{k} x{n}" for k, n in s["event_kinds"].items())
    con.print(f"events: {s['events']}" + (f" ({kinds})" if kinds else ""))
    if "loop" in s:
        con.print("loop: " + "  ".join(f"{k}={_fmt(v)}" for k, v in s["loop"].items()))
    lat = s.get("lateness")
    if lat and lat["ticks"]:
        con.print(f"lateness (tick start after its deadline, {lat['ticks']} ticks): p50 {_fmt_s(lat['p50_s'])}  "
                  f"p99 {_fmt_s(lat['p99_s'])}  max {_fmt_s(lat['max_s'])}  overruns {lat['overruns']} "
                  f"({100 * lat['overrun_fraction']:.2f} %, ticks later than one period)", highlight=False)
        width = lat["ticks"]
        for label, c in lat["histogram"]:
            bar = "#" * (round(40 * c / width) if c else 0)
            con.print(f"  {label:>17s} {c:9d} {bar}", highlight=False, markup=False)
    counters = s.get("device_counters") or {}
    if counters:
        con.print("device counters:")
        for dev, cs in counters.items():
            text = "  ".join((f"[bold red]{escape(k)}={v}[/]" if v else f"{escape(k)}={v}")
                             for k, v in cs.items()) or "(none)"
            con.print(f"  {escape(dev)}: {text}", highlight=False)
    tab = Table(show_header=True, header_style="bold")
    for col in ("channel", "unit", "shape", "min", "max", "mean", "NaN"):
        tab.add_column(col, justify="left" if col in ("channel", "unit") else "right", no_wrap=col == "channel")
    for name, c in s["channels"].items():
        tab.add_row(name, c["unit"], "x".join(map(str, c["shape"])) or "scalar", _fmt(c["min"]), _fmt(c["max"]),
                    _fmt(c["mean"]), str(c["nan"]))
    con.print(tab)


def replay(record: str | Path, as_json: bool = False) -> int:
    """``hil replay RECORD [--json]`` (parsed by hil.cli.main): print a record's summary and return 0;
    a missing file or one that is not a readable run record raises :class:`RecordError` (one line,
    exit 2)."""
    s = RunRecord.open(record).summary()
    if as_json:
        print(json.dumps(_jsonable(s), ensure_ascii=False))
    else:
        _print_summary(s)
    return 0


