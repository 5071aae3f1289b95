"""Measured-data CSV files: dyno data in and out (docs/interfaces.md §2).

A measured-data file is a CSV with a header row.  Required columns: ``time`` [s],
``displacement`` [m, extension positive], ``force`` [N, rebound positive]; optional:
``velocity`` [m/s], ``temperature`` [°C].  Extra columns are ignored, column names are
matched case-insensitively after stripping blanks, and ``.csv.gz`` files (recognised by
their gzip magic bytes) are read the same way.

Every problem with a file is reported as :class:`MeasuredDataError`, whose message is one
line naming the file, the data row (1-based, the header is not counted; the file line is
given too) and the problem.
"""

from __future__ import annotations

import csv
import gzip
import io
import math
import warnings
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from numpy.typing import ArrayLike

from damper_emulator.acquisition.rig import RigParams
from damper_emulator.dyno.limits import LIMITS, MeasuredLimits
from damper_emulator.errors import UserError
from damper_emulator.outputs import atomic_path

#: Columns every file must have, in the order they are written.
REQUIRED_COLUMNS = ("time", "displacement", "force")
#: Columns read when present.
OPTIONAL_COLUMNS = ("velocity", "temperature")

#: The bounds of what a damper dyno can produce (force, displacement, velocity, temperature,
#: time): :class:`~damper_emulator.dyno.limits.MeasuredLimits`, checked by
#: :func:`check_measured`.  Below, the heuristics that tell a wrong unit within them.

#: Force in kilonewtons.  A damper whose rod moves carries at least its seal friction
#: (43.7 N for the sport damper, about 24 N on the FSAE rig) and, gas-charged, its gas
#: force (398 N sport, 14–44 N FSAE at 50–150 psi); the smallest peak force of any file the
#: project knows is 75 N (the FSAE slow run).  Written in kN a force reads 20 only at
#: 20 kN, four times the sport damper's peak on the paper's chirp (5.0 kN at 1.5 m/s).  So
#: a file whose rod strokes at least MIN_STROKE_M but whose peak ``|force|`` stays below
#: MIN_PEAK_FORCE_N is in kN (a file that barely moves may legitimately read a tared 0).
MIN_PEAK_FORCE_N = 20.0
MIN_STROKE_M = 1e-3
#: Force in kN on a heavy damper (peak above 20 kN): at speed, a damper's force per unit
#: velocity is at least hundreds of N·s/m (peak force over 99th-percentile speed: FSAE
#: runs 1,370–4,870 N·s/m, sport chirp 3,860, paper sines 4,270–8,390), in kN a few units.
#: Checked where the 99th-percentile speed reaches DYNAMIC_SPEED_M_S (below it a
#: quasi-static test's force is gas and friction, not damping).
MIN_DAMPING_N_S_M = 100.0
DYNAMIC_SPEED_M_S = 0.1
#: Time in milliseconds.  A dyno records at tens of hertz or faster (the paper's
#: quasi-static test at 50 Hz, the FSAE rig at 300 Hz, chirps at 1 kHz): a median sample
#: interval of ``max_median_interval_s`` or more (2 Hz or slower) is a file in ms sampled
#: at up to 2 kHz.  A test runs minutes (the paper's longest 150 s, the FSAE runs up to
#: 96 s): a file spanning more than ``max_duration_s`` (a day) is a test of more than 86 s
#: in ms.
#: Time in ms (or velocity in mm/s) when a velocity column is given: the least-squares
#: gain of the velocity on ``d(displacement)/d(time)`` is 1 for consistent units (0.9–1.0
#: on the FSAE runs, whose velocity is a filtered derivative) and 1000 for either mistake;
#: the limit is their geometric mean.  Noise in the velocity does not bias the gain, noise
#: in the derivative only lowers it.
MAX_VELOCITY_GAIN = math.sqrt(1000.0)

_GZIP_MAGIC = b"\x1f\x8b"


class MeasuredDataError(UserError):
    """A measured-data file is unreadable or malformed; the message is one line."""


#: ``fail(message, row=None)``: the one-line error of a file (see :class:`CsvTable`)
_Fail = Callable[..., MeasuredDataError]


