"""Reading a recorded bag for the replay (:mod:`damper_emulator.replay`, item 1).

:func:`read_bag` reads and decodes the emulator's topics of a bag (``/damper/state``,
``/damper/force`` and the recorded ``/damper/valve_command``) into a :class:`BagData`,
refusing a malformed one in one line naming the bag; :func:`commands_at` aligns the
recorded valve commands with the model's samples as the node applies them.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from damper_emulator.bag import BagError, cdr_fast
from damper_emulator.bag.cdr_fast import JointStates
from damper_emulator.bag.raw_topics import RawTopic, read_raw
from damper_emulator.recording import read_valve_commands
from damper_emulator.topics import FORCE, STATE

JOINT_STATE = "sensor_msgs/msg/JointState"


@dataclass(frozen=True)
class BagData:
    """The emulator's topics of a bag, decoded."""

    path: Path
    state_raw: RawTopic
    state: JointStates
    force_raw: RawTopic
    force: JointStates
    #: ``(log_ns, command)`` of the recorded ``/damper/valve_command`` (None: not recorded)
    valve: tuple[np.ndarray, np.ndarray] | None = None
    #: what the recorded forces are, as the figure names them
    recorded: str = FORCE

    @property
    def recorded_duration_s(self) -> float:
        s = self.state.stamp_ns
        return float(s.max() - s.min()) * 1e-9 if s.size else 0.0


def read_bag(path: str | os.PathLike[str]) -> BagData:
    """Read and decode ``/damper/state`` and ``/damper/force`` of a bag.

    Raises
    ------
    BagError
        One line naming the bag: not a bag, a topic missing or empty or not a JointState,
        an undecodable message, a force without ``position[0]``, ``velocity[0]``,
        ``effort[0]``.
    """
    path = Path(path)
    raw = read_raw(path, [STATE, FORCE])
    decoded = {}
    for topic in (STATE, FORCE):
        r = raw[topic]
        if r.msgtype and r.msgtype != JOINT_STATE:
            raise BagError(f"bag {path}: {topic} is {r.msgtype}, not {JOINT_STATE}")
        if len(r) == 0:
            raise BagError(f"bag {path}: no messages on {topic}")
        decoded[topic] = cdr_fast.decode_joint_states(r.buf, r.offsets, r.lengths,
                                                      where=f"bag {path}: {topic}")
    force = decoded[FORCE]
    lacking = ~(force.has("position", 0) & force.has("velocity", 0) & force.has("effort", 0))
    if lacking.any():
        i = int(np.argmax(lacking))
        raise BagError(f"bag {path}: {FORCE} at {int(raw[FORCE].log_ns[i])} ns lacks "
                       f"position[0], velocity[0] or effort[0]")
    return BagData(path, raw[STATE], decoded[STATE], raw[FORCE], force,
                   read_valve_commands(path))


def commands_at(data: BagData, log_ns: np.ndarray, initial: float) -> np.ndarray | None:
    """Per model sample ``i`` (recorder time ``log_ns[i]``), the valve command for the step
    from sample ``i`` to ``i + 1``: the last valid recorded command (finite, in [0, 1], as
    the node accepts them) logged before sample ``i + 1``, else ``initial``; None when the
    bag holds no valve command.  (The start is settled at the command of the step from the
    first sample, not of the instant before it.)"""
    if data.valve is None:
        return None
    t, c = data.valve
    ok = np.isfinite(c) & (c >= 0.0) & (c <= 1.0)
    t, c = t[ok], c[ok]
    i = np.searchsorted(t, log_ns, side="right") - 1
    at = np.where(i >= 0, c[np.maximum(i, 0)] if c.size else initial, initial)
    # the node applies a command to the step that ends at the next sample it evaluates;
    # the batch kernel takes command[i] for the step from sample i to i + 1
    return np.append(at[1:], at[-1:]) if at.size else at
