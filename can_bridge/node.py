"""The ``can_bridge`` node (``damper-hil bridge``): an rclpy shell around
:class:`~can_bridge.core.BridgeCore` and a :class:`~can_bridge.bus.ResilientBus`.

A receive thread takes every frame from the bus as it arrives (``SCHED_FIFO`` when
permitted), publishes what it decodes and runs the watchdog at least every DBC cycle; an
input thread (SCHED_FIFO too) waits on ``/damper/force`` (and, in controller mode,
``/ride/state`` and ``/damper/state``) without an executor and turns each message into
frames.  The executor serves only the diagnostics timer and the parameter services.
Nothing is queued by the bridge: a frame that cannot be sent is counted and dropped, and a
failed bus is reopened with exponential backoff.
"""

from __future__ import annotations

import threading
import time

import can
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from can_bridge.bus import BusConfig, CanBusError, ResilientBus, open_bus
from can_bridge.core import BridgeCore
from can_bridge.dbc import load_database
from can_bridge.settings import (
    NODE_NAME,
    BridgeParams,
    bridge_params_from_mapping,
    default_bridge_mapping,
)
from damper_emulator.params import ParameterError
from damper_emulator.realtime.rt import RealtimeRequest, apply_realtime, set_thread_name
from damper_emulator.ros import topics
from damper_emulator.ros.common import (
    NotReadyError,
    SubscriptionThread,
    control_qos,
    declare_parameters,
    executor_priority,
    publish_diagnostics,
    set_stamp,
    wait_until_active,
)

#: A CAN timestamp further than this from the wall clock is not trusted as a stamp [s].
STAMP_TRUST_S = 1.0


def _frame_index(msg: JointState, name: str) -> int:
    return list(msg.name).index(name) if name in msg.name else -1