@dataclass(frozen=True)
class MeasuredData:
    """One measured-data file, as arrays of equal length (SI units)."""

    time: np.ndarray
    displacement: np.ndarray
    force: np.ndarray
    velocity: np.ndarray | None = None
    temperature: np.ndarray | None = None
    #: the file's name (no directory), e.g. ``sine_3hz.csv``
    name: str = ""
    #: the path it was read from
    path: str = ""
    #: the rig's measurement chain the file was recorded through (``--rig``), if known:
    #: the model's force passes through it before it is compared with :attr:`force`
    #: (:func:`damper_emulator.acquisition.model_record`)
    acquisition: RigParams | None = None

    def __len__(self) -> int:
        return int(self.time.size)

    @property
    def duration_s(self) -> float:
        return float(self.time[-1] - self.time[0])

    def velocity_or_derivative(self) -> np.ndarray:
        """The measured velocity, or the numerical derivative of the displacement [m/s]."""
        if self.velocity is not None:
            return self.velocity
        derivative: np.ndarray = np.gradient(self.displacement, self.time)
        return derivative


def open_text(path: Path) -> TextIO:
    """Text stream of a plain or gzip-compressed file."""
    with open(path, "rb") as fh:
        magic = fh.read(2)
    if magic == _GZIP_MAGIC:
        return io.TextIOWrapper(gzip.open(path, "rb"), encoding="utf-8-sig", newline="")
    return open(path, encoding="utf-8-sig", newline="")


def short_text(value: str) -> str:
    """A field's text cut to 40 characters for an error message."""
    return value if len(value) <= 40 else value[:37] + "..."


def failure(where: str | Path, what: str = "row") -> _Fail:
    """``fail(message, row=None)`` for measured data that is not read from a CSV table (a
    recording, a bag): a one-line :class:`MeasuredDataError` naming ``where`` and, with
    ``row`` (1-based), ``<what> <row>``."""
    def fail(msg: str, row: int | None = None) -> MeasuredDataError:
        at = f" {what} {row}" if row is not None else ""
        return MeasuredDataError(f"{where}:{at}: {msg}")
    return fail


def parse_number(text: str, column: str, row: int, fail: _Fail) -> float:
    """A finite number from one CSV field; otherwise the error ``fail(message, row)``
    returns, naming the column and what the field holds."""
    text = text.strip()
    try:
        val = float(text)
    except ValueError:
        what = "empty" if not text else f"'{short_text(text)}', not a number"
        raise fail(f"{column} is {what}", row) from None
    if not math.isfinite(val):
        raise fail(f"{column} is {text} (must be a finite number)", row)
    return val


@dataclass(frozen=True)
class CsvTable:
    """The columns of a CSV file read by :func:`read_csv_table`."""

    #: parsed values per column present in the file, in the order of the column spec (a
    #: list, or a float array where every column is numeric)
    values: Mapping[str, list[Any] | np.ndarray]
    #: number of data rows (blank lines not counted)
    rows: int
    #: ``fail(message, row=None)`` → a one-line :class:`MeasuredDataError` naming the file
    #: and, with ``row`` (1-based data row), the row and its line in the file
    fail: _Fail


