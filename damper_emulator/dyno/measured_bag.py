"""Measured data from a bag: the ``/damper/force`` messages of a rosbag2 bag as a
:class:`~damper_emulator.dyno.measured.MeasuredData` (docs/interfaces.md §2 and §6).

Each ``/damper/force`` message whose status bits are 0 (an output of the model on an accepted
input, :mod:`damper_emulator.force_message`) is one sample: ``header.stamp`` the time (from
the first such message), ``position[0]`` the displacement and ``velocity[0]`` the velocity
of the input sample used, ``effort[0]`` the force.  Fault outputs (no input, a timeout, the
last output on leaving 'active') are not samples.  The data pass the same checks as a
measured-data CSV (:func:`~damper_emulator.dyno.measured.check_measured`); a refusal names
the bag and the message (1-based, among the bag's ``/damper/force`` messages).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from damper_emulator import force_message
from damper_emulator.bag import BagError, cdr_fast
from damper_emulator.bag.raw_topics import read_raw
from damper_emulator.dyno.column_map import ColumnMap, read_mapped_csv, sidecar_map
from damper_emulator.dyno.mdf import SUFFIXES as MDF_SUFFIXES
from damper_emulator.dyno.mdf import is_mdf, read_mapped_mdf
from damper_emulator.dyno.measured import (
    MeasuredData,
    MeasuredDataError,
    check_measured,
    failure,
    read_measured_csv,
)
from damper_emulator.dyno.tdms import SUFFIX as TDMS_SUFFIX
from damper_emulator.dyno.tdms import is_tdms, read_mapped_tdms

#: The topic read.
FORCE_TOPIC = "/damper/force"
#: The message type it must have.
JOINT_STATE = "sensor_msgs/msg/JointState"


def is_bag(path: str | os.PathLike[str]) -> bool:
    """A rosbag2 directory (it holds ``metadata.yaml``)."""
    return (Path(path) / "metadata.yaml").is_file()


def read_measured_bag(path: str | os.PathLike[str]) -> MeasuredData:
    """The measured data of the bag at ``path`` (module docstring).

    Raises
    ------
    MeasuredDataError
        One line naming the bag: not readable as a bag, no ``/damper/force`` or not a
        JointState, an undecodable message, fewer than 2 model outputs, or samples no dyno
        produces (naming the message).
    """
    path = Path(path)
    where = f"bag {path}"
    try:
        raw = read_raw(path, [FORCE_TOPIC])[FORCE_TOPIC]
        if raw.msgtype and raw.msgtype != JOINT_STATE:
            raise BagError(f"{where}: {FORCE_TOPIC} is {raw.msgtype}, not {JOINT_STATE}")
        msgs = cdr_fast.decode_joint_states(raw.buf, raw.offsets, raw.lengths,
                                            where=f"{where}: {FORCE_TOPIC}")
    except BagError as exc:
        raise MeasuredDataError(str(exc)) from None
    status = force_message.status_column(msgs)
    main = force_message.MAIN
    x, v, f = (msgs.entry(field, main) for field in ("position", "velocity", "effort"))
    rows = np.flatnonzero((status == 0) & np.isfinite(x) & np.isfinite(v) & np.isfinite(f))
    if rows.size < 2:
        raise MeasuredDataError(f"{where}: {rows.size} model outputs on {FORCE_TOPIC} (of "
                                f"{len(msgs)} messages); need at least 2")
    stamps = msgs.stamp_ns[rows]
    data = MeasuredData(time=(stamps - stamps[0]) * 1e-9, displacement=x[rows],
                        force=f[rows], velocity=v[rows], name=path.name, path=str(path))
    sample_fail = failure(where, f"{FORCE_TOPIC} message")

    def fail(msg: str, row: int | None = None) -> MeasuredDataError:
        # a sample's row → its message's index in the bag
        return sample_fail(msg, None if row is None else int(rows[row - 1]) + 1)

    check_measured(data, fail)
    return data


#: the file names :func:`read_measured` reads as measured data (lower case), longest first
DATA_SUFFIXES = (".csv.gz", ".csv", TDMS_SUFFIX, *MDF_SUFFIXES)


def data_stem(name: str) -> str | None:
    """``name`` without its measured-data suffix (:data:`DATA_SUFFIXES`, any case); None
    for a file of another kind."""
    low = name.lower()
    for suffix in DATA_SUFFIXES:
        if low.endswith(suffix):
            return name[:len(name) - len(suffix)]
    return None


def read_measured(path: str | os.PathLike[str], columns: ColumnMap | None = None
                  ) -> MeasuredData:
    """Measured data from a CSV (``.csv``, ``.csv.gz``), a TDMS (``.tdms``) or MDF
    (``.mf4``, ``.mdf``) file, or a bag directory.  A file is read through ``columns``, or
    else through the column map of a :data:`~damper_emulator.dyno.column_map.SIDECAR`
    file beside it, where there is one (:mod:`damper_emulator.dyno.column_map`,
    :mod:`damper_emulator.dyno.tdms`, :mod:`damper_emulator.dyno.mdf`)."""
    if is_bag(path):
        return read_measured_bag(path)
    path = Path(path)
    if columns is None:
        columns = sidecar_map(path)
    if is_tdms(path):
        return read_mapped_tdms(path, columns if columns is not None else ColumnMap())
    if is_mdf(path):
        return read_mapped_mdf(path, columns if columns is not None else ColumnMap())
    return read_measured_csv(path) if columns is None else read_mapped_csv(path, columns)
