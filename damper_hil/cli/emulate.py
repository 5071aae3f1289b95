"""``damper-hil emulate``."""

from __future__ import annotations

import argparse

from damper_hil.cli.common import Formatter


def add_parser(sub) -> None:
    emulate = sub.add_parser(
        "emulate", formatter_class=Formatter,
        help="run the damper_emulator ROS 2 node (/damper/state in, /damper/force out)",
        description="Run the damper_emulator ROS 2 node until SIGINT/SIGTERM.\n\n"
                    "Parameters: groups 'emulator' (defaults: config/emulator.yaml),\n"
                    "'damper' and 'numerics' (defaults: config/sport.yaml), set with\n"
                    "  --ros-args --params-file FILE [-p emulator.rate_hz:=2000.0] ...")
    emulate.set_defaults(handler=run, takes_ros_args=True)


def run(args: argparse.Namespace) -> int:
    from damper_emulator.ros.common import spin_node
    from damper_emulator.ros.emulator import EmulatorNode

    return spin_node(EmulatorNode, args.ros_args)