def read_csv_table(path: str | Path, required: Sequence[str], optional: Sequence[str] = (),
                   parsers: Mapping[str, Callable[[str, str, int, _Fail], Any]] | None = None,
                   kind: str = "measured-data file") -> CsvTable:
    """Read the named columns of a CSV file (or ``.csv.gz``) with a header row.

    Column names are matched case-insensitively after stripping blanks; other columns
    are ignored.  Each field is parsed by ``parsers[column](text, column, row, fail)``
    (default :func:`parse_number`).  When every column is numeric (no ``parsers``) the
    file is first read by :func:`numpy.loadtxt`, about five times faster on long files;
    if that meets anything it does not take (or a value that is not finite), the file is
    read field by field instead, which finds the row and says what is wrong.

    Raises
    ------
    MeasuredDataError
        One line naming the file (``kind`` says what it is) and, where it applies, the
        data row and file line: unreadable or empty file, a column missing or given twice,
        a row without a value for a column, a field its parser refuses.
    """
    path = Path(path)
    where = str(path)
    parsers = parsers or {}
    lines: list[int] = []  # file line of each data row
    read_fast = False  # read by numpy.loadtxt: ``lines`` not recorded

    def fail(msg: str, row: int | None = None) -> MeasuredDataError:
        if row is None:
            return MeasuredDataError(f"{where}: {msg}")
        if row <= len(lines):
            line = lines[row - 1]
        elif read_fast:
            line = _file_line_of_row(path, row)
        else:
            line = row + 1
        return MeasuredDataError(f"{where}: row {row} (line {line}): {msg}")

    try:
        stream = open_text(path)
    except OSError as exc:
        raise fail(f"cannot read {kind}: {exc.strerror or exc}") from None
    try:
        with stream:
            rows = csv.reader(stream)
            header = next(rows, None)
            if header is None or not any(h.strip() for h in header):
                raise fail("empty file: expected a header row with columns "
                           + ", ".join(required))
            names = [h.strip().lower() for h in header]
            index: dict[str, int] = {}
            for col in (*required, *optional):
                hits = [i for i, n in enumerate(names) if n == col.lower()]
                if len(hits) > 1:
                    raise fail(f"header: column '{col}' appears {len(hits)} times")
                if hits:
                    index[col] = hits[0]
            missing = [c for c in required if c not in index]
            if missing:
                raise fail(f"header: missing required column '{missing[0]}' (have: "
                           f"{', '.join(h.strip() for h in header if h.strip()) or 'none'}; "
                           f"need {', '.join(required)})")
            cols = list(index)
            if not parsers:
                fast = _read_numeric_columns(path, [index[c] for c in cols])
                if fast is not None:
                    read_fast = True
                    return CsvTable({c: fast[:, k].copy() for k, c in enumerate(cols)},
                                    fast.shape[0], fail)
            values: dict[str, list[Any]] = {c: [] for c in cols}
            need = max(index.values()) + 1
            row = 0
            for fields_ in rows:
                if not fields_ or not any(f.strip() for f in fields_):
                    continue  # blank line
                row += 1
                lines.append(rows.line_num)
                if len(fields_) < need:
                    absent = next(c for c in cols if index[c] >= len(fields_))
                    raise fail(f"{len(fields_)} fields, no value for column '{absent}'", row)
                for c in cols:
                    values[c].append(parsers.get(c, parse_number)(fields_[index[c]], c, row,
                                                                  fail))
    except MeasuredDataError:
        raise
    except UnicodeDecodeError:
        raise fail("not a text CSV file (cannot decode as UTF-8)") from None
    except (OSError, EOFError, csv.Error, zlib.error) as exc:
        raise fail(f"cannot read {kind}: {exc}") from None
    return CsvTable(values, row, fail)


def _read_numeric_columns(path: Path, columns: Sequence[int]) -> np.ndarray | None:
    """The data rows' fields ``columns`` (0-based) as a float array of shape (rows,
    len(columns)), read by :func:`numpy.loadtxt` after the header row; ``None`` when the
    file holds anything it does not take (a field that is not a number, a short row,
    quotes, bytes that are not UTF-8), a value that is not finite, or no data row.  Blank
    lines are skipped, as :func:`read_csv_table` skips them."""
    try:
        with open_text(path) as stream:
            next(csv.reader(stream), None)  # the header, however it is quoted
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # "input contained no data"
                table = np.loadtxt(stream, dtype=float, delimiter=",", comments=None,
                                   usecols=tuple(columns), ndmin=2)
    except (ValueError, OSError, EOFError, csv.Error, zlib.error):
        return None
    if table.shape[0] == 0 or not np.isfinite(table).all():
        return None
    return table


def _file_line_of_row(path: Path, row: int) -> int:
    """The file line of data row ``row`` (1-based, blank lines not counted), as
    :func:`read_csv_table` numbers it: for an error found after a fast read."""
    with open_text(path) as stream:
        rows = csv.reader(stream)
        next(rows, None)
        count = 0
        for fields_ in rows:
            if fields_ and any(f.strip() for f in fields_):
                count += 1
                if count == row:
                    return rows.line_num
    return row + 1


