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
``position[1]`` the input age [s] (so a recording tells fault outputs from model outputs);
the layout is :mod:`damper_emulator.force_message`'s.
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

from damper_emulator import force_message, topics
from damper_emulator.bag.cdr_fast import JointStateSample
from damper_emulator.errors import UserError
from damper_emulator.model import jit
from damper_emulator.model.compressible import DamperModel
from damper_emulator.params import (
    DEFAULT_PARAMS_FILE,
    DamperParams,
    NumericsParams,
    config_from_mapping,
)
from damper_emulator.realtime.core import EmulatorCore, Output, Status
from damper_emulator.realtime.loop import LoopStats, PeriodicLoop
from damper_emulator.realtime.phase_lock import PhaseLock
from damper_emulator.realtime.rt import unlock_memory
from damper_emulator.realtime.settings import (
    RUNTIME_PARAMETERS,
    EmulatorParams,
    default_emulator_mapping,
    emulator_params_from_mapping,
)
from damper_emulator.ros.common import (
    JointStateIn,
    JointStateOut,
    SubscriptionThread,
    control_qos,
    executor_priority,
    publish_diagnostics,
    take_all,
)
from damper_emulator.ros.live import LiveServer, require_sdk
from damper_emulator.ros.managed import ManagedNode
from damper_emulator.ros.parameters import (
    declare_parameters,
    parameter_overrides,
    plain_value,
    unflatten,
)
from damper_emulator.schema import ParameterError, node_parameters, read_yaml

NODE_NAME = "damper_emulator"
#: how often the emulator's own live view (``live_port``) sends its latest output [Hz]
LIVE_RATE_HZ = 50.0


#: parameters under this prefix switch model extensions on (damper_emulator.model.extensions)
EXTENSIONS_PREFIX = "damper.extensions."


def _damper_defaults() -> dict:
    body = node_parameters(read_yaml(DEFAULT_PARAMS_FILE), str(DEFAULT_PARAMS_FILE))
    return {"damper": body["damper"], "numerics": body["numerics"]}


#: the schema of the model's parameter groups (group → dataclass)
MODEL_SCHEMA: dict[str, type] = {"damper": DamperParams, "numerics": NumericsParams}


def load_node_model(node: Node, extra: dict | None = None,
                    extra_schema: dict[str, type] | None = None) -> tuple[dict, DamperModel]:
    """Declare the damper (``damper``, ``numerics``) and ``extra`` parameter groups (their
    defaults; ``extra_schema``: their dataclasses) on ``node``, each with its schema's
    descriptor; returns ``(values, model)``.

    The defaults are config/sport.yaml's; when the given parameters name another damper
    (``damper.name``) but give no ``damper.adaptive.*``, that damper has no bypass (its valve
    command has no effect), as :func:`damper_emulator.params.load_config` reads such a file.
    ``damper.extensions.*`` parameters (a params file written by ``diagnose``) switch the
    model extensions they name on.
    """
    defaults = {**_damper_defaults(), **(extra or {})}
    overrides = parameter_overrides(node)
    ext = {n[len(EXTENSIONS_PREFIX):]: p.value for n, p in overrides.items()
           if n.startswith(EXTENSIONS_PREFIX)}
    if ext:  # model extensions exist only where a params file gives them
        defaults["damper"] = {**defaults["damper"],
                              "extensions": unflatten({k: plain_value(v)
                                                      for k, v in ext.items()})}
    values = declare_parameters(node, defaults, {**MODEL_SCHEMA, **(extra_schema or {})})
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


def input_sample(msg: JointState | JointStateSample, name: str) -> tuple[float, float] | str:
    """``(stroke, velocity)`` of the damper ``name`` in a JointState (the entry of that
    name, else entry 0), or why there is none."""
    i = list(msg.name).index(name) if name in msg.name else 0
    if len(msg.position) <= i or len(msg.velocity) <= i:
        return "JointState without position[0] and velocity[0]"
    return float(msg.position[i]), float(msg.velocity[i])


