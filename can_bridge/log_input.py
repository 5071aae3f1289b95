"""A recorded CAN log (Vector BLF or ASC) as the replay's input (``damper-hil replay
run.blf``).

:func:`read_can_log` reads the log with python-can's readers (:class:`can.LogReader`),
checks and decodes its frames through ``config/damper.dbc`` as the bridge does
(:class:`~can_bridge.codec.Receiver`: length, CRC-8, alive counter; a frame that fails is
dropped and counted) and gives the replay what it reads from a bag
(:class:`~damper_emulator.replay_input.BagData`), stamped with the frames' time stamps:

* **A dyno and the emulator** (``DAMPER_STATE`` frames: the bridge's log in mode dyno, or
  a dyno's own): each ``DAMPER_STATE`` is an input sample (``Stroke``, ``Velocity``), each
  ``DAMPER_FORCE`` a recorded output (``Force``, the emulator's ``Status`` bits,
  ``InputAge``, ``StrokeUsed``).  The frame carries no velocity: the output's velocity is
  that of the input sample it answered, found by ``StrokeUsed`` (the latest sample before
  it with that stroke; else the latest sample before it).  Where the outputs answer the
  samples one for one, each in turn (an emulator triggered by its input, or the model in
  the bridge, also where it stalled and answered the samples that came meanwhile in a
  burst), the outputs take their samples' stamps and the replay runs ``input`` over
  the samples from the first answered to the last; otherwise ``timer``, one tick per
  output at its frame's time.  The bridge's own fault frames (status bit 32: no force
  from the emulator) are not the emulator's outputs and are left out, counted.
* **A physical damper on a dyno** (``DYNO_FEEDBACK`` frames: the log of ``hybrid``, or
  of the dyno): each feedback is an input sample (``StrokeMeasured``, on the dyno's
  cycles counted by the alive counter, at the period that fits the frames' times) and the
  force measured in the same frame the recorded output, at the same stamp: the replay
  runs ``input`` and compares the model with the real damper.  The velocity is the
  stroke's cubic Savitzky–Golay derivative over :data:`VELOCITY_WINDOW` cycles (as
  ``--velocity-window`` of a measured-data file's column map), on the grid of the dyno's
  cycles: a cycle whose frame is not in the log (lost, or dropped by its checks) filled
  by interpolation.

A log with neither is one line (:class:`~can_bridge.can_log.CanLogError`), as is one that
python-can cannot read.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can
import numpy as np

from can_bridge.can_log import CanLogError
from can_bridge.codec import Receiver
from can_bridge.dbc import COUNTER_CYCLES, load_database
from damper_emulator import force_message
from damper_emulator.bag import cdr_fast
from damper_emulator.bag.raw_topics import RawTopic
from damper_emulator.dyno.column_map import savgol_velocity
from damper_emulator.errors import one_line
from damper_emulator.replay_input import JOINT_STATE, BagData
from damper_emulator.topics import FORCE, STATE

__all__ = ["read_can_log"]

#: decoded frames of one message: (time stamp [s], signal values)
_Frames = list[tuple[float, dict[str, Any]]]

STATE_MSG, FORCE_MSG, FEEDBACK_MSG = "DAMPER_STATE", "DAMPER_FORCE", "DYNO_FEEDBACK"
#: the bridge's own status bit in DAMPER_FORCE: no force from the emulator (a fault frame)
BRIDGE_NO_FORCE = 32
#: the emulator's status bits DAMPER_FORCE carries as they are
EMULATOR_BITS = 0x0F
#: the input samples searched back from an output for the one it answered
ANSWER_WINDOW = 16
#: the largest time stamp taken [s]: nanoseconds of it fit an int64 (a damaged log's
#: stamp beyond it is refused)
MAX_STAMP_S = 9.2e9
#: the samples of the measured stroke's derivative (a cubic Savitzky–Golay one): the
#: stroke comes in steps of 10 µm, whose plain derivative at 1 kHz is ±10 mm/s of noise,
#: some ±30 N of a damper's force at rest; over 11 ms the derivative is flat to some 50 Hz
VELOCITY_WINDOW = 11


def _frames(path: Path) -> Iterator[can.Message]:
    try:
        reader = can.LogReader(path)
    except OSError as exc:
        raise CanLogError(f"{path}: cannot read the CAN log: "
                          f"{exc.strerror or one_line(exc)}") from None
    except Exception as exc:  # noqa: BLE001 - python-can raises what its parser meets
        raise CanLogError(f"{path}: not a CAN log python-can can read "
                          f"({one_line(exc, with_type=True)})") from None
    try:
        yield from reader
    except Exception as exc:  # noqa: BLE001 - python-can raises what its parser meets
        raise CanLogError(f"{path}: a damaged CAN log: "
                          f"{one_line(exc, with_type=True)}") from None
    finally:
        reader.stop()


def _decode(path: Path, dbc: str | os.PathLike[str] | None
            ) -> tuple[dict[str, _Frames], Receiver]:
    receiver = Receiver(load_database(dbc), [STATE_MSG, FORCE_MSG, FEEDBACK_MSG])
    found: dict[str, _Frames] = {STATE_MSG: [], FORCE_MSG: [], FEEDBACK_MSG: []}
    for msg in _frames(path):
        if msg.is_error_frame or msg.is_remote_frame:
            continue
        got = receiver.accept(msg.arbitration_id, bytes(msg.data), msg.is_extended_id)
        if got is not None:
            stamp = float(msg.timestamp)
            if not abs(stamp) < MAX_STAMP_S:
                raise CanLogError(f"{path}: a {got.name} frame's time stamp, {stamp!r} s, "
                                  f"is not a time")
            found[got.name].append((stamp, got.values))
    return found, receiver


def _stamps_ns(seconds: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(seconds, dtype=float) * 1e9).astype(np.int64)


def _topic(name: str, stamp_ns: np.ndarray, names: list[str], position: np.ndarray,
           velocity: np.ndarray, effort: np.ndarray) -> tuple[RawTopic, cdr_fast.JointStates]:
    rows = cdr_fast.encode_joint_states(stamp_ns, names, position, velocity, effort)
    n, size = rows.shape
    buf = rows.reshape(-1)
    offsets = np.arange(n, dtype=np.int64) * size
    lengths = np.full(n, size, dtype=np.int64)
    raw = RawTopic(name, JOINT_STATE, stamp_ns.copy(), offsets, lengths, buf)
    return raw, cdr_fast.decode_joint_states(buf, offsets, lengths, where=name)


def _ordered(rows: _Frames) -> _Frames:
    return sorted(rows, key=lambda r: r[0])


def _answered(state_t: np.ndarray, state_x: np.ndarray, force_t: np.ndarray,
              used: np.ndarray) -> np.ndarray:
    """Per output: the index of the input sample it answered (-1: none before it).

    The outputs answer the samples in order: an output's sample is the first after the
    previous output's with its ``StrokeUsed`` that came before it (a sample's time is its
    arrival, an output's its sending: a sample that came while the emulator was still
    answering the one before is not the answer's, though its stroke may be the same);
    else the latest before it with that stroke (a timer emulator answers one sample
    twice); else the latest before it."""
    latest = np.searchsorted(state_t, force_t, side="right") - 1
    out = latest.copy()
    previous = -1
    for i, last in enumerate(latest.tolist()):
        if last < 0:
            continue
        hits = _window_hits(state_x, last, used[i])
        after = hits[hits > previous]
        if after.size:
            out[i] = int(after[0])
        elif hits.size:
            out[i] = int(hits[-1])
        previous = int(out[i])
    return out


def _window_hits(state_x: np.ndarray, last: int, stroke: float) -> np.ndarray:
    """The input samples with ``stroke`` among the :data:`ANSWER_WINDOW` up to ``last``."""
    lo = max(0, last - ANSWER_WINDOW + 1)
    return lo + np.flatnonzero(state_x[lo:last + 1] == stroke)


def _one_for_one(state_t: np.ndarray, state_x: np.ndarray, force_t: np.ndarray,
                 used: np.ndarray) -> int | None:
    """The input sample the first output answered where the outputs answer the samples
    one for one, each in turn (output ``i`` sample ``first + i``: its ``StrokeUsed`` that
    sample's stroke, sent after it came); else ``None``.

    The first sample is one of those :func:`_answered` would take for the first output
    (:func:`_window_hits`), the latest that holds for every output.  The outputs after it
    are not looked up in a window: an emulator that stalled answers the samples that came
    meanwhile in a burst, the last of them more than the window after its sample came,
    and still one for one."""
    n = used.size
    if n == 0:
        return None
    last = int(np.searchsorted(state_t, force_t[0], side="right")) - 1
    for first in _window_hits(state_x, last, used[0])[::-1].tolist():
        span = slice(first, first + n)
        if (first + n <= state_x.size and np.array_equal(state_x[span], used)
                and bool(np.all(state_t[span] <= force_t))):
            return int(first)
    return None


def _emulator_log(path: Path, states: _Frames, forces: _Frames
                  ) -> tuple[BagData, dict[str, Any]]:
    states, forces = _ordered(states), _ordered(forces)
    st = np.array([t for t, _ in states])
    sx = np.array([v["Stroke"] for _, v in states], dtype=float)
    sv = np.array([v["Velocity"] for _, v in states], dtype=float)
    status = np.array([int(v["Status"]) for _, v in forces], dtype=np.int64)
    own = (status & BRIDGE_NO_FORCE) != 0
    keep = np.flatnonzero(~own)
    if keep.size == 0:
        raise CanLogError(f"{path}: every DAMPER_FORCE frame is the bridge's fault frame "
                          f"(status bit {BRIDGE_NO_FORCE}): no emulator output to compare")
    ft = np.array([forces[i][0] for i in keep])
    fv = [forces[i][1] for i in keep]
    used = np.array([v["StrokeUsed"] for v in fv], dtype=float)
    # the emulator ran on its input when the outputs answer the input samples one for
    # one, each in turn, from the first answered to the last: the replay then steps the
    # model through those samples (the ones before, the emulator did not see); else each
    # output's sample is looked up on its own
    first = _one_for_one(st, sx, ft, used)
    one_for_one = first is not None
    answered = (np.arange(first, first + used.size) if first is not None
                else _answered(st, sx, ft, used))
    velocity_used = np.where(answered >= 0, sv[np.maximum(answered, 0)], 0.0)
    state_ns = _stamps_ns(st)
    if one_for_one:
        span = slice(int(answered[0]), int(answered[-1]) + 1)
        st, sx, sv, state_ns = st[span], sx[span], sv[span], state_ns[span]
        force_ns = state_ns.copy()
    else:
        force_ns = _stamps_ns(ft)
    state_raw, state = _topic(STATE, state_ns, ["damper"], sx[:, None], sv[:, None],
                              np.zeros((st.size, 0)))
    position, velocity, effort = force_message.columns(
        np.array([v["Force"] for v in fv], dtype=float), status[keep] & EMULATOR_BITS,
        used, velocity_used, np.array([v["InputAge"] for v in fv], dtype=float))
    force_raw, force = _topic(FORCE, force_ns, force_message.names("damper"), position,
                              velocity, effort)
    # logged when the frames went, whatever their stamps
    force_raw = dataclasses.replace(force_raw, log_ns=_stamps_ns(ft))
    info = {"kind": "emulator", "input_frames": int(st.size),
            "output_frames": int(len(forces)), "bridge_fault_frames": int(own.sum()),
            "outputs_answer_their_inputs": one_for_one}
    return BagData(path, state_raw, state, force_raw, force,
                   recorded="DAMPER_FORCE (the emulator's)"), info


def _cycles(t: np.ndarray, counters: np.ndarray) -> tuple[np.ndarray, float, float]:
    """The dyno's cycle of each feedback frame, counted from the first, the cycle's period
    [s] and the first cycle's time [s]: the cycles between two frames by the alive
    counter, whole counter turns (16 cycles or more lost) by the time between them at the
    median period; then the period and start that fit the frames' times best (their
    arrival jitters, the dyno's clock does not)."""
    if t.size < 2:
        return np.zeros(t.size, dtype=np.int64), 0.0, float(t[0]) if t.size else 0.0
    steps = np.diff(counters) % COUNTER_CYCLES
    steps[steps == 0] = COUNTER_CYCLES
    period = float(np.median(np.diff(t) / steps))
    if period > 0:
        turns = np.round((np.diff(t) / period - steps) / COUNTER_CYCLES)
        steps = steps + COUNTER_CYCLES * np.maximum(turns, 0).astype(np.int64)
    cycle = np.concatenate([[0], np.cumsum(steps)]).astype(np.int64)
    slope, start = np.polyfit(cycle.astype(float), t - t[0], 1)
    return cycle, float(slope), float(t[0] + start)


def _velocity(x: np.ndarray, cycle: np.ndarray, period: float) -> np.ndarray:
    """The stroke's derivative at each frame: on the whole grid of cycles (the lost ones
    filled by linear interpolation, so that the filter's window spans cycles, not frames),
    a cubic Savitzky–Golay derivative over :data:`VELOCITY_WINDOW` cycles."""
    if x.size < 2 or period <= 0:
        return np.zeros_like(x)
    grid = np.arange(int(cycle[-1]) + 1)
    filled = np.interp(grid, cycle, x)
    if filled.size < VELOCITY_WINDOW:
        gradient: np.ndarray = np.gradient(x, cycle * period)
        return gradient
    velocity: np.ndarray = savgol_velocity(filled, grid * period, VELOCITY_WINDOW)[cycle]
    return velocity


def _damper_log(path: Path, feedback: _Frames) -> tuple[BagData, dict[str, Any]]:
    feedback = _ordered(feedback)
    t = np.array([s for s, _ in feedback])
    x = np.array([v["StrokeMeasured"] for _, v in feedback], dtype=float)
    f = np.array([v["Force"] for _, v in feedback], dtype=float)
    cycle, period, start = _cycles(t, np.array([int(v["Counter"]) for _, v in feedback]))
    v = _velocity(x, cycle, period)
    stamp_ns = _stamps_ns(start + cycle * period)
    state_raw, state = _topic(STATE, stamp_ns, ["damper"], x[:, None], v[:, None],
                              np.zeros((x.size, 0)))
    position, velocity, effort = force_message.columns(f, np.zeros(x.size, np.int64), x, v,
                                                       np.zeros(x.size))
    force_raw, force = _topic(FORCE, stamp_ns, force_message.names("damper"), position,
                              velocity, effort)
    info = {"kind": "damper", "input_frames": int(x.size), "output_frames": int(x.size),
            "cycle_period_s": period, "cycles_without_frame": int(cycle[-1] + 1 - x.size)
            if x.size else 0}
    return BagData(path, state_raw, state, force_raw, force,
                   recorded="DYNO_FEEDBACK force (the damper's, measured)"), info


def read_can_log(path: str | os.PathLike[str], dbc: str | os.PathLike[str] | None = None
                 ) -> tuple[BagData, dict[str, Any]]:
    """The replay's input from a CAN log (module docstring), and what was in it:
    ``{"kind": "emulator" | "damper", "input_frames", "output_frames", "dropped"`` (by
    their checks), ``"lost"`` (by the alive counters), ``"other_frames", ...}``.

    Raises
    ------
    CanLogError
        One line naming the log: unreadable or damaged, or neither ``DAMPER_STATE`` with
        ``DAMPER_FORCE`` frames nor ``DYNO_FEEDBACK`` frames in it.
    DbcError
        An unreadable CAN database.
    """
    path = Path(path)
    if not path.is_file():
        raise CanLogError(f"{path}: no such CAN log")
    found, receiver = _decode(path, dbc)
    if found[STATE_MSG] and found[FORCE_MSG]:
        data, info = _emulator_log(path, found[STATE_MSG], found[FORCE_MSG])
    elif len(found[FEEDBACK_MSG]) >= 2:
        data, info = _damper_log(path, found[FEEDBACK_MSG])
    else:
        counts = ", ".join(f"{len(v)} {k}" for k, v in found.items())
        raise CanLogError(f"{path}: no DAMPER_STATE with DAMPER_FORCE frames, nor "
                          f"DYNO_FEEDBACK frames, to replay ({counts}; "
                          f"{receiver.drops.dropped} frames dropped by their checks)")
    d = receiver.drops
    info["dropped"] = {"checksum": d.checksum, "counter": d.counter, "length": d.length}
    info["lost"] = d.lost
    info["other_frames"] = d.unknown_id     # messages not replayed (DYNO_COMMAND, ...)
    return data, info
