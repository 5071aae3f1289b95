"""The ``live_view`` node (``damper-hil live``): ``/damper/force``, ``/ride/state`` and
``/diagnostics`` to the Foxglove live view (:mod:`damper_emulator.ros.live`).

The 1 kHz topics are not delivered through rclpy's executor (about 0.4 ms of Python per
message: with two 1 kHz topics most of a core, taken from the real-time loops on a small
machine): their subscriptions sit on a second node that no executor spins, and a timer
takes what has arrived, ``flush_rate_hz`` times a second.
"""

from __future__ import annotations

import math
import time

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from sensor_msgs.msg import JointState

from damper_emulator import force_message, topics
from damper_emulator.realtime.rt import RealtimeRequest, apply_realtime
from damper_emulator.ros.common import JointStateIn, control_qos, log_info, take_all
from damper_emulator.ros.live import LIVE_PRIORITY, LiveServer
from ride_sim.iso2631 import WeightingFilter
from ride_sim.params import RideConfig

NODE_NAME = "live_view"
#: the second node, which holds the 1 kHz subscriptions (the demo waits for it to subscribe)
INPUT_NODE_NAME = f"{NODE_NAME}_input"
#: how often the arrived messages are taken and sent [Hz]
FLUSH_RATE_HZ = 50.0
#: queue depth of the 1 kHz subscriptions: a second of messages.  On a busy 2-core machine
#: the view at normal priority (``--priority 0``) waits behind two SCHED_FIFO 1 kHz loops,
#: and its flushes came up to 1.5 s apart: a queue of one flush period lost the
#: samples between two flushes
QUEUE_DEPTH = 1000
#: the emulator's diagnostic status (its name's prefix)
EMULATOR_STATUS = "damper_emulator"


class RunningRms:
    """r.m.s. of a stream, from its sum of squares."""

    def __init__(self) -> None:
        self.n = 0
        self.sum_sq = 0.0

    def add(self, x: np.ndarray) -> None:
        self.n += x.size
        self.sum_sq += float(np.dot(x, x))

    @property
    def value(self) -> float:
        return math.sqrt(self.sum_sq / self.n) if self.n else 0.0


