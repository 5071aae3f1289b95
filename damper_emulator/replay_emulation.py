"""Re-simulating a recorded bag's inputs through the model as the emulator node did.

:func:`emulate` replays the inputs of a :class:`~damper_emulator.replay_input.BagData`
under the node's trigger (:func:`detect_trigger`; the semantics are items 1 and 2 of
:mod:`damper_emulator.replay`): the inputs the node accepted, for a timer bag matched to
each recorded tick, run through the compiled batch loop (:func:`run_model`), the fault
ticks given the fault output of ``fault_mode``; the result is a :class:`Replayed`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from damper_emulator import force_message
from damper_emulator.bag.cdr_fast import JointStates
from damper_emulator.errors import UserError
from damper_emulator.model.batch import simulate_commanded_samples, simulate_samples
from damper_emulator.model.compressible import DamperModel, DamperStepper
from damper_emulator.model.layout import new_state
from damper_emulator.realtime.core import (
    FAULT_OUTPUT,
    Status,
    fault_output,
    input_ok,
    stroke_window,
)
from damper_emulator.realtime.settings import EmulatorParams
from damper_emulator.replay_input import BagData, commands_at

#: how many of the latest state samples a timer tick's input is searched among
SEARCH_DEPTH = 256

_FAULT = int(FAULT_OUTPUT)
_INT64_MIN = np.iinfo(np.int64).min


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


def run_model(model: DamperModel, stamp_ns: np.ndarray, x: np.ndarray, v: np.ndarray,
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
    # a binary search in the sorted state stamps: np.isin sorts both sides and took
    # 1 ms of the 5 ms that emulate() spends on bags/demo_5s
    states = data.state.stamp_ns
    if np.any(states[1:] < states[:-1]):
        states = np.sort(states)
    forces = data.force.stamp_ns
    if states.size == 0:
        return "input" if forces.size == 0 else "timer"
    pos = np.minimum(np.searchsorted(states, forces), states.size - 1)
    return "input" if bool((states[pos] == forces).all()) else "timer"


def emulate(data: BagData, model: DamperModel, params: EmulatorParams,
            trigger: str | None = None) -> Replayed:
    """Replay the bag's inputs through the model as the emulator node did
    (:mod:`damper_emulator.replay`, items 1 and 2).

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
    force, flags = run_model(model, stamp_a, x[idx], v[idx],
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
    force_t, flags = run_model(model, f.stamp_ns[ticks], x_t, v_t,
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
