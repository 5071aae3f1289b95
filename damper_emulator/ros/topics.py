"""Topic names, message types and QoS of the project's ROS 2 interface (docs/interfaces.md)."""

from __future__ import annotations

STATE = "/damper/state"                 # sensor_msgs/JointState, into the emulator
FORCE = "/damper/force"                 # sensor_msgs/JointState, out of the emulator
VALVE_COMMAND = "/damper/valve_command"  # std_msgs/Float64, 0 softest .. 1 firmest
DIAGNOSTICS = "/diagnostics"            # diagnostic_msgs/DiagnosticArray
RIDE_STATE = "/ride/state"              # sensor_msgs/JointState: wheel, body, road (ride node)

#: topic → ROS 2 message type, for the recorder and the bag readers
TYPES = {
    STATE: "sensor_msgs/msg/JointState",
    FORCE: "sensor_msgs/msg/JointState",
    VALVE_COMMAND: "std_msgs/msg/Float64",
    DIAGNOSTICS: "diagnostic_msgs/msg/DiagnosticArray",
    RIDE_STATE: "sensor_msgs/msg/JointState",
}

#: Depth of the control topics' keep-last queues (reliable, volatile): 0.1 s at 1 kHz, so
#: that a recorder that falls behind for a moment is served from the publisher's history.
CONTROL_DEPTH = 100
#: Depth of the recorder's subscriptions (absorbs bursts while it writes).
RECORDER_DEPTH = 1000


def message_classes() -> dict:
    """topic → message class (rclpy), for subscriptions."""
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64
    classes = {"sensor_msgs/msg/JointState": JointState, "std_msgs/msg/Float64": Float64,
               "diagnostic_msgs/msg/DiagnosticArray": DiagnosticArray}
    return {topic: classes[t] for topic, t in TYPES.items()}
