"""``damper-hil ride``."""

from __future__ import annotations

import argparse

from damper_hil.cli.common import Formatter


def add_parser(sub) -> None:
    ride_node = sub.add_parser(
        "ride", formatter_class=Formatter,
        help="run the ride_sim ROS 2 node (quarter car closed over /damper/state, "
             "/damper/force)",
        description="Run the ride_sim ROS 2 node: one closed-loop ride against a running\n"
                    "emulator, then exit.  Parameters: groups 'quarter_car', 'simulation',\n"
                    "'road', 'ride' (defaults: config/quarter_car.yaml) and the damper's\n"
                    "'damper'/'numerics' (config/sport.yaml), set with\n"
                    "  --ros-args --params-file FILE [-p ride.clock:=lockstep] ...")
    ride_node.set_defaults(handler=run, takes_ros_args=True)


def run(args: argparse.Namespace) -> int:
    from damper_emulator.ros.common import spin_node
    from ride_sim.node import RideNode

    return spin_node(RideNode, args.ros_args)