class LiveNode(Node):
    """See the module docstring; ``decimation``: every how many-th force is sent;
    ``priority``: SCHED_FIFO priority of the view's threads (0: normal scheduling)."""

    def __init__(self, port: int, decimation: int, ride: RideConfig,
                 priority: int = LIVE_PRIORITY):
        super().__init__(NODE_NAME)
        #: read by spin_node: the DDS threads' SCHED_FIFO priority (0: normal).  The
        #: executor (this) thread gets it here, not through spin_node's
        #: ``main_thread_priority``: now, so that the WebSocket server's threads, started
        #: next, inherit it
        self.dds_priority = max(0, int(priority))
        if self.dds_priority:
            report = apply_realtime(RealtimeRequest(sched_fifo=True, priority=priority,
                                                    lock_memory=False))
            log_info(self, f"view threads: {report.summary()}")
        self.view = LiveServer(port)
        self.decimation = max(1, int(decimation))
        self.sprung_mass_kg = ride.quarter_car.sprung_mass_kg
        self._wk = WeightingFilter("Wk", 1.0 / ride.simulation.step_s)
        self._rms = {k: RunningRms() for k in ("accel_w", "sws", "dtl")}
        self._forces = 0
        self._ride_samples = 0
        #: what the view did, logged when it stops: flushes, the longest time between two
        #: [s], messages sent per channel
        self._flushes = 0
        self._last_flush: float | None = None
        self._flush_gap_max_s = 0.0
        self._sent = {"/live/damper": 0, "/live/ride": 0}
        self._ride_step_s = ride.simulation.step_s
        #: ride samples per /live/ride message: FLUSH_RATE_HZ in ride time, so the stream's
        #: rate does not depend on how often this process gets the processor
        self._ride_chunk = max(1, round(1.0 / (FLUSH_RATE_HZ * ride.simulation.step_s)))
        self._io = rclpy.create_node(INPUT_NODE_NAME, context=self.context)
        # best effort, as CDR bytes (a view: what a busy machine drops is not waited for)
        qos = control_qos(QUEUE_DEPTH, reliable=False)
        self._force_sub = self._io.create_subscription(JointState, topics.FORCE,
                                                       lambda _m: None, qos, raw=True)
        self._ride_sub = self._io.create_subscription(JointState, topics.RIDE_STATE,
                                                      lambda _m: None, qos, raw=True)
        self._force_in, self._ride_in = JointStateIn(), JointStateIn()
        self.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, self._on_diagnostics, 10)
        self.create_timer(1.0 / FLUSH_RATE_HZ, self._flush)
        self.exit_status = 0
        self.get_logger().info(f"live view on ws://127.0.0.1:{self.view.port} (open it in "
                               "Foxglove or Lichtblick; layout config/foxglove_layout.json)")

    def _t(self) -> float:
        return time.monotonic() - self.view.started

    def _flush(self) -> None:
        t = self._t()
        self._flushes += 1
        if self._last_flush is not None:
            self._flush_gap_max_s = max(self._flush_gap_max_s, t - self._last_flush)
        self._last_flush = t
        for data, _info in take_all(self._force_sub):
            self._forces += 1
            if self._forces % self.decimation:
                continue
            msg = self._force_in.decode(data)
            if isinstance(msg, str) or not msg.effort:
                continue
            self.view.damper(float(msg.effort[0]), _first(msg.position), _first(msg.velocity),
                             force_message.status_of(msg.effort))
            self._sent["/live/damper"] += 1
        ride = [self._ride_in.decode(data) for data, _i in take_all(self._ride_sub)]
        rows = [(m.position[0] - m.position[1], m.effort[1] / self.sprung_mass_kg,
                 m.effort[0]) for m in ride
                if not isinstance(m, str) and len(m.position) >= 2 and len(m.effort) >= 2]
        if not rows:
            return
        sws, accel, dtl = (np.array(c, dtype=float) for c in zip(*rows))
        accel_w = self._wk.process(accel)
        # one message per _ride_chunk samples (the last piece may be shorter), each stamped
        # back from now by the ride time of the samples after it
        start = 0
        while start < len(rows):
            end = min(start + self._ride_chunk - self._ride_samples % self._ride_chunk,
                      len(rows))
            self._rms["accel_w"].add(accel_w[start:end])
            self._rms["sws"].add(sws[start:end])
            self._rms["dtl"].add(dtl[start:end])
            self._ride_samples += end - start
            self.view.log("/live/ride", {
                "t": t - (len(rows) - end) * self._ride_step_s, "sws_m": float(sws[end - 1]),
                "body_accel_m_s2": float(accel[end - 1]), "dtl_n": float(dtl[end - 1]),
                "accel_w_rms_m_s2": self._rms["accel_w"].value,
                "sws_rms_m": self._rms["sws"].value, "dtl_rms_n": self._rms["dtl"].value,
                "samples": self._ride_samples})
            self._sent["/live/ride"] += 1
            start = end

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for s in msg.status:
            if s.name.startswith(EMULATOR_STATUS):
                self.view.loop({kv.key: kv.value for kv in s.values}, s.level, s.name,
                               s.message)

    def close(self) -> None:
        sent = ", ".join(f"{n} on {c}" for c, n in self._sent.items())
        log_info(
            self, f"sent {sent} ({self._ride_samples} ride samples, {self._forces} forces) in "
            f"{self._flushes} flushes, at most {self._flush_gap_max_s:.3f} s apart")
        self._io.destroy_node()
        self.view.stop()


def _first(values) -> float:
    return float(values[0]) if len(values) else math.nan
