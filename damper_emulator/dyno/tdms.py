"""National Instruments TDMS files (NI DAQ, LabVIEW dyno software) as measured data,
through a column map (:mod:`damper_emulator.dyno.column_map`), read by ``nptdms``.

The map names a channel as ``Group/Channel``, or by its name alone where no other group
has a channel of that name.  A channel's unit is its ``unit_string`` property (what
LabVIEW writes), else the one at the end of its name, converted to SI as a CSV column's
is.  Time is the time channel the map names (numbers in its unit, or TDMS time stamps:
seconds since the first, to the nanosecond), else the force channel's waveform time
(``wf_increment``, ``wf_start_offset``), else the map's sample rate.  The file is opened
lazily: only the mapped channels' data are read.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

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

#: the channel property LabVIEW and NI DAQ write a channel's unit into
UNIT_PROPERTY = "unit_string"
#: a TDMS file's name ends so (any case)
SUFFIX = ".tdms"


def is_tdms(path: str | Path) -> bool:
    """A TDMS file, by its name (:data:`SUFFIX`)."""
    return Path(path).suffix.lower() == SUFFIX


def read_mapped_tdms(path: str | Path, cmap: ColumnMap) -> MeasuredData:
    """A TDMS file read through ``cmap`` (module docstring), checked as a CSV is.

    Raises
    ------
    MeasuredDataError
        One line naming the file: unreadable, a channel missing or ambiguous, channels
        of different lengths, and every check of a measured-data file.
    ColumnMapError
        One line naming the channel: an unknown unit, or one of the wrong dimension.
    """
    from nptdms import TdmsFile

    path = Path(path)
    fail = sample_fail(path)

    try:
        tdms = TdmsFile.open(path)
    except OSError as exc:
        raise fail(f"cannot read the TDMS file: {exc.strerror or exc}") from None
    except Exception as exc:  # noqa: BLE001 - nptdms raises what its parser meets
        raise fail(f"not a TDMS file nptdms can read ({one_line(exc, with_type=True)})"
                   ) from None
    with tdms:
        channels = {(g.name, c.name): c for g in tdms.groups() for c in g.channels()}
        required = [q for q in REQUIRED_COLUMNS if q != "time"]
        arrays: dict[str, np.ndarray] = {}
        for quantity in (*required, *OPTIONAL_COLUMNS, "time"):
            channel = _find(channels, cmap.column(quantity), quantity in required, fail)
            if channel is None:
                continue
            try:
                raw = channel[:]
            except Exception as exc:  # noqa: BLE001 - a damaged segment
                raise fail(f"channel '{channel.path}': cannot read its data ({exc})"
                           ) from None
            arrays[quantity] = _si(quantity, channel, raw, fail)
        if "time" not in arrays and cmap.sample_rate_hz is None:
            force = _find(channels, cmap.column("force"), True, fail)
            assert force is not None
            try:
                arrays["time"] = np.asarray(force.time_track(), dtype=float)
            except (KeyError, ValueError):
                raise fail("no time: map a time channel, give a sample rate, or write "
                           "the force channel's wf_increment") from None
    lengths = {q: a.size for q, a in arrays.items()}
    if len(set(lengths.values())) > 1:
        raise fail("channels of different lengths: "
                   + ", ".join(f"{q} {n}" for q, n in lengths.items()))
    rows = next(iter(lengths.values()))
    if rows < 2:
        raise fail(f"{rows} samples; need at least 2")
    if not all(np.isfinite(a).all() for a in arrays.values()):
        q = next(q for q, a in arrays.items() if not np.isfinite(a).all())
        raise fail(f"{q} is not finite", int(np.flatnonzero(~np.isfinite(arrays[q]))[0]) + 1)
    return assemble(arrays, rows, cmap, fail, path)


def _find(channels: dict[tuple[str, str], Any], name: str, required: bool,
          fail: Any) -> Any:
    """The channel ``Group/Channel`` or ``Channel`` (one group's only) of ``name``."""
    group, _, channel = name.rpartition("/")
    hits = [c for (g, n), c in channels.items()
            if n.strip().lower() == channel.strip().lower()
            and (not group or g.strip().lower() == group.strip().lower())]
    if len(hits) > 1:
        raise fail(f"channel '{name}' is in {len(hits)} groups: name it as Group/Channel")
    if not hits:
        if required:
            have = ", ".join(f"{g}/{n}" for g, n in channels) or "none"
            raise fail(f"no channel '{name}' (have: {have})")
        return None
    return hits[0]


def _si(quantity: str, channel: Any, raw: np.ndarray, fail: Any) -> np.ndarray:
    """A channel's data in SI: time stamps as seconds since the first, numbers by the
    channel's unit (its property, else its name's)."""
    data = np.asarray(raw)
    if np.issubdtype(data.dtype, np.datetime64):
        if quantity != "time":
            raise fail(f"channel '{channel.path}' holds time stamps, not the {quantity}")
        ns = (data - data[0]).astype("timedelta64[ns]").astype(np.int64)
        return ns / 1e9
    try:
        values = data.astype(float)
    except (TypeError, ValueError):
        raise fail(f"channel '{channel.path}' holds {data.dtype}, not numbers") from None
    unit = channel.properties.get(UNIT_PROPERTY)
    try:
        factor = (si_factor(quantity, str(unit), channel.name) if unit
                  else column_units(quantity, channel.name))
    except ColumnMapError as exc:
        raise ColumnMapError(one_line(f"{channel.path}: {exc}")) from None
    return values if factor is None else values * factor[0] + factor[1]
