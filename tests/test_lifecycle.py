"""The emulator and the CAN bridge are managed (lifecycle) nodes.  Started with
``autostart:=false`` as separate processes, they are driven through every transition over
the standard ``lifecycle_msgs`` services (real DDS, localhost, ROS domains 150..152) and
what each publishes (ROS topics, CAN frames on a real ``udp_multicast`` bus) is checked in
each state: nothing before 'active'; outputs while active; on deactivation one last output
in the safe state (the emulator's fault mode with the ``INACTIVE`` bit, the bridge's fault
frame and fail-safe valve command) with the reason on ``/diagnostics``, then nothing."""

from __future__ import annotations

import math
import signal
import time

import pytest
from ros_probe import Probe
from test_bridge import ROOT, BusTap, bridge_params, start_node, udp_channel

from can_bridge import ForceStatus, load_database
from can_bridge.core import FORCE
from damper_emulator import force_message
from damper_emulator.params import load_config
from damper_emulator.realtime.core import Status
from damper_emulator.ros.managed import TRANSITION_NAMES, VALID_TRANSITIONS

pytestmark = [pytest.mark.ros, pytest.mark.can]

DOMAINS = {"emulator": 150, "dyno_bridge": 151, "controller_bridge": 152}
#: udp_multicast offsets of this file (tests/test_bridge.py uses 0..5 in the same process)
OFFSETS = {"dyno_bridge": 6, "controller_bridge": 7}
#: how long "nothing is published" is watched [s]
QUIET_S = 0.6


class Lifecycle:
    """The standard lifecycle services of one node, called from a probe."""

    def __init__(self, probe: Probe, node: str):
        from lifecycle_msgs.srv import ChangeState, GetState

        self.probe = probe
        self.change = probe.node.create_client(ChangeState, f"/{node}/change_state")
        self.get = probe.node.create_client(GetState, f"/{node}/get_state")
        for client in (self.change, self.get):
            assert probe.spin_until(client.service_is_ready, 120), node

    def _call(self, client, request, tries: int = 1):
        """``request`` over ``client``; ``tries`` > 1 sends an idempotent request again
        when no answer came: Fast DDS may lose a service's first exchange although the
        service was ready (ros2/rclcpp#1152; once in a clean clone's make test here)."""
        for _ in range(tries):
            fut = client.call_async(request)
            if self.probe.spin_until(fut.done, 60 / tries):
                return fut.result()
            client.remove_pending_request(fut)
        raise AssertionError(f"no answer from {client.service_name} in 60 s ({tries} tries)")

    def state(self) -> str:
        from lifecycle_msgs.srv import GetState

        return self._call(self.get, GetState.Request(), tries=3).current_state.label

    def transition(self, name: str) -> bool:
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState

        req = ChangeState.Request()
        req.transition.id = getattr(Transition, f"TRANSITION_{name.upper()}")
        return self._call(self.change, req).success


def _locked_kb(pid: int) -> int:
    """The process's locked memory (``VmLck`` of /proc/PID/status) [kB]."""
    with open(f"/proc/{pid}/status") as status:
        for line in status:
            if line.startswith("VmLck:"):
                return int(line.split()[1])
    return 0


def _diagnostics(probe: Probe, prefix: str) -> list:
    from diagnostic_msgs.msg import DiagnosticArray

    seen: list = []
    probe.node.create_subscription(
        DiagnosticArray, "/diagnostics",
        lambda m: seen.extend(s for s in m.status if s.name.startswith(prefix)), 10)
    return seen


