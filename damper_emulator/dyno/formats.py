"""The file formats a run writes its measured data in (``--format``): CSV
(:func:`~damper_emulator.dyno.measured.write_measured_csv`), ASAM MDF4
(:func:`~damper_emulator.dyno.mdf_writer.write_measured_mdf`) or both.  Every reader of
measured data reads either back without a column map."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

#: ``--format``'s choices and the suffixes each writes
FORMATS = {"csv": (".csv",), "mf4": (".mf4",), "both": (".csv", ".mf4")}
#: the format written unless asked otherwise
DEFAULT_FORMAT = "csv"
#: the help text of ``--format``
FORMAT_HELP = ("the time series as CSV, as ASAM MDF4 (.mf4: units and comments, for "
               "asammdf, CANape, INCA) or both (default: %(default)s)")


def write_measured(path: str | Path, fmt: str, time: ArrayLike, displacement: ArrayLike,
                   force: ArrayLike, velocity: ArrayLike | None = None,
                   temperature: ArrayLike | None = None,
                   comment: str = "damper-hil measured data") -> list[Path]:
    """Write measured data at ``path`` (its suffix replaced) in the format ``fmt`` (a key
    of :data:`FORMATS`); returns the paths written, CSV first.

    Raises
    ------
    ValueError
        An unknown format; arrays of unequal length.
    OutputError
        A file cannot be written.
    """
    # the writers imported here: the command line's parsers import this module for its
    # choices, and start faster without numpy's and the readers' imports
    from damper_emulator.dyno.mdf_writer import write_measured_mdf
    from damper_emulator.dyno.measured import write_measured_csv

    if fmt not in FORMATS:
        raise ValueError(f"unknown measured-data format {fmt!r} (choose from "
                         f"{', '.join(FORMATS)})")
    written = []
    for suffix in FORMATS[fmt]:
        target = Path(path).with_suffix(suffix)
        if suffix == ".csv":
            written.append(write_measured_csv(target, time, displacement, force, velocity,
                                              temperature))
        else:
            written.append(write_measured_mdf(target, time, displacement, force, velocity,
                                              temperature, comment))
    return written
