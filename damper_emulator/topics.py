"""Topic names, message types and QoS depths of the project's ROS 2 interface
(docs/interfaces.md §5).  Plain names and numbers, no rclpy: the bag tools
(:mod:`damper_emulator.recording`, :mod:`damper_emulator.replay`, the hybrid record) use
them without ROS."""

from __future__ import annotations

STATE = "/damper/state"                 # sensor_msgs/JointState, into the emulator
FORCE = "/damper/force"                 # sensor_msgs/JointState, out of the emulator
VALVE_COMMAND = "/damper/valve_command"  # std_msgs/Float64, 0 softest .. 1 firmest
DIAGNOSTICS = "/diagnostics"            # diagnostic_msgs/DiagnosticArray
RIDE_STATE = "/ride/state"              # sensor_msgs/JointState: wheel, body, road (ride node)
HYBRID_LOOP = "/hybrid/loop"            # sensor_msgs/JointState: target, command, twin (hybrid)

#: topic → ROS 2 message type, for the recorder and the bag readers
TYPES = {
    STATE: "sensor_msgs/msg/JointState",
    FORCE: "sensor_msgs/msg/JointState",
    VALVE_COMMAND: "std_msgs/msg/Float64",
    DIAGNOSTICS: "diagnostic_msgs/msg/DiagnosticArray",
    RIDE_STATE: "sensor_msgs/msg/JointState",
}

#: Depth of the control topics' subscriptions (volatile, keep-last): 0.1 s at 1 kHz; a
#: controller that falls behind wants the latest samples, not a backlog.  A loop on its own
#: clock (the timer-triggered emulator, the realtime ride, the bridge, the live view) takes
#: them best effort: a reliable reader that loses a sample (its middleware thread starved
#: on a busy machine) delivers nothing after it until the writer's next heartbeat repairs
#: it, seconds later, where best effort goes on with the next sample.  Inputs that must see
#: every sample (the input-triggered emulator, the lockstep ride, the recorder) stay
#: reliable.  Publishers are always reliable, so that both kinds match.
CONTROL_DEPTH = 100
#: Depth of the control topics' publishers' histories: 5 s at 1 kHz.  A reliable writer
#: drops a sample a slow reader has not acknowledged once its history is full, so this is
#: how long the recorder (the lowest real-time priority, so the first a busy machine
#: holds back) may fall behind without losing a message.  A reader with a shorter queue
#: (every controller) acknowledges what it has replaced, and costs the history nothing.
PUBLISHER_DEPTH = 5000
#: How long a publisher that goes away (the ride at its end, a managed node shutting down)
#: waits for every subscriber to acknowledge its history [s]: twice the history's span, so
#: that a recorder running behind takes the last messages before they go with the
#: publisher.  An up-to-date subscriber acknowledges within milliseconds.
ACK_TIMEOUT_S = 10.0
#: Depth of the recorder's subscriptions: 20 s at 1 kHz.  Its middleware thread takes
#: every message off the publishers' histories as it arrives; this queue holds them while
#: its Python thread, starved on a busy machine, catches up.
RECORDER_DEPTH = 20000

