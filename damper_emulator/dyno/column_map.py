"""Measured data as a lab exports it: a map from the project's quantities to a file's
columns, their units, time stamps, signs and zero (docs/interfaces.md §2).

A dyno's export rarely reads ``time,displacement,force`` in SI units.  A
:class:`ColumnMap` names the column of each quantity (``force="Force (N)"``), and
:func:`read_mapped_csv` reads a CSV (or ``.csv.gz``) through it into the project's
:class:`~damper_emulator.dyno.measured.MeasuredData`:

* **Units** from the column's name: a trailing ``(unit)`` or ``[unit]``, or a last
  ``_unit`` (``Force (N)``, ``Position [in]``, ``force_kN``, ``Temp_degF``), converted to
  SI by ``pint``.  A bracketed unit that ``pint`` does not know, or of the wrong
  dimension, is one line naming the column; a ``_word`` that is not a unit of the
  quantity is part of the name (``piston_position``, ``load_cell``; one letter counts
  only as the quantity's SI symbol, or C, F, K for a temperature).  A column without a
  unit is taken as SI, and the plain reader's checks for a wrong unit (millimetres,
  kilonewtons, ...) apply to it.
  Temperatures: ``C``/``°C``/``degC`` (not the coulomb), ``F``/``°F``/``degF``, ``K``.
* **Time** in seconds (or a unit), or ISO 8601 wall-clock stamps (``2025-11-14
  20:07:10.531160``, a ``Z``, a decimal comma: seconds since the first; a unit in the
  column's name, ``Timestamp (UTC)``, is then ignored), or, with no time column, the
  sample index at :attr:`ColumnMap.sample_rate_hz`.  Stamps that do not strictly
  increase are refused with the row named (:func:`~damper_emulator.dyno.measured.check_measured`).
* **Signs and zero**: :attr:`ColumnMap.force_sign` and :attr:`ColumnMap.displacement_sign`
  (±1) turn the file's into the project's convention (extension and rebound force
  positive, docs/model.md §1); ``displacement_zero="mid-stroke"`` puts the stroke's zero
  halfway between its extremes (the file's zero is often the sensor's end).
* **Velocity**: the file's column, or with :attr:`ColumnMap.velocity_window` the
  displacement's cubic Savitzky–Golay derivative over that many samples
  (:func:`savgol_velocity`; a noisy potentiometer's plain derivative is mostly noise), else
  the plain derivative.
* **The convention checked with energy**: a damper dissipates, so the force times the
  velocity integrates positive over the file in the project's convention, once the work
  of the force's part that depends on the stroke alone (the gas spring's, which a file
  that does not end where it began leaves uncancelled) is taken out
  (:func:`dissipated_fraction`).  A file whose integral is clearly negative is refused,
  with the flag that would put it right.  Only a file that moves both ways about alike
  (:data:`MIN_TRAVEL_BALANCE`) is checked: within one stroke the friction is the line's
  offset, and what is left tells nothing.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from damper_emulator.dyno.measured import (
    OPTIONAL_COLUMNS,
    REQUIRED_COLUMNS,
    MeasuredData,
    MeasuredDataError,
    check_measured,
    parse_number,
    read_csv_table,
    short_text,
)
from damper_emulator.errors import UserError

#: the quantities a map may name, with the SI unit each is converted to
QUANTITY_UNITS = {"time": "s", "displacement": "m", "force": "N", "velocity": "m/s",
                  "temperature": "degC"}
#: how a unit is written at the end of a column's name: ``(mm)``, ``[in]``, ``_kN``
_UNIT_IN_NAME = re.compile(r"(?:\(([^()]+)\)|\[([^\[\]]+)\]|_([A-Za-z°][A-Za-z°/0-9]*))\s*$")
#: temperature units as data files write them (``C`` would be the coulomb to pint)
_TEMPERATURE_ALIASES = {"c": "degC", "°c": "degC", "degc": "degC", "celsius": "degC",
                        "f": "degF", "°f": "degF", "degf": "degF", "fahrenheit": "degF",
                        "k": "kelvin", "kelvin": "kelvin"}
#: a file whose ∫ F·v dt is below this fraction of ∫ |F·v| dt is refused: a damper in the
#: project's convention gives +0.3 … +1 (friction and valves dissipate; the gas spring's
#: work cancels over whole cycles), one with a flipped sign as much below zero
MIN_DISSIPATED_FRACTION = -0.1
#: a file is checked for its convention only where its shorter way (extension or
#: compression travel) is at least this fraction of its longer
MIN_TRAVEL_BALANCE = 0.5
#: the displacement's zero settings
ZEROS = ("file", "mid-stroke")
#: the sidecar a folder of exports carries: the column map of every CSV in it
SIDECAR = "columns.yaml"
#: the polynomial order of the velocity's Savitzky–Golay filter (cubic)
SAVGOL_ORDER = 3


class ColumnMapError(UserError):
    """A column map that cannot be used (an unknown quantity, a bad value); one line."""


@dataclass(frozen=True)
class ColumnMap:
    """Where a file keeps each quantity, and how to read it (module docstring).

    ``columns`` maps a quantity of :data:`QUANTITY_UNITS` to the file's column name
    (matched case-insensitively, blanks stripped); a quantity not named is read from the
    column of its own name, where there is one.
    """

    columns: Mapping[str, str] = field(default_factory=dict)
    #: samples per second, where the file has no time column [Hz] (None: it has one)
    sample_rate_hz: float | None = None
    #: the file's force times this is rebound-positive force
    force_sign: float = 1.0
    #: the file's displacement times this is extension-positive displacement
    displacement_sign: float = 1.0
    #: ``"file"``: the displacement's zero as recorded; ``"mid-stroke"``: halfway between
    #: the file's smallest and largest displacement (smoothed, with a velocity window)
    displacement_zero: str = "file"
    #: no velocity column: the displacement's Savitzky–Golay derivative over this many
    #: samples (odd, at least :data:`SAVGOL_ORDER` + 2; None: the plain derivative)
    velocity_window: int | None = None

    def __post_init__(self) -> None:
        unknown = sorted(set(self.columns) - set(QUANTITY_UNITS))
        if unknown:
            raise ColumnMapError(f"column map: unknown quantity '{unknown[0]}' (one of "
                                 f"{', '.join(QUANTITY_UNITS)})")
        for name, sign in (("force_sign", self.force_sign),
                           ("displacement_sign", self.displacement_sign)):
            if sign not in (1.0, -1.0):
                raise ColumnMapError(f"column map: {name} must be 1 or -1, got {sign!r}")
        if self.displacement_zero not in ZEROS:
            raise ColumnMapError(f"column map: displacement_zero must be one of "
                                 f"{', '.join(ZEROS)}, got {self.displacement_zero!r}")
        rate = self.sample_rate_hz
        if rate is not None and not (np.isfinite(rate) and rate > 0):
            raise ColumnMapError(f"column map: sample_rate_hz must be a positive number of "
                                 f"samples per second, got {rate!r}")
        if rate is not None and "time" in self.columns:
            raise ColumnMapError("column map: a time column and a sample rate: give one")
        window = self.velocity_window
        if window is not None and (window % 2 == 0 or window < SAVGOL_ORDER + 2):
            raise ColumnMapError(f"column map: velocity_window must be an odd number of "
                                 f"samples, at least {SAVGOL_ORDER + 2}, got {window!r}")

    def column(self, quantity: str) -> str:
        """The file's column name of ``quantity``."""
        return self.columns.get(quantity, quantity)


