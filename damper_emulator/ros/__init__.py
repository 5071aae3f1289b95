"""ROS 2 (rclpy) shells: the ``damper_emulator`` node (:mod:`.emulator`), the bag recorder
(:mod:`.recorder`), the live view (:mod:`.live`), the hybrid run's status publisher
(:mod:`.status_publisher`), what the nodes share (:mod:`.common`, :mod:`.managed`) and the
process launcher of the closed-loop demo (:mod:`.launch`).  The quarter-car node is
:mod:`ride_sim.node`, the CAN bridge's :mod:`can_bridge.node`.

Only these shells and the nodes beside their cores (:mod:`ride_sim.node`,
:mod:`can_bridge.node`, :mod:`damper_hil.live_node`) import rclpy; the physics and the
real-time logic they wrap live in :mod:`damper_emulator.model`,
:mod:`damper_emulator.realtime` and :mod:`ride_sim`.
Topics and message types: ``docs/interfaces.md`` §5 and :mod:`damper_emulator.topics`.
"""
