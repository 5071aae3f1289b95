"""A recorded bag's time series as an ASAM MDF4 file (``demo --format mf4``).

One channel group per recorded topic (:class:`~damper_emulator.recording.Recording`), its
master channel the message stamps in seconds from the first stamp of the recording:

* ``/damper/state``: ``stroke`` [m], ``velocity`` [m/s] (the emulator's input);
* ``/damper/force``: ``stroke_used`` [m], ``velocity_used`` [m/s], ``force`` [N],
  ``status`` (the emulator's status bits, named in the comment), ``input_age`` [s];
* ``/ride/state``: the quarter car's ``wheel``, ``body`` and ``road`` heights [m], the
  dynamic tyre load ``dtl`` [N], the body force [N] and the damper force it applied [N];
* ``/damper/valve_command``: the adaptive damper's command [-], on its log times.

Written by :func:`~damper_emulator.dyno.mdf_writer.write_mdf` (units, comments, at once).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from damper_emulator.dyno.mdf_writer import MdfChannel, MdfGroup, write_mdf
from damper_emulator.realtime.core import Status
from damper_emulator.recording import Recording
from damper_emulator.topics import FORCE, RIDE_STATE, STATE, VALVE_COMMAND

#: the comment of the status channel: its bits
STATUS_COMMENT = "emulator status bits: " + ", ".join(
    f"{int(bit)} {bit.name}" for bit in Status if bit and bit.name)


def _first_ns(rec: Recording) -> int:
    stamps = [part.stamp_ns[:1] for part in (rec.state, rec.force, rec.ride)
              if part is not None and part.stamp_ns.size]
    if rec.valve_command is not None and rec.valve_command[0].size:
        stamps.append(rec.valve_command[0][:1])
    return int(min(int(s[0]) for s in stamps)) if stamps else 0


def recording_groups(rec: Recording) -> list[MdfGroup]:
    """The channel groups of ``rec`` (module docstring); a topic not recorded has none."""
    t0 = _first_ns(rec)

    def seconds(ns: np.ndarray) -> np.ndarray:
        return (np.asarray(ns, dtype=np.int64) - t0) * 1e-9

    groups = []
    if rec.state is not None:
        s = rec.state
        groups.append(MdfGroup(seconds(s.stamp_ns), [
            MdfChannel("stroke", s.stroke_m, "m", "the emulator's input stroke"),
            MdfChannel("velocity", s.velocity_m_s, "m/s", "the emulator's input velocity"),
        ], STATE))
    if rec.force is not None:
        f = rec.force
        groups.append(MdfGroup(seconds(f.stamp_ns), [
            MdfChannel("stroke_used", f.stroke_m, "m", "the stroke the force was computed at"),
            MdfChannel("velocity_used", f.velocity_m_s, "m/s",
                       "the velocity the force was computed at"),
            MdfChannel("force", f.force_n, "N", "the emulated damper force, rebound positive"),
            MdfChannel("status", np.asarray(f.status, dtype=np.uint8), "", STATUS_COMMENT),
            MdfChannel("input_age", f.input_age_s, "s", "the input sample's age (-1: none)"),
        ], FORCE))
    if rec.ride is not None:
        r = rec.ride
        groups.append(MdfGroup(seconds(r.stamp_ns), [
            MdfChannel("wheel", r.wheel_m, "m", "wheel (unsprung mass) height"),
            MdfChannel("body", r.body_m, "m", "body (sprung mass) height"),
            MdfChannel("road", r.road_m, "m", "road height under the tyre"),
            MdfChannel("dtl", r.dtl_n, "N", "dynamic tyre load"),
            MdfChannel("body_force", r.body_force_n, "N", "sprung mass times its acceleration"),
            MdfChannel("damper_force", r.damper_force_n, "N", "the damper force applied"),
        ], RIDE_STATE))
    if rec.valve_command is not None and rec.valve_command[0].size:
        log_ns, command = rec.valve_command
        groups.append(MdfGroup(seconds(log_ns), [
            MdfChannel("valve_command", command, "", "adaptive valve command, 0 soft to 1 "
                       "firm (on the recorder's log times)"),
        ], VALVE_COMMAND))
    return groups


def write_recording_mdf(rec: Recording, path: str | Path, comment: str) -> Path:
    """Write ``rec``'s time series (module docstring) to ``path``; returns it.

    Raises
    ------
    OutputError
        The file cannot be written.
    """
    return write_mdf(path, recording_groups(rec), comment)