@dataclass(frozen=True)
class ColumnOptions:
    """A command line's column options: a map file's map (None: each file's sidecar, or
    none), and the columns and settings given beside it, laid over that map."""

    base: ColumnMap | None = None
    columns: Mapping[str, str] = field(default_factory=dict)
    settings: Mapping[str, Any] = field(default_factory=dict)

    def for_file(self, path: str | Path) -> ColumnMap:
        """The map ``path`` is read through."""
        base = self.base or sidecar_map(path) or ColumnMap()
        return dataclasses.replace(base, columns={**base.columns, **self.columns},
                                   **self.settings)


def column_map_yaml(cmap: ColumnMap) -> str:
    """``cmap`` as the YAML of a column-map file (what :func:`load_column_map` reads):
    the columns, and each setting that is not the default."""
    import yaml

    doc: dict[str, Any] = {"columns": dict(cmap.columns)}
    default = ColumnMap()
    for f in dataclasses.fields(ColumnMap):
        value = getattr(cmap, f.name)
        if f.name != "columns" and value != getattr(default, f.name):
            doc[f.name] = value
    return yaml.safe_dump(doc, sort_keys=False, allow_unicode=True)


def write_sidecar(folder: str | Path, cmap: ColumnMap) -> Path:
    """Write ``cmap`` as the :data:`SIDECAR` of ``folder``: every data file there is then
    read through it.  Returns its path."""
    from damper_emulator.outputs import write_text

    return write_text(Path(folder) / SIDECAR, column_map_yaml(cmap))


