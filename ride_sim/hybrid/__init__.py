"""A physical damper in the loop (``damper-hil hybrid``): the cores, free of CAN and ROS.

* :mod:`.params`: the parameter groups (actuator, virtual rig, safety, compensator);
* :mod:`.actuator`: the transfer system, a transport delay and a second-order servo;
* :mod:`.rig`: the virtual dyno's physics (actuator, specimen damper, sensor noise);
* :mod:`.safety`: limits, the feedback watchdog and the instability detector.

The CAN shells (:mod:`can_bridge.virtual_rig`) and the command line sit on top.
"""
