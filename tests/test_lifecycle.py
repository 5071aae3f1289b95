"""Issue 18: the emulator and the CAN bridge are managed (lifecycle) nodes.  Started with
``autostart:=false`` as separate processes, they are driven through every transition over
the standard ``lifecycle_msgs`` services (real DDS, localhost, ROS domains 150..152) and
what each publishes (ROS topics, CAN frames on a real ``udp_multicast`` bus) is checked in
each state: nothing before 'active'; outputs while active; on deactivation one last output
in the safe state (the emulator's fault mode with the ``INACTIVE`` bit, the bridge's fault
frame and fail-safe valve command) with the reason on ``/diagnostics``, then nothing."""

from __future__ import annotations

import math
import time

import pytest
from ros_probe import Probe  # noqa: E402
from test_bridge import MS, BusTap, bridge_params, start_node, udp_channel  # noqa: E402

from can_bridge import ForceStatus, load_database
from can_bridge.core import FORCE
from damper_emulator import force_message
from damper_emulator.params import load_config
from damper_emulator.realtime.core import Status

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

    def _call(self, client, request):
        fut = client.call_async(request)
        assert self.probe.spin_until(fut.done, 60)
        return fut.result()

    def state(self) -> str:
        from lifecycle_msgs.srv import GetState

        return self._call(self.get, GetState.Request()).current_state.label

    def transition(self, name: str) -> bool:
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState

        req = ChangeState.Request()
        req.transition.id = getattr(Transition, f"TRANSITION_{name.upper()}")
        return self._call(self.change, req).success


def _locked_kb(pid: int) -> int:
    """The process's locked memory (``VmLck`` of /proc/PID/status) [kB]."""
    for line in open(f"/proc/{pid}/status"):
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

    from damper_emulator.ros import topics
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
        status = [force_message.status_of(m.effort) for m in forces]
        assert sum(s == 0 for s in status) > 200, set(status)   # the model's forces

        n_active = len(forces)
        assert lc.transition("deactivate") and lc.state() == "inactive"
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
        assert any("inactive: deactivated" in s.message for s in diags), \
            [s.message for s in diags][-5:]

        # active again: the forces resume; then back down to unconfigured and finalized
        assert lc.transition("activate") and lc.state() == "active"
        feed(0.5)
        assert len(forces) > n_inactive + 100
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
        assert lc.transition("deactivate")
        t_off = time.monotonic_ns()
        time.sleep(0.2)
        last = tap.decoded(FORCE, t_off - 50 * MS)
        assert last and int(last[-1][1]["Status"]) & ForceStatus.FORCE_TIMEOUT
        t1 = time.monotonic_ns()
        time.sleep(QUIET_S)
        assert not tap.of(FORCE, t1), "frames after the deactivation"
        # every frame it sent passed the receiver's checks (counter continuity included)
        assert tap.checked(FORCE, t0).total.dropped == 0
        probe.spin_for(0.5)
        assert any("inactive: deactivated" in s.message for s in diags), \
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

    from damper_emulator.ros import topics
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
