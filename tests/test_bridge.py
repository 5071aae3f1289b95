"""The CAN bridge's ``damper-hil bridge`` node as users run it (its core alone:
tests/test_bridge_core.py): separate processes over real DDS (localhost only, ROS domains
130..137), real python-can buses (``udp_multicast`` on interface-local ``ff11::`` groups,
one group and port per bus set-up derived from the process id), no mocks.

Node processes are started once per test class (class-scoped fixtures), so the whole file
takes well under a minute; the ``--over-can --external`` failure run (20 s connect timeout)
starts with the module and runs in the background.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path
from types import SimpleNamespace

import can
import numpy as np
import pytest
from ros_probe import Probe

from can_bridge import (
    BusConfig,
    Encoder,
    ForceStatus,
    Receiver,
    ResilientBus,
    load_database,
    socketcan_available,
    socketcan_problem,
)
from can_bridge.core import COMMAND, FORCE, MOTION, STATE
from can_bridge.settings import BridgeParams

pytestmark = [pytest.mark.ros, pytest.mark.can]

ROOT = Path(__file__).resolve().parent.parent
#: each set-up its own ROS domain (tests/test_nodes.py uses 120..126; the benchmark 138, 139)
DOMAINS = {"dyno": 130, "lone": 131, "sine": 132, "chirp": 133, "controller": 134,
           "badparams": 135, "external": 136, "socketcan": 137, "model": 144}
#: each bus set-up its own udp_multicast group and port (offset 0..9 within this process's
#: block of ports)
OFFSETS = {"dyno": 0, "lone": 1, "sine": 2, "chirp": 3, "controller": 4, "external": 5,
           "model": 6}
CLI = [sys.executable, "-m", "damper_hil.cli"]
STROKE_STEP = 1e-5           # DAMPER_STATE.Stroke / DAMPER_FORCE.StrokeUsed resolution [m]
VELOCITY_STEP = 2e-4         # DAMPER_STATE.Velocity resolution [m/s]


def udp_channel(offset: int) -> str:
    """An interface-local group and a UDP port private to this process and ``offset``.

    python-can binds the port on every address, so the port is what separates concurrent
    set-ups; ports 10000..16999 stay clear of the DDS ports of the domains in use here
    (7400 + 250·domain …) and of the kernel's ephemeral range."""
    pid = os.getpid()
    return (f"[ff11::d4:{offset:x}:{pid >> 16:x}:{pid & 0xFFFF:x}]:"
            f"{10000 + (pid % 700) * 10 + offset}")


@pytest.fixture(scope="module")
def db():
    return load_database()


MS = 1_000_000

# ======================================================================================
# helpers for the node tests
# ======================================================================================


