"""The layout of ``/damper/force`` (``sensor_msgs/msg/JointState``), in one place.

docs/interfaces.md §5.  Index 0 is the contract's: ``name[0]`` the damper, ``effort[0]``
the force [N, rebound +], ``position[0]`` / ``velocity[0]`` the input sample the force was
computed from.  Index 1 is ours, so that a recording tells fault outputs from the model's:
``name[1] = "<name>/status"``, ``effort[1]`` the emulator's status bits
(:class:`damper_emulator.realtime.core.Status`) as a float, ``position[1]`` the input age
[s] (:data:`NO_AGE` when there is no input), ``velocity[1]`` 0.

Everything that writes or reads the extra entries goes through this module: the emulator
node and the replay write them (:func:`values`, :func:`columns`), the ride node reads one message
(:func:`status_of`), the bag readers read whole columns (:func:`status_column`,
:func:`age_column`).  No ROS import: the layout is plain sequences and arrays.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol

import numpy as np

#: Index of the contract's entry (force, input stroke and velocity).
MAIN = 0
#: Index of the status entry (status bits in ``effort``, input age in ``position``).
STATUS = 1
#: Suffix of ``name[STATUS]`` after the damper's name.
STATUS_SUFFIX = "/status"
#: Input age written when the force was computed without an input [s].
NO_AGE = -1.0


#: Lengths of ``position``, ``velocity`` and ``effort``.
COUNTS = (2, 2, 2)


def status_name(damper: str) -> str:
    """``name[STATUS]`` for the damper named ``damper``."""
    return f"{damper}{STATUS_SUFFIX}"


def names(damper: str) -> list[str]:
    """The message's ``name`` for the damper named ``damper``."""
    return [damper, status_name(damper)]


def values(force_n: float, status: int, stroke_m: float, velocity_m_s: float,
           input_age_s: float) -> tuple[float, ...]:
    """``position``, ``velocity`` and ``effort`` of one output, one after the other
    (:data:`COUNTS`); non-finite stroke or velocity (no input) are written as 0 and a
    non-finite age as :data:`NO_AGE`."""
    x = stroke_m if math.isfinite(stroke_m) else 0.0
    v = velocity_m_s if math.isfinite(velocity_m_s) else 0.0
    age = input_age_s if math.isfinite(input_age_s) else NO_AGE
    return (x, age, v, 0.0, force_n, float(int(status)))


def columns(force_n: np.ndarray, status: np.ndarray, stroke_m: np.ndarray,
            velocity_m_s: np.ndarray, input_age_s: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(position, velocity, effort)``, shape ``(n, 2)`` each, of ``n`` messages (the
    vectorised :func:`values`, for writing a bag)."""
    n = np.asarray(force_n).size
    return (np.column_stack([stroke_m, input_age_s]),
            np.column_stack([velocity_m_s, np.zeros(n)]),
            np.column_stack([force_n, np.asarray(status).astype(float)]))


def input_age_of(position: Sequence[float]) -> float:
    """The input age [s] of one message's ``position`` (:data:`NO_AGE` when the entry is
    absent or not finite)."""
    if len(position) <= STATUS:
        return NO_AGE
    age = float(position[STATUS])
    return age if math.isfinite(age) else NO_AGE


def status_of(effort: Sequence[float]) -> int:
    """The status bits of one message's ``effort`` (0 when the entry is absent or not
    finite: a publisher that only fills the contract's entry)."""
    if len(effort) > STATUS and math.isfinite(effort[STATUS]):
        return int(effort[STATUS])
    return 0


class _Entries(Protocol):
    def entry(self, field: str, index: int) -> np.ndarray: ...


def status_column(messages: _Entries) -> np.ndarray:
    """Status bits of every message of decoded ``JointStates`` (0 where absent)."""
    s = messages.entry("effort", STATUS)
    return np.where(np.isfinite(s), s, 0.0).astype(np.int64)


def age_column(messages: _Entries) -> np.ndarray:
    """Input age [s] of every message of decoded ``JointStates`` (:data:`NO_AGE` where
    absent)."""
    a = messages.entry("position", STATUS)
    return np.where(np.isnan(a), NO_AGE, a)
