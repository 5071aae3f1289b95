"""The ``can_bridge`` node (``damper-hil bridge``): an rclpy shell around
:class:`~can_bridge.core.BridgeCore` and a :class:`~can_bridge.bus.ResilientBus`.

A receive thread takes every frame from the bus as it arrives (``SCHED_FIFO`` when
permitted), publishes what it decodes and runs the watchdog at least every DBC cycle; an
input thread (SCHED_FIFO too) waits on ``/damper/force`` (and, in controller mode,
``/ride/state`` and ``/damper/state``) without an executor and turns each message into
frames.  The executor serves only the diagnostics timer and the parameter services.

With ``model: true`` (dyno mode) there is no input thread and no emulator node: the
receive thread steps the damper's model itself (an
:class:`~damper_emulator.realtime.core.EmulatorCore` under ``trigger: input``, as the
emulator node's) on each ``DAMPER_STATE`` and sends its ``DAMPER_FORCE`` at once, then
publishes the state and the force on ``/damper/state`` and ``/damper/force`` for
observation and recording.  The force leaves within the dyno's cycle: no DDS hop and no
second process lie between the frame and its answer.
Nothing is queued by the bridge: a frame that cannot be sent is counted and dropped, and a
failed bus is reopened with exponential backoff.
"""

from __future__ import annotations

import threading
import time

import can
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from can_bridge.bus import BusConfig, CanBusError, ResilientBus, open_bus
from can_bridge.can_log import CanLog, CanLogError
from can_bridge.core import BridgeCore
from can_bridge.dbc import ForceStatus, load_database
from can_bridge.settings import (
    NODE_NAME,
    BridgeParams,
    bridge_params_from_mapping,
    default_bridge_mapping,
)
from damper_emulator import force_message, topics
from damper_emulator.bag.cdr_fast import JointStateSample
from damper_emulator.model.compressible import DamperModel
from damper_emulator.realtime.core import EmulatorCore, Output, Status
from damper_emulator.realtime.rt import RealtimeRequest, apply_realtime, set_thread_name
from damper_emulator.realtime.settings import EmulatorParams
from damper_emulator.ros.common import (
    JointStateIn,
    JointStateOut,
    SubscriptionThread,
    control_qos,
    executor_priority,
    publish_diagnostics,
)
from damper_emulator.ros.managed import ManagedNode
from damper_emulator.ros.parameters import declare_parameters
from damper_emulator.ros.readiness import NotReadyError, wait_until_active
from damper_emulator.schema import ParameterError

#: The emulator's status bits that DAMPER_FORCE.Status carries as they are (1..8).
EMULATOR_BITS = 0x0F
#: A CAN timestamp further than this from the wall clock is not trusted as a stamp [s].
STAMP_TRUST_S = 1.0


def _frame_index(msg: JointStateSample, name: str) -> int:
    return msg.name.index(name) if name in msg.name else -1


