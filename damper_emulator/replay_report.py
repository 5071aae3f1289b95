"""The replay's results: the comparison with the recording, the output bag and the
figure's data.

:func:`compare` measures replayed − recorded force over the model outputs with a recorded
counterpart (a :class:`Comparison`, item 5 of :mod:`damper_emulator.replay`);
:func:`write_replay_bag` writes ``/damper/state`` copied and the replayed ``/damper/force``
to a new bag (item 4); :func:`replay_traces` gives the arrays
:func:`damper_emulator.replay_figure.plot_replay` draws: recorded and replayed force, their
difference and a detail around the largest difference.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from damper_emulator import force_message
from damper_emulator.bag import BagError, BagWriter, cdr_fast, messages
from damper_emulator.realtime.core import FAULT_OUTPUT
from damper_emulator.realtime.settings import EmulatorParams
from damper_emulator.replay_emulation import Replayed
from damper_emulator.replay_figure import ReplayTraces
from damper_emulator.replay_input import JOINT_STATE, BagData
from damper_emulator.topics import FORCE, STATE, VALVE_COMMAND

_FAULT = int(FAULT_OUTPUT)


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
    """Compare the replayed forces with the recorded ones (:mod:`damper_emulator.replay`,
    item 5).

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
        The directory cannot be written, or holds something else
        (:mod:`damper_emulator.replay`, item 4).
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


def replay_traces(data: BagData, rep: Replayed, cmp: Comparison) -> ReplayTraces:
    """The arrays :func:`damper_emulator.replay_figure.plot_replay` draws from a replay and
    its comparison."""
    t0 = int(min(data.state.stamp_ns.min(), data.force.stamp_ns.min()))
    label = (f"r.m.s. {cmp.rms_n:.3g} N, max |·| {cmp.max_abs_n:.3g} N over {cmp.compared} "
             "model outputs" if cmp.compared else "")
    return ReplayTraces((data.force.stamp_ns - t0) * 1e-9, data.force.effort[:, 0].copy(),
                        (rep.stamp_ns - t0) * 1e-9, rep.force_n, np.flatnonzero(~rep.model),
                        cmp.index, cmp.difference_n, label, data.recorded)
