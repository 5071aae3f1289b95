"""The closed-loop demo as a ROS 2 launch (``damper-hil demo`` without its
report): the emulator and the CAN bridge in controller mode (``emulator_bridge.launch.py``),
the quarter car on the minor road, the skyhook controller on the bus and the MCAP recorder.

    ros2 launch damper_hil closed_loop.launch.py [damper_params:=...]
        [emulator_params:=...] [bridge_params:=...] [ride_params:=...]
        [skyhook_params:=...] [can_interface:=socketcan] [can_channel:=vcan0]
        [bag:=closed_loop_bag]

The ride node waits for the emulator's ``active`` before it starts its clock, and stops
after ``ride.duration_s``; stop the rest with Ctrl-C (the recorder closes the bag).
"""

from launch.actions import DeclareLaunchArgument, ExecuteProcess, IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

from launch import LaunchDescription

PACKAGE = "damper_hil"


def generate_launch_description() -> LaunchDescription:
    share = FindPackageShare(PACKAGE)
    args = {
        "damper_params": (PathJoinSubstitution([share, "config", "sport.yaml"]),
                          "the damper (a params file with 'damper')"),
        "ride_params": (PathJoinSubstitution([share, "config", "quarter_car.yaml"]),
                        "the quarter car, road and ride run"),
        "skyhook_params": (PathJoinSubstitution([share, "config", "skyhook.yaml"]),
                           "the skyhook controller's parameters"),
        "can_interface": ("socketcan", "python-can interface of the controller's bus"),
        "can_channel": ("vcan0", "its channel"),
        "bag": ("closed_loop_bag", "the bag the recorder writes"),
    }
    cfg = {name: LaunchConfiguration(name) for name in args}
    pair = PathJoinSubstitution([share, "launch", "emulator_bridge.launch.py"])
    return LaunchDescription([
        *(DeclareLaunchArgument(name, default_value=default, description=doc)
          for name, (default, doc) in args.items()),
        IncludeLaunchDescription(PythonLaunchDescriptionSource(pair), launch_arguments={
            "mode": "controller", "damper_params": cfg["damper_params"],
            "can_interface": cfg["can_interface"],
            "can_channel": cfg["can_channel"]}.items()),
        Node(package=PACKAGE, executable="ride", output="screen",
             parameters=[cfg["damper_params"], cfg["ride_params"]]),
        ExecuteProcess(cmd=["damper-hil", "skyhook", "--params", cfg["skyhook_params"],
                            "--damper-params", cfg["damper_params"],
                            "--can-interface", cfg["can_interface"],
                            "--can-channel", cfg["can_channel"]], output="screen"),
        Node(package=PACKAGE, executable="record", output="screen",
             arguments=["--out", cfg["bag"]]),
    ])
