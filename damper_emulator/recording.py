"""Arrays from a recorded bag (``damper-hil record``, the demo): the damper's input and
output and the ride state, for the demo report and the offline replay.

No rclpy: the bag is read with :mod:`damper_emulator.bag` (rosbags underneath).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from damper_emulator import force_message
from damper_emulator.bag import BagError, cdr_fast, open_bag
from damper_emulator.bag.raw_topics import read_raw
from damper_emulator.topics import DIAGNOSTICS, FORCE, RIDE_STATE, STATE, VALVE_COMMAND


@dataclass(frozen=True)
class DamperInput:
    """``/damper/state``: bag time and header stamp [ns], stroke [m], velocity [m/s]."""

    log_ns: np.ndarray
    stamp_ns: np.ndarray
    stroke_m: np.ndarray
    velocity_m_s: np.ndarray


@dataclass(frozen=True)
class DamperOutput:
    """``/damper/force``: bag time and stamp [ns], the input used (stroke, velocity), the
    force [N], the emulator's status bits and input age [s] (-1 / 0 when absent)."""

    log_ns: np.ndarray
    stamp_ns: np.ndarray
    stroke_m: np.ndarray
    velocity_m_s: np.ndarray
    force_n: np.ndarray
    status: np.ndarray
    input_age_s: np.ndarray


@dataclass(frozen=True)
class RideState:
    """``/ride/state``: heights [m] and rates of wheel, body and road, dynamic tyre load,
    body force M_b·z2'' and damper force [N]."""

    log_ns: np.ndarray
    stamp_ns: np.ndarray
    wheel_m: np.ndarray
    body_m: np.ndarray
    road_m: np.ndarray
    dtl_n: np.ndarray
    body_force_n: np.ndarray
    damper_force_n: np.ndarray
    wheel_rate_m_s: np.ndarray | None = None   # velocity[0], [1] (None in older bags)
    body_rate_m_s: np.ndarray | None = None


@dataclass(frozen=True)
class Recording:
    path: Path
    counts: dict[str, int]
    state: DamperInput | None
    force: DamperOutput | None
    ride: RideState | None
    last_diagnostics: dict[str, str]                  # the emulator's last /diagnostics
    #: ``(log_ns, command)`` of ``/damper/valve_command`` (None when not recorded)
    valve_command: tuple[np.ndarray, np.ndarray] | None = None
    #: the CAN bridge's last /diagnostics (empty when no bridge ran)
    bridge_diagnostics: dict[str, str] | None = None


def _lacking(path: Path, topic: str, raw, ok: np.ndarray, what: str) -> None:
    if not ok.all():
        i = int(np.argmax(~ok))
        raise BagError(f"bag {path}: {topic} at {int(raw.log_ns[i])} ns lacks {what}")


def read_valve_commands(path: str | Path) -> tuple[np.ndarray, np.ndarray] | None:
    """``(log_ns, command)`` of the bag's ``/damper/valve_command`` (``std_msgs/Float64``:
    a 4-byte CDR header, then the double, decoded in bulk), or None when it has none.

    Raises
    ------
    BagError
        A message too short for a Float64.
    """
    path = Path(path)
    try:
        r = read_raw(path, [VALVE_COMMAND])[VALVE_COMMAND]
    except BagError:
        return None
    if len(r) == 0:
        return None
    if (r.lengths < 12).any():
        raise BagError(f"bag {path}: {VALVE_COMMAND} holds a message too short for a "
                       "Float64")
    little = r.buf[r.offsets + 1] == 1
    raw8 = r.buf[(r.offsets + 4)[:, None] + np.arange(8)]
    raw8 = np.where(little[:, None], raw8, raw8[:, ::-1])
    return r.log_ns.copy(), np.ascontiguousarray(raw8).view("<f8").ravel().copy()


def read_recording(path: str | Path) -> Recording:
    """Read the damper and ride topics of a bag into arrays.

    The JointState topics are decoded in bulk (:mod:`damper_emulator.bag.cdr_fast`, as the
    replay reads them), ``/diagnostics`` by rosbags.

    Raises
    ------
    BagError
        One line: not a bag, unreadable, or a message without the fields the contract
        requires (``position[0]``, ``velocity[0]``; ``effort[0]`` on ``/damper/force``).
    """
    path = Path(path)
    last: dict[str, dict[str, str]] = {"damper_emulator": {}, "can_bridge": {}}
    with open_bag(path) as bag:
        counts = {name: info.count for name, info in bag.topics.items()}
        if DIAGNOSTICS in bag.topics:
            for _topic, _log_ns, msg in bag.messages([DIAGNOSTICS]):
                for status in msg.status:
                    node = status.name.split(":", 1)[0]
                    if node in last:
                        last[node] = {kv.key: kv.value for kv in status.values}
                        last[node]["message"] = status.message
    valve = read_valve_commands(path) if counts.get(VALVE_COMMAND) else None
    present = [t for t in (STATE, FORCE, RIDE_STATE) if counts.get(t)]
    raw = read_raw(path, present) if present else {}
    js = {t: cdr_fast.decode_joint_states(r.buf, r.offsets, r.lengths,
                                          where=f"bag {path}: {t}")
          for t, r in raw.items()}

    state = force = ride = None
    if STATE in js:
        m = js[STATE]
        _lacking(path, STATE, raw[STATE], m.has("position", 0) & m.has("velocity", 0),
                 "position[0], velocity[0]")
        state = DamperInput(raw[STATE].log_ns, m.stamp_ns, m.position[:, 0],
                            m.velocity[:, 0])
    if FORCE in js:
        m = js[FORCE]
        _lacking(path, FORCE, raw[FORCE], m.has("position", 0) & m.has("velocity", 0)
                 & m.has("effort", 0), "position[0], velocity[0] or effort[0]")
        status = force_message.status_column(m)
        age = force_message.age_column(m)
        force = DamperOutput(raw[FORCE].log_ns, m.stamp_ns, m.position[:, 0],
                             m.velocity[:, 0], m.effort[:, 0], status, age)
    if RIDE_STATE in js:
        m = js[RIDE_STATE]
        _lacking(path, RIDE_STATE, raw[RIDE_STATE], m.has("position", 2) & m.has("effort", 2),
                 "wheel/body/road")
        rates = m.has("velocity", 1).all()
        ride = RideState(raw[RIDE_STATE].log_ns, m.stamp_ns, m.position[:, 0],
                         m.position[:, 1], m.position[:, 2], m.effort[:, 0], m.effort[:, 1],
                         m.effort[:, 2], m.velocity[:, 0] if rates else None,
                         m.velocity[:, 1] if rates else None)
    return Recording(path, counts, state, force, ride, last["damper_emulator"], valve,
                     last["can_bridge"])