def sidecar_map(path: str | Path) -> ColumnMap | None:
    """The column map of the :data:`SIDECAR` beside ``path``, or None where there is
    none."""
    sidecar = Path(path).parent / SIDECAR
    return load_column_map(sidecar) if sidecar.is_file() else None


def parse_assignments(items: Iterable[str]) -> dict[str, str]:
    """``["force=Force (N)", ...]`` (a command line's ``--columns``) as a mapping;
    one-line :class:`ColumnMapError` for an item without ``=`` or a quantity named twice."""
    out: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        key, value = key.strip().lower(), value.strip()
        if not sep or not key or not value:
            raise ColumnMapError(f"column map: {item!r} is not QUANTITY=COLUMN (a data file? "
                                 "give the files before --columns, or end its list with --)")
        if key in out:
            raise ColumnMapError(f"column map: '{key}' given twice")
        out[key] = value
    return out


def unit_in_name(column: str) -> str | None:
    """The unit written at the end of a column's name (``"Force (N)"`` → ``"N"``,
    ``"force_kN"`` → ``"kN"``), or None."""
    found = _unit_and_form(column)
    return None if found is None else found[0]


def _unit_and_form(column: str) -> tuple[str, bool] | None:
    """The unit at the end of a column's name and whether it is bracketed (a ``_word``
    may be part of the name instead)."""
    match = _UNIT_IN_NAME.search(column.strip())
    if match is None:
        return None
    paren, bracket, suffix = match.groups()
    return ((paren or bracket).strip(), True) if suffix is None else (suffix, False)


#: the one-letter ``_x`` suffixes taken as units, per quantity
_ONE_LETTER_UNITS = {"time": {"s"}, "displacement": {"m"}, "force": {"N"},
                     "velocity": set(), "temperature": {"C", "F", "K"}}


def column_units(quantity: str, column: str) -> tuple[float, float] | None:
    """``(scale, offset)`` to SI from the unit in ``column``'s name, or None (no unit:
    SI).  A bracketed unit must be one of ``quantity`` (:func:`si_factor` says why not);
    a ``_word`` that is not is part of the name."""
    found = _unit_and_form(column)
    if found is None:
        return None
    unit, bracketed = found
    if bracketed:
        return si_factor(quantity, unit, column)
    if len(unit) == 1 and unit not in _ONE_LETTER_UNITS[quantity]:
        return None
    # upper-case exports: FORCE_KN is kN, DISP_MM mm (the first spelling of the quantity's
    # dimension wins; KN as written is no unit, kn the knot)
    for spelling in dict.fromkeys((unit, unit[0].lower() + unit[1:], unit.lower())):
        try:
            return si_factor(quantity, spelling, column)
        except ColumnMapError:
            continue
    return None


