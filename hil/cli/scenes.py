"""``hil scenes``: list the built-in scenes."""

from __future__ import annotations

import argparse
import json

from hil.cli.common import console
from hil.errors import EXIT_OK


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="print a JSON list of {name, description}")


def run(args: argparse.Namespace) -> int:
    from hil.scene.spec import builtin_scenes

    rows = builtin_scenes()
    if args.json:
        print(json.dumps([{"name": n, "description": d} for n, d in rows], indent=2))
        return EXIT_OK
    from rich.table import Table

    tab = Table("scene", "description", title="built-in scenes (usable by name: hil run NAME)")
    for n, d in rows:
        tab.add_row(n, d)
    console().print(tab)
    return EXIT_OK