def read_measured_csv(path: str | Path) -> MeasuredData:
    """Read and check a measured-data CSV (or ``.csv.gz``).

    Raises
    ------
    MeasuredDataError
        For an unreadable or empty file, a missing required column, a non-numeric, NaN or
        infinite value, time not strictly increasing, values in the wrong unit by orders of
        magnitude (displacement in millimetres, velocity in mm/s, temperature in kelvin,
        force in kilonewtons, time in milliseconds; the plausibility limits above) or
        fewer than 2 data rows.  The one-line message names the file and the data row.
    """
    path = Path(path)
    table = read_csv_table(path, REQUIRED_COLUMNS, OPTIONAL_COLUMNS)
    row, values, fail = table.rows, table.values, table.fail
    if row < 2:
        raise fail(f"{row} data row{'s' if row != 1 else ''}; need at least 2")
    arrays = {c: np.asarray(v, dtype=float) for c, v in values.items()}
    data = MeasuredData(time=arrays["time"], displacement=arrays["displacement"],
                        force=arrays["force"], velocity=arrays.get("velocity"),
                        temperature=arrays.get("temperature"), name=path.name,
                        path=str(path))
    check_measured(data, fail)
    return data


def check_measured(data: MeasuredData, fail: _Fail, limits: MeasuredLimits = LIMITS) -> None:
    """Refuse data a damper dyno cannot have produced, naming the first bad row.

    In order: time strictly increasing, no two samples closer than
    ``min_sample_interval_s``; every sample within its column's bounds (``limits``: force,
    displacement, velocity, temperature; a displacement beyond 1 m or a velocity beyond
    20 m/s is taken for millimetres, a temperature beyond 250 °C for kelvin); the time's
    unit (median interval, duration) and no single gap longer than ``max_gap_s``; no
    displacement jump faster than the velocity bound between two samples; no lone sample
    (one beyond all the others of its column by more than ``lone_sample_ratio`` times their
    range and ``lone_sample_floor`` of the bound); then the units within the bounds
    (velocity against the displacement's derivative: time in ms or velocity in mm/s; a
    force too small for the motion: kN).

    Raises
    ------
    MeasuredDataError
        ``fail(message, row)``: one line naming the row (1-based) and the problem.
    """
    lim = limits
    t = data.time
    bad = np.flatnonzero(~(np.diff(t) > 0))
    if bad.size:
        i = int(bad[0]) + 1  # 0-based index of the offending sample
        raise fail(f"time is not strictly increasing ({t[i - 1]:.9g} s then {t[i]:.9g} s)",
                   i + 1)
    close = np.flatnonzero(np.diff(t) < lim.min_sample_interval_s)
    if close.size:
        i = int(close[0]) + 1
        raise fail(f"time steps by {t[i] - t[i - 1]:.3g} s ({t[i - 1]:.9g} s then "
                   f"{t[i]:.9g} s), less than the {lim.min_sample_interval_s:g} s of the "
                   "fastest dyno sampling: a bad time stamp", i + 1)
    _check_bound(data.displacement, -lim.max_abs_displacement_m, lim.max_abs_displacement_m,
                 "displacement", "m", "looks like millimetres; expected metres", fail)
    if data.velocity is not None:
        _check_bound(data.velocity, -lim.max_abs_velocity_m_s, lim.max_abs_velocity_m_s,
                     "velocity", "m/s", "looks like mm/s; expected m/s", fail)
    if data.temperature is not None:
        _check_bound(data.temperature, lim.min_temperature_c, lim.max_temperature_c,
                     "temperature", "°C", "looks like kelvin; expected degrees Celsius", fail,
                     low_hint="a sensor fault")
    _check_bound(data.force, -lim.max_abs_force_n, lim.max_abs_force_n, "force", "N",
                 "not a damper dyno's force: another unit or scale, or a bad sample", fail)
    _check_time_unit(data, fail, lim)
    _check_jumps(data, fail, lim)
    for column, bound in (("force", lim.max_abs_force_n),
                          ("displacement", lim.max_abs_displacement_m),
                          ("velocity", lim.max_abs_velocity_m_s),
                          ("temperature", lim.max_temperature_c - lim.min_temperature_c)):
        values = getattr(data, column)
        if values is not None:
            _check_lone_sample(values, column, bound, fail, lim)
    _check_velocity_unit(data, fail)
    _check_force_unit(data, fail)


