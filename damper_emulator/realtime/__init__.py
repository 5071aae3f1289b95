"""Real-time side of the emulator, free of ROS: the per-sample emulator logic
(:mod:`.core`), the fixed-rate loop with absolute deadlines (:mod:`.loop`), operating-system
real-time settings (:mod:`.rt`) and the node parameters (:mod:`.settings`).

The ROS 2 nodes (:mod:`damper_emulator.ros`) and the offline replay
(:mod:`damper_emulator.replay`) are thin shells around these.
"""
