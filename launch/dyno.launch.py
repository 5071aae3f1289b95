"""Emulator + CAN bridge for a damper dyno: the dyno sends ``DAMPER_STATE`` on the bus and
receives ``DAMPER_FORCE``: ``emulator_bridge.launch.py`` with
``mode:=dyno``.

    ros2 launch damper_hil dyno.launch.py [damper_params:=...] [emulator_params:=...]
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
        PythonLaunchDescriptionSource(pair), launch_arguments={"mode": "dyno"}.items())])
