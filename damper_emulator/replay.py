"""Offline replay of a recorded bag through the damper emulator's model (``damper-hil replay``).

Pure Python and numpy (no rclpy): the bag is read with :mod:`damper_emulator.bag.cdr_fast`,
the model runs in the compiled batch loop of :mod:`damper_emulator.model.batch`
(the kernel :class:`~damper_emulator.model.compressible.DamperStepper` and therefore
:class:`~damper_emulator.realtime.core.EmulatorCore` use), and the output is a rosbag2 bag
written by :class:`~damper_emulator.bag.BagWriter`.  Deterministic: the same bag and
parameters give byte-identical output bags, and JSON files that differ only in the timing
fields (``elapsed_s``, ``speed_vs_real_time``, ``setup_s``, ``timings_s``).

Semantics
---------
1. **Input.**  ``/damper/state`` and ``/damper/force`` (``sensor_msgs/msg/JointState``) in
   log-time order.  A missing or empty topic, an undecodable message or a force without
   ``position[0]``, ``velocity[0]``, ``effort[0]`` is a one-line
   :class:`~damper_emulator.bag.BagError` naming the bag.  A state message's input is the
   entry named ``emulator.name`` (else entry 0), as in the node; a state without that
   entry, or one :meth:`EmulatorCore.check_input` refuses (non-finite, stroke beyond the
   travel plus ``stroke_tolerance_m``, ``|velocity| > max_velocity_m_s``), is an input the
   node rejected and the replay never uses.
2. **Trigger.**  If every recorded force stamp equals some state stamp the emulator ran
   ``trigger: input``, else ``trigger: timer``.

   *input*: one evaluation per accepted state sample, in log order, at its stamp; samples
   whose stamp is not after the previous accepted one are rejected (as
   :meth:`EmulatorCore.evaluate` does).  The model starts in quasi-steady equilibrium at
   the first accepted sample and then steps by the difference of the stamps.  Output:
   stamp = the state's stamp, ``position = [stroke, 0]``, ``velocity = [velocity, 0]``,
   ``effort = [force, status]`` (status ``MODEL`` when the step flagged a model fault);
   log time = that of the recorded force with the same stamp, else the state's.

   *timer*: each recorded force is one tick at its stamp.  A tick whose recorded status
   (``effort[1]``) has ``NO_INPUT`` or ``TIMEOUT`` is a fault tick: it outputs the fault
   force of ``fault_mode`` (``hold``: the last model force, ``zero``, ``passive``: the
   static force + ``passive_rate_ns_m`` × the last velocity; before the first model step
   the static force at rest) and does not step the model; its stroke, velocity, input age
   and status are copied from the recording.  Any other tick is a model tick: its input is
   the latest accepted state sample with stamp ≤ the tick's stamp whose velocity equals
   the recorded ``velocity[0]`` and whose stroke, held or extrapolated with the recorded
   input age (``position[1]``, ``input_mode: extrapolate``: ``x + v·min(age,
   max_extrapolation_s)``), equals the recorded ``position[0]``; failing that (within the
   256 latest samples) the latest whose velocity alone matches; failing that the latest
   with stamp ≤ the tick; failing that (no state sample before the tick: clocks of
   different machines) the input the force message reports.  The model steps by the
   difference of the stamps of consecutive model ticks; the first model tick starts it in
   quasi-steady equilibrium.  The node steps by its monotonic wake-up times, which are not
   in the bag; the stamps are wall-clock times taken when the force is published, after
   the input was taken and the model stepped, and that delay varies by tens of µs (more
   when the loop runs late).  On the demo bags this leaves some 7 to 14 N r.m.s. (0.4 to
   0.8 % of the force) between replay and recording, in spikes where the valve opens.
   Output: the recorded stamp, log time and layout, the replayed force,
   status = the recorded ``REJECTED`` bit | ``MODEL`` from the replayed step.
3. **Parameters.**  The damper: ``--params`` (default ``config/sport.yaml``); the emulator
   (``name``, ``input_mode``, ``max_extrapolation_s``, ``fault_mode``,
   ``passive_rate_ns_m``, input checks): ``config/emulator.yaml``, overridden by
   ``--emulator-params`` (a ROS 2 params file with an ``emulator`` group).  The trigger is
   detected, never taken from the parameters.
4. **Output.**  ``DIR/replay_bag/``: ``/damper/state`` copied (same bytes, same log times)
   and ``/damper/force`` replayed (same stamps and layout as the node's messages:
   ``name = [name, name/status]``, ``position = [stroke used, input age s or -1]``,
   ``velocity = [velocity used, 0]``, ``effort = [force N, status bits]``).  An existing
   ``replay_bag`` holding only ``metadata.yaml`` and ``.mcap`` files (an earlier replay) is
   replaced; anything else there is an error.
5. **Comparison** over the model outputs (not fault outputs) that have a recorded
   counterpart: r.m.s. and max |replayed − recorded| [N], relative r.m.s. (to the recorded
   force's r.m.s. over the same samples), counts.  ``DIR/replay.json`` (and ``--json``):
   ``{"bag", "trigger", "forces", "compared", "rms_N", "max_abs_N", "relative_rms",
   "elapsed_s", "recorded_duration_s", "speed_vs_real_time", ...}``; ``DIR/replay.png``:
   recorded and replayed force against time, their difference, and a detail around the
   largest difference.

The model runs in :func:`~damper_emulator.model.batch.simulate_samples`, the batch loop
around the stepper's kernel, on times in seconds relative to the first sample: its time
steps are float differences of those, equal to the node's ``Δns · 1e-9`` to about 1e-12
(relative), so a replay of exactly the node's inputs gives its forces to about 1e-6 N,
not bit for bit.

Recorded ``/damper/valve_command`` messages drive the model's valve command (with the
solenoid lag of the damper's ``adaptive`` group): each model sample takes the last valid
command the recorder logged before that sample's message (the recorder's clock orders both);
before the first, ``emulator.valve_command``.  A bag without valve commands replays at
``emulator.valve_command`` throughout.

The replay starts the model in quasi-steady equilibrium, as the node does when it starts.
A bag that begins while the node was already running (its first force a model output)
begins from another model state: the two converge within some 30 ms, so the JSON also
gives ``rms_N_after_first_0.1s``.  With ``trigger: timer`` the remaining difference is the
time base (item 2): the node's tick times are not in the bag.

``elapsed_s`` is the replay proper: reading and decoding the bag, the model, writing the
output bag and the comparison.  Building the model, the message typestore and loading the
compiled code (``setup_s``, once per process) and drawing the plot (``timings_s.plot``) are
timed separately.
``recorded_duration_s`` is the span of the ``/damper/state`` stamps (the signal's time).
"""

