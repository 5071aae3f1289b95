"""``damper-hil record``."""

from __future__ import annotations

import argparse
from pathlib import Path

from damper_hil.cli.common import Formatter


def add_parser(sub) -> None:
    record = sub.add_parser(
        "record", formatter_class=Formatter,
        help="record the damper topics to a rosbag2 (MCAP) bag until SIGINT/SIGTERM",
        description="Record /damper/state, /damper/force, /damper/valve_command,\n"
                    "/diagnostics and /ride/state to a rosbag2 bag with MCAP storage.\n"
                    "The bag is flushed every 0.25 s: killing the recorder loses at most\n"
                    "0.5 s and leaves a readable bag.")
    record.add_argument("--out", metavar="BAG", type=Path, required=True,
                        help="bag directory to create (must not exist or be empty)")
    record.add_argument("--topics", metavar="TOPIC", nargs="+",
                        help="record only these topics")
    record.set_defaults(handler=run, takes_ros_args=True)


def run(args: argparse.Namespace) -> int:
    from damper_emulator.ros.common import spin_node
    from damper_emulator.ros.recorder import RecorderNode

    return spin_node(lambda: RecorderNode(args.out, args.topics), args.ros_args)
