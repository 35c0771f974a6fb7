"""``hil mock``: simulated devices: 'hil mock serve SPEC' starts them and prints endpoints."""

from __future__ import annotations

import argparse

from hil.cli.common import OneLineArgumentParser, debug_parent
from hil.inputs import number_type, seed_type


def add_arguments(p: argparse.ArgumentParser) -> None:
    msub = p.add_subparsers(dest="mock_cmd", metavar="serve", parser_class=OneLineArgumentParser, required=True)
    ms = msub.add_parser("serve", parents=[debug_parent()], help="start simulated devices and print their endpoints",
                         description="Start a scene's simulated devices (or a spec's, or one --device) on their "
                                     "own and print where each one listens (hil.bench.serve).")
    serve_arguments(ms)


def run(args: argparse.Namespace) -> int:
    from hil.bench.serve import run

    return run(args)


def serve_arguments(ap: argparse.ArgumentParser) -> None:
    """The options of ``hil mock serve`` (checked together by :func:`hil.bench.serve.run`)."""
    ap.add_argument("scene", nargs="?", help="scene file or built-in scene name (see 'hil scenes')")
    ap.add_argument("--spec", help="instead of a scene: JSON string or .json/.yaml file (see hil.bench.serve)")
    ap.add_argument("--duration", type=number_type("non-negative"), default=None,
                    help="seconds to run (default: until Ctrl-C/SIGTERM)")
    ap.add_argument("--json", action="store_true", help="print the endpoints as one JSON line")
    ap.add_argument("--seed", type=seed_type, default=None,
                    help="scene: seed of noise and faults (default: the scene's)")
    ap.add_argument("--variant", choices=["locked", "free"], default=None, help="scene: SDEA plant variant")
    ap.add_argument("--can-interface", default="virtual",
                    help="scene: python-can interface of the CAN devices (virtual | udp_multicast | socketcan ...)")
    ap.add_argument("--can-channel", action="append", default=[], metavar="SCENE_CH=CH",
                    help="scene: serve scene CAN channel SCENE_CH on channel CH (repeatable)")
    ap.add_argument("--can-port", action="append", default=[], metavar="SCENE_CH=PORT",
                    help="scene, udp_multicast: UDP port of scene CAN channel SCENE_CH (repeatable; default "
                         "43113, 43114, ... one per channel)")
    ap.add_argument("--stream-rate", type=number_type("positive"), default=100.0,
                    help="scene: frame rate of streaming FT-300 sensors [Hz] (the sensor's is 100)")
    ap.add_argument("--plant-rate", type=number_type("positive"), default=1000.0,
                    help="spec: FreeJoints step rate [Hz]")
    ap.add_argument("--device", default=None, metavar="KIND",
                    help="serve ONE simulated device of this kind (instead of a scene or --spec): odrive, "
                         "cubemars, cia402, bota, dynamixel, ft300, ft300_stream")
    ap.add_argument("--node", type=int, default=None,
                    help="device: CAN node id (odrive 0..63, cia402 1..127) or CubeMars motor id")
    ap.add_argument("--ids", default=None, help="device dynamixel: comma-separated servo ids (default 1)")
    ap.add_argument("--unit", type=int, default=None, help="device ft300 / ft300_stream: Modbus slave id (default 9)")
    ap.add_argument("--port", type=int, default=None, help="device ft300: TCP port on 127.0.0.1 (default: a free one)")
    ap.add_argument("--pty", action="store_true",
                    help="device bota / ft300_stream / dynamixel: serve on a pty (the default and only transport)")
    ap.add_argument("--rate", type=number_type("positive"), default=None,
                    help="device: tick / frame rate [Hz] (CAN cyclic frames, Bota frames; default 1000, "
                         "FT-300 stream 100)")
