"""ROS 2 (rclpy) shells: the ``damper_emulator`` node (:mod:`.emulator`), the quarter-car
``ride_sim`` node (:mod:`.ride`), the bag recorder (:mod:`.recorder`) and the process
launcher of the closed-loop demo (:mod:`.launch`).

Only this package imports rclpy; the physics and the real-time logic they wrap live in
:mod:`damper_emulator.model`, :mod:`damper_emulator.realtime` and :mod:`ride_sim`.
Topics and message types: ``docs/interfaces.md`` §5 and :mod:`.topics`.
"""