def test_the_emulator_through_every_transition(tmp_path):
    from sensor_msgs.msg import JointState

    from damper_emulator import topics
    from damper_emulator.ros.common import control_qos, set_stamp

    node = start_node("emulator", "emulate", DOMAINS["emulator"], tmp_path, {
        "autostart": False, "emulator.trigger": "timer", "emulator.fault_mode": "passive",
        "emulator.input_timeout_s": 0.1, "emulator.diagnostics_period_s": 0.2})
    probe = Probe(DOMAINS["emulator"])
    forces: list = []
    try:
        probe.node.create_subscription(JointState, topics.FORCE, forces.append,
                                       control_qos(1000))
        states = probe.node.create_publisher(JointState, topics.STATE, control_qos(10))
        diags = _diagnostics(probe, "damper_emulator")
        lc = Lifecycle(probe, "damper_emulator")
        assert lc.state() == "unconfigured"
        probe.spin_for(QUIET_S)
        assert not forces, "forces before configure"
        assert lc.transition("configure") and lc.state() == "inactive"
        probe.spin_for(QUIET_S)
        assert not forces, "forces while inactive"

        assert lc.transition("activate") and lc.state() == "active"

        def feed(seconds: float) -> None:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                msg = JointState(name=["damper"], position=[0.01], velocity=[0.0])
                set_stamp(msg.header.stamp, time.time_ns())
                states.publish(msg)
                probe.spin_for(0.002, 0.001)

        feed(1.0)

        def model_forces() -> int:
            return sum(force_message.status_of(m.effort) == 0 for m in forces)

        # the model's forces, computed while fed (reliable: late on a loaded machine, and
        # all there)
        assert probe.spin_until(lambda: model_forces() > 200, 10), \
            {force_message.status_of(m.effort) for m in forces}

        n_active = len(forces)
        assert lc.transition("deactivate") and lc.state() == "inactive"
        # reliable delivery keeps the order, not the time: a lost sample comes again on
        # the writer's next heartbeat (seconds on a loaded CI machine)
        assert probe.spin_until(lambda: any(
            force_message.status_of(m.effort) == int(Status.INACTIVE)
            for m in forces[n_active:]), 10), "no INACTIVE force on leaving 'active'"
        probe.spin_for(QUIET_S)
        last = forces[-1]
        assert force_message.status_of(last.effort) == int(Status.INACTIVE)
        # fault mode 'passive' at rest: the static gas force, -A_rod p_gas (eq 30)
        d = load_config().damper
        static = -math.pi / 4 * d.rod_diameter_m ** 2 * d.gas_pressure_static_pa
        assert last.effort[0] == pytest.approx(static, rel=1e-3)
        assert [force_message.status_of(m.effort) for m in forces[n_active:]].count(
            int(Status.INACTIVE)) == 1
        n_inactive = len(forces)
        probe.spin_for(QUIET_S)
        assert len(forces) == n_inactive, "forces after the deactivation"
        assert probe.spin_until(lambda: any(
            "inactive: deactivated" in s.message for s in diags), 10), \
            [s.message for s in diags][-5:]

        # active again: the forces resume; then back down to unconfigured and finalized
        assert lc.transition("activate") and lc.state() == "active"
        feed(0.5)
        # (as above: on a loaded machine the forces of those 0.5 s may arrive seconds late)
        assert probe.spin_until(lambda: len(forces) > n_inactive + 100, 10), \
            f"{len(forces) - n_inactive} forces after activating again"
        locked_active = _locked_kb(node.proc.pid)
        assert lc.transition("deactivate") and lc.transition("cleanup")
        assert lc.state() == "unconfigured"
        if locked_active:  # mlockall was permitted: cleanup gives the memory back
            assert _locked_kb(node.proc.pid) == 0, locked_active
        assert lc.transition("unconfigured_shutdown") and lc.state() == "finalized"
    finally:
        probe.close()
        node.stop()
    assert "Traceback" not in node.log_path.read_text()


@pytest.fixture(scope="module")
def db():
    return load_database()


