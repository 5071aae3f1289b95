"""Offline replay of a recorded bag through the damper emulator's model (``damper-hil replay``).

Pure Python and numpy (no rclpy): the bag is read with
:mod:`damper_emulator.bag.raw_topics` and :mod:`damper_emulator.bag.cdr_fast`, the model
runs in the compiled batch loop of :mod:`damper_emulator.model.batch` (the kernel
:class:`~damper_emulator.model.compressible.DamperStepper` and therefore
:class:`~damper_emulator.realtime.core.EmulatorCore` use), and the output is a rosbag2 bag
written by :class:`~damper_emulator.bag.BagWriter`.  Deterministic: the same bag and
parameters give byte-identical output bags, and JSON files that differ only in the timing
fields (``elapsed_s``, ``speed_vs_real_time``, ``compute_s``,
``compute_speed_vs_real_time``, ``setup_s``, ``timings_s``, ``command_s``).

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
output bag and the comparison.  ``compute_s`` is the model's part of it (matching the
inputs and the compiled batch loop; ``compute_speed_vs_real_time``).  Building the model,
the message typestore and loading the compiled code (``setup_s``, once per process) and
drawing the plot (``timings_s.plot``) are timed separately, and ``command_s`` is the whole
process's time until the JSON is written (from its start, on Linux; elsewhere from the
replay's), what a user waits for.
``recorded_duration_s`` is the span of the ``/damper/state`` stamps (the signal's time).

Here: the command (:func:`run_replay`) and the emulator parameters it reads
(:func:`load_emulator_params`).  Reading the bag and aligning its valve commands:
:mod:`damper_emulator.replay_input`; re-simulating its inputs:
:mod:`damper_emulator.replay_emulation`; the comparison, the output bag and the plot:
:mod:`damper_emulator.replay_report`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import gc
import math
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from damper_emulator.bag import raw_topics
from damper_emulator.model.compressible import DamperModel, DamperStepper
from damper_emulator.plot_process import PlotProcess
from damper_emulator.realtime.settings import (
    DEFAULT_EMULATOR_FILE,
    EmulatorParams,
    default_emulator_mapping,
    emulator_params_from_mapping,
)
from damper_emulator.replay_emulation import emulate, run_model
from damper_emulator.replay_figure import PRELOAD
from damper_emulator.replay_input import JOINT_STATE, BagData, read_bag
from damper_emulator.replay_report import compare, replay_traces, write_replay_bag
from damper_emulator.schema import node_parameters, read_yaml

__all__ = [
    "load_emulator_params",
    "run_replay",
]

REPLAY_BAG = "replay_bag"
REPLAY_JSON = "replay.json"
REPLAY_PNG = "replay.png"


#: reads a recording as the replay's input: ``(data, what it held)``
Reader = Callable[[Path], tuple[BagData, dict[str, Any]]]


def _read_bag(path: Path) -> tuple[BagData, dict[str, Any]]:
    return read_bag(path), {"kind": "bag"}


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


def _process_age_s(fallback_start: float) -> float:
    """Seconds since this process started (``/proc/self/stat``'s start time against the
    boot clock, to a clock tick), else since ``fallback_start`` [``time.perf_counter``]."""
    try:
        fields = Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()
        started = int(fields[19]) / os.sysconf("SC_CLK_TCK")   # field 22: starttime
        return time.clock_gettime(time.CLOCK_BOOTTIME) - started
    except (OSError, ValueError, IndexError, AttributeError):
        return time.perf_counter() - fallback_start


def _round(value: float | None, digits: int = 6) -> float | None:
    if value is None or not math.isfinite(value):
        return None
    return float(f"{value:.{digits}g}")


def run_replay(bag: str | os.PathLike[str], out: str | os.PathLike[str],
               json_path: str | os.PathLike[str] | None = None,
               params_file: str | os.PathLike[str] | None = None,
               emulator_params_file: str | os.PathLike[str] | None = None,
               plot: bool = True,
               progress: Callable[[str], None] | None = None,
               reader: Reader | None = None) -> dict[str, Any]:
    """Replay ``bag`` into the folder ``out`` (module docstring); returns the JSON
    document, also written to ``out/replay.json`` and ``json_path``.

    ``reader`` reads another kind of recording as a bag's topics, and says what it held
    (``replay.json``'s ``input``): a CAN log, :func:`can_bridge.log_input.read_can_log`.

    ``out`` and ``json_path`` are written as one set
    (:class:`~damper_emulator.outputs.Outputs`): checked before the replay, renamed into
    place when it is done (an earlier replay's folder replaced as a whole), left as they
    were when it fails; ``progress`` hears ``wrote ...`` for each once in place.

    Raises
    ------
    BagError
        Unreadable or malformed bag, output bag that cannot be written.
    ValueError
        Bad parameter files (:class:`~damper_emulator.schema.ParameterError`).
    OutputError
        An output that cannot be written.
    """
    from damper_emulator.outputs import Outputs

    with Outputs(say=progress, inputs=[bag, params_file, emulator_params_file]) as outputs:
        staged = outputs.folder(Path(out))
        json_at = outputs.file(Path(json_path)) if json_path is not None else None
        # the figure's process once the outputs are checked, before the work: it imports
        # matplotlib on another core while this one loads the model and replays the bag
        with (PlotProcess("damper_emulator.replay_figure", "plot_replay", PRELOAD) if plot
              else contextlib.nullcontext()) as painter:
            return _replay(Path(bag), Path(out), staged, json_at, params_file,
                           emulator_params_file, painter, progress, reader or _read_bag)


def _replay(bag: Path, out: Path, staged: Path, json_at: Path | None,
            params_file: str | os.PathLike[str] | None,
            emulator_params_file: str | os.PathLike[str] | None,
            painter: PlotProcess | None, progress: Callable[[str], None] | None,
            reader: Reader) -> dict[str, Any]:
    """:func:`run_replay`, its outputs written into ``staged`` (named as in ``out``) and
    ``json_at``; the figure drawn by ``painter`` (None: no figure)."""
    import json

    from damper_emulator.bag import messages
    from damper_emulator.params import DEFAULT_PARAMS_FILE, load_config

    say = progress or (lambda _text: None)
    t_setup = time.perf_counter()
    model = DamperModel(load_config(params_file))
    params, emulator_source = load_emulator_params(emulator_params_file)
    messages.type_hash(JOINT_STATE)   # the typestore, built once per process
    raw_topics.warm_up()              # compiled code from numba's cache
    run_model(model, np.array([0, 1_000_000], dtype=np.int64), np.zeros(2), np.zeros(2))
    DamperStepper(model).warm_up()    # the per-tick stepper of timer bags
    setup_s = time.perf_counter() - t_setup

    # The replay makes no reference cycles worth collecting, but allocates ~10 container
    # objects per message: with the collector on, its full passes over the process's
    # (numba, rosbags, numpy) objects would take longer than the replay itself.
    gc_was_enabled = gc.isenabled()
    gc.disable()
    try:
        t0 = time.perf_counter()
        data, held = reader(bag)
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
        "input": held,
        "trigger": rep.trigger,
        "forces": int(rep.stamp_ns.size),
        "compared": cmp.compared,
        "rms_N": _round(cmp.rms_n),
        "max_abs_N": _round(cmp.max_abs_n),
        "relative_rms": _round(cmp.relative_rms),
        "elapsed_s": round(elapsed, 6),
        "recorded_duration_s": round(duration, 6),
        "speed_vs_real_time": round(duration / elapsed, 1) if elapsed > 0 else None,
        "compute_s": round(timings["emulate"], 6),
        "compute_speed_vs_real_time": (round(duration / timings["emulate"], 1)
                                       if timings["emulate"] > 0 else None),
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
    if painter is not None:
        t5 = time.perf_counter()
        rms = (f"r.m.s. {cmp.rms_n:.3g} N ({100 * cmp.relative_rms:.3g} % of the recorded)"
               if cmp.rms_n is not None and cmp.relative_rms is not None else
               f"r.m.s. {cmp.rms_n:.3g} N" if cmp.rms_n is not None else "nothing compared")
        painter.call(staged / REPLAY_PNG, replay_traces(data, rep, cmp),
                     f"Replay of {bag} ({rep.trigger} trigger, damper "
                     f"'{model.cfg.damper.name}'): {rms}")
        doc["timings_s"]["plot"] = round(time.perf_counter() - t5, 6)
        doc["files"].insert(1, REPLAY_PNG)
    doc["command_s"] = round(_process_age_s(t_setup), 3)
    text = json.dumps(doc, indent=2) + "\n"
    for target in (staged / REPLAY_JSON, json_at):
        if target is not None:
            target.write_text(text, encoding="utf-8")
    return doc
