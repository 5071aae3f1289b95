"""Arrays from a recorded bag (``damper-hil record``, the demo): the damper's input and
output and the ride state, for the demo report and the offline replay.

No rclpy: the bag is read with :mod:`damper_emulator.bag` (rosbags underneath).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from damper_emulator.bag import BagError, open_bag

STATE = "/damper/state"
FORCE = "/damper/force"
RIDE_STATE = "/ride/state"
DIAGNOSTICS = "/diagnostics"


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


@dataclass(frozen=True)
class Recording:
    path: Path
    counts: dict[str, int]
    state: DamperInput | None
    force: DamperOutput | None
    ride: RideState | None
    last_diagnostics: dict[str, str]


def _stamp(msg) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def _at(values, i: int, default: float) -> float:
    return float(values[i]) if len(values) > i else default


def read_recording(path: str | Path) -> Recording:
    """Read the damper and ride topics of a bag into arrays.

    Raises
    ------
    BagError
        One line: not a bag, unreadable, or a message without the fields the contract
        requires (``position[0]``, ``velocity[0]``; ``effort[0]`` on ``/damper/force``).
    """
    path = Path(path)
    rows: dict[str, list] = {STATE: [], FORCE: [], RIDE_STATE: []}
    diagnostics: dict[str, str] = {}
    with open_bag(path) as bag:
        counts = {name: info.count for name, info in bag.topics.items()}
        wanted = [t for t in (STATE, FORCE, RIDE_STATE, DIAGNOSTICS) if t in bag.topics]
        for topic, log_ns, msg in bag.messages(wanted):
            if topic == DIAGNOSTICS:
                for status in msg.status:
                    if status.name.startswith("damper_emulator"):
                        diagnostics = {kv.key: kv.value for kv in status.values}
                        diagnostics["message"] = status.message
                continue
            if topic == RIDE_STATE:
                if len(msg.position) < 3 or len(msg.effort) < 3:
                    raise BagError(f"bag {path}: {topic} at {log_ns} ns lacks wheel/body/road")
                rows[topic].append((log_ns, _stamp(msg), msg.position[0], msg.position[1],
                                    msg.position[2], msg.effort[0], msg.effort[1],
                                    msg.effort[2]))
                continue
            if len(msg.position) < 1 or len(msg.velocity) < 1 or (
                    topic == FORCE and len(msg.effort) < 1):
                raise BagError(f"bag {path}: {topic} at {log_ns} ns lacks position[0], "
                               f"velocity[0]" + (" or effort[0]" if topic == FORCE else ""))
            if topic == STATE:
                rows[topic].append((log_ns, _stamp(msg), msg.position[0], msg.velocity[0]))
            else:
                rows[topic].append((log_ns, _stamp(msg), msg.position[0], msg.velocity[0],
                                    msg.effort[0], _at(msg.effort, 1, 0.0),
                                    _at(msg.position, 1, -1.0)))

    def columns(topic: str, n: int) -> list[np.ndarray] | None:
        if not rows[topic]:
            return None
        a = np.array(rows[topic], dtype=object)
        cols = [np.asarray(a[:, 0], dtype=np.int64), np.asarray(a[:, 1], dtype=np.int64)]
        cols += [np.asarray(a[:, j], dtype=float) for j in range(2, n)]
        return cols

    s = columns(STATE, 4)
    f = columns(FORCE, 7)
    r = columns(RIDE_STATE, 8)
    force = None
    if f is not None:
        f[5] = f[5].astype(np.int64)
        force = DamperOutput(*f)
    return Recording(path, counts, DamperInput(*s) if s else None, force,
                     RideState(*r) if r else None, diagnostics)
