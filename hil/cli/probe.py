"""``hil probe``: list what answers on a CAN channel, serial port or Modbus address (--scene writes a scene stub)."""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    from hil.bench.probe import add_arguments as probe_arguments

    probe_arguments(p)


def run(args: argparse.Namespace) -> int:
    from hil.bench.probe import run as _probe_run  # lazy: start-up time of the other commands

    return _probe_run(args)
