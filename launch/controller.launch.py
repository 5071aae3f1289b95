"""Emulator + CAN bridge for an adaptive-damper controller test: the controller (an
ECU, or ``damper-hil skyhook``) reads ``VEHICLE_MOTION`` and ``DAMPER_FORCE`` and sends
``VALVE_COMMAND``; the damper's motion comes from ``/damper/state`` (the ride node, a rig,
a bag): ``emulator_bridge.launch.py`` with
``mode:=controller``.

    ros2 launch damper_hil controller.launch.py [damper_params:=...] [emulator_params:=...]
        [bridge_params:=...] [can_interface:=socketcan] [can_channel:=vcan0]
"""

from launch.actions import IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import PathJoinSubstitution
from launch_ros.substitutions import FindPackageShare

from launch import LaunchDescription


def generate_launch_description() -> LaunchDescription:
    pair = PathJoinSubstitution([FindPackageShare("damper_hil"), "launch",
                                 "emulator_bridge.launch.py"])
    return LaunchDescription([IncludeLaunchDescription(
        PythonLaunchDescriptionSource(pair), launch_arguments={"mode": "controller"}.items())])
