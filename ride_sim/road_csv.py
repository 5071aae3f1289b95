"""Road profile files: :func:`read_profile_csv` and :func:`write_profile_csv`, CSV with a
header line and the columns ``distance`` [m] and ``height`` [m] (other columns are
ignored); every problem is a one-line :class:`~ride_sim.road.RoadError` naming the file and
the line."""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from ride_sim.road import MIN_PROFILE_POINTS, RoadError, RoadProfile

#: Column names accepted in a profile CSV (after stripping and lower-casing).
_DISTANCE_COLUMNS = ("distance", "distance_m")
_HEIGHT_COLUMNS = ("height", "height_m")
#: Header written by :func:`write_profile_csv`.
_CSV_HEADER = ("distance", "height")


def _column(header: list[str], names: tuple[str, ...], path: Path, line: int) -> int:
    for name in names:
        if name in header:
            return header.index(name)
    raise RoadError(f"{path}: line {line}: missing column '{names[0]}' in header "
                    f"{','.join(header)}")


def _cell(row: list[str], col: int, what: str, path: Path, line: int) -> float:
    if col >= len(row) or not row[col].strip():
        raise RoadError(f"{path}: line {line}: missing value for column '{what}'")
    text = row[col].strip()
    try:
        value = float(text)
    except ValueError:
        raise RoadError(f"{path}: line {line}: {what} {text!r} is not a number") from None
    if not math.isfinite(value):
        raise RoadError(f"{path}: line {line}: {what} {text!r} is not finite")
    return value


def read_profile_csv(path: str | Path, *, name: str | None = None) -> RoadProfile:
    """Read a road profile from CSV.

    Parameters
    ----------
    path : str or Path
        CSV file: a header line with the columns ``distance`` [m] and ``height`` [m]
        (``distance_m`` / ``height_m`` also accepted, case-insensitive; other columns are
        ignored), then one row per sample with strictly increasing distance.  Blank lines
        and lines starting with ``#`` are skipped.
    name : str, optional
        Profile name (default: the file stem).

    Raises
    ------
    RoadError
        One line naming the file, the line and the problem (unreadable file, missing
        column or value, non-numeric or non-finite value, non-increasing distance, fewer
        than two rows).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise RoadError(f"{path}: cannot read road profile: {exc.strerror}") from None
    except UnicodeDecodeError:
        raise RoadError(f"{path}: not a UTF-8 text file") from None
    reader = csv.reader(io.StringIO(text))
    d_col = h_col = -1
    header_seen = False
    distance: list[float] = []
    height: list[float] = []
    prev_line = 0
    try:
        for row in reader:
            line = reader.line_num
            if not any(cell.strip() for cell in row) or row[0].lstrip().startswith("#"):
                continue
            if not header_seen:
                header = [cell.strip().lower() for cell in row]
                d_col = _column(header, _DISTANCE_COLUMNS, path, line)
                h_col = _column(header, _HEIGHT_COLUMNS, path, line)
                header_seen = True
                continue
            s = _cell(row, d_col, "distance", path, line)
            z = _cell(row, h_col, "height", path, line)
            if distance and s <= distance[-1]:
                raise RoadError(f"{path}: line {line}: distance {s:g} m is not greater than "
                                f"{distance[-1]:g} m on line {prev_line}")
            distance.append(s)
            height.append(z)
            prev_line = line
    except csv.Error as exc:
        raise RoadError(f"{path}: line {reader.line_num}: malformed CSV: {exc}") from None
    if not header_seen:
        raise RoadError(f"{path}: empty file, expected a header with columns "
                        f"'distance' and 'height'")
    if len(distance) < MIN_PROFILE_POINTS:
        raise RoadError(f"{path}: needs at least {MIN_PROFILE_POINTS} data rows, "
                        f"found {len(distance)}")
    return RoadProfile(np.array(distance), np.array(height),
                       path.stem if name is None else name)


def write_profile_csv(profile: RoadProfile, path: str | Path) -> None:
    """Write a profile as CSV (``distance,height`` header, [m]) readable by
    :func:`read_profile_csv`; values are written with full precision (exact round trip)."""
    path = Path(path)
    try:
        with path.open("w", newline="", encoding="utf-8") as fh:
            writer = csv.writer(fh)
            writer.writerow(_CSV_HEADER)
            for s, z in zip(profile.distance_m.tolist(), profile.height_m.tolist()):
                writer.writerow((repr(s), repr(z)))
    except OSError as exc:
        raise RoadError(f"{path}: cannot write road profile: {exc.strerror}") from None
