"""The closed-loop demo as a ROS 2 launch (issue 18; ``damper-hil demo`` without its
report): the emulator, the quarter car on the minor road, the CAN bridge in controller
mode, the skyhook controller on the bus and the MCAP recorder.

    ros2 launch damper_hil closed_loop.launch.py [damper_params:=...]
        [emulator_params:=...] [ride_params:=...] [bridge_params:=...]
        [skyhook_params:=...] [can_interface:=socketcan] [can_channel:=vcan0]
        [bag:=closed_loop_bag]

The ride node waits for the emulator's ``active`` before it starts its clock, and stops
after ``ride.duration_s``; stop the rest with Ctrl-C (the recorder closes the bag).
"""

from launch.actions import DeclareLaunchArgument, ExecuteProcess
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import LifecycleNode, Node
from launch_ros.substitutions import FindPackageShare

from launch import LaunchDescription

PACKAGE = "damper_hil"


def _config(name: str) -> PathJoinSubstitution:
    return PathJoinSubstitution([FindPackageShare(PACKAGE), "config", name])


def generate_launch_description() -> LaunchDescription:
    args = {
        "damper_params": (_config("sport.yaml"), "the damper (a params file with 'damper')"),
        "emulator_params": (_config("emulator.yaml"), "the emulator node's parameters"),
        "ride_params": (_config("quarter_car.yaml"), "the quarter car, road and ride run"),
        "bridge_params": (_config("bridge.yaml"), "the CAN bridge node's parameters"),
        "skyhook_params": (_config("skyhook.yaml"), "the skyhook controller's parameters"),
        "can_interface": ("socketcan", "python-can interface of the controller's bus"),
        "can_channel": ("vcan0", "its channel"),
        "bag": ("closed_loop_bag", "the bag the recorder writes"),
    }
    cfg = {name: LaunchConfiguration(name) for name in args}
    return LaunchDescription([
        *(DeclareLaunchArgument(name, default_value=default, description=doc)
          for name, (default, doc) in args.items()),
        LifecycleNode(package=PACKAGE, executable="emulator", name="damper_emulator",
                      namespace="", output="screen",
                      parameters=[cfg["damper_params"], cfg["emulator_params"]]),
        Node(package=PACKAGE, executable="ride", output="screen",
             parameters=[cfg["damper_params"], cfg["ride_params"]]),
        LifecycleNode(package=PACKAGE, executable="bridge", name="can_bridge", namespace="",
                      output="screen",
                      parameters=[cfg["bridge_params"], {
                          "mode": "controller", "can_interface": cfg["can_interface"],
                          "can_channel": cfg["can_channel"]}]),
        ExecuteProcess(cmd=["damper-hil", "skyhook", "--params", cfg["skyhook_params"],
                            "--damper-params", cfg["damper_params"],
                            "--can-interface", cfg["can_interface"],
                            "--can-channel", cfg["can_channel"]], output="screen"),
        Node(package=PACKAGE, executable="record", output="screen",
             arguments=["--out", cfg["bag"]]),
    ])