@cache
def _registry() -> Any:
    import pint

    return pint.UnitRegistry()


def si_factor(quantity: str, unit: str, column: str) -> tuple[float, float]:
    """``(scale, offset)`` that take ``quantity`` written in ``unit`` to its SI unit
    (:data:`QUANTITY_UNITS`): ``si = scale · value + offset`` (an offset only for
    temperatures).  One-line :class:`ColumnMapError` for a unit pint does not know or of
    the wrong dimension."""
    import pint

    ureg = _registry()
    text = _TEMPERATURE_ALIASES.get(unit.lower(), unit) if quantity == "temperature" else unit
    target = QUANTITY_UNITS[quantity]
    try:
        q0 = ureg.Quantity(0.0, text).to(target).magnitude
        q1 = ureg.Quantity(1.0, text).to(target).magnitude
    except pint.errors.UndefinedUnitError:
        raise ColumnMapError(f"column '{column}': unknown unit '{unit}' for the {quantity}"
                             ) from None
    except pint.errors.DimensionalityError:
        raise ColumnMapError(f"column '{column}': '{unit}' is not a unit of "
                             f"{quantity} (wanted one convertible to {target})") from None
    except Exception as exc:  # noqa: BLE001 - pint's parser raises what its tokens do
        # (ZeroDivisionError for '1/0', tokenize.TokenError for '(N', ValueError, ...)
        raise ColumnMapError(f"column '{column}': cannot read the unit '{unit}'"
                             + (f" ({exc})" if str(exc) else "")) from None
    return float(q1 - q0), float(q0)


def _number_or_stamp(text: str, column: str, row: int, fail: Any) -> float | datetime:
    """A time field as a number, or an ISO 8601 stamp as a datetime."""
    try:
        return parse_number(text, column, row, fail)
    except MeasuredDataError:
        pass
    try:
        return _parse_iso(text)
    except ValueError:
        raise fail(f"column '{column}': {short_text(text)!r} is neither a number nor an "
                   "ISO 8601 time stamp", row) from None


def _parse_iso(text: str) -> datetime:
    """An ISO 8601 stamp as Python 3.11's ``datetime.fromisoformat`` reads it, also on
    3.10 (whose parser takes neither a ``Z``, a decimal comma, nor more than six
    fraction digits)."""
    text = text.strip()
    if text[-1:] in ("Z", "z"):
        text = text[:-1] + "+00:00"
    match = re.search(r"(\d{2}:\d{2}:\d{2})[.,](\d+)", text)
    if match:
        digits = (match.group(2) + "000000")[:6]
        text = text[:match.start()] + f"{match.group(1)}.{digits}" + text[match.end():]
    return datetime.fromisoformat(text)


