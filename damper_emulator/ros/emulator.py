"""The ``damper_emulator`` node (``damper-hil emulate``): ``/damper/state`` in,
``/damper/force`` out, from :class:`~damper_emulator.realtime.core.EmulatorCore`.

``trigger: timer`` (default)
    A dedicated loop thread (:class:`~damper_emulator.realtime.loop.PeriodicLoop`, absolute
    deadlines, ``SCHED_FIFO`` / ``mlockall`` / CPU affinity when permitted) evaluates the
    model at ``rate_hz`` from the latest accepted input sample (held or extrapolated) and
    publishes every force; it takes the input samples and valve commands itself at each
    tick.
``trigger: input``
    One force per input sample, computed and published as each sample arrives, on an input
    thread without an executor (:class:`~damper_emulator.ros.common.SubscriptionThread`,
    SCHED_FIFO when permitted, which also takes the valve commands), with the input's stamp;
    the model advances by the difference of the input stamps.  This is the lockstep
    clock of the ride simulation.

``/damper/force`` carries, besides the contract's ``name[0]`` / ``position[0]`` /
``velocity[0]`` / ``effort[0]``, a second entry ``name[1] = "<name>/status"`` whose
``effort[1]`` is the :class:`~damper_emulator.realtime.core.Status` bits of that output and
``position[1]`` the input age [s] (so a recording tells fault outputs from model outputs).
``/diagnostics`` reports loop timing, input age, rejected inputs and faults every
``diagnostics_period_s``.
"""

from __future__ import annotations

import dataclasses
import gc
import math
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from damper_emulator.model.compressible import DamperModel
from damper_emulator.params import (DEFAULT_PARAMS_FILE, ParameterError, config_from_mapping,
                                    node_parameters, read_yaml)
from damper_emulator.realtime.core import EmulatorCore, Output, Status
from damper_emulator.realtime.loop import PeriodicLoop
from damper_emulator.realtime.settings import (RUNTIME_PARAMETERS, default_emulator_mapping,
                                               emulator_params_from_mapping)
from damper_emulator.ros import topics
from damper_emulator.ros.common import (SubscriptionThread, control_qos, declare_parameters,
                                        plain_value, publish_diagnostics, set_stamp, stamp_ns,
                                        take_all, unflatten)

NODE_NAME = "damper_emulator"


#: parameters under this prefix switch model extensions on (damper_emulator.model.extensions)
EXTENSIONS_PREFIX = "damper.extensions."


def _damper_defaults() -> dict:
    body = node_parameters(read_yaml(DEFAULT_PARAMS_FILE), str(DEFAULT_PARAMS_FILE))
    return {"damper": body["damper"], "numerics": body["numerics"]}


def load_node_model(node: Node, extra: dict | None = None) -> tuple[dict, DamperModel]:
    """Declare the damper (``damper``, ``numerics``) and ``extra`` parameter groups on
    ``node``; returns ``(values, model)``.

    The defaults are config/sport.yaml's; when the given parameters name another damper
    (``damper.name``) but give no ``damper.adaptive.*``, that damper has no bypass (its valve
    command has no effect), as :func:`damper_emulator.params.load_config` reads such a file.
    ``damper.extensions.*`` parameters (a params file written by ``diagnose``) switch the
    model extensions they name on.
    """
    defaults = {**_damper_defaults(), **(extra or {})}
    overrides = getattr(node, "_parameter_overrides", {})
    ext = {n[len(EXTENSIONS_PREFIX):]: p.value for n, p in overrides.items()
           if n.startswith(EXTENSIONS_PREFIX)}
    if ext:  # model extensions (issue 7) exist only where a params file gives them
        defaults["damper"] = {**defaults["damper"],
                              "extensions": unflatten({k: plain_value(v)
                                                      for k, v in ext.items()})}
    values = declare_parameters(node, defaults, defaults.keys())
    damper = dict(values["damper"])
    named = overrides.get("damper.name")
    if named is not None and named.value != defaults["damper"]["name"] and \
            not any(n.startswith("damper.adaptive.") for n in overrides):
        # A params file for another damper without an `adaptive` group describes a damper
        # without a solenoid bypass: the defaults' (sport's) bypass must not leak in.
        damper.pop("adaptive", None)
    cfg = config_from_mapping({"damper": damper, "numerics": values["numerics"]},
                              f"node {node.get_name()} parameters")
    return values, DamperModel(cfg)


def input_sample(msg: JointState, name: str) -> tuple[float, float] | str:
    """``(stroke, velocity)`` of the damper ``name`` in a JointState (the entry of that
    name, else entry 0), or why there is none."""
    i = list(msg.name).index(name) if name in msg.name else 0
    if len(msg.position) <= i or len(msg.velocity) <= i:
        return "JointState without position[0] and velocity[0]"
    return float(msg.position[i]), float(msg.velocity[i])


