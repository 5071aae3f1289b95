"""The bag recorder (``damper-hil record``): every topic of the project's interface to a
rosbag2 bag with MCAP storage (:class:`damper_emulator.bag.BagWriter`), flushed every
0.25 s so that a SIGKILL loses at most 0.5 s and leaves a readable bag.  Stopped by SIGINT
or SIGTERM, it first takes every message still queued, so that a recorder running behind
(it has the lowest real-time priority: a busy machine holds it back first) loses nothing.

Messages are recorded as the serialized CDR they arrived in (``raw`` subscriptions), with
the reception time as the bag timestamp (as rosbag2 does).  A topic enters the bag with its
first message, with the QoS its publisher offers (``offered_qos_profiles``).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

from rclpy.duration import Duration
from rclpy.node import Node

from damper_emulator import topics
from damper_emulator.bag import BagWriter, Qos
from damper_emulator.bag.qos import INFINITE_NS
from damper_emulator.errors import UserError
from damper_emulator.realtime.rt import RealtimeRequest, apply_realtime
from damper_emulator.ros.common import (
    StopSignals,
    SubscriptionThread,
    control_qos,
    executor_priority,
    log_info,
)

NODE_NAME = "damper_hil_recorder"
#: SCHED_FIFO priority (when permitted) of the recorder's input and DDS threads: below the
#: emulator's loop and the bridge, above everything that runs normally, so that a busy
#: machine delays the recording rather than losing it.
RECORDER_PRIORITY = 50
#: SCHED_FIFO priority (when permitted) of the bag's flush thread: just below the input
#: thread.  Every Python thread of the process shares the GIL, and a flush thread at normal
#: priority that a busy machine preempts while it holds the GIL stops the input thread too.
FLUSH_PRIORITY = RECORDER_PRIORITY - 2


def _ns(duration: Duration) -> int:
    ns = int(duration.nanoseconds)
    return INFINITE_NS if ns <= 0 or ns >= INFINITE_NS else ns


def offered_qos(profile) -> Qos:
    """An rclpy ``QoSProfile`` as the bag's :class:`~damper_emulator.bag.Qos` (RMW's
    "default" durations, 0, are infinite)."""
    def name(policy, default: str) -> str:
        text = policy.name.lower()
        return text if text != "unknown" else default
    return Qos(reliability=name(profile.reliability, "reliable"),
               durability=name(profile.durability, "volatile"),
               history=name(profile.history, "keep_last"), depth=int(profile.depth),
               deadline_ns=_ns(profile.deadline), lifespan_ns=_ns(profile.lifespan),
               liveliness=name(profile.liveliness, "automatic"),
               liveliness_lease_duration_ns=_ns(profile.liveliness_lease_duration),
               avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions))


class RecorderNode(Node):
    """Record ``record_topics`` (default: all of :data:`topics.TYPES`) into ``bag_path``."""

    def __init__(self, bag_path: str | Path, record_topics: Sequence[str] | None = None,
                 flush_period_s: float = 0.25):
        super().__init__(NODE_NAME)
        names = list(record_topics or topics.TYPES)
        unknown = [t for t in names if t not in topics.TYPES]
        if unknown:
            raise UserError(f"cannot record {unknown[0]}: known topics are "
                             f"{', '.join(topics.TYPES)}")
        self.writer = BagWriter(bag_path, flush_period_s=flush_period_s,
                                custom_data={"recorded_by": "damper-hil record"},
                                flush_thread_setup=lambda: apply_realtime(RealtimeRequest(
                                    sched_fifo=True, priority=FLUSH_PRIORITY,
                                    lock_memory=False, cpu_dma_latency_us=-1)))
        self.exit_status = 0
        self._handles: dict[str, object] = {}
        self.counts = {t: 0 for t in names}
        classes = _message_classes()
        # taken on a thread of its own without the executor (about 0.4 ms of Python per
        # message through it: at the 3 kHz of the demo's topics, more than a core)
        self._input = SubscriptionThread(
            self, [(classes[name], name, self._callback(name)) for name in names],
            control_qos(topics.RECORDER_DEPTH), "recorder-in",
            RealtimeRequest(sched_fifo=True, priority=RECORDER_PRIORITY, lock_memory=False,
                            cpu_dma_latency_us=-1), raw=True)
        #: read by spin_node: the DDS threads' SCHED_FIFO priority
        self.dds_priority = RECORDER_PRIORITY
        #: read by spin_node: the executor thread's SCHED_FIFO priority (0: normal)
        self.main_thread_priority = executor_priority(RECORDER_PRIORITY)
        self.get_logger().info(f"recording {', '.join(names)} to {bag_path}")

    #: Read by :func:`~damper_emulator.ros.common.spin_node`: SIGINT and SIGTERM end
    #: :meth:`run` (rclpy's handler would shut the context down first, and the messages
    #: still queued could not be taken any more).
    OWN_SIGNALS = True

    def run(self, executor) -> None:
        signals = StopSignals()
        self._input.start()
        signals.spin(executor, self.context)

    def _callback(self, name: str):
        writer = self.writer

        def record(data: bytes) -> None:
            now = time.time_ns()
            handle = self._handles.get(name)
            if handle is None:
                handle = self._handles[name] = writer.add_topic(
                    name, topics.TYPES[name], qos=self._offered(name))
            writer.write(handle, now, data)
            self.counts[name] += 1
        return record

    def _offered(self, name: str) -> Qos:
        infos = self._input.io_node.get_publishers_info_by_topic(name)
        return offered_qos(infos[0].qos_profile) if infos else Qos()

    def close(self) -> None:
        # every message the middleware holds has been acknowledged to its publisher, which
        # may be gone: take them all before the bag is closed
        self._input.stop(drain=True)
        if self._input.failed:
            self.exit_status = 1
        self.writer.close()
        log_info(self, "bag closed: " + ", ".join(f"{t} {n}" for t, n in self.counts.items()))


def _message_classes() -> dict:
    """topic → message class (rclpy), for subscriptions."""
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64
    classes = {"sensor_msgs/msg/JointState": JointState, "std_msgs/msg/Float64": Float64,
               "diagnostic_msgs/msg/DiagnosticArray": DiagnosticArray}
    return {topic: classes[t] for topic, t in topics.TYPES.items()}
