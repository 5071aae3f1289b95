"""The CAN bridge's core without ROS and without a bus (:class:`can_bridge.core.BridgeCore`,
explicit clocks): frames in, samples and commands out, forces in, frames out, the watchdog.
The node over real DDS and real buses is tests/test_bridge.py."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from can_bridge import Encoder, ForceStatus, Receiver, load_database
from can_bridge.core import COMMAND, FORCE, MOTION, STATE, BridgeCore
from can_bridge.settings import BridgeParams

STROKE_STEP = 1e-5           # DAMPER_STATE.Stroke / DAMPER_FORCE.StrokeUsed resolution [m]
VELOCITY_STEP = 2e-4         # DAMPER_STATE.Velocity resolution [m/s]


@pytest.fixture(scope="module")
def db():
    return load_database()


# ======================================================================================
# BridgeCore alone: no ROS, no bus, explicit clocks
# ======================================================================================

T0 = 10**12                  # an arbitrary monotonic time [ns]
MS = 1_000_000


def _core(db, **changes) -> BridgeCore:
    return BridgeCore(dataclasses.replace(BridgeParams(), **changes), db)


def _force_values(db, data: bytes) -> dict:
    return Receiver(db, [FORCE]).decode_values(FORCE, data)


def test_core_state_frames_become_samples(db):
    core = _core(db)
    enc = Encoder(db, STATE)
    for stroke, velocity in [(0.012345, -0.4321), (-0.3, 6.0), (0.0, 0.0), (1e-5, -2e-4)]:
        data, _ = enc.encode(Stroke=stroke, Velocity=velocity)
        kind, x, v = core.on_frame(enc.frame_id, data, T0)
        assert kind == "state"
        assert abs(x - stroke) <= STROKE_STEP / 2 + 1e-12
        assert abs(v - velocity) <= VELOCITY_STEP / 2 + 1e-12
    assert core.counters.states_in == 4 and core.receiver.drops.dropped == 0
    # another message's frame is not an inbound sample (and no receive error)
    cmd, _ = Encoder(db, COMMAND).encode(Command=0.5)
    assert core.on_frame(0x110, cmd, T0) is None
    assert core.receiver.drops.unknown_id == 1 and core.receiver.drops.dropped == 0


def test_core_drops_bad_frames_and_flags_the_next_force(db):
    core = _core(db)
    enc = Encoder(db, STATE)
    good, _ = enc.encode(Stroke=0.01, Velocity=0.1)
    assert core.on_frame(enc.frame_id, good, T0) is not None
    clean = _force_values(db, core.force_frame(100.0, 0, 1e-4, 0.01, T0 + MS))
    assert clean["Status"] == 0
    drops = core.receiver.drops

    nxt, _ = enc.encode(Stroke=0.011, Velocity=0.1)
    corrupt = nxt[:7] + bytes([nxt[7] ^ 0x01])
    assert core.on_frame(enc.frame_id, corrupt, T0 + MS) is None
    assert drops.checksum == 1
    assert core.on_frame(enc.frame_id, nxt[:7], T0 + MS) is None          # DLC 7
    assert drops.length == 1
    assert core.on_frame(enc.frame_id, nxt, T0 + MS) is not None
    assert core.on_frame(enc.frame_id, nxt, T0 + MS) is None              # counter repeated
    assert drops.counter == 1 and drops.accepted == 2 and drops.dropped == 3

    flagged = _force_values(db, core.force_frame(100.0, 0, 1e-4, 0.011, T0 + 2 * MS))
    assert flagged["Status"] == ForceStatus.CAN_RX_ERRORS
    after = _force_values(db, core.force_frame(100.0, 0, 1e-4, 0.011, T0 + 3 * MS))
    assert after["Status"] == 0                      # the flag is for the next frame only
    # a counter jump (frames lost on the way) flags the next frame too
    enc.encode(Stroke=0.0, Velocity=0.0)
    jumped, _ = enc.encode(Stroke=0.0, Velocity=0.0)
    assert core.on_frame(enc.frame_id, jumped, T0 + 3 * MS) is not None
    assert drops.lost == 1
    assert _force_values(db, core.force_frame(1.0, 0, 0.0, 0.0, T0 + 4 * MS))["Status"] == \
        ForceStatus.CAN_RX_ERRORS


def test_core_force_frame_saturation_nan_and_status(db):
    core = _core(db)
    enc = Encoder(db, STATE)
    core.on_frame(enc.frame_id, enc.encode(Stroke=0.0, Velocity=0.0)[0], T0)
    v = _force_values(db, core.force_frame(20000.0, 8, 2e-4, 0.0123, T0))
    assert v["Force"] == 16383.5
    assert v["Status"] == ForceStatus.FORCE_SATURATED | ForceStatus.MODEL
    assert v["InputAge"] == pytest.approx(2e-4) and v["StrokeUsed"] == pytest.approx(0.0123)
    v = _force_values(db, core.force_frame(-1e9, 0, 0.0, 0.0, T0))
    assert v["Force"] == -16384.0 and v["Status"] == ForceStatus.FORCE_SATURATED
    v = _force_values(db, core.force_frame(-math.inf, 0, 0.0, 0.0, T0))
    assert v["Force"] == -16384.0 and v["Status"] == ForceStatus.FORCE_SATURATED
    assert core.counters.saturated == 3
    # NaN force, age and stroke: a finite frame (age 'unknown')
    v = _force_values(db, core.force_frame(math.nan, 2, math.nan, math.nan, T0))
    assert all(math.isfinite(x) for x in v.values())
    assert v["Force"] == 0.0 and v["InputAge"] == pytest.approx(0.0255)
    assert v["StrokeUsed"] == 0.0 and v["Status"] == ForceStatus.INPUT_TIMEOUT
    # in range: rounded to the 0.5 N resolution, no flag
    v = _force_values(db, core.force_frame(-1234.26, 0, 1e-3, -0.05, T0))
    assert v["Force"] == -1234.5 and v["Status"] == 0


def test_core_watchdog_sends_force_timeout_at_most_once_per_cycle(db):
    core = _core(db, force_timeout_s=0.02)
    assert core.force_cycle_ns == MS
    # no force ever: fault frames, one per DBC cycle whatever the call rate
    times = [T0 + k * MS // 4 for k in range(41)]          # every 0.25 ms for 10 ms
    frames = [(t, core.watchdog(t)[0]) for t in times]
    sent = [t for t, f in frames if f is not None]
    assert len(sent) == 11 and np.all(np.diff(sent) >= MS)
    v = _force_values(db, frames[0][1])
    assert v["Status"] & ForceStatus.FORCE_TIMEOUT and v["Force"] == 0.0
    assert v["Status"] & ForceStatus.CAN_STATE_TIMEOUT     # and no DAMPER_STATE either
    assert core.counters.fault_frames_out == 11 and core.fault_active
    # forces flowing: silence
    t = T0 + 20 * MS
    core.force_frame(10.0, 0, 0.0, 0.0, t)
    assert "no /damper/force" not in core.fault_text
    assert core.watchdog(t + 10 * MS) == (None, None)
    assert core.watchdog(t + 20 * MS)[0] is None           # not more than the timeout
    # forces stop: after the timeout, a fault frame every cycle, one timeout counted
    late = [core.watchdog(t + 20 * MS + k * MS // 2)[0] for k in range(1, 9)]
    assert sum(f is not None for f in late) == 4 and late[0] is not None
    assert core.counters.force_timeouts == 1 and "no /damper/force" in core.fault_text


def test_core_state_timeout_sets_its_bit(db):
    core = _core(db, state_timeout_s=0.02)
    enc = Encoder(db, STATE)
    # no DAMPER_STATE yet: flagged, not counted as a timeout (nothing went silent)
    assert _force_values(db, core.force_frame(0.0, 1, 0.0, 0.0, T0))["Status"] == \
        ForceStatus.CAN_STATE_TIMEOUT | ForceStatus.NO_INPUT
    assert core.counters.state_timeouts == 0
    core.on_frame(enc.frame_id, enc.encode(Stroke=0.0, Velocity=0.0)[0], T0)
    assert _force_values(db, core.force_frame(0.0, 0, 0.0, 0.0, T0 + 19 * MS))["Status"] == 0
    v = _force_values(db, core.force_frame(0.0, 2, 0.0, 0.0, T0 + 21 * MS))
    assert v["Status"] == ForceStatus.CAN_STATE_TIMEOUT | ForceStatus.INPUT_TIMEOUT
    core.force_frame(0.0, 0, 0.0, 0.0, T0 + 22 * MS)
    assert core.counters.state_timeouts == 1 and "no DAMPER_STATE" in core.fault_text
    core.on_frame(enc.frame_id, enc.encode(Stroke=0.0, Velocity=0.0)[0], T0 + 30 * MS)
    assert _force_values(db, core.force_frame(0.0, 0, 0.0, 0.0, T0 + 31 * MS))["Status"] == 0
    assert not core.fault_active


def test_core_controller_mode_commands_and_fail_safe(db):
    core = _core(db, mode="controller", command_timeout_s=0.1, fail_safe_command=0.5,
                 force_timeout_s=10.0)
    assert core.receiver.names == (COMMAND,)
    enc = Encoder(db, COMMAND)
    assert core.on_frame(enc.frame_id, enc.encode(Command=0.1234)[0], T0) == \
        ("command", pytest.approx(0.1234, abs=1e-4))
    assert core.on_frame(enc.frame_id, enc.encode(Command=1.7)[0], T0 + 5 * MS) == \
        ("command", 1.0)                                   # saturated by the sender
    core.force_frame(0.0, 0, 0.0, 0.0, T0 + 5 * MS)
    # DAMPER_STATE frames are not the controller's
    state, _ = Encoder(db, STATE).encode(Stroke=0.0, Velocity=0.0)
    assert core.on_frame(0x100, state, T0 + 6 * MS) is None
    assert core.watchdog(T0 + 100 * MS)[1] is None         # not yet silent for 0.1 s
    assert core.watchdog(T0 + 106 * MS)[1] == 0.5           # fail-safe, once
    assert core.watchdog(T0 + 107 * MS)[1] is None
    assert core.watchdog(T0 + 500 * MS)[1] is None
    assert core.command == 0.5 and core.counters.command_timeouts == 1
    assert "fail-safe" in core.fault_text
    # the controller speaks again: its command, and the fail-safe is re-armed
    assert core.on_frame(enc.frame_id, enc.encode(Command=0.2)[0], T0 + 600 * MS)[0] == \
        "command"
    assert core.watchdog(T0 + 650 * MS)[1] is None
    assert core.watchdog(T0 + 701 * MS)[1] == 0.5 and core.counters.command_timeouts == 2
    # controller mode does not flag the absence of DAMPER_STATE
    assert _force_values(db, core.force_frame(0.0, 0, 0.0, 0.0, T0 + 702 * MS))["Status"] == 0


def test_core_motion_frames_are_decimated_to_the_dbc_cycle(db):
    core = _core(db, mode="controller")
    assert core.motion_cycle_ns == 5 * MS
    rx = Receiver(db, [MOTION])
    frames = []
    for k in range(50):                                    # 1 kHz for 50 ms
        data = core.motion_frame(-0.1234, 0.5678, 0.69, T0 + k * MS)
        if data is not None:
            frames.append((k, rx.accept(core.motion_encoder.frame_id, data)))
    assert [k for k, _ in frames] == list(range(0, 50, 5))
    assert rx.total.accepted == 10 and rx.total.dropped == 0 and rx.total.lost == 0
    values = frames[-1][1].values
    assert values["BodyVelocity"] == pytest.approx(-0.1234, abs=0.5e-4)
    assert values["WheelVelocity"] == pytest.approx(0.5678, abs=1e-4)
    assert values["DamperVelocity"] == pytest.approx(0.69, abs=1e-4)
    assert core.counters.motion_out == 10


def test_a_private_loopback_bus_port_is_no_dds_port_nor_ephemeral(monkeypatch):
    """The UDP port of a private ``udp_multicast`` bus (the demo's, ``dyno --over-can``'s),
    for every process id: none of the ports Fast DDS takes for a ROS domain valid on Linux
    (RTPS port mapping: ``7400 + 250·domain`` plus offsets under 250, domains 0..101), so
    in particular none of the run's own domain, which follows the process id too; and
    outside the kernel's default ephemeral range.  (``20000 + pid % 30000`` put pid 30914
    on port 20914, a discovery port of its domain 54: the bridge could not open the bus.)"""
    import os

    from can_bridge import loopback
    from damper_emulator.ros import launch

    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    for pid in (30914, *range(1, 200_000, 997)):
        monkeypatch.setattr(os, "getpid", lambda pid=pid: pid)
        port = int(loopback.default_bus("udp_multicast").channel.rsplit(":", 1)[1])
        domain = int(launch.ros_environment()["ROS_DOMAIN_ID"])
        assert not 7400 + 250 * domain <= port < 7400 + 250 * (domain + 1), (pid, port)
        assert port >= 7400 + 250 * 102 and not 32768 <= port <= 60999 and port < 65536