def test_the_dyno_bridge_through_every_transition(tmp_path, db):
    channel = udp_channel(OFFSETS["dyno_bridge"])
    tap = BusTap(channel, db)
    node = start_node("bridge", "bridge", DOMAINS["dyno_bridge"], tmp_path,
                      bridge_params(channel, autostart=False, emulator_node="",
                                    diagnostics_period_s=0.2))
    probe = Probe(DOMAINS["dyno_bridge"])
    try:
        diags = _diagnostics(probe, "can_bridge")
        lc = Lifecycle(probe, "can_bridge")
        assert lc.state() == "unconfigured"
        t0 = time.monotonic_ns()
        time.sleep(QUIET_S)
        assert not tap.of(FORCE, t0), "frames before configure"
        assert lc.transition("configure") and lc.state() == "inactive"
        t0 = time.monotonic_ns()
        time.sleep(QUIET_S)
        assert not tap.of(FORCE, t0), "frames while inactive"
        assert lc.transition("activate") and lc.state() == "active"
        # no emulator: the watchdog's fault frames, one per DBC cycle
        assert tap.wait_for(lambda: len(tap.of(FORCE, t0)) > 20, 10), node.log_tail()
        frames = tap.decoded(FORCE, t0)
        assert all(int(v["Status"]) & ForceStatus.FORCE_TIMEOUT and v["Force"] == 0.0
                   for _, v in frames)
        t_off = time.monotonic_ns()
        assert lc.transition("deactivate")
        time.sleep(0.2)
        last = tap.decoded(FORCE, t_off)
        assert last and int(last[-1][1]["Status"]) & ForceStatus.FORCE_TIMEOUT
        t1 = time.monotonic_ns()
        time.sleep(QUIET_S)
        assert not tap.of(FORCE, t1), "frames after the deactivation"
        # every frame it sent passed the receiver's checks (counter continuity included)
        assert tap.checked(FORCE, t0).total.dropped == 0
        probe.spin_for(0.5)
        assert probe.spin_until(lambda: any(
            "inactive: deactivated" in s.message for s in diags), 10), \
            [s.message for s in diags][-5:]
        assert lc.transition("cleanup") and lc.state() == "unconfigured"
        assert lc.transition("unconfigured_shutdown") and lc.state() == "finalized"
    finally:
        probe.close()
        tap.close()
        node.stop()
    assert "Traceback" not in node.log_path.read_text()


def test_the_controller_bridge_applies_its_fail_safe_command_on_deactivation(tmp_path, db):
    from std_msgs.msg import Float64

    from damper_emulator import topics
    from damper_emulator.ros.common import control_qos

    channel = udp_channel(OFFSETS["controller_bridge"])
    tap = BusTap(channel, db)
    node = start_node("bridge", "bridge", DOMAINS["controller_bridge"], tmp_path,
                      bridge_params(channel, mode="controller", autostart=False,
                                    emulator_node="", fail_safe_command=0.25))
    probe = Probe(DOMAINS["controller_bridge"])
    commands: list[float] = []
    try:
        probe.node.create_subscription(Float64, topics.VALVE_COMMAND,
                                       lambda m: commands.append(m.data), control_qos(10))
        lc = Lifecycle(probe, "can_bridge")
        assert lc.transition("configure") and lc.transition("activate")
        probe.spin_for(0.3)
        assert not commands
        assert lc.transition("deactivate")
        assert probe.spin_until(lambda: commands, 5)
        assert commands == [0.25]
        assert lc.transition("cleanup") and lc.state() == "unconfigured"
    finally:
        probe.close()
        tap.close()
        node.stop()


# ======================================================================================
# every lifecycle request, valid or not, in every state: the node stays up
# ======================================================================================

#: Transition ids a request may carry: every id lifecycle_msgs defines (the manager's and
#: the state machine's internal ones), and ids it does not define.
REQUEST_IDS = [*sorted(TRANSITION_NAMES), 9, 99, 255]
#: Labels a request may carry: every transition label of the design, and one that is none.
REQUEST_LABELS = ("configure", "cleanup", "activate", "deactivate", "shutdown",
                  "unconfigured_shutdown", "create", "destroy", "no_such_transition")
#: The labels valid in each state (the managed-node design's transition labels).
VALID_LABELS = {"unconfigured": {"configure", "shutdown"},
                "inactive": {"cleanup", "activate", "shutdown"},
                "active": {"deactivate", "shutdown"}, "finalized": set()}
#: What each valid transition leads to (the managed-node design).
GOAL = {"configure": "inactive", "cleanup": "unconfigured", "activate": "active",
        "deactivate": "inactive", "unconfigured_shutdown": "finalized",
        "inactive_shutdown": "finalized", "active_shutdown": "finalized"}
#: Walks through the valid transitions, each from the state where it is valid; each walk
#: is one node process (a shutdown ends it), together they take every valid transition.
WALKS = (("configure", "cleanup", "configure", "activate", "deactivate", "activate",
          "active_shutdown"),
         ("unconfigured_shutdown",),
         ("configure", "inactive_shutdown"))
#: The project's managed nodes, as each table test starts them: subcommand, node name and
#: parameters.  A node class added later must be added here (checked below).
MANAGED_NODES = {
    "EmulatorNode": ("emulate", "damper_emulator", {
        "emulator.trigger": "timer", "emulator.fault_mode": "passive",
        "emulator.diagnostics_period_s": 0.2}),
    "BridgeNode": ("bridge", "can_bridge", {"emulator_node": "",
                                            "diagnostics_period_s": 0.2}),
}
#: ROS domain and udp_multicast offset of each table test
TABLE_DOMAINS = {"EmulatorNode": 154, "BridgeNode": 155}
TABLE_OFFSETS = {"BridgeNode": 8}