def _stamp_seconds(values: Any, column: str, fail: Any) -> np.ndarray:
    """ISO stamps as the seconds since the first, counted in whole microseconds (as POSIX
    seconds, a float has only about 0.2 µs of resolution left); a number among them is
    refused."""
    stamps = [isinstance(v, datetime) for v in values]
    if not all(stamps):
        row = stamps.index(not stamps[0]) + 1
        raise fail(f"column '{column}': numbers and ISO time stamps mixed", row)
    first = values[0]
    try:
        micros = [(v - first) // timedelta(microseconds=1) for v in values]
    except TypeError:  # naive and aware stamps mixed
        raise fail(f"column '{column}': time stamps with and without a time zone mixed"
                   ) from None
    return np.asarray(micros, dtype=float) / 1e6    # as timedelta.total_seconds rounds


def savgol_velocity(x: np.ndarray, t: np.ndarray, window: int) -> np.ndarray:
    """The cubic Savitzky–Golay derivative of ``x`` over ``window`` samples [m/s]; on
    irregular sampling (an interval more than 1 % off the median), the gradient of the
    smoothed signal against the time stamps."""
    from scipy.signal import savgol_filter

    dt = np.diff(t)
    h = float(np.median(dt))
    if np.all(np.abs(dt - h) <= 0.01 * h):
        velocity: np.ndarray = savgol_filter(x, window, SAVGOL_ORDER, deriv=1, delta=h)
        return velocity
    gradient: np.ndarray = np.gradient(savgol_filter(x, window, SAVGOL_ORDER), t)
    return gradient


def mid_stroke(x: np.ndarray, window: int | None) -> float:
    """Halfway between the smallest and largest of ``x``, smoothed over ``window``
    samples where given (one noisy sample then cannot move it)."""
    from scipy.signal import savgol_filter

    smooth = x if window is None else savgol_filter(x, window, SAVGOL_ORDER)
    return float(0.5 * (smooth.min() + smooth.max()))


def dissipated_fraction(time: np.ndarray, velocity: np.ndarray, force: np.ndarray,
                        displacement: np.ndarray) -> float:
    """``∫ F_d·v dt / ∫ |F_d·v| dt`` over the file (trapezoids), ``F_d`` the force less its
    least-squares line in the displacement (a spring and a static force, whose work a
    file that ends elsewhere than it began does not cancel: on a slow test the gas force
    is ten times the friction): +1 where that force always opposes the motion in the
    project's convention, −1 where always along it."""
    from scipy.integrate import trapezoid

    basis = np.column_stack([np.ones_like(displacement), displacement])
    coef, *_ = np.linalg.lstsq(basis, force, rcond=None)
    power = (force - basis @ coef) * velocity
    total = float(trapezoid(np.abs(power), time))
    return float(trapezoid(power, time)) / total if total > 0 else 0.0


def read_mapped_csv(path: str | Path, cmap: ColumnMap) -> MeasuredData:
    """A measured-data CSV (or ``.csv.gz``) read through ``cmap`` (module docstring),
    checked as :func:`~damper_emulator.dyno.measured.read_measured_csv` checks a plain
    one.

    Raises
    ------
    MeasuredDataError
        One line naming the file (and the row, where one is at fault).
    ColumnMapError
        One line naming the column: an unknown unit, or one of the wrong dimension.
    """
    path = Path(path)
    required = [q for q in REQUIRED_COLUMNS if not (q == "time" and cmap.sample_rate_hz)]
    names = {q: cmap.column(q) for q in (*required, *OPTIONAL_COLUMNS)}
    table = read_csv_table(path, [names[q] for q in required],
                           [names[q] for q in OPTIONAL_COLUMNS],
                           parsers={names["time"]: _number_or_stamp} if "time" in required
                           else None)
    fail = table.fail
    if table.rows < 2:
        raise fail(f"{table.rows} data row{'s' if table.rows != 1 else ''}; need at least 2")
    arrays: dict[str, np.ndarray] = {}
    for quantity, column in names.items():
        if column not in table.values:
            continue
        raw = table.values[column]
        if quantity == "time" and any(isinstance(v, datetime) for v in raw):
            arrays[quantity] = _stamp_seconds(raw, column, fail)   # no unit to apply
            continue
        values = np.asarray(raw, dtype=float)
        factor = column_units(quantity, column)
        if factor is not None:
            values = values * factor[0] + factor[1]
        arrays[quantity] = values
    return assemble(arrays, table.rows, cmap, fail, path)


def assemble(arrays: dict[str, np.ndarray], rows: int, cmap: ColumnMap, fail: Any,
             path: Path) -> MeasuredData:
    """The quantities of a file read through ``cmap`` (SI values; ``time`` absent where
    the map gives a sample rate) as checked :class:`MeasuredData`: the time as recorded
    (as the plain CSV reader keeps it: a series' files on one clock keep their places,
    :func:`damper_emulator.diagnose.series.series_positions`), the signs, the zero, the
    velocity (module docstring), the plain reader's checks and the convention's."""
    if "time" not in arrays:
        if cmap.sample_rate_hz is None:
            raise fail("no time: map a time column, or give a sample rate")
        arrays["time"] = np.arange(rows) / cmap.sample_rate_hz
    window = cmap.velocity_window
    if window is not None and rows < window:
        raise fail(f"{rows} data rows; need at least {window} for the velocity filter")
    reading = arrays["displacement"]
    if cmap.displacement_zero == "mid-stroke":
        reading = reading - mid_stroke(reading, window)
    x = cmap.displacement_sign * reading
    velocity = arrays.get("velocity")
    if velocity is not None:
        velocity = velocity * cmap.displacement_sign
    elif window is not None:
        velocity = savgol_velocity(x, arrays["time"], window)
    data = MeasuredData(time=arrays["time"], displacement=x,
                        force=arrays["force"] * cmap.force_sign, velocity=velocity,
                        temperature=arrays.get("temperature"), name=path.name,
                        path=str(path))
    check_measured(data, fail)
    _check_convention(data, fail)
    return data


def sample_fail(path: Path) -> Any:
    """``fail(message, sample=None)``: the one-line error of a binary file's reader
    (TDMS, MDF), naming the file and the sample (a damaged file's names and its
    library's messages may hold any character: made one line)."""
    from damper_emulator.errors import one_line

    def fail(message: str, row: int | None = None) -> MeasuredDataError:
        where = f"{path}: sample {row}: " if row is not None else f"{path}: "
        return MeasuredDataError(where + one_line(message))

    return fail


def _check_convention(data: MeasuredData, fail: Any) -> None:
    """Refuse a file whose force works along its motion (module docstring)."""
    from scipy.integrate import trapezoid

    v = data.velocity_or_derivative()
    ways = sorted(float(trapezoid(np.maximum(s * v, 0.0), data.time)) for s in (1.0, -1.0))
    if ways[1] <= 0 or ways[0] < MIN_TRAVEL_BALANCE * ways[1]:
        return
    fraction = dissipated_fraction(data.time, v, data.force, data.displacement)
    if fraction < MIN_DISSIPATED_FRACTION:
        raise fail(f"the force times the velocity integrates to {100 * fraction:.0f} % of "
                   "its magnitude: the force drives the motion instead of resisting it, so "
                   "the force's or the displacement's sign is the opposite of the project's "
                   "(rebound force and extension positive); give --force-sign -1 (or "
                   "--displacement-sign -1)")


def load_column_map(path: str | Path) -> ColumnMap:
    """A column map from a YAML file (a sidecar beside the data files): the keys
    ``columns`` (quantity → column), ``sample_rate_hz``, ``force_sign``,
    ``displacement_sign``, ``displacement_zero``; one line for anything else."""
    from damper_emulator.schema import read_yaml

    doc = read_yaml(Path(path))
    if not isinstance(doc, Mapping):
        raise ColumnMapError(f"{path}: a column map is a mapping (columns:, force_sign:, ...)")
    keys = {"columns", "sample_rate_hz", "force_sign", "displacement_sign",
            "displacement_zero", "velocity_window"}
    unknown = sorted(set(map(str, doc)) - keys)
    if unknown:
        raise ColumnMapError(f"{path}: unknown key '{unknown[0]}' (one of "
                             f"{', '.join(sorted(keys))})")
    columns = doc.get("columns") or {}
    if not isinstance(columns, Mapping):
        raise ColumnMapError(f"{path}: columns must map quantities to column names")
    try:
        return ColumnMap(columns={str(k).lower(): str(v) for k, v in columns.items()},
                         sample_rate_hz=(None if doc.get("sample_rate_hz") is None
                                         else float(doc["sample_rate_hz"])),
                         force_sign=float(doc.get("force_sign", 1.0)),
                         displacement_sign=float(doc.get("displacement_sign", 1.0)),
                         displacement_zero=str(doc.get("displacement_zero", "file")),
                         velocity_window=(None if doc.get("velocity_window") is None
                                          else int(doc["velocity_window"])))
    except ColumnMapError as exc:
        raise ColumnMapError(f"{path}: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise ColumnMapError(f"{path}: {exc}") from None
