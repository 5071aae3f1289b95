"""``damper-hil live``."""

from __future__ import annotations

import argparse
from pathlib import Path

from damper_emulator.ros.live import LIVE_PRIORITY
from damper_hil.cli.common import Formatter, number_type, positive_int

#: the Foxglove SDK's default port
DEFAULT_PORT = 8765
#: every how many-th /damper/force sample the view sends (1 kHz -> 250 Hz)
DEFAULT_DECIMATION = 4


def add_parser(sub) -> None:
    live = sub.add_parser(
        "live", formatter_class=Formatter,
        help="serve the live view (Foxglove WebSocket) of the running damper and ride",
        description="Run the live_view ROS 2 node: /damper/force, /ride/state and\n"
                    "/diagnostics, served as JSON channels /live/damper, /live/ride and\n"
                    "/live/loop on a Foxglove WebSocket server on 127.0.0.1 (foxglove-sdk).\n"
                    "Open ws://127.0.0.1:PORT in Foxglove or Lichtblick and load\n"
                    "config/foxglove_layout.json: force against velocity and time, the ride\n"
                    "metrics as they accumulate, the emulator loop's status.")
    live.add_argument("--port", type=positive_int, default=DEFAULT_PORT,
                      help=f"WebSocket port (default: {DEFAULT_PORT})")
    live.add_argument("--decimation", metavar="N", type=positive_int,
                      default=DEFAULT_DECIMATION,
                      help=f"send every N-th force sample (default: {DEFAULT_DECIMATION}: "
                           "250 Hz of a 1 kHz emulator)")
    live.add_argument("--priority", metavar="P", default=None,
                      type=number_type("an integer 0..99", lambda v: 0 <= v <= 99, int),
                      help="SCHED_FIFO priority of the view's threads when permitted, 0 for "
                           f"normal scheduling (default: {LIVE_PRIORITY}: above normal "
                           "processes, below the recorder and the loops)")
    live.add_argument("--quarter-car", metavar="CAR.yaml", type=Path, default=None,
                      help="the ride's car (sprung mass, time step; default "
                           "config/quarter_car.yaml)")
    live.set_defaults(handler=run, takes_ros_args=True)


def run(args: argparse.Namespace) -> int:
    from damper_emulator.ros.common import spin_node
    from damper_hil.live_node import LiveNode
    from ride_sim.params import load_ride_config

    ride = load_ride_config(args.quarter_car)
    priority = LIVE_PRIORITY if args.priority is None else args.priority
    return spin_node(lambda: LiveNode(args.port, args.decimation, ride, priority),
                     args.ros_args)