from __future__ import annotations

import dataclasses
import gc
import math
import os
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from damper_emulator import force_message
from damper_emulator.bag import BagError, BagWriter, cdr_fast, messages
from damper_emulator.bag.cdr_fast import JointStates, RawTopic
from damper_emulator.errors import UserError
from damper_emulator.model.batch import simulate_commanded_samples, simulate_samples
from damper_emulator.model.compressible import DamperModel, DamperStepper
from damper_emulator.model.layout import new_state
from damper_emulator.params import node_parameters, read_yaml
from damper_emulator.realtime.core import (
    FAULT_OUTPUT,
    Status,
    fault_output,
    input_ok,
    stroke_window,
)
from damper_emulator.realtime.settings import (
    DEFAULT_EMULATOR_FILE,
    EmulatorParams,
    default_emulator_mapping,
    emulator_params_from_mapping,
)
from damper_emulator.recording import read_valve_commands
from damper_emulator.topics import FORCE, STATE, VALVE_COMMAND

__all__ = [
    "BagData",
    "Replayed",
    "Comparison",
    "read_bag",
    "detect_trigger",
    "emulate",
    "compare",
    "write_replay_bag",
    "load_emulator_params",
    "plot_replay",
    "run_replay",
]

JOINT_STATE = "sensor_msgs/msg/JointState"
REPLAY_BAG = "replay_bag"
REPLAY_JSON = "replay.json"
REPLAY_PNG = "replay.png"
#: how many of the latest state samples a timer tick's input is searched among
SEARCH_DEPTH = 256

