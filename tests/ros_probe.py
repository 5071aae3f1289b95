"""A ROS 2 node of the test process, in its own context and domain (localhost only), for the
node tests to publish, subscribe and spin with."""

from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path

#: How long a sender waits for its subscriber to be matched [s].
DISCOVERY_S = 10.0


class Probe:
    """A node of the test process in its own context and domain."""

    def __init__(self, domain: int, name: str = "probe"):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        self._rclpy = rclpy
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(self, predicate, timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if predicate():
                return True
            self.executor.spin_once(timeout_sec=0.01)
        return predicate()

    def spin_for(self, seconds: float, step_s: float = 0.005) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=step_s)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self._rclpy.shutdown(context=self.context)


def cold_environment(root: Path, domain: int) -> dict:
    """The environment of a node started as a new user starts it: ROS domain ``domain``,
    localhost only, an empty ``NUMBA_CACHE_DIR`` under ``root`` (a first start)."""
    from damper_emulator.ros.launch import ros_environment

    env = ros_environment(domain)
    env["NUMBA_CACHE_DIR"] = str(root / "numba-cache")
    return env


def send_states_on_a_grid(domain: int, first_ns: int, period_ns: int, duration_s: float,
                          priority: int = 60) -> None:
    """A child process's sender of ``/damper/state`` (``multiprocessing`` spawn): one
    sample at each wall-clock instant ``first_ns + k·period_ns`` for ``duration_s``, from a
    thread under SCHED_FIFO at ``priority`` where permitted, in a process with no other
    Python (a sender in the test's own process shares the GIL with its probe's executor,
    and on a loaded machine came milliseconds late).  It starts once the subscriber is
    matched (at most ``DISCOVERY_S``), and where that is past ``first_ns`` (a loaded
    machine: the process's start and its discovery took seconds), at the next instant of
    the same grid: ``duration_s`` of samples, all on the grid, whenever it starts."""
    import math

    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    import rclpy
    from rclpy.context import Context
    from sensor_msgs.msg import JointState

    from damper_emulator import topics
    from damper_emulator.ros.common import control_qos

    with contextlib.suppress(PermissionError, OSError):
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    context = Context()
    rclpy.init(context=context, domain_id=domain)
    node = rclpy.create_node("grid_sender", context=context)
    pub = node.create_publisher(JointState, topics.STATE, control_qos(10))
    msg = JointState()
    msg.name = ["damper"]
    deadline = time.monotonic() + DISCOVERY_S
    while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
        time.sleep(0.01)
    late = time.time_ns() - first_ns
    if late > 0:
        first_ns += -(-late // period_ns) * period_ns
    end = first_ns + int(duration_s * 1e9)
    due, k = first_ns, 0
    while due < end:
        delay = due - time.time_ns()
        if delay > 0:
            time.sleep(delay * 1e-9)
        k += 1
        msg.position = [0.01 * math.sin(k * 2e-3)]
        msg.velocity = [0.02]
        pub.publish(msg)
        due += period_ns
    node.destroy_node()
    rclpy.shutdown(context=context)
