"""``/diagnostics`` from a process that is not a node: a publisher called from any thread.

:class:`StatusPublisher` opens a context and a node of its own (``ROS_DOMAIN_ID`` from the
environment, discovery as the environment says) and publishes one ``DiagnosticStatus``
per call to :meth:`StatusPublisher.publish`, without an executor: nothing spins, so no
thread of rclpy's competes with the caller's real-time loop.  ``damper-hil hybrid --ros``
publishes the twin's residual and the tracking through it once a second.
"""

from __future__ import annotations

from collections.abc import Mapping

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context

from damper_emulator import topics
from damper_emulator.ros.common import publish_diagnostics


class StatusPublisher:
    """A node ``node_name`` with a ``/diagnostics`` publisher.  Use as a context manager."""

    def __init__(self, node_name: str) -> None:
        from rclpy.signals import SignalHandlerOptions

        self.context = Context()
        # rclpy's handlers would replace the process's own: ``hybrid`` stops its run in
        # order on SIGINT and SIGTERM
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(node_name, context=self.context)
        self._pub = self.node.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)

    def publish(self, name: str, level: int, message: str, hardware_id: str,
                values: Mapping[str, str]) -> None:
        """One ``DiagnosticStatus`` stamped now (level 0 OK, 1 WARN, 2 ERROR)."""
        publish_diagnostics(self.node, self._pub, name, bytes([level]), message,
                            hardware_id, values)

    def close(self) -> None:
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)

    def __enter__(self) -> StatusPublisher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