def _check_bound(values: np.ndarray, lo: float, hi: float, column: str, unit: str,
                 hint: str, fail: _Fail, low_hint: str | None = None) -> None:
    """Every value in ``[lo, hi]``; else the row of the first beyond."""
    beyond = np.flatnonzero((values < lo) | (values > hi))
    if not beyond.size:
        return
    i = int(beyond[0])
    if lo == -hi:
        raise fail(f"{column} {values[i]:.6g} exceeds {hi:g} {unit} in magnitude: {hint}",
                   i + 1)
    side = "above" if values[i] > hi else "below"
    raise fail(f"{column} {values[i]:.6g} {unit} is {side} the {hi if side == 'above' else lo:g}"
               f" {unit} a damper reaches: {hint if side == 'above' else low_hint or hint}",
               i + 1)


def _check_jumps(data: MeasuredData, fail: _Fail, lim: MeasuredLimits) -> None:
    """No displacement change between two samples faster than the velocity bound."""
    rate = np.abs(np.diff(data.displacement)) / np.diff(data.time)
    fast = np.flatnonzero(rate > lim.max_abs_velocity_m_s)
    if fast.size:
        i = int(fast[0]) + 1
        x, t = data.displacement, data.time
        raise fail(f"displacement jumps from {x[i - 1]:.6g} m to {x[i]:.6g} m in "
                   f"{t[i] - t[i - 1]:.3g} s ({rate[i - 1]:.3g} m/s; a damper dyno moves at "
                   f"most {lim.max_abs_velocity_m_s:g} m/s): a bad sample", i + 1)


def _check_lone_sample(values: np.ndarray, column: str, bound: float, fail: _Fail,
                       lim: MeasuredLimits) -> None:
    """Refuse a single sample far beyond all the others of its column (a spike)."""
    n = values.size
    if n < 3:
        return
    part = np.partition(values, (0, 1, n - 2, n - 1))
    lo1, lo2, hi2, hi1 = part[0], part[1], part[n - 2], part[n - 1]
    floor = lim.lone_sample_floor * bound
    for excess, rest, index in ((hi1 - hi2, hi2 - lo1, int(np.argmax(values))),
                                (lo2 - lo1, hi1 - lo2, int(np.argmin(values)))):
        if excess > floor and excess > lim.lone_sample_ratio * rest:
            raise fail(f"{column} {values[index]:.6g} lies {excess:.3g} beyond every other "
                       f"sample, whose range is {rest:.3g}: a lone spike, not a damper's "
                       "signal", index + 1)


def _check_time_unit(data: MeasuredData, fail: _Fail, lim: MeasuredLimits) -> None:
    """Refuse time in milliseconds, and a gap within a test.

    Raises
    ------
    MeasuredDataError
        ``fail(message, row)``: a median sample interval of ``max_median_interval_s`` or
        more (row: the first such interval's end), a file longer than ``max_duration_s``
        (row: the first sample beyond it), a single interval longer than ``max_gap_s``
        (row: its end).
    """
    hint = "looks like milliseconds; expected seconds"
    t = data.time
    steps = np.diff(t)
    step = float(np.median(steps))
    if step >= lim.max_median_interval_s:
        i = int(np.argmax(steps >= lim.max_median_interval_s)) + 1
        raise fail(f"time steps by {step:.6g} s (median), a dyno samples faster than "
                   f"{1 / lim.max_median_interval_s:g} Hz: {hint}", i + 1)
    if data.duration_s > lim.max_duration_s:
        i = int(np.argmax(t - t[0] > lim.max_duration_s))
        raise fail(f"time spans {data.duration_s:.6g} s, more than a day "
                   f"({lim.max_duration_s:g} s) for a dyno test: {hint}", i + 1)
    gap = np.flatnonzero(steps > lim.max_gap_s)
    if gap.size:
        i = int(gap[0]) + 1
        raise fail(f"time jumps by {steps[i - 1]:.6g} s ({t[i - 1]:.9g} s then {t[i]:.9g} s), "
                   f"more than the {lim.max_gap_s:g} s a test pauses: two tests in one file, "
                   "or a bad time stamp", i + 1)


