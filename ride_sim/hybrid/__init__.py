"""A physical damper in the loop (``damper-hil hybrid``): the cores, free of CAN and ROS.

* :mod:`.params`: the parameter groups (actuator, virtual rig, safety, compensator);
* :mod:`.actuator`: the transfer system, a transport delay and a second-order servo;
* :mod:`.rig`: the virtual dyno's physics (actuator, specimen damper, sensor noise);
* :mod:`.safety`: limits, the feedback watchdog and the instability detector;
* :mod:`.transfer`: the excitation, the identification and the online tracker of the
  transfer system;
* :mod:`.compensator`: the model-based compensation and its loop-gain margin;
* :mod:`.rig_host`, :mod:`.host`, :mod:`.protocol_host`: the host's phases, the ride, the
  dyno protocols;
* :mod:`.criteria`, :mod:`.recorder`, :mod:`.offline`: tracking criteria, the record, the
  loop on a simulated timeline.

The CAN shells (:mod:`can_bridge.virtual_rig`) and the command line sit on top.
"""