_FAULT = int(FAULT_OUTPUT)
_INT64_MIN = np.iinfo(np.int64).min


# ------------------------------------------------------------------------------------------
# reading


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
    raw = cdr_fast.read_raw(path, [STATE, FORCE])
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


def load_emulator_params(path: str | os.PathLike[str] | None = None
                         ) -> tuple[EmulatorParams, str]:
    """``(params, source)``: ``config/emulator.yaml``'s ``emulator`` group, overridden by
    the ``emulator`` group of the params file ``path`` when given.

    Raises
    ------
    ParameterError
        One line: unreadable file, no ``emulator`` group, a bad value.
    """
    mapping = default_emulator_mapping()
    if path is None:
        return emulator_params_from_mapping(mapping, str(DEFAULT_EMULATOR_FILE)), str(
            DEFAULT_EMULATOR_FILE)
    where = str(path)
    body = node_parameters(read_yaml(path), where, "emulator")
    return emulator_params_from_mapping({**mapping, **dict(body["emulator"])}, where), where


# ------------------------------------------------------------------------------------------
# emulation


@dataclass(frozen=True)
class Replayed:
    """The replayed ``/damper/force`` messages (one row each) and how they were obtained.

    ``recorded[i]`` is the index of the recorded force message that output ``i``
    corresponds to (-1: none); ``model[i]`` tells a model output from a fault output.
    """

    trigger: str
    log_ns: np.ndarray
    stamp_ns: np.ndarray
    stroke_m: np.ndarray
    velocity_m_s: np.ndarray
    input_age_s: np.ndarray
    force_n: np.ndarray
    status: np.ndarray
    model: np.ndarray
    recorded: np.ndarray
    counts: dict[str, int]