class BridgeNode(Node):
    """See the module docstring.  Parameters: config/bridge.yaml (no group)."""

    def __init__(self):
        super().__init__(NODE_NAME)
        defaults = default_bridge_mapping()
        values = declare_parameters(self, defaults, {"": BridgeParams})
        p = self.params = bridge_params_from_mapping(values, f"node {NODE_NAME} parameters")
        #: read by spin_node: the DDS threads' SCHED_FIFO priority (0: normal scheduling)
        self.dds_priority = p.dds_priority
        #: read by spin_node: the executor thread's SCHED_FIFO priority (0: normal)
        self.main_thread_priority = executor_priority(p.priority) if p.sched_fifo else 0
        db = load_database(p.dbc_file or None)
        self.core = BridgeCore(p, db)
        cfg = BusConfig(interface=p.can_interface, channel=p.can_channel, bitrate=p.bitrate,
                        receive_ids=self.core.receiver.frame_ids)
        try:
            open_bus(cfg).shutdown()     # a wrong interface or channel: one line, exit 2
        except CanBusError as exc:
            raise ParameterError(str(exc)) from None
        self.bus = ResilientBus(cfg, backoff_initial_s=p.backoff_initial_s,
                                backoff_max_s=p.backoff_max_s)
        self.exit_status = 0
        self._force_id = self.core.force_encoder.frame_id
        self._motion_id = self.core.motion_encoder.frame_id
        self._errors_seen = 0
        self._tx_failed = 0
        qos = control_qos(topics.CONTROL_DEPTH)
        inputs = [(JointState, topics.FORCE, self._on_force)]
        if p.mode == "dyno":
            self._state_pub = self.create_publisher(JointState, topics.STATE, qos)
        else:
            self._valve_pub = self.create_publisher(Float64, topics.VALVE_COMMAND, qos)
            self._damper_velocity = 0.0
            inputs += [(JointState, topics.STATE, self._on_damper_state),
                       (JointState, topics.RIDE_STATE, self._on_ride_state)]
        # the 1 kHz inputs on a thread of their own, without the executor
        self._ros_in = SubscriptionThread(self, inputs, qos, "ros-in", RealtimeRequest(
            sched_fifo=p.sched_fifo, priority=p.priority, lock_memory=False))
        self._diag_pub = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        self.create_timer(p.diagnostics_period_s, self._publish_diagnostics)
        self._stop = threading.Event()
        # DAMPER_FORCE frames come from two threads (forces: the input thread; fault frames:
        # the receive thread's watchdog) with one alive counter: encode and send them under one
        # lock, so that no two frames share a counter and they go out in counter order
        self._force_lock = threading.Lock()
        self._rx = threading.Thread(target=self._receive_loop, name="can-rx", daemon=True)
        self._rt_report = None
        self.get_logger().info(
            f"mode {p.mode} on {p.can_interface} channel {p.can_channel} "
            f"({p.bitrate} bit/s), database {p.dbc_file or 'config/damper.dbc'}")

    # ---- lifecycle --------------------------------------------------------------------

    def run(self, executor) -> None:
        self._rx.start()
        self._ros_in.start()
        p = self.params
        if p.emulator_node:
            # the frames flow meanwhile (fault frames with the no-force status until the
            # emulator's forces arrive); this only says what the bridge waits for
            try:
                waited = wait_until_active(self, p.emulator_node, p.wait_for_emulator_s,
                                           executor=executor)
                self.get_logger().info(f"/{p.emulator_node} is active (waited "
                                       f"{waited:.1f} s)")
            except NotReadyError as exc:
                self.get_logger().error(f"{exc}; sending DAMPER_FORCE fault frames until "
                                        f"forces arrive")
        executor.spin()

    def close(self) -> None:
        self._stop.set()
        self._ros_in.stop()
        if self._rx.is_alive():
            self._rx.join(2.0)
        self.bus.close()
        if self._ros_in.failed:
            self.exit_status = 1

    # ---- CAN → ROS --------------------------------------------------------------------

    def _receive_loop(self) -> None:
        set_thread_name("can-rx")
        p = self.params
        self._rt_report = apply_realtime(RealtimeRequest(
            sched_fifo=p.sched_fifo, priority=p.priority, lock_memory=False))
        if self._rt_report.refused:
            self.get_logger().warning(f"receive thread: {self._rt_report.summary()}")
        core = self.core
        try:
            while not self._stop.is_set():
                # wake for the next frame or the watchdog's next deadline
                msg = self.bus.recv(core.watchdog_wait_ns(time.monotonic_ns()) * 1e-9)
                now_ns = time.monotonic_ns()
                if msg is not None and not msg.is_error_frame:
                    out = core.on_frame(msg.arbitration_id, msg.data, now_ns)
                    if out is not None:
                        self._publish_inbound(out, msg.timestamp)
                errors = self.bus.rx_error_frames
                if errors != self._errors_seen:
                    self._errors_seen = errors
                    core.note_rx_errors()
                with self._force_lock:
                    frame, command = core.watchdog(now_ns)
                    if frame is not None:
                        self._send(self._force_id, frame)
                if command is not None:
                    self.get_logger().warning(
                        f"no VALVE_COMMAND for {p.command_timeout_s:g} s: fail-safe command "
                        f"{command:g}")
                    self._valve_pub.publish(Float64(data=float(command)))
        except Exception as exc:  # noqa: BLE001 - reported, then the node stops
            self.get_logger().error(f"receive thread stopped: {exc!r}")
            self.exit_status = 1
            rclpy.try_shutdown()

    def _publish_inbound(self, out, can_stamp_s: float) -> None:
        if out[0] == "state":
            _, x, v = out
            msg = JointState()
            now = time.time_ns()
            stamp = int(can_stamp_s * 1e9) if can_stamp_s and \
                abs(can_stamp_s * 1e9 - now) < STAMP_TRUST_S * 1e9 else now
            set_stamp(msg.header.stamp, stamp)
            msg.name = [self.params.damper_name]
            msg.position = [x]
            msg.velocity = [v]
            self._state_pub.publish(msg)
        else:
            self._valve_pub.publish(Float64(data=float(out[1])))

    # ---- ROS → CAN --------------------------------------------------------------------

    def _send(self, frame_id: int, data: bytes) -> None:
        if not self.bus.send(can.Message(arbitration_id=frame_id, data=data,
                                         is_extended_id=False)):
            self._tx_failed += 1

    def _on_force(self, msg: JointState) -> None:
        name = self.params.damper_name
        i = max(_frame_index(msg, name), 0)
        if len(msg.effort) <= i:
            return
        s = _frame_index(msg, f"{name}/status")
        status = int(msg.effort[s]) if s >= 0 and len(msg.effort) > s else 0
        age = float(msg.position[s]) if s >= 0 and len(msg.position) > s else float("nan")
        stroke = float(msg.position[i]) if len(msg.position) > i else float("nan")
        with self._force_lock:
            frame = self.core.force_frame(float(msg.effort[i]), status & 0x0F, age, stroke,
                                          time.monotonic_ns())
            self._send(self._force_id, frame)

    def _on_damper_state(self, msg: JointState) -> None:
        i = max(_frame_index(msg, self.params.damper_name), 0)
        if len(msg.velocity) > i:
            self._damper_velocity = float(msg.velocity[i])

    def _on_ride_state(self, msg: JointState) -> None:
        w, b = _frame_index(msg, "wheel"), _frame_index(msg, "body")
        if w < 0 or b < 0 or len(msg.velocity) <= max(w, b):
            return
        frame = self.core.motion_frame(float(msg.velocity[b]), float(msg.velocity[w]),
                                       self._damper_velocity, time.monotonic_ns())
        if frame is not None:
            self._send(self._motion_id, frame)

    # ---- diagnostics ------------------------------------------------------------------

    def _publish_diagnostics(self) -> None:
        c, d, bus = self.core.counters, self.core.receiver.drops, self.bus
        values = {
            "mode": self.params.mode,
            "interface": f"{self.params.can_interface} {self.params.can_channel}",
            "bus_state": bus.state,
            "bus_reopens": str(bus.reopen_count),
            "bus_last_error": bus.last_error or "",
            "rx_error_frames": str(bus.rx_error_frames),
            "tx_failed": str(self._tx_failed),
            "frames_accepted": str(d.accepted),
            "dropped_length": str(d.length),
            "dropped_checksum": str(d.checksum),
            "dropped_counter": str(d.counter),
            "lost_frames": str(d.lost),
            # no count of other identifiers: the bus filter (receive_ids) drops those
            # frames before the receiver sees them (in the kernel on socketcan)
            "states_in": str(c.states_in),
            "commands_in": str(c.commands_in),
            "forces_out": str(c.forces_out),
            "fault_frames_out": str(c.fault_frames_out),
            "motion_out": str(c.motion_out),
            "state_timeouts": str(c.state_timeouts),
            "force_timeouts": str(c.force_timeouts),
            "command_timeouts": str(c.command_timeouts),
            "saturated_forces": str(c.saturated),
            "valve_command": "" if self.core.command is None else f"{self.core.command:g}",
            "realtime": self._rt_report.summary() if self._rt_report else "",
        }
        level, message = DiagnosticStatus.OK, "ok"
        if d.dropped or d.lost:
            level, message = DiagnosticStatus.WARN, "frames dropped or lost"
        if self.core.fault_active:
            level, message = DiagnosticStatus.ERROR, self.core.fault_text
        if not bus.is_up:
            level, message = DiagnosticStatus.ERROR, f"bus down: {bus.last_error}"
        publish_diagnostics(self, self._diag_pub, f"{NODE_NAME}: {self.params.mode}", level,
                            message, self.params.can_channel, values)
