"""The ``ride_sim`` node (``damper-hil ride``): the quarter car of :mod:`ride_sim` closed over
ROS.  It publishes ``/damper/state`` from the suspension motion (through the motion ratio)
and applies ``/damper/force`` (zero-order hold), on the run's random road
(:class:`~ride_sim.session.RideSession`).

``ride.clock: realtime``
    A loop thread at ``simulation.step_s`` (absolute deadlines) advances the car with the
    latest force received (the emulator's static force before the first): hardware in the
    loop, transport delays included.
``ride.clock: lockstep``
    Each sample publishes the state stamped with the simulation time and waits for the
    force carrying that stamp (the emulator runs ``trigger: input``); as fast as the loop
    goes, deterministic, and equal to :func:`ride_sim.session.offline_run`.

``/ride/state`` (``sensor_msgs/JointState``, every sample): ``name = [wheel, body, road]``;
``position`` their heights [m] (deviations from static equilibrium, up +); ``velocity``
their rates [m/s]; ``effort = [dynamic tyre load N, body vertical force M_b·z2'' N, damper
force N]``.  At the end the node logs the ride metrics and writes them to
``ride.metrics_file`` (JSON) when set, then exits.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
import rclpy
from rclpy.duration import Duration
from rclpy.node import Node
from sensor_msgs.msg import JointState

from damper_emulator import force_message, topics
from damper_emulator.model.compressible import DamperStepper
from damper_emulator.outputs import write_text
from damper_emulator.realtime.loop import PeriodicLoop
from damper_emulator.realtime.rt import RealtimeRequest
from damper_emulator.ros.common import (
    JointStateIn,
    JointStateOut,
    control_qos,
    executor_priority,
    take_all,
)
from damper_emulator.ros.emulator import load_node_model
from damper_emulator.ros.readiness import NotReadyError, wait_until_active
from damper_emulator.schema import node_parameters, read_yaml
from ride_sim import loop_delay
from ride_sim import quarter_car as qc
from ride_sim.params import (
    DEFAULT_QUARTER_CAR_FILE,
    QuarterCarParams,
    RideRunParams,
    RoadParams,
    SimulationParams,
    ride_config_from_mapping,
)
from ride_sim.session import RideSession

NODE_NAME = "ride_sim"
#: ``name`` of /ride/state (docs/interfaces.md)
RIDE_STATE_NAMES = ("wheel", "body", "road")
#: Bit of ``damper_fault_bits`` (beside the emulator's Status bits) set when a force message
#: carried a non-finite force, which the ride ignores (the previous force stays held).
NON_FINITE_FORCE = 1 << 16
#: Bit of ``damper_fault_bits`` set when a force message could not be decoded as a
#: JointState (a publisher's bug), which the ride ignores as well.
MALFORMED_FORCE = 1 << 17
#: the ride's parameter groups (group → dataclass)
RIDE_SCHEMA: dict[str, type] = {"quarter_car": QuarterCarParams, "simulation": SimulationParams,
                                "road": RoadParams, "ride": RideRunParams}
GROUPS = tuple(RIDE_SCHEMA)


def _ride_defaults() -> dict:
    body = node_parameters(read_yaml(DEFAULT_QUARTER_CAR_FILE), str(DEFAULT_QUARTER_CAR_FILE),
                           "quarter_car")
    return {g: body[g] for g in GROUPS}


class RideNode(Node):
    """See the module docstring.  Parameters: ``quarter_car``, ``simulation``, ``road``,
    ``ride`` (config/quarter_car.yaml) and the damper's ``damper`` / ``numerics`` (its
    static force, carried by the spring)."""

    def __init__(self):
        super().__init__(NODE_NAME)
        values, model = load_node_model(self, _ride_defaults(), RIDE_SCHEMA)
        cfg = ride_config_from_mapping({g: values[g] for g in GROUPS},
                                       f"node {NODE_NAME} parameters")
        self.cfg = cfg
        self.run_params = cfg.ride
        #: read by spin_node: the executor thread's SCHED_FIFO priority (0: normal)
        self.main_thread_priority = (executor_priority(cfg.ride.priority)
                                     if cfg.ride.sched_fifo else 0)
        #: read by spin_node: the DDS threads' SCHED_FIFO priority (0: normal).  Under
        #: normal scheduling beside the other nodes' real-time threads on a two-core
        #: machine the force reached the ride up to 0.75 s late
        self.dds_priority = cfg.ride.dds_priority
        static = DamperStepper(model).force_n
        self.session = RideSession(cfg.quarter_car, cfg.road, cfg.ride, cfg.simulation.step_s,
                                   static)
        self.static_force_n = static
        self.exit_status = 0
        self.damper_name = "damper"
        out_qos = control_qos(topics.PUBLISHER_DEPTH)
        self._state_pub = self.create_publisher(JointState, topics.STATE, out_qos)
        self._state_out = JointStateOut(self._state_pub, [self.damper_name], (1, 1, 0))
        self._ride_pub = (self.create_publisher(JointState, topics.RIDE_STATE, out_qos)
                          if cfg.ride.publish_ride_state else None)
        self._ride_out = (JointStateOut(self._ride_pub, RIDE_STATE_NAMES, (3, 3, 3))
                          if self._ride_pub is not None else None)
        self._force_in = JointStateIn()
        if cfg.ride.clock == "lockstep":
            # every force answers one sample: reliable
            self.create_subscription(JointState, topics.FORCE, self._on_force,
                                     control_qos(topics.CONTROL_DEPTH), raw=True)
            self._io_node = None
        else:
            # the loop thread takes the forces itself (no executor thread holding the GIL
            # at 1 kHz while the loop thread waits for it); best effort: it applies the
            # latest force on its own clock (topics.py)
            self._io_node = rclpy.create_node(f"{NODE_NAME}_input", context=self.context)
            self._force_sub = self._io_node.create_subscription(
                JointState, topics.FORCE, lambda _msg: None,
                control_qos(topics.CONTROL_DEPTH, reliable=False), raw=True)
        self._forces: dict[int, tuple[float, int]] = {}     # lockstep: stamp → force
        #: realtime: the latest force (received [monotonic ns], force, status, wall-clock
        #: stamp of the state it answers or -1)
        self._latest: tuple[int, float, int, int] | None = None
        #: realtime: each sample's state stamp [wall-clock ns], and the loop delay of the
        #: force applied at each sample [samples] (:mod:`ride_sim.loop_delay`)
        self._state_stamps = np.zeros(self.session.n + 1, np.int64)
        self._delays = np.full(self.session.n + 1, -1, np.int64)
        self.delay_bound_s = loop_delay.delay_bound_s(cfg.quarter_car)
        self._loop: PeriodicLoop | None = None
        self._started_ns = 0
        self.faults = 0
        self._span: list[int] = []    # realtime: sample and monotonic time of first/last tick
        start = time.monotonic()
        self.session.warm_up()
        self.get_logger().info(f"ride kernels loaded and exercised in "
                               f"{time.monotonic() - start:.2f} s")
        self.get_logger().info(
            f"{cfg.ride.clock} run: {cfg.ride.duration_s:g} s (+{cfg.ride.lead_in_s:g} s "
            f"lead-in) at {cfg.ride.speed_m_s:g} m/s, {self.session.n} samples of "
            f"{cfg.simulation.step_s * 1e3:g} ms, road seed {cfg.ride.seed}")

    # ---- messages ---------------------------------------------------------------------

    def _on_force(self, data: bytes) -> None:
        msg = self._force_in.decode(data)
        if isinstance(msg, str):
            self.faults |= MALFORMED_FORCE
            return
        if not msg.effort:
            return
        force = float(msg.effort[0])
        status = force_message.status_of(msg.effort)
        if not math.isfinite(force):
            self.faults |= NON_FINITE_FORCE
            return
        if self.run_params.clock == "lockstep":
            self._forces[msg.stamp_ns] = (force, status)
        else:
            age = force_message.input_age_of(msg.position)
            answered = (msg.stamp_ns - int(round(age * 1e9))
                        if age >= 0.0 else -1)
            self._latest = (time.monotonic_ns(), force, status, answered)

    def _publish_state(self, stamp: int, x: float, v: float) -> None:
        self._state_out.publish(stamp, (x, v))

    def _publish_ride(self, stamp: int) -> None:
        if self._ride_out is None:
            return
        row = self.session.last()
        k = self.session.k - 1
        u0, u1 = qc.road_pair(self.session.heights, k)   # the road over the step
        self._ride_out.publish(stamp, (
            float(row[qc.O_Z1]), float(row[qc.O_Z2]), float(u0),
            float(row[qc.O_Z1D]), float(row[qc.O_Z2D]), float(u1 - u0) / self.session.dt_s,
            float(row[qc.O_DTL]), float(row[qc.O_ACC]) * self.cfg.quarter_car.sprung_mass_kg,
            float(row[qc.O_F])))

    # ---- running ----------------------------------------------------------------------

    def _wait_for_emulator(self, executor) -> bool:
        """Wait until the emulator is active (its lifecycle state, over its get_state
        service) and enough nodes subscribe to /damper/state; say what is awaited."""
        p = self.run_params
        deadline = time.monotonic() + p.wait_for_emulator_s
        if p.emulator_node:
            try:
                waited = wait_until_active(self, p.emulator_node, p.wait_for_emulator_s,
                                           executor=executor)
            except NotReadyError as exc:
                self.get_logger().error(f"no emulator: {exc}")
                self.exit_status = 1
                return False
            self.get_logger().info(f"/{p.emulator_node} is active (waited {waited:.1f} s)")
        said = False
        while time.monotonic() < deadline and rclpy.ok():
            if (self.count_subscribers(topics.STATE) >= p.state_subscribers
                    and self.count_publishers(topics.FORCE) > 0):
                return True
            if not said:
                self.get_logger().info(f"waiting for {p.state_subscribers} subscribers to "
                                       f"{topics.STATE} and a publisher of {topics.FORCE}")
                said = True
            executor.spin_once(timeout_sec=0.05)
        self.get_logger().error(
            f"no emulator: {self.count_subscribers(topics.STATE)} of "
            f"{p.state_subscribers} subscribers to {topics.STATE} and "
            f"{self.count_publishers(topics.FORCE)} publishers of {topics.FORCE} after "
            f"{p.wait_for_emulator_s:g} s")
        self.exit_status = 1
        return False

    def run(self, executor) -> None:
        if not self._wait_for_emulator(executor):
            return
        self._started_ns = time.monotonic_ns()
        if self.run_params.clock == "lockstep":
            self._run_lockstep(executor)
            self._span = [0, self._started_ns, self.session.k, time.monotonic_ns()]
        else:
            self._run_realtime(executor)
        # reliable delivery needs the publisher alive: let every subscriber (a recorder)
        # acknowledge the last samples before the process exits
        for pub in (self._state_pub, self._ride_pub):
            if pub is not None and not pub.wait_for_all_acked(
                    Duration(seconds=topics.ACK_TIMEOUT_S)):
                self.get_logger().warning(f"{pub.topic_name}: not every subscriber "
                                          f"acknowledged the last samples")
        if self.exit_status == 0:
            self._finish()

    def _run_lockstep(self, executor) -> None:
        s = self.session
        timeout = self.run_params.force_timeout_s
        while not s.done and rclpy.ok():
            stamp = s.time_ns()
            x, v = s.motion()
            self._publish_state(stamp, x, v)
            deadline = time.monotonic() + timeout
            while stamp not in self._forces:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or not rclpy.ok():
                    self.get_logger().error(
                        f"no force for sample {s.k} (t = {stamp * 1e-9:.3f} s) within "
                        f"{timeout:g} s: is the emulator running with "
                        f"emulator.trigger: input?")
                    self.exit_status = 1
                    return
                executor.spin_once(timeout_sec=remaining)
            force, status = self._forces.pop(stamp)
            self._forces.clear()
            self.faults |= status
            s.apply(force, status)
            self._publish_ride(stamp)

    def _run_realtime(self, executor) -> None:
        s = self.session
        p = self.run_params
        timeout_ns = int(p.force_timeout_s * 1e9)

        sub = self._force_sub

        def tick(now_ns: int) -> None:
            if s.done:
                raise StopIteration
            for msg, _info in take_all(sub):
                self._on_force(msg)
            latest = self._latest
            k = s.k
            if latest is None:
                force, status = self.static_force_n, 0
                if now_ns - self._started_ns > timeout_ns:
                    raise TimeoutError(f"no force from the emulator within "
                                       f"{p.force_timeout_s:g} s of the start")
            else:
                recv, force, status, answered = latest
                if now_ns - recv > timeout_ns:
                    raise TimeoutError(f"no force from the emulator for "
                                       f"{(now_ns - recv) * 1e-9:.3f} s")
                if answered >= 0 and k > 0:
                    # the last sample whose state was published by then (the emulator's
                    # reception, which its age counts from, follows the publication)
                    j = int(np.searchsorted(self._state_stamps[:k], answered, "right")) - 1
                    if j >= 0:
                        self._delays[k] = k - j
            span = self._span
            if span:
                span[2], span[3] = s.k, now_ns
            else:
                span += [s.k, now_ns, s.k, now_ns]
            stamp = time.time_ns()
            x, v = s.motion()
            self._publish_state(stamp, x, v)
            self._state_stamps[k] = stamp
            self.faults |= status
            s.apply(force, status)
            self._publish_ride(stamp)

        self._loop = PeriodicLoop(s.dt_s, tick, name="ride-loop",
                                  realtime=RealtimeRequest(sched_fifo=p.sched_fifo,
                                                           priority=p.priority,
                                                           lock_memory=False),
                                  capacity=s.n + 16)
        self._loop.start()
        while rclpy.ok() and self._loop.running:
            executor.spin_once(timeout_sec=0.05)
        self._loop.stop()
        self._io_node.destroy_node()
        self._io_node = None
        err = self._loop.error
        if err is not None and not isinstance(err, StopIteration):
            self.get_logger().error(f"ride aborted at sample {s.k}: {err}")
            self.exit_status = 1

    def _finish(self) -> None:
        s = self.session
        try:
            m = s.metrics()
        except ValueError as exc:
            self.get_logger().error(str(exc))
            self.exit_status = 1
            return
        elapsed = (time.monotonic_ns() - self._started_ns) * 1e-9
        # the loop's own pace: samples advanced over the time between the first and the
        # last tick (not the start-up or the wait for acknowledgements after it)
        k0, t0, k1, t1 = self._span or (0, 0, 0, 0)
        loop_s = (t1 - t0) * 1e-9
        rtf = (k1 - k0) * s.dt_s / loop_s if loop_s > 0 else None
        doc = {
            "clock": self.run_params.clock,
            "samples": s.k,
            "lead_in_samples": s.n_lead,
            "step_s": s.dt_s,
            "speed_m_s": self.run_params.speed_m_s,
            "duration_s": self.run_params.duration_s,
            "seed": self.run_params.seed,
            "elapsed_s": round(elapsed, 3),
            "real_time_factor": round(rtf, 4) if rtf is not None else None,
            "loop_s": round(loop_s, 3),
            "damper_fault_bits": int(self.faults),
            "static_force_n": self.static_force_n,
            "metrics": m,
        }
        if self._loop is not None:
            st = self._loop.stats.summary()
            doc["loop"] = {"period_p50_us": st.period_p50_us, "period_p99_us": st.period_p99_us,
                           "period_max_us": st.period_max_us, "overruns": st.overruns,
                           "skipped": st.skipped, "realtime": self._loop.report.summary()}
            delay = loop_delay.summarise(self._delays[:s.k], s.dt_s, self.delay_bound_s)
            doc["loop_delay"] = delay
            late = loop_delay.warning(delay)
            if late:
                self.get_logger().warning(late)
        self.get_logger().info(
            f"ride done: {s.k} samples in {elapsed:.1f} s; SWS r.m.s. "
            f"{m['sws_rms'] * 1e3:.2f} mm, weighted body acceleration r.m.s. "
            f"{m['accel_w_rms']:.3f} m/s², DTL r.m.s. {m['dtl_rms']:.0f} N")
        if self.run_params.metrics_file:
            path = Path(self.run_params.metrics_file)
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
                write_text(path, json.dumps(doc, indent=2) + "\n")
            except OSError as exc:
                self.get_logger().error(f"cannot write {path}: {exc.strerror}")
                self.exit_status = 1

