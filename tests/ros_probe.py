"""A ROS 2 node of the test process, in its own context and domain (localhost only), for the
node tests to publish, subscribe and spin with."""

from __future__ import annotations

import os
import time
from pathlib import Path


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