def test_every_managed_node_class_is_in_the_table():
    """Every class of the project that derives from ManagedNode (found in the source, so
    that a node added later cannot be forgotten) is driven by the table test below."""
    import ast

    found = set()
    for path in ROOT.glob("*/**/*.py"):
        if path.parts[len(ROOT.parts)] in ("tests", ".venv", "benchmarks"):
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ClassDef) and any(
                    getattr(b, "id", getattr(b, "attr", "")) == "ManagedNode"
                    for b in node.bases):
                found.add(node.name)
    assert found == set(MANAGED_NODES), found


class _Requests(Lifecycle):
    """:class:`Lifecycle` with requests by raw id and label, and the node's process."""

    def __init__(self, probe: Probe, node: str, process):
        super().__init__(probe, node)
        self.process = process

    def request(self, transition_id: int = 0, label: str = "") -> bool:
        from lifecycle_msgs.srv import ChangeState

        req = ChangeState.Request()
        req.transition.id = transition_id
        req.transition.label = label
        return self._call(self.change, req).success

    def refuses_everything_invalid(self, state: str) -> None:
        """Every id and label not valid in ``state`` is refused; the node stays in
        ``state`` and up."""
        valid = set(VALID_TRANSITIONS[state])
        for tid in REQUEST_IDS:
            if tid in valid:
                continue
            assert not self.request(transition_id=tid), (state, tid)
            assert self.process.poll() is None, (state, tid, self.process.log_tail())
        for label in REQUEST_LABELS:
            if label in VALID_LABELS[state]:
                continue
            assert not self.request(label=label), (state, label)
        assert self.state() == state and self.process.poll() is None


def _start_managed(kind: str, tmp_path, channel: str | None):
    subcommand, name, params = MANAGED_NODES[kind]
    params = {"autostart": False, **params}
    if channel is not None:
        params.update(bridge_params(channel))
    return start_node(f"{name}_table", subcommand, TABLE_DOMAINS[kind], tmp_path, params)


@pytest.mark.parametrize("kind", sorted(MANAGED_NODES))
def test_every_transition_in_every_state_is_taken_or_refused(kind, tmp_path, db):
    """The table of (state × transition): over the real ``change_state`` service, every
    transition id lifecycle_msgs defines (and some it does not), and every label, in each
    primary state.  A valid one is taken (``success``, the design's goal state); any other
    is refused (``success = False``) and the node stays in its state, up.  Leaving
    'active' (deactivate, shutdown) always sends the safe output: the emulator's
    ``INACTIVE`` force, the bridge's fault frame."""
    from lifecycle_msgs.msg import Transition
    from sensor_msgs.msg import JointState

    from damper_emulator import topics
    from damper_emulator.ros.common import control_qos

    name = MANAGED_NODES[kind][1]
    channel = udp_channel(TABLE_OFFSETS[kind]) if kind in TABLE_OFFSETS else None
    tap = BusTap(channel, db) if channel is not None else None
    try:
        for walk in WALKS:
            node = _start_managed(kind, tmp_path, channel)
            probe = Probe(TABLE_DOMAINS[kind])
            forces: list = []
            probe.node.create_subscription(JointState, topics.FORCE, forces.append,
                                           control_qos(1000))
            try:
                lc = _Requests(probe, name, node)
                state = "unconfigured"
                assert lc.state() == state
                for step in walk:
                    lc.refuses_everything_invalid(state)
                    t_before = time.monotonic_ns()
                    n_before = len(forces)
                    if state == "active" and tap is not None:
                        _feed_forces(probe, tap, t_before)  # forces, no faults
                    assert lc.request(transition_id=getattr(
                        Transition, f"TRANSITION_{step.upper()}")), \
                        (state, step, node.log_tail())
                    left_active = state == "active"
                    state = GOAL[step]
                    assert lc.state() == state, (step, node.log_tail())
                    if left_active:
                        _assert_safe_output(kind, probe, forces, n_before, tap, t_before)
                lc.refuses_everything_invalid(state)
                assert state == "finalized"
            finally:
                probe.close()
                assert node.stop() == 0, node.log_tail(20)
            log = node.log_path.read_text()
            assert "Traceback" not in log and "internal error" not in log, log[-2000:]
    finally:
        if tap is not None:
            tap.close()