def _check_velocity_unit(data: MeasuredData, fail: _Fail) -> None:
    """Refuse a velocity column 1000 times the displacement's derivative.

    Raises
    ------
    MeasuredDataError
        ``fail(message, row)`` (row: the peak velocity) where the velocity is
        MAX_VELOCITY_GAIN times the derivative of the displacement or more (checked where
        the rod strokes at least MIN_STROKE_M): time in ms, or velocity in mm/s.
    """
    x, v, t = data.displacement, data.velocity, data.time
    if v is None or np.ptp(x) < MIN_STROKE_M:
        return
    derivative = np.gradient(x, t)
    power = float(np.dot(derivative, derivative))
    gain = float(np.dot(v, derivative)) / power if power > 0 else 0.0
    if abs(gain) > MAX_VELOCITY_GAIN:
        i = int(np.argmax(np.abs(v)))
        raise fail(f"velocity is {gain:.4g} × d(displacement)/d(time): time looks like "
                   "milliseconds; expected seconds (or velocity is in mm/s, expected m/s)",
                   i + 1)


def _check_force_unit(data: MeasuredData, fail: _Fail) -> None:
    """Refuse force in kilonewtons.

    Raises
    ------
    MeasuredDataError
        ``fail(message, row)`` naming the row of the peak ``|force|``: below
        MIN_PEAK_FORCE_N while the rod strokes at least MIN_STROKE_M, or below
        MIN_DAMPING_N_S_M times the 99th-percentile speed where that reaches
        DYNAMIC_SPEED_M_S (the velocity column, else the derivative of the displacement).
    """
    hint = "looks like kilonewtons; expected newtons"
    f = data.force
    i = int(np.argmax(np.abs(f)))
    peak = abs(float(f[i]))
    stroke = float(np.ptp(data.displacement))
    if stroke >= MIN_STROKE_M and peak < MIN_PEAK_FORCE_N:
        raise fail(f"force peaks at {f[i]:.6g} while the displacement moves "
                   f"{stroke * 1e3:.3g} mm; a moving damper gives at least "
                   f"{MIN_PEAK_FORCE_N:g} N: {hint}", i + 1)
    speed = float(np.percentile(np.abs(data.velocity_or_derivative()), 99))
    if speed >= DYNAMIC_SPEED_M_S and peak / speed < MIN_DAMPING_N_S_M:
        raise fail(f"force peaks at {f[i]:.6g} at speeds of {speed:.3g} m/s "
                   f"(99th percentile), {peak / speed:.3g} N·s/m; a damper gives at least "
                   f"{MIN_DAMPING_N_S_M:g} N·s/m: {hint}", i + 1)


def write_measured_csv(path: str | Path, time: ArrayLike, displacement: ArrayLike,
                       force: ArrayLike, velocity: ArrayLike | None = None,
                       temperature: ArrayLike | None = None) -> Path:
    """Write a measured-data CSV (gzip-compressed when ``path`` ends in ``.gz``), at once
    (:func:`~damper_emulator.outputs.atomic_path`).

    Columns ``time,displacement[,velocity],force[,temperature]`` in SI units, values
    formatted ``%.9g``.  Returns the path written.

    Raises
    ------
    ValueError
        Arrays of unequal length or not one-dimensional.
    OutputError
        The file cannot be written.
    """
    path = Path(path)
    cols = [("time", time), ("displacement", displacement)]
    if velocity is not None:
        cols.append(("velocity", velocity))
    cols.append(("force", force))
    if temperature is not None:
        cols.append(("temperature", temperature))
    arrays = [np.asarray(a, dtype=float) for _, a in cols]
    n = arrays[0].size
    for (name, _), a in zip(cols, arrays):
        if a.ndim != 1 or a.size != n:
            raise ValueError(f"measured-data column '{name}' has shape {a.shape}, "
                             f"expected ({n},)")
    with atomic_path(path) as at:
        np.savetxt(at, np.column_stack(arrays), fmt="%.9g", delimiter=",",
                   header=",".join(name for name, _ in cols), comments="")
    return path
