"""``hil check-realtime``: the machine's wake-up latency (cyclictest's way) and the loop rates it holds."""

from __future__ import annotations

import argparse

from hil.inputs import number_type


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rate", type=number_type("positive"), default=2000.0, help="loop rate to check [Hz]")
    p.add_argument("--seconds", type=number_type("positive"), default=5.0, help="seconds per measurement")
    p.add_argument("--no-rt", action="store_true", help="without SCHED_FIFO / mlockall / CPU affinity")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the tables")


def run(args: argparse.Namespace) -> int:
    from hil.run.realtime import check_realtime

    return check_realtime(args.rate, args.seconds, rt=not args.no_rt, as_json=args.json)
