"""``damper-hil bridge``."""

from __future__ import annotations

import argparse

from damper_hil.cli.common import PROG, Formatter
from damper_hil.cli.virtual_rig import add_can_log_option


def add_parser(sub) -> None:
    bridge = sub.add_parser(
        "bridge", formatter_class=Formatter,
        help="run the can_bridge ROS 2 node (CAN frames of config/damper.dbc <-> topics)",
        description="Run the can_bridge ROS 2 node until SIGINT/SIGTERM.\n\n"
                    "mode dyno: DAMPER_STATE frames -> /damper/state, /damper/force ->\n"
                    "DAMPER_FORCE frames.  mode controller: VALVE_COMMAND frames ->\n"
                    "/damper/valve_command, /ride/state -> VEHICLE_MOTION frames,\n"
                    "/damper/force -> DAMPER_FORCE frames (status).  Frames with a wrong\n"
                    "length, checksum or counter are dropped and counted; silence puts a\n"
                    "fault status into DAMPER_FORCE and /diagnostics; a failed bus is\n"
                    "reopened with backoff.  Parameters (no group; defaults:\n"
                    "config/bridge.yaml): can_interface, can_channel, bitrate, mode, ...",
        epilog="examples:\n"
               f"  {PROG} bridge --ros-args -p can_interface:=socketcan -p can_channel:=vcan0\n"
               f"  {PROG} bridge --ros-args -p can_interface:=udp_multicast "
               "-p \"can_channel:='[ff11::d4:1]:43000'\" -p mode:=controller\n"
               f"  {PROG} bridge --can-log bridge_run.blf --ros-args -p "
               "can_interface:=udp_multicast -p \"can_channel:='[ff11::d4:1]:43000'\"\n"
               "(a channel with a port needs the inner YAML quotes)")
    add_can_log_option(bridge)
    bridge.set_defaults(handler=run, takes_ros_args=True)


def run(args: argparse.Namespace) -> int:
    from can_bridge.node import BridgeNode
    from damper_emulator.ros.common import spin_node

    ros_args = list(args.ros_args)
    if args.can_log is not None:   # the node's parameter can_log, as a YAML string
        quoted = str(args.can_log).replace("'", "''")
        ros_args += ["-p", f"can_log:='{quoted}'"]
    return spin_node(BridgeNode, ros_args)