class BusTap:
    """A python-can udp_multicast bus of the test: sends frames, records every frame that
    arrives (its own echoed ones included) with the monotonic arrival time."""

    def __init__(self, channel: str, db):
        self.db = db
        self.bus = ResilientBus(BusConfig(interface="udp_multicast", channel=channel))
        assert self.bus.ensure_open(), self.bus.last_error
        self.frames: list[tuple[int, int, bytes]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="test-can-rx", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self.bus.recv(0.05)
            if msg is not None:
                self.frames.append((time.monotonic_ns(), msg.arbitration_id, bytes(msg.data)))

    def send(self, frame_id: int, data: bytes) -> int:
        """Send a frame; returns the time [ns, monotonic] just before it went out: no
        receiver can have had it earlier (a time taken after the send returns can be late
        by a preemption, on a loaded machine more than a millisecond)."""
        sent = time.monotonic_ns()
        assert self.bus.send(can.Message(arbitration_id=frame_id, data=data,
                                         is_extended_id=False)), self.bus.last_error
        return sent

    def of(self, name: str, since_ns: int = 0,
           until_ns: float = math.inf) -> list[tuple[int, bytes]]:
        """(arrival, payload) of the frames of message ``name`` that arrived in
        ``[since_ns, until_ns)``."""
        frame_id = self.db.get_message_by_name(name).frame_id
        return [(t, d) for t, i, d in list(self.frames)
                if i == frame_id and since_ns <= t < until_ns]

    def decoded(self, name: str, since_ns: int = 0,
                until_ns: float = math.inf) -> list[tuple[int, dict]]:
        rx = Receiver(self.db, [name])
        return [(t, rx.decode_values(name, d)) for t, d in self.of(name, since_ns, until_ns)]

    def checked(self, name: str, since_ns: int = 0, until_ns: float = math.inf) -> Receiver:
        """A fresh Receiver that has accepted (or dropped) those frames of ``name``."""
        rx = Receiver(self.db, [name])
        for _, d in self.of(name, since_ns, until_ns):
            rx.accept(self.db.get_message_by_name(name).frame_id, d)
        return rx

    def wait_for(self, predicate, timeout_s: float, tick=None) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if predicate():
                return True
            if tick is not None:
                tick()
            time.sleep(0.01)
        return predicate()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.bus.close()


def start_node(name: str, subcommand: str, domain: int, tmp: Path, params=None):
    from damper_emulator.ros.launch import NodeProcess, node_command, ros_environment

    return NodeProcess(name, node_command(subcommand, params), ros_environment(domain),
                       tmp / "logs")


def bridge_params(channel: str, **more) -> dict:
    return {"can_interface": "udp_multicast", "can_channel": channel, **more}


def one_line_error(stderr: str) -> str:
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("damper-hil: error:"), stderr
    assert "Traceback" not in stderr
    return lines[0]


def _cli_env(domain: int) -> dict:
    from damper_emulator.ros.launch import ros_environment

    return ros_environment(domain)


@pytest.fixture(scope="module", autouse=True)
def external_run(tmp_path_factory):
    """``dyno --over-can --external`` with nothing on its bus: started with the module, it
    waits out its 20 s connect timeout in the background while the other tests run."""
    out = tmp_path_factory.mktemp("external")
    cmd = [*CLI, "dyno", "--protocol", "sine", "--over-can", "--external",
           "--can-interface", "udp_multicast", "--can-channel", udp_channel(OFFSETS["external"]),
           "--out", str(out)]
    proc = subprocess.Popen(cmd, env=_cli_env(DOMAINS["external"]), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    run = SimpleNamespace(proc=proc, started=time.monotonic(), ended=math.inf, out="",
                          err="")

    def wait() -> None:  # the command's own end, whatever the other tests take meanwhile
        run.out, run.err = proc.communicate()
        run.ended = time.monotonic()

    waiter = threading.Thread(target=wait, daemon=True)
    waiter.start()
    run.waiter = waiter
    yield run
    if proc.poll() is None:
        proc.kill()
    waiter.join(timeout=60)


# ======================================================================================
# 2. the bridge node in dyno mode, with the emulator (timer) and alone
# ======================================================================================


@pytest.fixture(scope="class")
def dyno_rig(tmp_path_factory, db):
    from diagnostic_msgs.msg import DiagnosticArray

    tmp = tmp_path_factory.mktemp("dyno")
    channel, lone_channel = udp_channel(OFFSETS["dyno"]), udp_channel(OFFSETS["lone"])
    nodes, taps, probe = [], [], None
    try:
        # input timeout 0.1 s: a busy 2-core machine may delay a sample by 20 ms
        nodes.append(start_node("emulator", "emulate", DOMAINS["dyno"], tmp,
                                {"emulator.trigger": "timer",
                                 "emulator.input_timeout_s": 0.1}))
        nodes.append(start_node("bridge", "bridge", DOMAINS["dyno"], tmp,
                                bridge_params(channel, diagnostics_period_s=0.2)))
        nodes.append(start_node("lone_bridge", "bridge", DOMAINS["lone"], tmp,
                                bridge_params(lone_channel)))
        tap, lone = BusTap(channel, db), BusTap(lone_channel, db)
        taps += [tap, lone]
        probe = Probe(DOMAINS["dyno"])
        diags: list = []
        probe.node.create_subscription(
            DiagnosticArray, "/diagnostics",
            lambda m: diags.extend((time.monotonic_ns(), s) for s in m.status
                                   if s.name.startswith("can_bridge")), 10)
        enc = Encoder(db, STATE)
        assert lone.wait_for(lambda: len(lone.of(FORCE)) > 100, 90), nodes[2].log_tail()
        fault = ForceStatus.FORCE_TIMEOUT | ForceStatus.NO_INPUT | ForceStatus.INPUT_TIMEOUT

        def emulator_answers() -> bool:
            recent = tap.decoded(FORCE, time.monotonic_ns() - 100 * MS)
            return sum(not int(v["Status"]) & fault for _, v in recent) >= 50

        assert tap.wait_for(emulator_answers, 90, tick=lambda: _stream(
            tap, enc, [0.01] * 10, 0.0)), "\n".join(n.log_tail() for n in nodes)
        yield SimpleNamespace(tap=tap, lone=lone, probe=probe, diags=diags, enc=enc,
                              nodes=nodes)
        for n in nodes:
            assert n.poll() is None, f"{n.name} stopped: {n.log_tail()}"
    finally:
        if probe is not None:
            probe.close()
        for t in taps:
            t.close()
        for n in reversed(nodes):
            n.stop()


def _stream(tap: BusTap, enc: Encoder, strokes, velocity: float,
            sent_at: list[int] | None = None) -> int:
    """Send one DAMPER_STATE per stroke at about 1 kHz; returns the monotonic time just
    before the last frame was sent (no receiver can have it earlier), and appends each
    frame's to ``sent_at``."""
    last = 0
    next_t = time.monotonic()
    for x in strokes:
        data = enc.encode(Stroke=float(x), Velocity=velocity)[0]
        last = time.monotonic_ns()
        tap.send(enc.frame_id, data)
        if sent_at is not None:
            sent_at.append(last)
        next_t += 1e-3
        delay = next_t - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    return last


def _lasting_run(bits: list[int], flag: int) -> int:
    """Where the run of ``flag``-ed statuses that lasts to the end begins (``len(bits)``:
    the last status is not flagged)."""
    clear = [i for i, b in enumerate(bits) if not b & flag]
    return clear[-1] + 1 if clear else 0


class TestDynoBridge:
    def test_states_in_forces_out_with_the_stroke_used(self, dyno_rig, db):
        tap, enc = dyno_rig.tap, dyno_rig.enc
        t0 = time.monotonic_ns()
        raw = 1000 + np.arange(400)                        # strokes 10.00 .. 13.99 mm
        last = _stream(tap, enc, raw * STROKE_STEP, 0.01)
        assert tap.wait_for(lambda: any(round(v["StrokeUsed"] / STROKE_STEP) == raw[-1]
                                        for _, v in tap.decoded(FORCE, last)), 5.0)
        t1 = time.monotonic_ns()
        forces = tap.decoded(FORCE, t0, t1)
        fault = ForceStatus.NO_INPUT | ForceStatus.INPUT_TIMEOUT | ForceStatus.FORCE_TIMEOUT
        model = [v for _, v in forces if not int(v["Status"]) & fault]
        assert len(model) >= 200, (f"{len(forces)} force frames, {len(model)} from the "
                                   f"model; status bits seen "
                                   f"{sorted(set(int(v['Status']) for _, v in forces))}")
        used = np.array([round(v["StrokeUsed"] / STROKE_STEP) for v in model])
        stray = sorted(set(used) - set(raw))
        assert not stray, f"StrokeUsed not among the strokes sent: {stray[:5]}"
        assert len(set(used)) >= 100                       # it follows the stream
        assert used[-1] == raw[-1]                          # the last sample
        assert all(math.isfinite(v["Force"]) for v in model)
        assert all(abs(v["Force"]) > 1.0 for v in model)    # the gas force at least
        # every frame of the bridge passes the receiver's checks (CRC, counter, length)
        checked = tap.checked(FORCE, t0, t1)
        assert checked.total.dropped == 0 and checked.total.accepted == len(forces)

    def test_a_dyno_bridge_publishes_no_valve_command(self, dyno_rig):
        """The valve command is the controller's: in dyno mode the bridge advertises
        /damper/state only (and /damper/force with ``model: true``)."""
        probe = dyno_rig.probe

        def publishers(topic: str) -> list[str]:
            return [i.node_name for i in probe.node.get_publishers_info_by_topic(topic)]

        # the bridge's publishers discovered (a loaded machine took more than 0.5 s), then
        # a moment more for any other it has
        assert probe.spin_until(lambda: "can_bridge" in publishers("/damper/state"), 20.0)
        probe.spin_for(0.5)
        assert "can_bridge" not in publishers("/damper/valve_command")

    def test_every_parameter_is_described_over_the_services(self, dyno_rig):
        """``ros2 param describe`` over the real services: every parameter of both nodes
        has its real type, a description with its unit, its rule and its limits, and only
        the schema's run-time parameters are writable."""
        import math as m

        from rcl_interfaces.msg import ParameterType as T
        from rcl_interfaces.srv import DescribeParameters, ListParameters

        probe = dyno_rig.probe

        def call(srv_type, name, request):
            client = probe.node.create_client(srv_type, name)
            assert probe.spin_until(client.service_is_ready, 30), name
            fut = client.call_async(request)
            assert probe.spin_until(fut.done, 10), name
            return fut.result()

        described = {}
        for node in ("damper_emulator", "can_bridge"):
            names = call(ListParameters, f"/{node}/list_parameters",
                         ListParameters.Request()).result.names
            names = [n for n in names                                 # not rclpy's own
                     if n not in ("use_sim_time", "start_type_description_service")]
            assert len(names) > (50 if node == "damper_emulator" else 15), names
            for d in call(DescribeParameters, f"/{node}/describe_parameters",
                          DescribeParameters.Request(names=names)).descriptors:
                described[(node, d.name)] = d
        for (node, name), d in described.items():
            assert d.description and not d.dynamic_typing, (node, name)
            assert d.type in (T.PARAMETER_DOUBLE, T.PARAMETER_INTEGER, T.PARAMETER_BOOL,
                              T.PARAMETER_STRING, T.PARAMETER_DOUBLE_ARRAY), (node, name)
            if d.type == T.PARAMETER_DOUBLE:
                # a physical quantity: its unit in brackets, [-] when dimensionless
                assert "[" in d.description and d.additional_constraints, (node, name, d)
            if d.type == T.PARAMETER_INTEGER:
                assert len(d.integer_range) == 1, (node, name)
        emu = {name: d for (node, name), d in described.items() if node == "damper_emulator"}
        bridge = {name: d for (node, name), d in described.items() if node == "can_bridge"}
        # limits a reader knows without the code: 1 <= γ <= 5/3 (isothermal .. monatomic),
        # SCHED_FIFO priorities 1..99, a valve command in [0, 1], a friction force >= 0
        gamma = emu["damper.gas_gamma"].floating_point_range[0]
        assert (gamma.from_value, gamma.to_value) == (1.0, 5.0 / 3.0)
        prio = emu["emulator.priority"].integer_range[0]
        assert (prio.from_value, prio.to_value) == (1, 99)
        cmd = bridge["fail_safe_command"].floating_point_range[0]
        assert (cmd.from_value, cmd.to_value) == (0.0, 1.0)
        friction = emu["damper.friction_force_n"]
        assert friction.floating_point_range[0].from_value == 0.0
        assert m.isinf(friction.floating_point_range[0].to_value)
        assert "[N]" in friction.description
        assert emu["emulator.fault_mode"].type == T.PARAMETER_STRING
        assert "passive" in emu["emulator.fault_mode"].additional_constraints
        # writable at run time: some of the emulator's own settings, nothing else
        writable = sorted(n for n, d in emu.items() if not d.read_only)
        assert "emulator.fault_mode" in writable and "emulator.input_timeout_s" in writable
        assert not [n for n in writable if not n.startswith("emulator.")], writable
        assert emu["emulator.rate_hz"].read_only and emu["damper.gas_gamma"].read_only
        assert all(d.read_only for d in bridge.values())

    def test_bad_frames_are_dropped_and_counted_in_diagnostics(self, dyno_rig, db):
        tap, enc, probe, diags = dyno_rig.tap, dyno_rig.enc, dyno_rig.probe, dyno_rig.diags
        n = 3
        t_bad = time.monotonic_ns()
        for _ in range(n):
            good, _ = enc.encode(Stroke=0.012, Velocity=0.0)
            tap.send(enc.frame_id, good[:7] + bytes([good[7] ^ 0x5A]))   # checksum
            tap.send(enc.frame_id, good[:7])                             # DLC 7
            tap.send(enc.frame_id, good)                                  # accepted
            tap.send(enc.frame_id, good)                                  # counter repeated
            time.sleep(0.002)
        def counted() -> tuple[int, ...]:
            values = {kv.key: kv.value for kv in diags[-1][1].values} if diags else {}
            return tuple(int(values.get(k, -1)) for k in
                         ("dropped_checksum", "dropped_length", "dropped_counter"))

        # the counts of the diagnostics that follow (whenever the bridge got to them)
        probe.spin_until(lambda: counted() == (n, n, n), 30)
        status = diags[-1][1]
        values = {kv.key: kv.value for kv in status.values}
        assert status.name == "can_bridge: dyno" and values["mode"] == "dyno"
        assert (int(values["dropped_checksum"]), int(values["dropped_length"]),
                int(values["dropped_counter"])) == (n, n, n), values
        assert int(values["frames_accepted"]) >= n + 400
        # other identifiers never pass the bus filter: no count that could only read 0
        assert "unknown_ids" not in values
        assert values["bus_state"] == "up" and status.level != status.OK
        # the next DAMPER_FORCE after a dropped frame carries CAN_RX_ERRORS (waited for: the
        # diagnostics above can reach the probe before the tap's thread has read that frame)
        def flagged() -> list:
            return [v for _, v in tap.decoded(FORCE, t_bad)
                    if int(v["Status"]) & ForceStatus.CAN_RX_ERRORS]
        assert tap.wait_for(lambda: bool(flagged()), 10), \
            f"{len(tap.of(FORCE, t_bad))} DAMPER_FORCE frames since the bad ones, none flagged"

    def test_silence_sets_the_timeout_bits(self, dyno_rig):
        """When the dyno falls silent, the bridge flags DAMPER_STATE's absence (bit 16) and
        the emulator its input timeout (bit 2).  What the code guarantees, whatever the
        host's scheduling: no flag before its timeout has passed since the bridge last
        heard the dyno, and the flags last while the dyno is silent; the emulator keeps
        answering.  When the bridge last heard the dyno is bounded by the frame each answer
        used (its StrokeUsed): the bridge had that frame, so it flags no earlier than the
        timeout after that frame was sent.  A flag inside the stream is the bridge's
        reception falling that far behind (a stall of the machine), reported as designed.
        A frame the bridge sends while the emulator is late is its fault frame (bit 32,
        0 N); how late the flags come is benchmarks' business."""
        tap, enc = dyno_rig.tap, dyno_rig.enc
        t0 = time.monotonic_ns()
        raw = 1500 + np.arange(200)                        # strokes 15.00 .. 16.99 mm
        sent_at: list[int] = []
        last = _stream(tap, enc, raw * STROKE_STEP, 0.01, sent_at)
        want = ForceStatus.CAN_STATE_TIMEOUT | ForceStatus.INPUT_TIMEOUT

        def answered_late() -> list[int]:
            return [int(v["Status"]) for _, v in tap.decoded(FORCE, last)
                    if int(v["Status"]) & want == want
                    and not int(v["Status"]) & ForceStatus.FORCE_TIMEOUT]

        assert tap.wait_for(lambda: len(answered_late()) > 50, 30), \
            sorted({int(v["Status"]) for _, v in tap.decoded(FORCE, last)})
        fresh = [v for t, v in tap.decoded(FORCE, t0) if t < last]
        assert any(not int(v["Status"]) & ForceStatus.CAN_STATE_TIMEOUT for v in fresh)
        state_timeout_ns = int(BridgeParams().state_timeout_s * 1e9)
        sent_of = dict(zip(raw.tolist(), sent_at, strict=True))
        flagged = [t - sent_of[k] for t, v in tap.decoded(FORCE, t0)
                   if int(v["Status"]) & ForceStatus.CAN_STATE_TIMEOUT
                   and not int(v["Status"]) & ForceStatus.FORCE_TIMEOUT
                   and (k := round(v["StrokeUsed"] / STROKE_STEP)) in sent_of]
        assert len(flagged) > 50
        early = [dt * 1e-6 for dt in flagged if dt < state_timeout_ns]
        assert not early, f"flagged {early[:5]} ms after the frame the answer used was sent"
        after = tap.decoded(FORCE, last)
        bits = [int(v["Status"]) for _, v in after]
        assert len(bits) - _lasting_run(bits, ForceStatus.CAN_STATE_TIMEOUT) > 50, bits
        # the emulator's timeout lasts once the silence has set it (no input comes back)
        answers = [b for b in bits if not b & ForceStatus.FORCE_TIMEOUT]
        assert len(answers) - _lasting_run(answers, ForceStatus.INPUT_TIMEOUT) > 50, answers
        assert all(v["Force"] == 0.0 for _, v in after
                   if int(v["Status"]) & ForceStatus.FORCE_TIMEOUT)

    def test_without_emulator_force_timeout_frames_keep_coming(self, dyno_rig):
        """No emulator: the watchdog's fault frames keep coming, each the fault frame
        (0 N, FORCE_TIMEOUT and CAN_STATE_TIMEOUT), every one passing the receiver's checks
        (counter continuity included).  That they come at most once per DBC cycle is the
        core's guarantee (test_core_watchdog_sends_force_timeout_at_most_once_per_cycle,
        explicit clocks); their rate on a real bus is benchmarks/can_bench.py's."""
        lone = dyno_rig.lone
        t0 = time.monotonic_ns()
        assert lone.wait_for(lambda: len(lone.of(FORCE, t0)) >= 200, 30)
        frames = lone.decoded(FORCE, t0)
        want = ForceStatus.FORCE_TIMEOUT | ForceStatus.CAN_STATE_TIMEOUT
        assert all(int(v["Status"]) == want and v["Force"] == 0.0 for _, v in frames)
        checked = lone.checked(FORCE, t0)
        t = np.array([a for a, _ in frames])
        assert checked.total.dropped == 0, (
            f"{checked.total}; largest gap between frames received "
            f"{np.max(np.diff(t)) * 1e-6:.1f} ms")

    def test_forces_and_fault_frames_share_one_counter_sequence(self, dyno_rig):
        """Forces (the bridge's executor thread) and fault frames (its receive thread)
        alternate: one DAMPER_FORCE alive counter, frames in counter order, each force's
        values as published."""
        from sensor_msgs.msg import JointState

        from damper_emulator import topics
        from damper_emulator.ros.common import control_qos

        lone = dyno_rig.lone
        probe = Probe(DOMAINS["lone"], "force_source")
        try:
            pub = probe.node.create_publisher(JointState, topics.FORCE, control_qos(100))
            assert probe.spin_until(lambda: pub.get_subscription_count() > 0, 30)
            # the bridge takes forces best effort: until it has matched this publisher on
            # its side too, what is sent is dropped, so wait for a first force frame
            primer = JointState(name=["damper"], position=[0.0], velocity=[0.0], effort=[1.0])

            def primed() -> bool:
                pub.publish(primer)
                return any(v["Force"] == 1.0 for _, v in lone.decoded(FORCE, since))
            since = time.monotonic_ns()
            assert probe.spin_until(primed, 30)
            probe.spin_for(0.05)
            t0 = time.monotonic_ns()
            for burst in range(8):                 # 20 forces, then 30 ms of silence
                for j in range(20):
                    pub.publish(JointState(name=["damper", "damper/status"],
                                           position=[1e-3 * j, 2e-4], velocity=[0.0, 0.0],
                                           effort=[100.0 * (burst + 1) + j, 0.0]))
                    probe.spin_for(0.001, 0.002)
                probe.spin_for(0.03, 0.002)
            time.sleep(0.05)
        finally:
            probe.close()
        t1 = time.monotonic_ns()
        frames = lone.decoded(FORCE, t0, t1)
        forces = [v for _, v in frames if not int(v["Status"]) & ForceStatus.FORCE_TIMEOUT]
        faults = [v for _, v in frames if int(v["Status"]) & ForceStatus.FORCE_TIMEOUT]
        # the two threads take turns: runs of forces and runs of fault frames (as many as
        # the silences the receive thread was awake in: a stalled host has fewer)
        kinds = [bool(int(v["Status"]) & ForceStatus.FORCE_TIMEOUT) for _, v in frames]
        turns = sum(a != b for a, b in itertools.pairwise(kinds))
        assert len(forces) == 160 and faults and turns >= 8, (len(faults), turns)
        assert [v["Force"] for v in forces] == [100.0 * (b + 1) + j for b in range(8)
                                                for j in range(20)]
        assert [round(v["StrokeUsed"] / STROKE_STEP) for v in forces] == \
            [100 * j for _ in range(8) for j in range(20)]
        assert all(v["InputAge"] == pytest.approx(2e-4) for v in forces)
        # the status carries the bridge's bit 16 (no DAMPER_STATE), not FORCE_TIMEOUT
        assert all(int(v["Status"]) == ForceStatus.CAN_STATE_TIMEOUT for v in forces)
        checked = lone.checked(FORCE, t0, t1)
        assert (checked.total.dropped, checked.total.lost) == (0, 0)


# ======================================================================================
# 2b. the bridge alone, stepping the damper's model itself (model: true)
# ======================================================================================


@pytest.fixture(scope="class")
def model_bridge(tmp_path_factory, db):
    """One bridge with ``model: true``, the touring damper's params file and an emulator
    check of its own (``|velocity|`` up to 1 m/s), nothing else: answering once its model
    is loaded."""
    from sensor_msgs.msg import JointState

    from damper_emulator.ros.launch import NodeProcess, node_command, ros_environment

    tmp = tmp_path_factory.mktemp("model")
    channel = udp_channel(OFFSETS["model"])
    can_log = tmp / "bridge.asc"
    node = NodeProcess("model_bridge", node_command(
        "bridge", bridge_params(channel, model=True, can_log=str(can_log),
                                **{"emulator.max_velocity_m_s": 1.0}),
        [ROOT / "config" / "touring.yaml"]),
        ros_environment(DOMAINS["model"]), tmp / "logs")
    tap, probe = None, None
    try:
        tap = BusTap(channel, db)
        probe = Probe(DOMAINS["model"])
        seen = {"state": [], "force": []}
        for topic, key in (("/damper/state", "state"), ("/damper/force", "force")):
            probe.node.create_subscription(JointState, topic,
                                           lambda m, k=key: seen[k].append(m), 10000)
        enc = Encoder(db, STATE)

        def answered() -> bool:
            recent = tap.decoded(FORCE, time.monotonic_ns() - 100 * MS)
            return any(round(v["StrokeUsed"] / STROKE_STEP) == 500 for _, v in recent)

        assert tap.wait_for(answered, 90, tick=lambda: _stream(tap, enc, [0.005] * 5, 0.0)), \
            node.log_tail()

        def observed() -> bool:     # the probe's subscriptions matched: they receive
            _stream(tap, enc, [0.005] * 5, 0.0)
            probe.spin_for(0.05)
            return bool(seen["state"]) and bool(seen["force"])

        assert tap.wait_for(observed, 30), node.log_tail()
        yield SimpleNamespace(tap=tap, probe=probe, seen=seen, enc=enc, node=node,
                              can_log=can_log, tmp=tmp)
        assert node.poll() is None, f"the bridge stopped: {node.log_tail()}"
    finally:
        if probe is not None:
            probe.close()
        if tap is not None:
            tap.close()
        node.stop()


class TestModelInTheBridge:
    def test_every_state_is_answered_with_the_force_of_that_state(self, model_bridge, db):
        """1000 states at 1 kHz, each a stroke of its own (a tag) and the velocity of a
        1 Hz sine: each comes back as exactly one DAMPER_FORCE with its stroke, and the
        forces are the touring damper's model stepped over the states' own stamps (the
        batch kernel, not the bridge's stepper), to the Force signal's resolution."""
        from damper_emulator.model.compressible import DamperModel, simulate
        from damper_emulator.params import load_config

        rig = model_bridge
        tap, probe = rig.tap, rig.probe
        probe.spin_for(0.5)
        rig.seen["state"].clear()
        rig.seen["force"].clear()
        raw = 1000 + np.arange(1000)                       # strokes 10.00 .. 19.99 mm
        velocity = np.round(0.3 * np.sin(2 * np.pi * np.arange(raw.size) * 1e-3)
                            / VELOCITY_STEP) * VELOCITY_STEP
        t0 = time.monotonic_ns()
        sent: list[int] = []
        for k in range(0, raw.size, 50):                   # the velocity changes per frame
            for x, v in zip(raw[k:k + 50] * STROKE_STEP, velocity[k:k + 50]):
                _stream(tap, rig.enc, [x], float(v), sent)
        assert tap.wait_for(lambda: any(round(v["StrokeUsed"] / STROKE_STEP) == raw[-1]
                                        for _, v in tap.decoded(FORCE, sent[-1])), 5.0)
        forces = [v for _, v in tap.decoded(FORCE, t0)]
        tags = [round(v["StrokeUsed"] / STROKE_STEP) for v in forces]
        answered = [t for t in tags if raw[0] <= t <= raw[-1]]
        assert sorted(answered) == list(raw), (
            f"{len(set(answered))} of {raw.size} states answered, "
            f"{len(answered) - len(set(answered))} twice")
        assert all(int(v["Status"]) == 0 for v in forces
                   if raw[0] <= round(v["StrokeUsed"] / STROKE_STEP) <= raw[-1])
        # the states as the bridge stamped and published them: the model's time base
        assert probe.spin_until(lambda: len(rig.seen["state"]) >= raw.size, 10)
        states = [m for m in rig.seen["state"]
                  if raw[0] <= round(m.position[0] / STROKE_STEP) <= raw[-1]]
        assert len(states) == raw.size
        stamp = np.array([m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec
                          for m in states])
        x = np.array([m.position[0] for m in states])
        v = np.array([m.velocity[0] for m in states])
        model = DamperModel(load_config(ROOT / "config" / "touring.yaml"))
        expected = simulate(model, (stamp - stamp[0]) * 1e-9, x, v).force_n
        by_tag = {round(f["StrokeUsed"] / STROKE_STEP): f["Force"] for f in forces}
        got = np.array([by_tag[round(xi / STROKE_STEP)] for xi in x])
        resolution = db.get_message_by_name(FORCE).get_signal_by_name("Force").scale
        # the bridge's model runs on from the fixture's states, the reference starts
        # quasi-steady at the first of these: the two converge within some 30 ms
        settled = slice(100, None)
        np.testing.assert_allclose(got[settled], expected[settled], rtol=0, atol=resolution)
        # the published forces are the frames' (observation and recording)
        assert probe.spin_until(lambda: len(rig.seen["force"]) >= raw.size, 10)
        published = {round(m.position[0] / STROKE_STEP): m.effort[0]
                     for m in rig.seen["force"]}
        np.testing.assert_allclose([published[round(xi / STROKE_STEP)] for xi in x], got,
                                   rtol=0, atol=resolution)
        # a state the emulator group's check refuses (|velocity| above the fixture's
        # 1 m/s) is answered too: the fault output (hold: the last force) with the
        # "rejected" bit, not silence
        beyond = _stream(tap, rig.enc, [0.03], 2.0)
        assert tap.wait_for(lambda: any(round(v["StrokeUsed"] / STROKE_STEP) == 3000
                                        for _, v in tap.decoded(FORCE, beyond)), 5.0)
        (answer,) = [v for _, v in tap.decoded(FORCE, beyond)
                     if round(v["StrokeUsed"] / STROKE_STEP) == 3000]
        assert int(answer["Status"]) == int(ForceStatus.INPUT_REJECTED)
        assert answer["Force"] == pytest.approx(got[-1], abs=resolution)

    def test_its_can_log_holds_the_traffic_and_replays_as_it_ran(self, model_bridge, db):
        """``can_log`` (ASC here: written as the bridge runs, flushed within 0.5 s): every
        DAMPER_STATE the bridge received and DAMPER_FORCE it sent, in python-can's reader;
        replayed, the log runs ``input`` (each force answered its own state) and gives the
        bridge's forces back, on the states' stamps as the log keeps them (to the µs)."""
        rig = model_bridge
        strokes = 0.006 + 0.004 * np.sin(2 * np.pi * np.arange(300) / 300)
        _stream(rig.tap, rig.enc, strokes, 0.05)
        time.sleep(1.0)                                     # the ASC writer's flush
        frames = list(can.ASCReader(rig.can_log))
        ids = {db.get_message_by_name(n).frame_id: n for n in (STATE, FORCE)}
        names = [(ids.get(f.arbitration_id), f.is_rx) for f in frames]
        assert set(names) == {(STATE, True), (FORCE, False)}, set(names)
        assert names.count((FORCE, False)) >= names.count((STATE, True)) >= strokes.size
        out = rig.tmp / "replay"
        checks = rig.tmp / "emulator.yaml"          # the bridge's own input check
        checks.write_text("/**:\n  ros__parameters:\n    emulator:\n"
                          "      max_velocity_m_s: 1.0\n")
        r = subprocess.run([*CLI, "replay", str(rig.can_log), "--out", str(out), "--params",
                            str(ROOT / "config" / "touring.yaml"), "--emulator-params",
                            str(checks)], capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr
        doc = json.loads((out / "replay.json").read_text())
        assert doc["input"]["kind"] == "emulator" and doc["trigger"] == "input", doc["input"]
        assert doc["compared"] >= strokes.size
        # the Force signal's resolution is 0.5 N: rounding leaves 0.14 N r.m.s.; the log's
        # times to the µs (ASC) add a little (0.16 N r.m.s., 0.253 N at most here)
        resolution = db.get_message_by_name(FORCE).get_signal_by_name("Force").scale
        assert doc["rms_N"] < 0.5 * resolution and doc["max_abs_N"] < resolution, doc


# ======================================================================================
# 3. loopback dyno over CAN vs the offline virtual dyno (the acceptance test)
# ======================================================================================


def _loopback_vs_offline(tmp: Path, key: str, protocol: list[str]) -> None:
    from damper_emulator.dyno.measured import read_measured_csv

    env = _cli_env(DOMAINS[key])
    base = [*CLI, "dyno", *protocol]
    # one after the other: the offline run would take the CPU the real-time run needs
    over = subprocess.run([*base, "--over-can", "--can-interface", "udp_multicast",
                           "--can-channel", udp_channel(OFFSETS[key]), "--out", str(tmp / "can")],
                          env=env, capture_output=True, text=True, timeout=180)
    assert over.returncode == 0, over.stderr
    offline = subprocess.run([*base, "--out", str(tmp / "offline")], env=env,
                             capture_output=True, text=True, timeout=180)
    assert offline.returncode == 0, offline.stderr
    assert "Traceback" not in over.stderr
    csvs = sorted(p.name for p in (tmp / "can").glob("*.csv"))
    assert csvs and csvs == sorted(p.name for p in (tmp / "offline").glob("*.csv"))
    doc = json.loads((tmp / "can" / "dyno.json").read_text())
    run = doc["over_can"]["runs"][0]
    stall_samples = 0
    for name in csvs:
        can_data = read_measured_csv(tmp / "can" / name)
        off_data = read_measured_csv(tmp / "offline" / name)
        np.testing.assert_allclose(can_data.time, off_data.time)
        np.testing.assert_allclose(can_data.displacement, off_data.displacement, atol=1e-9)
        f_rms = np.sqrt(np.mean(off_data.force ** 2))
        err = np.abs(can_data.force - off_data.force)
        assert np.isfinite(can_data.force).all()
        # The emulator steps on its own timer, so the loop is not bit for bit the offline
        # run (largest difference about 50 N of 1.9 kN).  A stall of a virtual machine's
        # host can put one sample's force up to ~900 N off: at most 0.5 % of the samples
        # may be further off than 5 % of the force r.m.s., plus the samples a measured
        # stall spans (and one either side): the longest stall the dyno measured in its
        # own send timing (an 18 ms stall at 500 Hz puts 11 of 2001 off), or the forces
        # that came back late, computed on a stale input (a stall on the emulator's side),
        # whichever is more; the others must agree to 1 %.
        outliers = err > 0.05 * f_rms
        stalled = max(math.ceil(run["send_interval_error_max_ms"] * 1e-3 * run["rate_hz"]),
                      run["late_samples"]) + 2
        assert outliers.sum() <= 0.005 * outliers.size + stalled, (
            f"{name}: {outliers.sum()} samples off; run {run}")
        stall_samples += max(0, int(outliers.sum()) - math.floor(0.005 * outliers.size))
        diff = np.sqrt(np.mean(err[~outliers] ** 2))
        assert diff / f_rms < 0.01, (f"{name}: r.m.s. difference {diff:.1f} N of "
                                     f"{f_rms:.0f} N; run {run}")
    assert doc["over_can"]["nodes_started"] is True
    # the run's own figure, over every sample: within 2 % unless the samples a stall put
    # off (allowed above, beyond the 0.5 %) are in it: a few at up to ~900 N take it past
    if stall_samples == 0:
        assert run["relative_rms_vs_offline_quantised"] < 0.02, run
    else:
        warnings.warn(f"{key}: {stall_samples} samples a stall put off count in the run's "
                      f"r.m.s. ({run['relative_rms_vs_offline_quantised']:.2%})", stacklevel=1)
    # No frame may arrive corrupt.  A datagram the kernel drops while a process of the
    # loop is stalled (its socket buffer full) is lost on udp_multicast as on a real bus
    # under an overrun: at most the frames the measured stall spans.
    dropped = run["frames_dropped"]
    assert (dropped["length"], dropped["checksum"], dropped["counter"]) == (0, 0, 0), run
    assert dropped["lost"] <= stalled, run


# Sample rate 500 Hz: at 1 kHz the three Python processes of the loop (dyno, bridge,
# emulator) need about one core of a 2-core machine, and with other jobs running the
# emulator falls more than the /damper/state queue (100 samples) behind and samples are lost
# (the run then fails, as it should: "N forces did not come back" or "computed from another
# sample").  benchmarks/can_bench.py measures the 1 kHz case.
def test_loopback_sine_over_can_matches_the_offline_dyno(tmp_path):
    _loopback_vs_offline(tmp_path, "sine", ["--protocol", "sine", "--frequency", "2",
                                            "--cycles", "3", "--rate", "500"])


def test_loopback_chirp_over_can_matches_the_offline_dyno(tmp_path):
    _loopback_vs_offline(tmp_path, "chirp", ["--protocol", "chirp", "--duration", "4",
                                             "--f-end", "10", "--rate", "500"])


# ======================================================================================
# 4. the bridge node in controller mode
# ======================================================================================


@pytest.fixture(scope="class")
def controller_rig(tmp_path_factory, db):
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    from damper_emulator import topics
    from damper_emulator.ros.common import control_qos

    tmp = tmp_path_factory.mktemp("controller")
    channel = udp_channel(OFFSETS["controller"])
    bridge = start_node("bridge", "bridge", DOMAINS["controller"], tmp,
                        bridge_params(channel, mode="controller", fail_safe_command=0.5,
                                      command_timeout_s=0.1))
    tap = probe = None
    try:
        tap = BusTap(channel, db)
        probe = Probe(DOMAINS["controller"])
        valves: list[tuple[int, float]] = []
        probe.node.create_subscription(
            Float64, topics.VALVE_COMMAND,
            lambda m: valves.append((time.monotonic_ns(), m.data)), control_qos(100))
        ride_pub = probe.node.create_publisher(JointState, topics.RIDE_STATE, control_qos(10))
        state_pub = probe.node.create_publisher(JointState, topics.STATE, control_qos(10))
        assert probe.spin_until(lambda: ride_pub.get_subscription_count() > 0
                                and state_pub.get_subscription_count() > 0
                                and probe.node.count_publishers(topics.VALVE_COMMAND) > 0,
                                90), bridge.log_tail()
        yield SimpleNamespace(tap=tap, probe=probe, valves=valves, ride_pub=ride_pub,
                              state_pub=state_pub, enc=Encoder(db, COMMAND), bridge=bridge)
        assert bridge.poll() is None, bridge.log_tail()
    finally:
        if probe is not None:
            probe.close()
        if tap is not None:
            tap.close()
        bridge.stop()


class TestControllerBridge:
    def test_valve_commands_then_the_fail_safe(self, controller_rig):
        r = controller_rig
        # until the bridge's publisher has matched us: warm-up commands
        end = time.monotonic() + 30
        while not r.valves and time.monotonic() < end:
            r.tap.send(r.enc.frame_id, r.enc.encode(Command=0.05)[0])
            r.probe.spin_for(0.01, 0.002)
        assert r.valves, r.bridge.log_tail()
        r.probe.spin_for(0.05, 0.002)
        first = len(r.valves)
        sent = [0.1234, 0.25, 0.75, 0.9999, 0.0, 1.0, 0.3333]
        last = 0
        for value in sent:
            last = r.tap.send(r.enc.frame_id, r.enc.encode(Command=value)[0])
            r.probe.spin_for(0.005, 0.002)
        assert r.probe.spin_until(lambda: any(
            t > last and v == pytest.approx(0.5) for t, v in r.valves), 30)
        r.probe.spin_for(0.3, 0.002)
        # every command, in order, then the fail-safe (0.5, which none of them is)
        values = [v for _, v in r.valves[first:]]
        i = next(k for k, v in enumerate(values) if v == pytest.approx(0.5))
        assert values[:i][-len(sent):] == pytest.approx(sent, abs=1e-4), values
        # silent for command_timeout_s (0.1 s): the fail-safe command, once, never before
        # the timeout (how soon after it is benchmarks' business)
        fail_safe = [(t, v) for t, v in r.valves if t > last and v == pytest.approx(0.5)]
        assert len(fail_safe) == 1, r.valves[first:]
        assert (fail_safe[0][0] - last) * 1e-9 >= 0.1
        assert r.valves[-1][1] == 0.5

    def test_ride_state_becomes_vehicle_motion(self, controller_rig):
        from sensor_msgs.msg import JointState

        r = controller_rig
        damper = JointState(name=["damper"], position=[0.01], velocity=[0.42])
        r.state_pub.publish(damper)
        r.probe.spin_for(0.2, 0.002)
        t0 = time.monotonic_ns()
        ride = JointState(name=["wheel", "body", "road"], position=[0.0, 0.0, 0.0],
                          velocity=[0.3, -0.12, 0.05])
        end = time.monotonic() + 0.2
        published = 0
        while time.monotonic() < end:                      # about 1 kHz, as the ride node
            r.ride_pub.publish(ride)
            published += 1
            r.probe.spin_for(0.001, 0.002)
        duration = time.monotonic_ns() - t0
        time.sleep(0.1)
        motion = r.tap.decoded(MOTION, t0)
        assert 5 <= len(motion) <= duration / (4.75 * MS) + 2, (len(motion), published)
        for _, v in motion:
            assert v["BodyVelocity"] == pytest.approx(-0.12, abs=1e-4)
            assert v["WheelVelocity"] == pytest.approx(0.3, abs=2e-4)
            assert v["DamperVelocity"] == pytest.approx(0.42, abs=2e-4)
        checked = r.tap.checked(MOTION, t0)
        assert checked.total.dropped == 0


# ======================================================================================
# 5. command-line failures: one line, exit status 2
# ======================================================================================


def test_bad_bridge_parameters_exit_2_with_one_line():
    missing = "vcan0" if not socketcan_available("vcan0") else "dhilnocan0"
    cases = [(["-p", "mode:=sideways"], "mode"),
             (["-p", "can_interface:=socketcan", "-p", f"can_channel:={missing}"],
              "socketcan"),
             (["-p", "colour:=red"], "colour"),
             (["-p", "mode:=controller", "-p", "model:=true"],
              "model is true in mode 'controller'")]
    env = _cli_env(DOMAINS["badparams"])
    procs = [subprocess.Popen([*CLI, "bridge", "--ros-args", *args], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for args, _ in cases]
    try:
        results = [p.communicate(timeout=60) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.communicate()
    for (args, word), p, (_, err) in zip(cases, procs, results):
        assert p.returncode == 2, (args, err)
        assert word in one_line_error(err), err


def test_over_can_external_with_nothing_running_fails_in_one_line(external_run):
    external_run.waiter.join(timeout=60)
    err = external_run.err
    elapsed = external_run.ended - external_run.started
    assert external_run.proc.returncode == 2, err
    line = one_line_error(err)
    assert "no DAMPER_FORCE" in line and "20 s" in line
    assert elapsed >= 20                                   # it waited the connect timeout


# ======================================================================================
# 6. socketcan on vcan0, where the kernel has it
# ======================================================================================


def test_bridge_on_socketcan_vcan0(tmp_path, db):
    problem = socketcan_problem("vcan0")
    if problem is not None:
        pytest.skip(f"socketcan: {problem}")
    assert socketcan_available("vcan0")
    from sensor_msgs.msg import JointState

    from damper_emulator import topics
    from damper_emulator.ros.common import control_qos

    bridge = start_node("bridge", "bridge", DOMAINS["socketcan"], tmp_path,
                        {"can_interface": "socketcan", "can_channel": "vcan0"})
    probe = Probe(DOMAINS["socketcan"])
    states: list = []
    force_rx = Receiver(db, [FORCE])
    enc = Encoder(db, STATE)
    try:
        probe.node.create_subscription(JointState, topics.STATE,
                                       lambda m: states.append(m), control_qos(10))
        with ResilientBus(BusConfig(interface="socketcan", channel="vcan0")) as bus:
            assert bus.ensure_open(), bus.last_error
            forces = []
            end = time.monotonic() + 60
            while time.monotonic() < end and not (states and forces):
                data, _ = enc.encode(Stroke=0.01234, Velocity=-0.2)
                bus.send(can.Message(arbitration_id=enc.frame_id, data=data,
                                     is_extended_id=False))
                probe.spin_for(0.01, 0.002)
                while (msg := bus.recv(0.0)) is not None:
                    got = force_rx.accept(msg.arbitration_id, msg.data)
                    if got is not None:
                        forces.append(got.values)
        assert states, bridge.log_tail()
        assert states[-1].position[0] == pytest.approx(0.01234, abs=STROKE_STEP)
        assert states[-1].velocity[0] == pytest.approx(-0.2, abs=VELOCITY_STEP)
        assert forces and int(forces[-1]["Status"]) & ForceStatus.FORCE_TIMEOUT
    finally:
        probe.close()
        bridge.stop()
