"""Time series written as ASAM MDF4 (``.mf4``), by ``asammdf``: what CANape, INCA and
``asammdf``'s own viewer open.

:func:`write_mdf` writes channel groups (:class:`MdfGroup`): each a master channel
(time [s]) and one channel per :class:`MdfChannel`, with its unit, its comment and, where
the stored values are not physical ones, the conversion a measurement tool applies to show
them (a linear ``a·raw + b``, or a value-to-text table for a state).  The file's header
comment names what wrote it.  :func:`write_measured_mdf` writes measured data with the
channels a measured-data file has (``displacement``, ``velocity``, ``force``,
``temperature``, in SI): every command reads it back without a column map
(:func:`~damper_emulator.dyno.measured_bag.read_measured`), to the bit, where the CSV keeps
nine significant digits.

The file appears at once (:func:`~damper_emulator.outputs.atomic_path`): a reader sees the
old file or the new one, never part of one.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from damper_emulator.outputs import atomic_path

#: the MDF version written (4.10: what CANape 11+, INCA 7+ and asammdf read)
MDF_VERSION = "4.10"
#: the name asammdf gives every group's master channel (time [s])
MASTER = "time"
#: the channels of a measured-data file: name, unit, comment
MEASURED_CHANNELS = {
    "displacement": ("m", "damper displacement (stroke), extension positive"),
    "velocity": ("m/s", "damper velocity, extension positive"),
    "force": ("N", "damper force, rebound positive"),
    "temperature": ("degC", "damper (oil) temperature"),
}


@dataclass(frozen=True)
class MdfChannel:
    """One channel of an MDF file.

    Attributes
    ----------
    name : str
    values : ndarray, shape (n,)
        What the file stores: physical values (float), or raw ones that ``linear`` or
        ``states`` convert.
    unit : str
        The physical value's unit (after the conversion).
    comment : str
        What the channel holds, as a measurement tool shows it.
    linear : (a, b), optional
        Physical value = ``a · raw + b``.
    states : mapping of int to str, optional
        A value-to-text table (a state or flag channel).
    """

    name: str
    values: np.ndarray
    unit: str = ""
    comment: str = ""
    linear: tuple[float, float] | None = None
    states: Mapping[int, str] = field(default_factory=dict)

    def conversion(self) -> dict[str, object] | None:
        """The conversion in ``asammdf``'s form (None: the values are physical)."""
        if self.states:
            table: dict[str, object] = {"default": b""}
            for i, (raw, text) in enumerate(sorted(self.states.items())):
                table[f"val_{i}"] = raw
                table[f"text_{i}"] = text.encode("utf-8")
            return table
        if self.linear is not None:
            return {"a": float(self.linear[0]), "b": float(self.linear[1])}
        return None


@dataclass(frozen=True)
class MdfGroup:
    """Channels sampled at the same times: one channel group of an MDF file.

    Attributes
    ----------
    time : ndarray, shape (n,)
        The master channel [s].
    channels : sequence of MdfChannel
    comment : str
        What the group holds (a source: ``/damper/force``, the dyno's feedback).
    """

    time: np.ndarray
    channels: Sequence[MdfChannel]
    comment: str = ""


def write_mdf(path: str | Path, groups: Sequence[MdfGroup], comment: str) -> Path:
    """Write ``groups`` as an MDF4 file (module docstring); ``comment`` is the file's
    (what wrote it, from what).  Returns the path written.

    Raises
    ------
    ValueError
        A channel whose length is not its group's, or a name used twice in the file (a
        tool finds a channel by its name).
    OutputError
        The file cannot be written.
    """
    from asammdf import MDF, Signal

    names = [c.name for g in groups for c in g.channels]
    if len(set(names)) != len(names) or MASTER in names:
        raise ValueError(f"MDF channel names must be distinct and not '{MASTER}': {names}")
    mdf = MDF(version=MDF_VERSION)
    try:
        mdf.header.comment = comment
        for group in groups:
            t = np.asarray(group.time, dtype=float)
            for c in group.channels:
                if np.shape(c.values) != t.shape:
                    raise ValueError(f"MDF channel '{c.name}' has shape "
                                     f"{np.shape(c.values)}, expected {t.shape}")
            mdf.append([Signal(np.asarray(c.values), t, name=c.name, unit=c.unit,
                               comment=c.comment, conversion=c.conversion())
                        for c in group.channels], comment=group.comment or comment)
        with atomic_path(path) as at:
            mdf.save(at, overwrite=True, compression=2)
    finally:
        mdf.close()
    return Path(path)


def write_measured_mdf(path: str | Path, time: ArrayLike, displacement: ArrayLike,
                       force: ArrayLike, velocity: ArrayLike | None = None,
                       temperature: ArrayLike | None = None,
                       comment: str = "damper-hil measured data") -> Path:
    """Write measured data as an MDF4 file: the twin of
    :func:`~damper_emulator.dyno.measured.write_measured_csv`, in SI, read back without a
    column map.  Returns the path written.

    Raises
    ------
    ValueError
        Arrays of unequal length or not one-dimensional.
    OutputError
        The file cannot be written.
    """
    given = {"displacement": displacement, "velocity": velocity, "force": force,
             "temperature": temperature}
    channels = [MdfChannel(name, np.asarray(values, dtype=float), *MEASURED_CHANNELS[name])
                for name, values in given.items() if values is not None]
    return write_mdf(path, [MdfGroup(np.asarray(time, dtype=float), channels)], comment)
