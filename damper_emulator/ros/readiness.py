"""Readiness: waiting for a managed node to become active, from its lifecycle state topic
or service, with a report of what is awaited."""

from __future__ import annotations

import time
from collections.abc import Callable

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from damper_emulator.errors import DamperHilError

#: How often a waiting node says again what it is waiting for [s].
WAIT_REPORT_PERIOD_S = 5.0
#: Longest single spin of a waiting node [s].
WAIT_SPIN_S = 0.1
#: The lifecycle state a managed node is ready in.
ACTIVE = "active"
#: A managed node of this project publishes its lifecycle state on ``/<node>/<this>``
#: (``lifecycle_msgs/msg/State``, reliable, transient local, depth 1: latched).
LIFECYCLE_STATE_TOPIC = "lifecycle_state"


def latched_qos() -> QoSProfile:
    """Reliable, transient local, keep-last 1: a late subscriber gets the latest message."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def lifecycle_state_topic(node_name: str) -> str:
    """``/<node_name>/lifecycle_state``: where the managed node publishes its state."""
    return f"/{node_name.strip('/')}/{LIFECYCLE_STATE_TOPIC}"


class NotReadyError(DamperHilError, RuntimeError):
    """A managed node did not become active in time (one line, naming the node and the
    state last seen)."""


def wait_until_active(node: Node, target: str, timeout_s: float,
                      say: Callable[[str], None] | None = None, executor=None,
                      stop: Callable[[], bool] | None = None) -> float:
    """Wait until the managed node ``target`` (e.g. ``damper_emulator``) is in the
    lifecycle state ``active``: the project's readiness handshake (a node becomes active
    only once its compiled code is loaded and exercised and its loop runs).

    The state comes from the node's latched ``/<target>/lifecycle_state`` topic, not from
    its ``get_state`` service: an rclpy server holds the GIL while the middleware waits (up
    to 100 ms) for a new client's response reader to match, which stalls the server's
    real-time loop (measured: three 100 ms stalls at the demo's start); a latched topic
    costs the publisher nothing.

    ``say`` (default: ``node``'s logger) hears what is being waited for, at once and then
    every :data:`WAIT_REPORT_PERIOD_S`.  ``executor`` spins ``node`` meanwhile (default: a
    private one).  ``stop`` (optional) ends the wait early when it returns true (a
    :class:`NotReadyError` saying so).  Returns the seconds waited; raises
    :class:`NotReadyError` after ``timeout_s``.
    """
    from lifecycle_msgs.msg import State

    say = say or node.get_logger().info
    topic = lifecycle_state_topic(target)
    seen: list[str] = []
    sub = node.create_subscription(State, topic, lambda m: seen.append(m.label),
                                   latched_qos())
    own = executor is None
    if own:
        executor = SingleThreadedExecutor(context=node.context)
        executor.add_node(node)
    start = time.monotonic()
    deadline = start + timeout_s
    next_report = start
    try:
        while not (seen and seen[-1] == ACTIVE):
            now = time.monotonic()
            last = (f"lifecycle state '{seen[-1]}'" if seen else
                    "no state yet (the node is not up, or is still loading)")
            if stop is not None and stop():
                raise NotReadyError(f"stopped while waiting for /{target.strip('/')} "
                                    f"(last seen: {last})")
            if now >= deadline or not node.context.ok():
                raise NotReadyError(f"/{target.strip('/')} did not become active within "
                                    f"{timeout_s:g} s (last seen: {last}; on {topic})")
            if now >= next_report:
                say(f"waiting for /{target.strip('/')} to become active: {last}")
                next_report = now + WAIT_REPORT_PERIOD_S
            executor.spin_once(timeout_sec=min(WAIT_SPIN_S, max(0.0, deadline - now)))
        return time.monotonic() - start
    finally:
        node.destroy_subscription(sub)
        if own:
            executor.remove_node(node)
            executor.shutdown()


class ReadinessProbe:
    """A node of its own (own context, ``domain_id``, localhost-only discovery) for a
    process that is not a node itself, e.g. the demo, to ask whether a managed node is
    active: :meth:`wait` is :func:`wait_until_active`.  Use as a context manager."""

    def __init__(self, domain_id: int, name: str = "readiness_probe"):
        import os

        from rclpy.context import Context
        from rclpy.signals import SignalHandlerOptions

        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        self.context = Context()
        # the process keeps its own signals: rclpy's handlers would replace them and
        # swallow SIGTERM (the demo rode on after a kill, its nodes left running)
        rclpy.init(context=self.context, domain_id=int(domain_id),
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(name, context=self.context)

    def wait(self, target: str, timeout_s: float,
             say: Callable[[str], None] | None = None) -> float:
        return wait_until_active(self.node, target, timeout_s, say)

    def close(self) -> None:
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)

    def __enter__(self) -> ReadinessProbe:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