class BridgeNode(ManagedNode):
    """See the module docstring.  Parameters: config/bridge.yaml (no group) and
    ``autostart``.

    A managed (lifecycle) node.  Its parameters, the CAN database and the bus (opened once
    and closed again) are checked when it is created: a bad value is one line and exit 2.
    ``configure`` builds the bridge's core, the bus and the publishers; ``activate`` starts
    the receive and input threads; ``deactivate`` (and ``shutdown`` from active) stops
    them, then puts the outputs in their safe state: one ``DAMPER_FORCE`` fault frame
    (0 N, Status bit 32, as when the emulator falls silent) and, in controller mode, the
    fail-safe valve command on ``/damper/valve_command``, with the reason on
    ``/diagnostics``; ``cleanup`` closes the bus and releases the publishers.  The real-time
    settings are the threads' own and end with them.
    """

    def __init__(self):
        super().__init__(NODE_NAME)
        defaults = default_bridge_mapping()
        values = declare_parameters(self, defaults, {"": BridgeParams})
        p = self.params = bridge_params_from_mapping(values, f"node {NODE_NAME} parameters")
        #: ``model: true``: the damper and the emulator group's settings it is stepped with
        self._model_setup: tuple[DamperModel, EmulatorParams] | None = None
        if p.model:
            from damper_emulator.realtime.settings import (
                default_emulator_mapping,
                emulator_params_from_mapping,
            )
            from damper_emulator.ros.emulator import load_node_model

            emu_values, model = load_node_model(
                self, {"emulator": default_emulator_mapping()}, {"emulator": EmulatorParams})
            self._model_setup = (model, emulator_params_from_mapping(
                emu_values["emulator"], f"node {NODE_NAME} parameters"))
        #: the model stepped in the receive thread (``model: true``), from configure on
        self.emulator: EmulatorCore | None = None
        self._force_pub = None
        self._force_out: JointStateOut | None = None
        #: read by spin_node: the DDS threads' SCHED_FIFO priority (0: normal scheduling)
        self.dds_priority = p.dds_priority
        #: read by spin_node: the executor thread's SCHED_FIFO priority (0: normal)
        self.main_thread_priority = executor_priority(p.priority) if p.sched_fifo else 0
        self._db = load_database(p.dbc_file or None)
        self._bus_config = BusConfig(interface=p.can_interface, channel=p.can_channel,
                                     bitrate=p.bitrate,
                                     receive_ids=BridgeCore(p, self._db).receiver.frame_ids)
        try:
            open_bus(self._bus_config).shutdown()  # a wrong interface or channel: exit 2
        except CanBusError as exc:
            raise ParameterError(str(exc)) from None
        #: the raw traffic's log (``can_log``), over the node's whole life: a configure
        #: after a cleanup goes on writing it
        try:
            self.can_log = CanLog(p.can_log) if p.can_log else None
        except CanLogError as exc:
            raise ParameterError(str(exc)) from None
        self.core: BridgeCore | None = None
        self.bus: ResilientBus | None = None
        self._state_pub = self._valve_pub = self._diag_pub = None
        self._diag_timer = None
        self._ros_in: SubscriptionThread | None = None
        self._rx: threading.Thread | None = None
        self._stop = threading.Event()
        # DAMPER_FORCE frames come from two threads (forces: the input thread; fault frames:
        # the receive thread's watchdog) with one alive counter: encode and send them under one
        # lock, so that no two frames share a counter and they go out in counter order
        self._force_lock = threading.Lock()
        self._rt_report = None
        self._errors_seen = 0
        self._tx_failed = 0
        self._damper_velocity = 0.0
        self._force_in, self._state_in, self._ride_in = (JointStateIn(), JointStateIn(),
                                                         JointStateIn())
        self._state_out: JointStateOut | None = None
        #: input messages that are not JointState CDR (a publisher's bug), ignored
        self._malformed = 0
        #: why the node is not active (after a deactivation: in /diagnostics)
        self._inactive_reason = ""
        self.get_logger().info(
            f"mode {p.mode} on {p.can_interface} channel {p.can_channel} "
            f"({p.bitrate} bit/s), database {p.dbc_file or 'config/damper.dbc'}")

    # ---- lifecycle --------------------------------------------------------------------

    def _configure(self) -> str | None:
        p = self.params
        self.core = BridgeCore(p, self._db)
        self._force_id = self.core.force_encoder.frame_id
        self._motion_id = self.core.motion_encoder.frame_id
        self.bus = ResilientBus(self._bus_config, backoff_initial_s=p.backoff_initial_s,
                                backoff_max_s=p.backoff_max_s, log=self.can_log)
        qos = control_qos(topics.PUBLISHER_DEPTH)
        if p.mode == "dyno":
            self._state_pub = self.create_lifecycle_publisher(JointState, topics.STATE, qos)
            self._state_out = JointStateOut(self._state_pub, [p.damper_name], (1, 1, 0))
            if self._model_setup is not None:
                # the model's compiled code loaded (or compiled) before any frame is answered
                self.emulator = EmulatorCore(*self._model_setup)
                self.emulator.warm_up()
                self._force_pub = self.create_lifecycle_publisher(JointState, topics.FORCE,
                                                                  qos)
                self._force_out = JointStateOut(self._force_pub,
                                                force_message.names(p.damper_name),
                                                force_message.COUNTS)
        else:
            self._valve_pub = self.create_lifecycle_publisher(Float64, topics.VALVE_COMMAND,
                                                              qos)
        self._diag_pub = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        self._diag_timer = self.create_timer(p.diagnostics_period_s,
                                             self._publish_diagnostics)
        return None

    def _activate(self) -> None:
        p = self.params
        controller = p.mode == "controller"
        self._stop.clear()
        self._rx = threading.Thread(target=self._receive_loop, name="can-rx", daemon=True)
        if self.emulator is not None:       # the forces are the receive thread's own
            self._rx.start()
            self._inactive_reason = ""
            self.get_logger().info("active: answering DAMPER_STATE with the model's force")
            return
        # the 1 kHz inputs on a thread of their own, without the executor, as CDR bytes;
        # best effort: each frame carries the latest sample (topics.py).  Each force wakes
        # the thread; the vehicle's motion is sampled at VEHICLE_MOTION's cycle.
        self._ros_in = SubscriptionThread(
            self, [(JointState, topics.FORCE, self._on_force)],
            control_qos(topics.CONTROL_DEPTH, reliable=False), "ros-in",
            RealtimeRequest(sched_fifo=p.sched_fifo, priority=p.priority, lock_memory=False),
            raw=True,
            polled=([(JointState, topics.STATE), (JointState, topics.RIDE_STATE)]
                    if controller else ()),
            after_wake=self._send_motion if controller else None)
        self._rx.start()
        self._ros_in.start()
        self._inactive_reason = ""
        self.get_logger().info(f"active: bridging {p.mode} frames")

    def _stop_io(self) -> None:
        self._stop.set()
        if self._ros_in is not None:
            self._ros_in.stop()
            if self._ros_in.failed:
                self.exit_status = 1
            self._ros_in = None
        if self._rx is not None:
            if self._rx.is_alive():
                self._rx.join(2.0)
            self._rx = None

    def _leave_active(self, reason: str) -> None:
        """Stop the threads, then the safe state: a fault frame and, in controller mode,
        the fail-safe valve command (class docstring)."""
        self._stop_io()
        self._inactive_reason = reason
        core = self.core
        if core is None or self.bus is None:
            return
        with self._force_lock:
            self._send(self._force_id, core.fault_frame(time.monotonic_ns()))
        if self.params.mode == "controller" and self._valve_pub is not None:
            core.command = self.params.fail_safe_command
            self._valve_pub.publish(Float64(data=float(self.params.fail_safe_command)))
        self._publish_diagnostics()
        self.get_logger().info(f"inactive ({reason}): fault frame sent"
                               + (f", fail-safe command {self.params.fail_safe_command:g}"
                                  if self.params.mode == "controller" else ""))

    def _release(self) -> None:
        if self._diag_timer is not None:
            self.destroy_timer(self._diag_timer)
            self._diag_timer = None
        for pub in (self._state_pub, self._valve_pub, self._force_pub):
            if pub is not None:
                self.destroy_lifecycle_publisher(pub)
        self._state_pub = self._valve_pub = self._force_pub = None
        self._force_out = None
        self.emulator = None
        if self._diag_pub is not None:
            self.destroy_publisher(self._diag_pub)
            self._diag_pub = None
        if self.bus is not None:
            self.bus.close()
            self.bus = None
        self.core = None

    def before_spin(self, executor) -> None:
        p = self.params
        if p.emulator_node and not p.model:
            # the frames flow meanwhile (fault frames with the no-force status until the
            # emulator's forces arrive); this only says what the bridge waits for
            try:
                waited = wait_until_active(self, p.emulator_node, p.wait_for_emulator_s,
                                           executor=executor, stop=lambda: self.stopping)
                self.get_logger().info(f"/{p.emulator_node} is active (waited "
                                       f"{waited:.1f} s)")
            except NotReadyError as exc:
                if self.stopping:
                    return
                self.get_logger().error(f"{exc}; sending DAMPER_FORCE fault frames until "
                                        f"forces arrive")

    def close(self) -> None:
        self._stop_io()
        if self.bus is not None:
            self.bus.close()
        if self.can_log is not None:
            try:
                self.can_log.close()
                self.get_logger().info(f"wrote {self.can_log.path} "
                                       f"({self.can_log.frames} CAN frames)")
            except CanLogError as exc:
                self.get_logger().error(str(exc))

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
                    if out is not None and out[0] == "state" and self.emulator is not None:
                        self._answer(out[1], out[2], msg.timestamp)
                    elif out is not None:
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

    @staticmethod
    def _stamp(can_stamp_s: float) -> int:
        """A state's stamp [ns, the wall clock]: the frame's CAN time stamp where it is
        trusted (within :data:`STAMP_TRUST_S` of now), else now."""
        now = time.time_ns()
        return int(can_stamp_s * 1e9) if can_stamp_s and \
            abs(can_stamp_s * 1e9 - now) < STAMP_TRUST_S * 1e9 else now

    def _answer(self, x: float, v: float, can_stamp_s: float) -> None:
        """``model: true``: the force of the state ``(x, v)`` out as ``DAMPER_FORCE`` at
        once, then the state and the force on their topics.  The model steps by the
        states' stamps, as the emulator node under ``trigger: input``; a sample the input
        checks reject (or not after the previous one) is answered with the fault output
        and its status bit."""
        emulator = self.emulator
        assert emulator is not None and self._force_out is not None
        stamp = self._stamp(can_stamp_s)
        out = emulator.evaluate(stamp, float(x), float(v))
        if out is None:
            out = Output(emulator.fault_force(), float(x), float(v), stamp, 0.0,
                         Status.REJECTED, 0)
        with self._force_lock:
            frame = self.core.force_frame(out.force_n, int(out.status) & EMULATOR_BITS,
                                          out.input_age_s, out.stroke_m, time.monotonic_ns())
            self._send(self._force_id, frame)
        self._state_out.publish(stamp, (float(x), float(v)))
        self._force_out.publish(stamp, force_message.values(
            out.force_n, int(out.status), out.stroke_m, out.velocity_m_s, out.input_age_s))

    def _publish_inbound(self, out, can_stamp_s: float) -> None:
        if out[0] == "state":
            _, x, v = out
            self._state_out.publish(self._stamp(can_stamp_s), (float(x), float(v)))
        else:
            self._valve_pub.publish(Float64(data=float(out[1])))

    # ---- ROS → CAN --------------------------------------------------------------------

    def _send(self, frame_id: int, data: bytes) -> None:
        if not self.bus.send(can.Message(arbitration_id=frame_id, data=data,
                                         is_extended_id=False)):
            self._tx_failed += 1

    def _on_force(self, data: bytes) -> None:
        msg = self._force_in.decode(data)
        if isinstance(msg, str):
            self._malformed += 1
            return
        name = self.params.damper_name
        i = max(_frame_index(msg, name), 0)
        if len(msg.effort) <= i:
            return
        s = _frame_index(msg, f"{name}/status")
        status = int(msg.effort[s]) if s >= 0 and len(msg.effort) > s else 0
        age = float(msg.position[s]) if s >= 0 and len(msg.position) > s else float("nan")
        stroke = float(msg.position[i]) if len(msg.position) > i else float("nan")
        bits = status & EMULATOR_BITS
        if status & Status.INACTIVE:  # the emulator's last output: no forces follow
            bits |= int(ForceStatus.FORCE_TIMEOUT)
        with self._force_lock:
            frame = self.core.force_frame(float(msg.effort[i]), bits, age, stroke,
                                          time.monotonic_ns())
            self._send(self._force_id, frame)

    def _send_motion(self, now_ns: int) -> int | None:
        """A ``VEHICLE_MOTION`` frame from the latest /ride/state and /damper/state when
        one is due and a new ride state has come; the time until the next is due [ns]."""
        core, ros_in = self.core, self._ros_in
        if core is None or ros_in is None:
            return None
        if core.motion_due(now_ns):
            state = ros_in.latest(topics.STATE)
            if state is not None:
                msg = self._state_in.decode(state)
                if isinstance(msg, str):
                    self._malformed += 1
                else:
                    i = max(_frame_index(msg, self.params.damper_name), 0)
                    if len(msg.velocity) > i:
                        self._damper_velocity = float(msg.velocity[i])
            ride = ros_in.latest(topics.RIDE_STATE)
            msg = None if ride is None else self._ride_in.decode(ride)
            if isinstance(msg, str):
                self._malformed += 1
            elif msg is not None:
                w, b = _frame_index(msg, "wheel"), _frame_index(msg, "body")
                if w >= 0 and b >= 0 and len(msg.velocity) > max(w, b):
                    frame = core.motion_frame(float(msg.velocity[b]), float(msg.velocity[w]),
                                              self._damper_velocity, now_ns)
                    if frame is not None:
                        self._send(self._motion_id, frame)
                        return core.motion_wait_ns(now_ns)
            # none sent (no new ride state): look again a cycle later, or at the next force
            return core.motion_cycle_ns
        return core.motion_wait_ns(now_ns)

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
            "malformed_inputs": str(self._malformed),
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
            "model": ("" if self.emulator is None else
                      f"in the bridge, damper '{self.emulator.model.cfg.damper.name}'"),
        }
        if self.emulator is not None:
            e = self.emulator.counters
            values.update({"model_inputs_accepted": str(e.accepted),
                           "model_inputs_rejected": str(e.rejected),
                           "model_last_rejection": e.last_rejection,
                           "model_faults": str(e.model_faults)})
        level, message = DiagnosticStatus.OK, "ok"
        if d.dropped or d.lost:
            level, message = DiagnosticStatus.WARN, "frames dropped or lost"
        if self.core.fault_active:
            level, message = DiagnosticStatus.ERROR, self.core.fault_text
        if not bus.is_up:
            level, message = DiagnosticStatus.ERROR, f"bus down: {bus.last_error}"
        if self._inactive_reason:
            values["inactive_reason"] = self._inactive_reason
            level, message = DiagnosticStatus.WARN, (
                f"inactive: {self._inactive_reason}; a DAMPER_FORCE fault frame sent"
                + (", fail-safe valve command applied" if self.params.mode == "controller"
                   else "") + ", nothing more until active")
        publish_diagnostics(self, self._diag_pub, f"{NODE_NAME}: {self.params.mode}", level,
                            message, self.params.can_channel, values)
