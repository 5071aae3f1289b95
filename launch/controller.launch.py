"""Emulator + CAN bridge for an adaptive-damper controller test (issue 18): the controller
(an ECU, or ``damper-hil skyhook``) reads ``VEHICLE_MOTION`` and ``DAMPER_FORCE`` and sends
``VALVE_COMMAND`` on the bus; the damper's motion comes from ``/damper/state`` (the ride
node, a rig, a bag).

    ros2 launch damper_hil controller.launch.py [damper_params:=...]
        [emulator_params:=...] [bridge_params:=...] [can_interface:=socketcan]
        [can_channel:=vcan0]
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
        "can_interface": ("socketcan", "python-can interface of the controller's bus"),
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
                          "mode": "controller", "can_interface": cfg["can_interface"],
                          "can_channel": cfg["can_channel"]}]),
    ])
