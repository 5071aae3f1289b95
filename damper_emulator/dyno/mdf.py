"""ASAM MDF files (``.mf4``, ``.mdf``: CANape, INCA, dSPACE) as measured data, through a
column map (:mod:`damper_emulator.dyno.column_map`), read by ``asammdf``.

The map names a channel by its name (one channel group's only).  A channel's unit is the
one the file gives it, else the one at the end of its name, converted to SI as a CSV
column's is, after the file's own conversion (``asammdf`` applies a channel's conversion
rule: raw counts to physical values).  Time is the force channel's master channel (its
time stamps in seconds), or a mapped time channel, or the map's sample rate; a channel
recorded on another time base (another raster, another group) is interpolated linearly
onto the force's.  The file is opened lazily: only the mapped channels are read.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from damper_emulator.dyno.column_map import (
    ColumnMap,
    ColumnMapError,
    assemble,
    column_units,
    sample_fail,
    si_factor,
)
from damper_emulator.dyno.measured import OPTIONAL_COLUMNS, REQUIRED_COLUMNS, MeasuredData
from damper_emulator.errors import one_line

#: the file names read as MDF
SUFFIXES = (".mf4", ".mdf")


def is_mdf(path: str | Path) -> bool:
    """An MDF file, by its name."""
    return Path(path).suffix.lower() in SUFFIXES


def read_mapped_mdf(path: str | Path, cmap: ColumnMap) -> MeasuredData:
    """An MDF file read through ``cmap`` (module docstring), checked as a CSV is.

    The file is read in a child process: ``asammdf``'s compiled parts crash the process
    (a segmentation fault) on some damaged files, which must cost the user one line, not
    the command.

    Raises
    ------
    MeasuredDataError
        One line naming the file: unreadable or damaged, a channel missing or in several
        groups, and every check of a measured-data file.
    ColumnMapError
        One line naming the channel: an unknown unit, or one of the wrong dimension.
    """
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures.process import BrokenProcessPool

    path = Path(path)
    fail = sample_fail(path)

    if not path.is_file():
        raise fail("cannot read the MDF file: no such file")
    required = [q for q in REQUIRED_COLUMNS if q != "time"]
    # time: a mapped channel, else the force's master channel (every group has one)
    timed = ["time"] if "time" in cmap.columns else []
    names = {q: cmap.column(q) for q in (*required, *OPTIONAL_COLUMNS, *timed)}
    try:
        with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
            found = pool.submit(read_signals, str(path), names, required).result()
    except BrokenProcessPool:
        raise fail("asammdf crashed reading it: a damaged MDF file") from None
    if isinstance(found, str):
        raise fail(found)
    base = found["force"]
    stamps = base.timestamps
    if stamps.size < 2:
        raise fail(f"{stamps.size} samples; need at least 2")
    arrays: dict[str, np.ndarray] = {}
    for quantity, signal in found.items():
        values = signal.samples
        if signal.timestamps.size != stamps.size or not np.array_equal(signal.timestamps,
                                                                        stamps):
            if signal.timestamps.size < 2 or np.any(np.diff(signal.timestamps) <= 0):
                raise fail(f"channel '{signal.name}': its time stamps do not increase")
            values = np.interp(stamps, signal.timestamps, values)
        arrays[quantity] = _si(quantity, signal.name, signal.unit, values)
    if "time" not in arrays and cmap.sample_rate_hz is None:
        arrays["time"] = stamps
    for quantity, values in arrays.items():
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise fail(f"{quantity} is not finite", int(bad[0]) + 1)
    return assemble(arrays, stamps.size, cmap, fail, path)


@dataclass(frozen=True)
class Channel:
    """One channel as the child process read it: float samples, time stamps [s], unit."""

    name: str
    samples: np.ndarray
    timestamps: np.ndarray
    unit: str


def read_signals(path: str, names: dict[str, str], required: list[str]
                 ) -> dict[str, Channel] | str:
    """The child process's part of :func:`read_mapped_mdf`: each quantity's channel, or
    the one-line problem."""
    import logging

    from asammdf import MDF

    logging.getLogger("asammdf").setLevel(logging.CRITICAL)   # its own error lines
    try:
        mdf = MDF(path)
    except Exception as exc:  # noqa: BLE001 - asammdf raises what its parser meets
        return f"not an MDF file asammdf can read ({one_line(exc, with_type=True)})"
    try:
        out = {}
        for quantity, name in names.items():
            hits = mdf.channels_db.get(name, ())
            if not hits:
                folded = [n for n in mdf.channels_db
                          if n.strip().lower() == name.strip().lower()]
                hits = mdf.channels_db[folded[0]] if len(folded) == 1 else ()
            if len(hits) > 1:
                return f"channel '{name}' is in {len(hits)} channel groups"
            if not hits:
                if quantity in required:
                    have = ", ".join(sorted(n for n in mdf.channels_db if n != "time"))
                    return f"no channel '{name}' (have: {have or 'none'})"
                continue
            group, index = hits[0]
            signal = mdf.get(group=group, index=index)
            try:
                samples = np.asarray(signal.samples, dtype=float)
            except (TypeError, ValueError):
                return f"channel '{name}' holds {signal.samples.dtype}, not numbers"
            out[quantity] = Channel(name, samples, np.asarray(signal.timestamps, float),
                                    str(signal.unit or "").strip())
        return out
    except Exception as exc:  # noqa: BLE001 - a damaged block
        return f"cannot read its channels ({one_line(exc, with_type=True)})"
    finally:
        with contextlib.suppress(Exception):      # closing a damaged file
            mdf.close()


def _si(quantity: str, name: str, unit: str, values: np.ndarray) -> np.ndarray:
    """A channel's samples in SI, by the unit the file gives it, else its name's."""
    try:
        factor = si_factor(quantity, unit, name) if unit else column_units(quantity, name)
    except ColumnMapError as exc:
        raise ColumnMapError(one_line(str(exc))) from None
    return values if factor is None else values * factor[0] + factor[1]
