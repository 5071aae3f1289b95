"""The CAN bridge for a damper dyno, stepping the damper's model itself: the dyno sends
``DAMPER_STATE`` on the bus and receives each ``DAMPER_FORCE`` within its cycle
(``emulator_bridge.launch.py`` with ``mode:=dyno model:=true``; ``/damper/state`` and
``/damper/force`` are published for observation and recording).

    ros2 launch damper_hil dyno.launch.py [damper_params:=...] [emulator_params:=...]
        [bridge_params:=...] [can_interface:=socketcan] [can_channel:=vcan0]

The emulator node behind the bridge instead (its own 1 kHz clock):
``emulator_bridge.launch.py mode:=dyno``.
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
        PythonLaunchDescriptionSource(pair),
        launch_arguments={"mode": "dyno", "model": "true"}.items())])