class EmulatorNode(ManagedNode):
    """See the module docstring.  Parameters: groups ``emulator`` (config/emulator.yaml),
    ``damper`` and ``numerics`` (config/sport.yaml), and ``autostart``.

    A managed (lifecycle) node.  Its parameters are read and checked, and the damper model
    built, when it is created (a bad value is one line and exit 2).  ``configure`` loads the
    compiled kernels and exercises every path the loop can take
    (:meth:`EmulatorCore.warm_up`): nothing is compiled once the node is active.
    ``activate`` starts the loop (or the input thread) and the outputs; ``deactivate`` (and
    ``shutdown`` from active) stops them after one last output in the configured
    ``fault_mode`` with the ``INACTIVE`` status bit, the reason on ``/diagnostics``;
    ``cleanup`` releases the publishers, the model's core and the loop's ``mlockall``
    (the latency request and SCHED_FIFO end with the loop).  ``active`` is the readiness
    the ride, the bridge and the demo wait for
    (:func:`~damper_emulator.ros.readiness.wait_until_active`).  With ``autostart: true`` (the
    default) the node configures and activates itself at start.
    """

    def __init__(self):
        super().__init__(NODE_NAME)
        values, model = load_node_model(self, {"emulator": default_emulator_mapping()},
                                        {"emulator": EmulatorParams})
        self.params = emulator_params_from_mapping(values["emulator"],
                                                   f"node {NODE_NAME} parameters")
        self.model = model
        self.core: EmulatorCore | None = None
        #: read by spin_node: the DDS threads' SCHED_FIFO priority (0: normal scheduling)
        self.dds_priority = self.params.dds_priority
        #: read by spin_node: the executor thread's SCHED_FIFO priority (0: normal)
        self.main_thread_priority = (executor_priority(self.params.priority)
                                     if self.params.sched_fifo else 0)
        p = self.params
        self._force_pub = None
        self._force_out: JointStateOut | None = None
        self._state_in = JointStateIn()
        self._diag_pub = None
        self._diag_timer = None
        self._input_thread: SubscriptionThread | None = None
        self._io_node = None
        self._state_sub = self._valve_sub = None
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._last: Output | None = None
        self._loop: PeriodicLoop | None = None
        self._stats: LoopStats | None = None
        self._realtime_summary = ""
        self._first_input_tick = -1     # loop tick of the first output from an input
        self._compiled_after_ready = 0
        #: compiled specialisations when the node became active (None: not yet)
        self._compiled_at_ready: int | None = None
        self.warm_up_s = math.nan
        #: why the node is not active (after a deactivation: in /diagnostics)
        self._inactive_reason = ""
        self._live: LiveServer | None = None
        #: the timer loop's lock to the input's arrivals (None: off, or not active)
        self._phase_lock: PhaseLock | None = None
        self._memory_locked = False
        self._live_timer = None
        if p.live_port:
            require_sdk()  # missing: one line and exit 2 at start, not at configure
        self.get_logger().info(
            f"damper '{model.cfg.damper.name}', trigger {p.trigger}"
            + (f" at {p.rate_hz:g} Hz" if p.trigger == "timer" else "")
            + f", input timeout {p.input_timeout_s * 1e3:g} ms, fault mode {p.fault_mode}")

    # ---- lifecycle --------------------------------------------------------------------

    def _configure(self) -> str | None:
        p = self.params
        self.get_logger().info(f"configuring: loading and exercising the compiled model "
                               f"(kernel cache {jit.CACHE_DIR}; the first run compiles, "
                               f"some seconds)")
        start = time.monotonic()
        self.core = EmulatorCore(self.model, p)
        self.core.warm_up()
        self.warm_up_s = time.monotonic() - start
        self._force_pub = self.create_lifecycle_publisher(JointState, topics.FORCE,
                                                          control_qos(topics.PUBLISHER_DEPTH))
        self._force_out = JointStateOut(self._force_pub, force_message.names(p.name),
                                        force_message.COUNTS)
        self._diag_pub = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        if p.trigger == "timer":
            # The loop thread takes the input itself at each tick (no executor thread
            # competing for the GIL at the input rate): a subscription on a second node of
            # the same context that no executor spins.
            self._io_node = rclpy.create_node(f"{NODE_NAME}_input", context=self.context)
            # best effort: the loop runs on its own clock and wants the latest sample
            # (topics.py)
            self._state_sub = self._io_node.create_subscription(
                JointState, topics.STATE, lambda _msg: None,
                control_qos(topics.CONTROL_DEPTH, reliable=False), raw=True)
            self._valve_sub = self._io_node.create_subscription(
                Float64, topics.VALVE_COMMAND, lambda _msg: None,
                control_qos(topics.CONTROL_DEPTH))
        self._diag_timer = self.create_timer(p.diagnostics_period_s,
                                             self._publish_diagnostics)
        if p.live_port:
            try:
                self._live = LiveServer(p.live_port, name=NODE_NAME)
            except UserError as exc:  # the port is taken, ...
                return str(exc)
            # the latest output, from the executor thread: the loop never waits for the view
            self._live_timer = self.create_timer(1.0 / LIVE_RATE_HZ, self._publish_live)
            self.get_logger().info(f"live view on ws://127.0.0.1:{self._live.port}")
        self.get_logger().info(f"configured: model exercised in {self.warm_up_s:.2f} s")
        return None

    def _activate(self) -> None:
        p = self.params
        # everything built so far is long-lived: keep the cyclic collector off it
        gc.collect()
        gc.freeze()
        self._compiled_at_ready = jit.compiled_signatures()
        if p.trigger == "input":
            # one force per input, computed on a thread of its own as each input arrives
            self._input_thread = SubscriptionThread(
                self, [(JointState, topics.STATE, self._on_state),
                       (Float64, topics.VALVE_COMMAND, self._on_valve)],
                control_qos(topics.CONTROL_DEPTH), "emulator-in", p.realtime_request(),
                raw=[topics.STATE])
            self._input_thread.start()
        else:
            for sub in (self._state_sub, self._valve_sub):   # nothing from before 'active'
                for _ in take_all(sub):
                    pass
            capacity = max(4096, int(p.rate_hz * p.stats_window_s))
            self._loop = PeriodicLoop(1.0 / p.rate_hz, self._tick,
                                      realtime=p.realtime_request(), capacity=capacity,
                                      name="emulator-loop")
            self._phase_lock = (PhaseLock(self._loop.period_ns, round(p.phase_lock_us * 1e3))
                                if p.phase_lock_us > 0 else None)
            self._stats = self._loop.stats
            self._loop.start()
            report = self._loop.report
            self._memory_locked = report.memory_locked
            self._realtime_summary = report.summary()
            log = self.get_logger().warning if report.refused else self.get_logger().info
            log(f"real-time settings: {self._realtime_summary}")
        self._inactive_reason = ""
        self.get_logger().info("active: publishing " + topics.FORCE)

    def _leave_active(self, reason: str) -> None:
        """Stop the loop (or input thread), then publish one last output in the configured
        fault mode (``fault_mode``: hold, zero or passive) with the ``INACTIVE`` status bit,
        and the reason on ``/diagnostics``: a dyno or ride listening knows the forces
        stopped on purpose, and what the damper was left at."""
        self._stop_io()
        self._inactive_reason = reason
        if self.core is not None and self._force_pub is not None:
            last = self._last
            out = Output(self.core.fault_force(), last.stroke_m if last else math.nan,
                         last.velocity_m_s if last else math.nan, 0, math.nan,
                         Status.INACTIVE, 0)
            self._publish(out, time.time_ns())
            self._publish_diagnostics()
        self.get_logger().info(f"inactive ({reason}): one {self.params.fault_mode} output, "
                               "then none")

    def _stop_io(self) -> None:
        if self._input_thread is not None:
            self._input_thread.stop()
            if self._input_thread.failed:
                self.exit_status = 1
            self._input_thread = None
        if self._loop is not None:
            self._loop.stop()
            self._loop = None
        self._check_compiled()

    def _release(self) -> None:
        if self._memory_locked:  # the loop's mlockall is the process's: give it back
            self._memory_locked = not unlock_memory()
        if self._live_timer is not None:
            self.destroy_timer(self._live_timer)
            self._live_timer = None
        if self._live is not None:
            self._live.stop()
            self._live = None
        if self._diag_timer is not None:
            self.destroy_timer(self._diag_timer)
            self._diag_timer = None
        if self._io_node is not None:
            self._io_node.destroy_node()
            self._io_node = None
            self._state_sub = self._valve_sub = None
        if self._force_pub is not None:
            self.destroy_lifecycle_publisher(self._force_pub)
            self._force_pub = None
            self._force_out = None
        if self._diag_pub is not None:
            self.destroy_publisher(self._diag_pub)
            self._diag_pub = None
        self.core = None

    def _check_compiled(self) -> None:
        """A compile after 'active' is a bug (a stall of the loop): say so."""
        if self._compiled_at_ready is None:
            return
        grown = jit.compiled_signatures() - self._compiled_at_ready
        self._compiled_after_ready += grown
        if grown:
            self.get_logger().error(f"bug: {grown} kernel specialisation(s) compiled after "
                                    f"the node became active (warm-up incomplete)")
            self.exit_status = 1
        self._compiled_at_ready = None

    def close(self) -> None:
        stats = self._stats
        self._stop_io()
        if stats is not None and self.params.stats_file:
            stats.save(self.params.stats_file, realtime=self._realtime_summary,
                       warm_up_s=self.warm_up_s, first_input_tick=self._first_input_tick,
                       compiled_after_ready=self._compiled_after_ready)

    # ---- callbacks --------------------------------------------------------------------

    def _on_state(self, data: bytes, received_ns: int | None = None) -> None:
        msg = self._state_in.decode(data)
        if isinstance(msg, str):
            self.core.reject_malformed(msg)
            return
        sample = input_sample(msg, self.params.name)
        if isinstance(sample, str):
            self.core.reject_malformed(sample)
            return
        x, v = sample
        stamp = msg.stamp_ns
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

    def _take_inputs(self, now_ns: int) -> tuple[int, int]:
        """Every sample that arrived since the last tick, oldest first; each is received
        at its DDS reception time (mapped onto the monotonic clock).  Returns how many
        were taken and the newest one's time since its arrival [ns] (0: unknown)."""
        taken = delay = 0
        for msg, info in take_all(self._state_sub):
            received = info.get("received_timestamp", 0) if isinstance(info, dict) else 0
            delay = max(0, time.time_ns() - received) if received else 0
            self._on_state(msg, now_ns - delay)
            taken += 1
        return taken, delay

    def _take_valve_commands(self) -> None:
        """Every valve command that arrived since the last tick, in order (the last wins)."""
        for msg, _info in take_all(self._valve_sub):
            self._on_valve(msg)

    def _tick(self, now_ns: int) -> None:
        self._take_valve_commands()
        taken, lag_ns = self._take_inputs(now_ns)
        lock, loop = self._phase_lock, self._loop    # (None once the loop is stopped)
        if lock is not None and loop is not None:
            loop.shift_next(lock.shift_ns(taken if lag_ns else 0, lag_ns))
        out = self.core.tick(now_ns)
        self._publish(out, time.time_ns())
        if self._first_input_tick < 0 and not out.status & Status.NO_INPUT:
            self._first_input_tick = self._stats.ticks

    def _publish(self, out: Output, stamp: int) -> None:
        self._last = out
        assert self._force_out is not None, "publishing before configure"
        self._force_out.publish(stamp, force_message.values(
            out.force_n, int(out.status), out.stroke_m, out.velocity_m_s, out.input_age_s))

    def _on_set_parameters(self, params) -> SetParametersResult:
        """Accept a run-time change of the ``emulator`` group where its schema allows one
        (rclpy has already refused the read-only parameters, see
        :func:`~damper_emulator.ros.parameters.parameter_descriptor`) and the group's rules
        hold; the loop takes the new values at its next tick."""
        changes = {}
        for p in params:
            key = p.name.removeprefix("emulator.")
            if key == p.name:          # (the emulator's read-only ones rclpy refused)
                return SetParametersResult(
                    successful=False,
                    reason=f"{p.name} does not change while the node runs; changeable: "
                           + ", ".join(f"emulator.{k}" for k in RUNTIME_PARAMETERS))
            changes[key] = p.value
        try:
            new = emulator_params_from_mapping(
                {**dataclasses.asdict(self.params), **changes}, "parameter change")
        except ParameterError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        if self.core is not None:
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
            "warm_up_s": f"{self.warm_up_s:.3f}",
            "compiled_after_ready": str(jit.compiled_signatures() - self._compiled_at_ready
                                        if self._compiled_at_ready is not None else 0),
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
            if self._phase_lock is not None:
                values["phase_lock_error_us"] = f"{self._phase_lock.error_ns / 1e3:.1f}"
            if s.overruns:
                level, message = DiagnosticStatus.WARN, f"{s.overruns} loop overruns"
        if c.rejected:
            level, message = DiagnosticStatus.WARN, f"{c.rejected} inputs rejected"
        if status_bits & Status.TIMEOUT:
            level, message = DiagnosticStatus.ERROR, "input timeout: fault output"
        elif status_bits & Status.NO_INPUT:
            level, message = DiagnosticStatus.WARN, "no input yet"
        if self._inactive_reason:
            values["inactive_reason"] = self._inactive_reason
            level, message = DiagnosticStatus.WARN, (
                f"inactive: {self._inactive_reason}; outputs stopped after one "
                f"{self.params.fault_mode} output")
        name = f"{NODE_NAME}: {self.params.name}"
        publish_diagnostics(self, self._diag_pub, name, level, message, self.params.name,
                            values)
        if self._live is not None:
            self._live.loop(values, level, name, message)

    def _publish_live(self) -> None:
        """The latest output on ``/live/damper`` (``live_port``)."""
        out = self._last
        if self._live is not None and out is not None:
            self._live.damper(out.force_n, out.stroke_m, out.velocity_m_s, int(out.status))