def _feed_forces(probe: Probe, tap, since_ns: int) -> None:
    """Emulator forces on ``/damper/force`` at about 1 kHz (what a bridge in dyno mode
    turns into DAMPER_FORCE frames): 20 after the first that the bridge turned into a
    frame (it takes them best effort, and drops what comes before it has matched this
    publisher on its side)."""
    from sensor_msgs.msg import JointState

    from damper_emulator import topics
    from damper_emulator.ros.common import control_qos

    pub = probe.node.create_publisher(JointState, topics.FORCE, control_qos(100))
    assert probe.spin_until(lambda: pub.get_subscription_count() > 0, 30)

    def force(j: int) -> JointState:
        return JointState(name=["damper", "damper/status"], position=[1e-3, 2e-4],
                          velocity=[0.0, 0.0], effort=[100.0 + j, 0.0])

    def forwarded() -> bool:
        pub.publish(force(0))
        return any(not int(v["Status"]) & ForceStatus.FORCE_TIMEOUT
                   for _, v in tap.decoded(FORCE, since_ns))
    assert probe.spin_until(forwarded, 30), "no force forwarded"
    for j in range(20):
        pub.publish(force(j))
        probe.spin_for(0.001, 0.001)
    probe.node.destroy_publisher(pub)


def _assert_safe_output(kind: str, probe: Probe, forces: list, n_before: int, tap,
                        t_before: int) -> None:
    """The node just left 'active' (after ``t_before``; the bridge was fed forces then):
    its last output is the safe one, and nothing follows it."""
    if kind == "EmulatorNode":
        assert probe.spin_until(lambda: any(
            force_message.status_of(m.effort) == int(Status.INACTIVE)
            for m in forces[n_before:]), 10), "no INACTIVE force on leaving 'active'"
        probe.spin_for(0.2)
        assert force_message.status_of(forces[-1].effort) == int(Status.INACTIVE)
        n_after = len(forces)
        probe.spin_for(QUIET_S)
        assert len(forces) == n_after, "forces after the safe output"
    else:
        # forces were flowing (no fault bit) just before; the last frame is the fault frame
        assert tap.wait_for(lambda: tap.of(FORCE, t_before), 10)
        time.sleep(QUIET_S)
        frames = tap.decoded(FORCE, t_before)
        assert any(not int(v["Status"]) & ForceStatus.FORCE_TIMEOUT for _, v in frames)
        last = frames[-1][1]
        assert int(last["Status"]) & ForceStatus.FORCE_TIMEOUT and last["Force"] == 0.0
        t_last = frames[-1][0]
        time.sleep(QUIET_S)
        assert tap.of(FORCE, t_last + 1) == [], "frames after the safe output"


@pytest.mark.parametrize(("kind", "signum"), [("EmulatorNode", signal.SIGTERM),
                                         ("BridgeNode", signal.SIGINT)])
def test_a_stop_signal_while_active_sends_the_safe_output(kind, signum, tmp_path, db):
    """SIGINT (a launch file's Ctrl-C) or SIGTERM (a service manager's stop) while active
    is a shutdown transition: the safe output goes out, with the signal as the reason on
    ``/diagnostics``, and the process exits 0."""
    from sensor_msgs.msg import JointState

    from damper_emulator import topics
    from damper_emulator.ros.common import control_qos

    subcommand, name, params = MANAGED_NODES[kind]
    channel = udp_channel(TABLE_OFFSETS[kind]) if kind in TABLE_OFFSETS else None
    tap = BusTap(channel, db) if channel is not None else None
    params = {**params, **(bridge_params(channel) if channel is not None else {})}
    node = start_node(f"{name}_signal", subcommand, TABLE_DOMAINS[kind], tmp_path, params)
    probe = Probe(TABLE_DOMAINS[kind])
    forces: list = []
    probe.node.create_subscription(JointState, topics.FORCE, forces.append,
                                   control_qos(1000))
    diags = _diagnostics(probe, name)
    try:
        if tap is None:
            assert probe.spin_until(lambda: len(forces) > 100, 120), node.log_tail()
        else:
            assert tap.wait_for(lambda: len(tap.of(FORCE)) > 100, 120), node.log_tail()
        # the probe hears the node's diagnostics (its subscription matched) before the stop
        assert probe.spin_until(lambda: diags, 30), node.log_tail()
        t_before, n_before = time.monotonic_ns(), len(forces)
        if tap is not None:
            _feed_forces(probe, tap, t_before)
        node.proc.send_signal(signum)
        assert probe.spin_until(lambda: any(
            f"stopped by {signum.name}" in s.message for s in diags), 10), node.log_tail()
        assert node.wait(20) == 0, node.log_tail(20)
        probe.spin_for(0.2)
        _assert_safe_output(kind, probe, forces, n_before, tap, t_before)
    finally:
        probe.close()
        if tap is not None:
            tap.close()
        node.stop()
    assert "Traceback" not in node.log_path.read_text()