class EmulatorNode(Node):
    """See the module docstring.  Parameters: groups ``emulator`` (config/emulator.yaml),
    ``damper`` and ``numerics`` (config/sport.yaml)."""

    def __init__(self):
        super().__init__(NODE_NAME)
        values, model = load_node_model(self, {"emulator": default_emulator_mapping()})
        self.params = emulator_params_from_mapping(values["emulator"],
                                                   f"node {NODE_NAME} parameters")
        self.core = EmulatorCore(model, self.params)
        #: read by spin_node: the DDS threads' SCHED_FIFO priority (0: normal scheduling)
        self.dds_priority = self.params.dds_priority
        self.exit_status = 0
        p = self.params
        self._status_name = f"{p.name}/status"
        self._force_pub = self.create_publisher(JointState, topics.FORCE,
                                                control_qos(topics.CONTROL_DEPTH))
        self._diag_pub = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        self._input_thread = None
        if p.trigger == "input":
            # one force per input, computed on a thread of its own as each input arrives
            self._input_thread = SubscriptionThread(
                self, [(JointState, topics.STATE, self._on_state),
                       (Float64, topics.VALVE_COMMAND, self._on_valve)],
                control_qos(topics.CONTROL_DEPTH), "emulator-in", p.realtime_request())
            self._io_node = None
        else:
            # The loop thread takes the input itself at each tick (no executor thread
            # competing for the GIL at the input rate): a subscription on a second node of
            # the same context that no executor spins.
            self._io_node = rclpy.create_node(f"{NODE_NAME}_input",
                                              context=self.context)
            self._state_sub = self._io_node.create_subscription(
                JointState, topics.STATE, lambda _msg: None,
                control_qos(topics.CONTROL_DEPTH))
            self._valve_sub = self._io_node.create_subscription(
                Float64, topics.VALVE_COMMAND, lambda _msg: None,
                control_qos(topics.CONTROL_DEPTH))
        self._diag_timer = self.create_timer(p.diagnostics_period_s, self._publish_diagnostics)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._last: Output | None = None
        self._warned_rejection = False
        self._loop: PeriodicLoop | None = None
        self.get_logger().info(
            f"damper '{model.cfg.damper.name}', trigger {p.trigger}"
            + (f" at {p.rate_hz:g} Hz" if p.trigger == "timer" else "")
            + f", input timeout {p.input_timeout_s * 1e3:g} ms, fault mode {p.fault_mode}")

    # ---- lifecycle --------------------------------------------------------------------

    def run(self, executor) -> None:
        p = self.params
        # everything built so far is long-lived: keep the cyclic collector off it
        gc.collect()
        gc.freeze()
        if self._input_thread is not None:
            self._input_thread.start()
        if p.trigger == "timer":
            capacity = max(4096, int(p.rate_hz * p.stats_window_s))
            self._loop = PeriodicLoop(1.0 / p.rate_hz, self._tick,
                                      realtime=p.realtime_request(), capacity=capacity,
                                      name="emulator-loop")
            self._loop.start()
            report = self._loop.report
            if report.refused:
                self.get_logger().warning(f"real-time settings: {report.summary()}")
            else:
                self.get_logger().info(f"real-time settings: {report.summary()}")
        executor.spin()

    def close(self) -> None:
        if self._input_thread is not None:
            self._input_thread.stop()
            if self._input_thread.failed:
                self.exit_status = 1
        if self._loop is not None:
            self._loop.stop()
        if self._io_node is not None:
            self._io_node.destroy_node()
            self._io_node = None
        if self._loop is not None:
            if self.params.stats_file:
                self._loop.stats.save(self.params.stats_file,
                                      realtime=self._loop.report.summary())

    # ---- callbacks --------------------------------------------------------------------

    def _on_state(self, msg: JointState, received_ns: int | None = None) -> None:
        sample = input_sample(msg, self.params.name)
        if isinstance(sample, str):
            self.core.counters.reject("range", sample)
            return
        x, v = sample
        stamp = stamp_ns(msg.header.stamp)
        if self.params.trigger == "input":
            out = self.core.evaluate(stamp, x, v)
            if out is not None:
                self._publish(out, stamp)
        else:
            self.core.submit(stamp, x, v,
                             time.monotonic_ns() if received_ns is None else received_ns)

    def _on_valve(self, msg: Float64) -> None:
        reason = self.core.set_valve_command(float(msg.data))
        if reason:
            self.get_logger().warning(f"valve command refused: {reason}")

    def _take_inputs(self, now_ns: int) -> None:
        """Every sample that arrived since the last tick, oldest first; each is received
        at its DDS reception time (mapped onto the monotonic clock)."""
        for msg, info in take_all(self._state_sub):
            received = info.get("received_timestamp", 0) if isinstance(info, dict) else 0
            delay = time.time_ns() - received if received else 0
            self._on_state(msg, now_ns - max(0, delay))

    def _take_valve_commands(self) -> None:
        """Every valve command that arrived since the last tick, in order (the last wins)."""
        for msg, _info in take_all(self._valve_sub):
            self._on_valve(msg)

    def _tick(self, now_ns: int) -> None:
        self._take_valve_commands()
        self._take_inputs(now_ns)
        out = self.core.tick(now_ns)
        self._publish(out, time.time_ns())

    def _publish(self, out: Output, stamp: int) -> None:
        self._last = out
        msg = JointState()
        set_stamp(msg.header.stamp, stamp)
        msg.name = [self.params.name, self._status_name]
        x = out.stroke_m if math.isfinite(out.stroke_m) else 0.0
        v = out.velocity_m_s if math.isfinite(out.velocity_m_s) else 0.0
        age = out.input_age_s if math.isfinite(out.input_age_s) else -1.0
        msg.position = [x, age]
        msg.velocity = [v, 0.0]
        msg.effort = [out.force_n, float(int(out.status))]
        self._force_pub.publish(msg)

    def _on_set_parameters(self, params) -> SetParametersResult:
        changes = {}
        for p in params:
            key = p.name.removeprefix("emulator.")
            if key == p.name or key not in RUNTIME_PARAMETERS:
                return SetParametersResult(
                    successful=False,
                    reason=f"{p.name} is read-only while the node runs (restart it with a "
                           f"new params file); changeable: "
                           + ", ".join(f"emulator.{k}" for k in RUNTIME_PARAMETERS))
            changes[key] = p.value
        try:
            new = emulator_params_from_mapping(
                {**dataclasses.asdict(self.core.params), **changes}, "parameter change")
        except ParameterError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        self.core.params = new
        self.params = new
        return SetParametersResult(successful=True)

    # ---- diagnostics ------------------------------------------------------------------

    def _publish_diagnostics(self) -> None:
        loop = self._loop
        if loop is not None and loop.error is not None and self.exit_status == 0:
            self.get_logger().error(f"emulator loop stopped: {loop.error!r}")
            self.exit_status = 1
            rclpy.try_shutdown()
            return
        c = self.core.counters
        last = self._last
        status_bits = last.status if last is not None else Status.NO_INPUT
        values = {
            "trigger": self.params.trigger,
            "rate_hz_nominal": f"{self.params.rate_hz:g}",
            "status_bits": str(int(status_bits)),
            "force_n": f"{last.force_n:.3f}" if last else "nan",
            "input_age_ms": (f"{last.input_age_s * 1e3:.3f}"
                             if last and math.isfinite(last.input_age_s) else "nan"),
            "inputs_accepted": str(c.accepted),
            "inputs_rejected": str(c.rejected),
            "rejected_non_finite": str(c.rejected_non_finite),
            "rejected_out_of_range": str(c.rejected_range),
            "rejected_stamp": str(c.rejected_stamp),
            "last_rejection": c.last_rejection,
            "timeouts": str(c.timeouts),
            "fault_outputs": str(c.fault_ticks),
            "model_faults": str(c.model_faults),
            "fault_mode": self.params.fault_mode,
            "valve_command": f"{self.core.valve_command:g}",
        }
        level, message = DiagnosticStatus.OK, "ok"
        if loop is not None:
            s = loop.stats.summary(
                last=int(self.params.rate_hz * self.params.diagnostics_period_s) + 1)
            values.update({
                "ticks": str(s.ticks),
                "achieved_rate_hz": f"{s.achieved_rate_hz:.2f}",
                "window_ticks": str(int(self.params.rate_hz * self.params.diagnostics_period_s)),
                "period_p50_us": f"{s.period_p50_us:.1f}",
                "period_p99_us": f"{s.period_p99_us:.1f}",
                "period_max_us": f"{s.period_max_us:.1f}",
                "period_error_p99_us": f"{s.error_p99_us:.1f}",
                "wake_latency_p99_us": f"{s.wake_p99_us:.1f}",
                "tick_work_p99_us": f"{s.work_p99_us:.1f}",
                "tick_work_max_us": f"{s.work_max_us:.1f}",
                "overruns": str(s.overruns),
                "skipped_deadlines": str(s.skipped),
                "realtime": loop.report.summary(),
            })
            if s.overruns:
                level, message = DiagnosticStatus.WARN, f"{s.overruns} loop overruns"
        if c.rejected:
            level, message = DiagnosticStatus.WARN, f"{c.rejected} inputs rejected"
        if status_bits & Status.TIMEOUT:
            level, message = DiagnosticStatus.ERROR, "input timeout: fault output"
        elif status_bits & Status.NO_INPUT:
            level, message = DiagnosticStatus.WARN, "no input yet"
        publish_diagnostics(self, self._diag_pub, f"{NODE_NAME}: {self.params.name}", level, message,
                            self.params.name, values)
