"""Emulator + CAN bridge for a damper dyno (issue 18): the dyno sends ``DAMPER_STATE`` on
the bus and receives ``DAMPER_FORCE``.

    ros2 launch damper_hil dyno.launch.py [damper_params:=my_damper.yaml]
        [emulator_params:=...] [bridge_params:=...] [can_interface:=socketcan]
        [can_channel:=vcan0]

Both nodes are managed (lifecycle) nodes that configure and activate themselves
(``autostart``); the bridge runs in ``dyno`` mode and waits for the emulator's ``active``.
"""

from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import LifecycleNode
from launch_ros.substitutions import FindPackageShare

from launch import LaunchDescription

PACKAGE = "damper_hil"


def _config(name: str) -> PathJoinSubstitution:
    return PathJoinSubstitution([FindPackageShare(PACKAGE), "config", name])


def generate_launch_description() -> LaunchDescription:
    args = {
        "damper_params": (_config("sport.yaml"), "the damper (a params file with 'damper')"),
        "emulator_params": (_config("emulator.yaml"), "the emulator node's parameters"),
        "bridge_params": (_config("bridge.yaml"), "the CAN bridge node's parameters"),
        "can_interface": ("socketcan", "python-can interface of the dyno's bus"),
        "can_channel": ("vcan0", "its channel"),
    }
    cfg = {name: LaunchConfiguration(name) for name in args}
    return LaunchDescription([
        *(DeclareLaunchArgument(name, default_value=default, description=doc)
          for name, (default, doc) in args.items()),
        LifecycleNode(package=PACKAGE, executable="emulator", name="damper_emulator",
                      namespace="", output="screen",
                      parameters=[cfg["damper_params"], cfg["emulator_params"]]),
        LifecycleNode(package=PACKAGE, executable="bridge", name="can_bridge", namespace="",
                      output="screen",
                      parameters=[cfg["bridge_params"], {
                          "mode": "dyno", "can_interface": cfg["can_interface"],
                          "can_channel": cfg["can_channel"]}]),
    ])