def _accepted_inputs(state: JointStates, params: EmulatorParams, model: DamperModel
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(ok, stroke, velocity)`` per state message: the node's input and whether
    :meth:`EmulatorCore.check_input` accepts it."""
    idx = state.index_of(params.name)
    present = state.has("position", idx) & state.has("velocity", idx)
    x = state.entry("position", idx)
    v = state.entry("velocity", idx)
    with np.errstate(invalid="ignore"):
        ok = present & input_ok(x, v, stroke_window(model.stroke_limits_m,
                                                     params.stroke_tolerance_m),
                                params.max_velocity_m_s)
    return ok, x, v


def _run_model(model: DamperModel, stamp_ns: np.ndarray, x: np.ndarray, v: np.ndarray,
               command: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Forces and fault flags of the model driven through the samples (quasi-steady start at
    the first, then steps by the stamp differences), by the stepper's compiled kernel;
    ``command[i]`` is the valve command from sample ``i`` on (None: sport throughout)."""
    n = stamp_ns.size
    force = np.empty(n)
    flags = np.zeros(n, dtype=np.int64)
    if n:
        t = (stamp_ns - stamp_ns[0]).astype(float) * 1e-9
        args = (model.prm, model.tables[0].coef, model.tables[1].coef, new_state(), t,
                np.ascontiguousarray(x, dtype=float), np.ascontiguousarray(v, dtype=float))
        if command is None:
            simulate_samples(*args, force, np.empty(n), np.empty(n), flags)
        else:
            simulate_commanded_samples(*args, np.ascontiguousarray(command, dtype=float),
                                np.full(n, np.nan), force, np.empty(n), np.empty(n),
                                np.empty(n), flags)
    return force, flags


def detect_trigger(data: BagData) -> str:
    """``"input"`` if every recorded force stamp is a state stamp, else ``"timer"``."""
    return "input" if np.isin(data.force.stamp_ns, data.state.stamp_ns).all() else "timer"


def emulate(data: BagData, model: DamperModel, params: EmulatorParams,
            trigger: str | None = None) -> Replayed:
    """Replay the bag's inputs through the model as the emulator node did (module docstring).

    ``trigger`` defaults to :func:`detect_trigger`.
    """
    trigger = trigger or detect_trigger(data)
    if trigger == "input":
        return _emulate_input(data, model, params)
    if trigger == "timer":
        return _emulate_timer(data, model, params)
    raise UserError(f"trigger must be 'timer' or 'input', got {trigger!r}")


def _emulate_input(data: BagData, model: DamperModel, params: EmulatorParams) -> Replayed:
    state = data.state
    ok, x, v = _accepted_inputs(state, params, model)
    stamp = state.stamp_ns
    prev_max = np.maximum.accumulate(np.where(ok, stamp, _INT64_MIN))
    prev_max = np.concatenate([[_INT64_MIN], prev_max[:-1]])
    accepted = ok & (stamp > prev_max)
    idx = np.flatnonzero(accepted)
    stamp_a = stamp[idx]
    force, flags = _run_model(model, stamp_a, x[idx], v[idx],
                              commands_at(data, data.state_raw.log_ns[idx],
                                          params.valve_command))
    # the recorded force of each output, by stamp (accepted stamps strictly increase)
    rec_stamp = data.force.stamp_ns
    recorded = np.full(idx.size, -1, dtype=np.int64)
    if idx.size:
        pos = np.searchsorted(stamp_a, rec_stamp)
        hit = (pos < idx.size) & (stamp_a[np.minimum(pos, idx.size - 1)] == rec_stamp)
        recorded[pos[hit]] = np.flatnonzero(hit)  # the last recorded one of a stamp wins
    log = np.where(recorded >= 0, data.force_raw.log_ns[np.maximum(recorded, 0)],
                   data.state_raw.log_ns[idx])
    counts = {"inputs": len(state), "inputs_accepted": int(idx.size),
              "inputs_rejected": int(len(state) - idx.size),
              "recorded_without_replay": int(len(data.force) - (recorded >= 0).sum()),
              "replayed_without_record": int((recorded < 0).sum())}
    return Replayed("input", log, stamp_a, x[idx], v[idx], np.zeros(idx.size), force,
                    np.where(flags != 0, int(Status.MODEL), 0).astype(np.int64),
                    np.ones(idx.size, dtype=bool), recorded, counts)


def _match_inputs(data: BagData, params: EmulatorParams, model: DamperModel,
                  ticks: np.ndarray, age: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """Stroke and velocity used at each model tick (``ticks``: indices of recorded forces),
    and how the inputs were found."""
    f = data.force
    ok, x_all, v_all = _accepted_inputs(data.state, params, model)
    cand = np.flatnonzero(ok)
    order = cand[np.argsort(data.state.stamp_ns[cand], kind="stable")]
    s_stamp = data.state.stamp_ns[order]
    s_x, s_v = x_all[order], v_all[order]
    t_stamp = f.stamp_ns[ticks]
    rec_x = f.position[ticks, 0]
    rec_v = f.velocity[ticks, 0]
    tick_age = age[ticks]
    extrapolate = params.input_mode == "extrapolate"
    j0 = np.searchsorted(s_stamp, t_stamp, side="right") - 1
    chosen = np.full(ticks.size, -1, dtype=np.int64)
    counts = {}
    for kind in ("exact", "velocity"):
        open_ = np.flatnonzero((chosen < 0) & (j0 >= 0))
        for k in range(SEARCH_DEPTH):
            if open_.size == 0:
                break
            j = j0[open_] - k
            valid = j >= 0
            open_, j = open_[valid], j[valid]
            hit = s_v[j] == rec_v[open_]
            if kind == "exact":
                xs = s_x[j]
                if extrapolate:
                    xs = xs + s_v[j] * np.minimum(np.maximum(tick_age[open_], 0.0),
                                                  params.max_extrapolation_s)
                hit &= xs == rec_x[open_]
            chosen[open_[hit]] = j[hit]
            open_ = open_[~hit]
        counts[f"inputs_matched_{kind}"] = int((chosen >= 0).sum()) - sum(counts.values())
    latest = (chosen < 0) & (j0 >= 0)
    chosen[latest] = j0[latest]
    counts["inputs_latest_before_tick"] = int(latest.sum())
    counts["inputs_from_force_message"] = int((chosen < 0).sum())
    use = chosen >= 0
    x = np.where(use, s_x[np.maximum(chosen, 0)] if s_x.size else np.nan, rec_x)
    v = np.where(use, s_v[np.maximum(chosen, 0)] if s_v.size else np.nan, rec_v)
    if extrapolate:
        x = np.where(use, x + v * np.minimum(np.maximum(tick_age, 0.0),
                                             params.max_extrapolation_s), x)
    return x, v, counts


def _emulate_timer(data: BagData, model: DamperModel, params: EmulatorParams) -> Replayed:
    f = data.force
    n = len(f)
    rec_status = force_message.status_column(f)
    age = force_message.age_column(f)
    fault = (rec_status & _FAULT) != 0
    ticks = np.flatnonzero(~fault)
    x_t, v_t, counts = _match_inputs(data, params, model, ticks, age)
    force_t, flags = _run_model(model, f.stamp_ns[ticks], x_t, v_t,
                                commands_at(data, data.force_raw.log_ns[ticks],
                                            params.valve_command))

    stroke = f.position[:, 0].copy()
    velocity = f.velocity[:, 0].copy()
    stroke[ticks], velocity[ticks] = x_t, v_t
    force = np.empty(n)
    force[ticks] = force_t
    status = rec_status.copy()
    status[ticks] = (rec_status[ticks] & int(Status.REJECTED)) | np.where(
        flags != 0, int(Status.MODEL), 0)
    # fault outputs from the last model tick before each (EmulatorCore.fault_force)
    last = np.maximum.accumulate(np.where(~fault, np.arange(n), -1))
    static = DamperStepper(model).force_n
    faults = np.flatnonzero(fault)
    prev = last[faults]
    has_prev = prev >= 0
    force[faults] = fault_output(
        params.fault_mode, np.where(has_prev, force[np.maximum(prev, 0)], static),
        np.where(has_prev, velocity[np.maximum(prev, 0)], 0.0), static,
        params.passive_rate_ns_m)
    counts = {"ticks": n, "model_ticks": int(ticks.size), "fault_ticks": int(faults.size),
              **counts}
    return Replayed("timer", data.force_raw.log_ns.copy(), f.stamp_ns.copy(), stroke,
                    velocity, age, force, status, ~fault, np.arange(n, dtype=np.int64),
                    counts)


# ------------------------------------------------------------------------------------------
# comparison


@dataclass(frozen=True)
class Comparison:
    """Replayed − recorded force over the model outputs with a recorded counterpart."""

    compared: int
    rms_n: float | None
    max_abs_n: float | None
    relative_rms: float | None
    recorded_rms_n: float | None
    rms_after_settle_n: float | None
    status_mismatches: int
    stroke_mismatches: int
    index: np.ndarray          # outputs compared
    difference_n: np.ndarray   # replayed − recorded at those


def compare(data: BagData, rep: Replayed, settle_s: float = 0.1) -> Comparison:
    """Compare the replayed forces with the recorded ones (module docstring, item 5).

    ``rms_after_settle_n`` leaves out the model outputs of the first ``settle_s`` seconds
    after the first one: where the bag starts while the node was already running, the
    node's model state at the first recorded tick is not the quasi-steady state the
    replay starts from, and the two converge within some 30 ms.
    """
    rec_status = force_message.status_column(data.force)
    sel = np.flatnonzero(rep.model & (rep.recorded >= 0))
    r = rep.recorded[sel]
    sel = sel[(rec_status[r] & _FAULT) == 0]
    r = rep.recorded[sel]
    diff = rep.force_n[sel] - data.force.effort[r, 0]
    m = int(sel.size)
    rms = rec_rms = rel = max_abs = rms_settled = None
    if m:
        rms = float(np.sqrt(np.mean(diff ** 2)))
        rec_rms = float(np.sqrt(np.mean(data.force.effort[r, 0] ** 2)))
        rel = rms / rec_rms if rec_rms > 0 else None
        max_abs = float(np.abs(diff).max())
        stamps = rep.stamp_ns[sel]
        settled = stamps >= stamps[0] + int(round(settle_s * 1e9))
        if settled.any():
            rms_settled = float(np.sqrt(np.mean(diff[settled] ** 2)))
    status_mismatch = int((rep.status[sel] != rec_status[r]).sum())
    stroke_mismatch = int((rep.stroke_m[sel] != data.force.position[r, 0]).sum())
    return Comparison(m, rms, max_abs, rel, rec_rms, rms_settled, status_mismatch,
                      stroke_mismatch, sel, diff)


# ------------------------------------------------------------------------------------------
# output


def _prepare_bag_dir(path: Path, source: Path) -> None:
    if path.resolve() == source.resolve():
        raise BagError(f"bag {path}: is the bag being replayed; choose another --out")
    if path.is_dir() and any(path.iterdir()):
        entries = list(path.iterdir())
        if all(p.is_file() and (p.name == "metadata.yaml" or p.suffix == ".mcap")
               for p in entries):
            shutil.rmtree(path)  # an earlier replay's bag
        else:
            raise BagError(f"bag {path}: exists and holds other files than a bag's; "
                           f"not overwriting")


def write_replay_bag(path: str | os.PathLike[str], data: BagData, rep: Replayed,
                     params: EmulatorParams) -> Path:
    """Write ``/damper/state`` (copied), the replayed ``/damper/force`` and the recorded
    ``/damper/valve_command`` (re-encoded, same values and times) to a new bag.

    Raises
    ------
    BagError
        The directory cannot be written, or holds something else (module docstring, item 4).
    """
    path = Path(path)
    _prepare_bag_dir(path, data.path)
    rows = cdr_fast.encode_joint_states(
        rep.stamp_ns, force_message.names(params.name),
        *force_message.columns(rep.force_n, rep.status, rep.stroke_m, rep.velocity_m_s,
                               rep.input_age_s))
    forces = cdr_fast.rows_to_bytes(rows)
    states = data.state_raw.all_data()
    # one flush at close: nothing for the background thread to do; no fsync (a replay is
    # reproducible, a power cut costs a re-run)
    with BagWriter(path, flush_period_s=3600.0, fsync=False) as writer:
        t_state = writer.add_topic(STATE, JOINT_STATE)
        t_force = writer.add_topic(FORCE, JOINT_STATE)
        write = writer.write
        for log_ns, msg in zip(data.state_raw.log_ns.tolist(), states):
            write(t_state, log_ns, msg)
        for log_ns, msg in zip(rep.log_ns.tolist(), forces):
            write(t_force, log_ns, msg)
        if data.valve is not None:
            t_valve = writer.add_topic(VALVE_COMMAND, "std_msgs/msg/Float64")
            for log_ns, value in zip(data.valve[0].tolist(), data.valve[1].tolist()):
                write(t_valve, log_ns, messages.float64(value))
    return path


def plot_replay(path: str | os.PathLike[str], data: BagData, rep: Replayed,
                cmp: Comparison, title: str, zoom_s: float = 0.25) -> Path:
    """Recorded and replayed force against time, their difference, and a ``zoom_s`` detail
    around the largest difference (PNG)."""
    from damper_emulator.dyno.plots import decorate, new_figure, save

    t0 = int(min(data.state.stamp_ns.min(), data.force.stamp_ns.min()))
    fig = new_figure(11.0, 9.5)
    ax, ax_d, ax_z = fig.subplots(3, 1, height_ratios=(3, 2, 2.4))
    ax_d.sharex(ax)
    t_rec = (data.force.stamp_ns - t0) * 1e-9
    t_rep = (rep.stamp_ns - t0) * 1e-9
    f_rec = data.force.effort[:, 0]
    fault = np.flatnonzero(~rep.model)

    def overlay(a, faults: np.ndarray) -> None:
        a.plot(t_rec, f_rec * 1e-3, color="tab:blue", linewidth=2.2, alpha=0.45,
               label="recorded /damper/force")
        a.plot(t_rep, rep.force_n * 1e-3, color="black", linewidth=0.7,
               label="replayed (model and fault outputs)")
        if faults.size:
            a.plot(t_rep[faults], rep.force_n[faults] * 1e-3, linestyle="none", marker="|",
                   color="tab:red", markersize=8, label=f"fault outputs ({faults.size})")

    overlay(ax, fault)
    decorate(ax, "", "force [kN, rebound +]")
    ax.set_title(title, fontsize="medium")
    if cmp.compared:
        ax_d.plot(t_rep[cmp.index], cmp.difference_n, color="tab:purple", linewidth=0.7,
                  label=f"r.m.s. {cmp.rms_n:.3g} N, max |·| {cmp.max_abs_n:.3g} N over "
                        f"{cmp.compared} model outputs")
        worst = cmp.index[int(np.argmax(np.abs(cmp.difference_n)))]
        centre = float(t_rep[worst])
    else:
        centre = float(t_rep[0]) if t_rep.size else 0.0
    decorate(ax_d, "time [s] (from the first stamp)", "replayed − recorded [N]")
    first = float(min(t_rec.min(), t_rep.min() if t_rep.size else t_rec.min()))
    last = float(max(t_rec.max(), t_rep.max() if t_rep.size else t_rec.max()))
    lo = min(max(centre - zoom_s / 2, first), max(last - zoom_s, first))
    hi = lo + zoom_s
    overlay(ax_z, fault[(t_rep[fault] >= lo) & (t_rep[fault] <= hi)])
    inside = (t_rec >= lo) & (t_rec <= hi)
    ax_z.plot(t_rec[inside], f_rec[inside] * 1e-3, linestyle="none", marker=".",
              markersize=3, color="tab:blue", label="recorded samples")
    ax_z.set_xlim(lo, hi)
    near = np.concatenate([f_rec[inside], rep.force_n[(t_rep >= lo) & (t_rep <= hi)]])
    if near.size:
        pad = 0.08 * max(float(np.ptp(near)), 1.0)
        ax_z.set_ylim((near.min() - pad) * 1e-3, (near.max() + pad) * 1e-3)
    ax_z.set_title(f"detail: {zoom_s * 1e3:g} ms around the largest difference",
                   fontsize="small")
    decorate(ax_z, "time [s] (from the first stamp)", "force [kN, rebound +]")
    return save(fig, path)


# ------------------------------------------------------------------------------------------
# the command


def _round(value: float | None, digits: int = 6) -> float | None:
    if value is None or not math.isfinite(value):
        return None
    return float(f"{value:.{digits}g}")


def run_replay(bag: str | os.PathLike[str], out: str | os.PathLike[str],
               json_path: str | os.PathLike[str] | None = None,
               params_file: str | os.PathLike[str] | None = None,
               emulator_params_file: str | os.PathLike[str] | None = None,
               plot: bool = True,
               progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Replay ``bag`` into the folder ``out`` (module docstring); returns the JSON
    document, also written to ``out/replay.json`` and ``json_path``.

    ``out`` and ``json_path`` are written as one set
    (:class:`~damper_emulator.outputs.Outputs`): checked before the replay, renamed into
    place when it is done (an earlier replay's folder replaced as a whole), left as they
    were when it fails; ``progress`` hears ``wrote ...`` for each once in place.

    Raises
    ------
    BagError
        Unreadable or malformed bag, output bag that cannot be written.
    ValueError
        Bad parameter files (:class:`~damper_emulator.params.ParameterError`).
    OutputError
        An output that cannot be written.
    """
    from damper_emulator.outputs import Outputs

    with Outputs(say=progress, inputs=[bag, params_file, emulator_params_file]) as outputs:
        staged = outputs.folder(Path(out))
        json_at = outputs.file(Path(json_path)) if json_path is not None else None
        return _replay(Path(bag), Path(out), staged, json_at, params_file,
                       emulator_params_file, plot, progress)


def _replay(bag: Path, out: Path, staged: Path, json_at: Path | None,
            params_file: str | os.PathLike[str] | None,
            emulator_params_file: str | os.PathLike[str] | None, plot: bool,
            progress: Callable[[str], None] | None) -> dict[str, Any]:
    """:func:`run_replay`, its outputs written into ``staged`` (named as in ``out``) and
    ``json_at``."""
    import json

    from damper_emulator.bag import messages
    from damper_emulator.params import DEFAULT_PARAMS_FILE, load_config

    say = progress or (lambda _text: None)
    t_setup = time.perf_counter()
    model = DamperModel(load_config(params_file))
    params, emulator_source = load_emulator_params(emulator_params_file)
    messages.type_hash(JOINT_STATE)   # the typestore, built once per process
    cdr_fast.warm_up()                # compiled code from numba's cache
    _run_model(model, np.array([0, 1_000_000], dtype=np.int64), np.zeros(2), np.zeros(2))
    DamperStepper(model).warm_up()    # the per-tick stepper of timer bags
    setup_s = time.perf_counter() - t_setup

    # The replay makes no reference cycles worth collecting, but allocates ~10 container
    # objects per message: with the collector on, its full passes over the process's
    # (numba, rosbags, numpy) objects would take longer than the replay itself.
    gc_was_enabled = gc.isenabled()
    gc.disable()
    try:
        t0 = time.perf_counter()
        data = read_bag(bag)
        t1 = time.perf_counter()
        rep = emulate(data, model, params)
        t2 = time.perf_counter()
        write_replay_bag(staged / REPLAY_BAG, data, rep, params)
        bag_out = out / REPLAY_BAG
        t3 = time.perf_counter()
        cmp = compare(data, rep)
        t4 = time.perf_counter()
    finally:
        if gc_was_enabled:
            gc.enable()
    timings = {"read": t1 - t0, "emulate": t2 - t1, "write_bag": t3 - t2, "compare": t4 - t3}
    elapsed = t4 - t0
    if cmp.stroke_mismatches:
        say(f"note: {cmp.stroke_mismatches} of {cmp.compared} replayed strokes differ from "
            f"the recorded ones: was the bag recorded with other emulator parameters "
            f"(input_mode {params.input_mode} here)?")
    duration = data.recorded_duration_s
    doc: dict[str, Any] = {
        "bag": str(bag),
        "trigger": rep.trigger,
        "forces": int(rep.stamp_ns.size),
        "compared": cmp.compared,
        "rms_N": _round(cmp.rms_n),
        "max_abs_N": _round(cmp.max_abs_n),
        "relative_rms": _round(cmp.relative_rms),
        "elapsed_s": round(elapsed, 6),
        "recorded_duration_s": round(duration, 6),
        "speed_vs_real_time": round(duration / elapsed, 1) if elapsed > 0 else None,
        "recorded_forces": len(data.force),
        "state_messages": len(data.state),
        "valve_commands": 0 if data.valve is None else int(data.valve[1].size),
        "recorded_rms_N": _round(cmp.recorded_rms_n),
        "rms_N_after_first_0.1s": _round(cmp.rms_after_settle_n),
        "status_mismatches": cmp.status_mismatches,
        "stroke_mismatches": cmp.stroke_mismatches,
        "counts": rep.counts,
        "params_file": str(params_file if params_file is not None else DEFAULT_PARAMS_FILE),
        "emulator_params_file": emulator_source,
        "emulator": {k: v for k, v in dataclasses.asdict(params).items()
                     if k in ("name", "input_mode", "max_extrapolation_s", "fault_mode",
                              "passive_rate_ns_m", "max_velocity_m_s",
                              "stroke_tolerance_m")},
        "replay_bag": str(bag_out),
        "files": [REPLAY_BAG, REPLAY_JSON],
        "setup_s": round(setup_s, 6),
        "timings_s": {k: round(v, 6) for k, v in timings.items()},
    }
    if plot:
        t5 = time.perf_counter()
        rms = (f"r.m.s. {cmp.rms_n:.3g} N ({100 * cmp.relative_rms:.3g} % of the recorded)"
               if cmp.rms_n is not None and cmp.relative_rms is not None else
               f"r.m.s. {cmp.rms_n:.3g} N" if cmp.rms_n is not None else "nothing compared")
        plot_replay(staged / REPLAY_PNG, data, rep, cmp,
                    f"Replay of {bag} ({rep.trigger} trigger, damper "
                    f"'{model.cfg.damper.name}'): {rms}")
        doc["timings_s"]["plot"] = round(time.perf_counter() - t5, 6)
        doc["files"].insert(1, REPLAY_PNG)
    text = json.dumps(doc, indent=2) + "\n"
    for target in (staged / REPLAY_JSON, json_at):
        if target is not None:
            target.write_text(text, encoding="utf-8")
    return doc
