"""Emulator + CAN bridge, the pair every rig needs; ``dyno.launch.py``,
``controller.launch.py`` and ``closed_loop.launch.py`` include it.

    ros2 launch damper_hil emulator_bridge.launch.py mode:=dyno|controller [model:=true]
        [damper_params:=my_damper.yaml] [emulator_params:=...] [bridge_params:=...]
        [can_interface:=socketcan] [can_channel:=vcan0]

Both are managed (lifecycle) nodes that configure and activate themselves (``autostart``);
the bridge waits for the emulator's ``active``.  With ``model:=true`` (dyno mode) the
bridge steps the damper's model itself and no emulator node starts.
"""

from launch.actions import DeclareLaunchArgument
from launch.conditions import UnlessCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import LifecycleNode
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare

from launch import LaunchDescription

PACKAGE = "damper_hil"


def config(name: str) -> PathJoinSubstitution:
    """A file of the installed package's ``config/``."""
    return PathJoinSubstitution([FindPackageShare(PACKAGE), "config", name])


#: the arguments: name → (default, description)
ARGUMENTS = {
    "mode": ("dyno", "dyno (DAMPER_STATE in, DAMPER_FORCE out) or controller (an ECU on "
                     "the bus: VALVE_COMMAND in, VEHICLE_MOTION and DAMPER_FORCE out)"),
    "model": ("false", "dyno mode: the bridge steps the damper's model itself and answers "
                       "each DAMPER_STATE at once (no emulator node)"),
    "damper_params": (config("sport.yaml"), "the damper (a params file with 'damper')"),
    "emulator_params": (config("emulator.yaml"), "the emulator node's parameters"),
    "bridge_params": (config("bridge.yaml"), "the CAN bridge node's parameters"),
    "can_interface": ("socketcan", "python-can interface of the bus"),
    "can_channel": ("vcan0", "its channel"),
}


def generate_launch_description() -> LaunchDescription:
    cfg = {name: LaunchConfiguration(name) for name in ARGUMENTS}
    return LaunchDescription([
        *(DeclareLaunchArgument(name, default_value=default, description=doc)
          for name, (default, doc) in ARGUMENTS.items()),
        LifecycleNode(package=PACKAGE, executable="emulator", name="damper_emulator",
                      namespace="", output="screen",
                      parameters=[cfg["damper_params"], cfg["emulator_params"]],
                      condition=UnlessCondition(cfg["model"])),
        # the damper's and the emulator's files too: the bridge reads them with model:=true
        LifecycleNode(package=PACKAGE, executable="bridge", name="can_bridge", namespace="",
                      output="screen",
                      parameters=[cfg["damper_params"], cfg["emulator_params"],
                                  cfg["bridge_params"], {
                          "mode": cfg["mode"], "can_interface": cfg["can_interface"],
                          "can_channel": cfg["can_channel"],
                          "model": ParameterValue(cfg["model"], value_type=bool)}]),
    ])