class _Hooks:
    """A managed node whose hooks record their calls, and one of which raises (the first
    time it is called, or every time)."""

    @staticmethod
    def node(context, raising: str = "", reason: str | None = None, always: bool = False):
        from damper_emulator.ros.managed import ManagedNode

        class Recorded(ManagedNode):
            def __init__(self):
                self.calls: list = []
                super().__init__("recorded_hooks", context=context)

            def _hook(self, name, *args):
                first = all(c[0] != name for c in self.calls)
                self.calls.append((name, *args))
                if name == raising and (first or always):
                    raise RuntimeError(f"{name} is broken")

            def _configure(self):
                self._hook("configure")
                return reason

            def _activate(self):
                self._hook("activate")

            def _leave_active(self, why):
                self._hook("leave_active", why)

            def _stop_io(self):
                self._hook("stop_io")

            def _release(self):
                self._hook("release")

        return Recorded()


@pytest.fixture
def context():
    import os

    import rclpy
    from rclpy.context import Context

    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    ctx = Context()
    rclpy.init(context=ctx, domain_id=156)
    yield ctx
    rclpy.shutdown(context=ctx)


@pytest.mark.parametrize("raising", ["activate", "leave_active"])
def test_a_transition_that_raises_leaves_the_safe_state_and_unconfigured(context, raising):
    """A hook that raises is a bug: logged, the transition fails, the outputs go to their
    safe state before everything is released, and the node is 'unconfigured' (so a
    manager can configure it again), not dead and not stuck."""
    from rclpy.lifecycle import TransitionCallbackReturn as R

    node = _Hooks.node(context, raising=raising)
    try:
        assert node.trigger_configure() == R.SUCCESS
        if raising == "activate":
            assert node.trigger_activate() == R.ERROR
        else:
            assert node.trigger_activate() == R.SUCCESS
            assert node.trigger_deactivate() == R.ERROR
        names = [c[0] for c in node.calls]
        # error processing: the safe output (again, where leaving raised), then release
        assert names[-3:] == ["leave_active", "stop_io", "release"], node.calls
        assert "failed" in node.calls[-3][1]
        assert node.lifecycle_state == "unconfigured" and node.exit_status == 1
        assert node.trigger_configure() == R.SUCCESS   # only valid from 'unconfigured'
    finally:
        node.destroy_node()


def test_a_configure_that_cannot_releases_and_stays_unconfigured(context):
    """``_configure`` returning a reason (a port taken, ...): the transition fails, what
    was built is released, the node stays 'unconfigured'; nothing is a bug."""
    from rclpy.lifecycle import TransitionCallbackReturn as R

    node = _Hooks.node(context, reason="the live view's port is taken")
    try:
        assert node.trigger_configure() == R.FAILURE
        assert [c[0] for c in node.calls] == ["configure", "release"]
        assert node.lifecycle_state == "unconfigured" and node.exit_status == 0
        assert node.trigger_configure() == R.FAILURE   # still valid: still unconfigured
    finally:
        node.destroy_node()


def test_when_error_processing_fails_the_node_is_finalized(context):
    from rclpy.lifecycle import TransitionCallbackReturn as R

    node = _Hooks.node(context, raising="release", always=True)
    try:
        assert node.trigger_configure() == R.SUCCESS
        assert node.trigger_cleanup() == R.ERROR     # release raises, then again in on_error
        assert node.lifecycle_state == "finalized"
        with pytest.raises(Exception, match="not registered"):   # finalized: no transition
            node.trigger_configure()
    finally:
        node.destroy_node()
