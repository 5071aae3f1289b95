"""FSAE racing-damper dyno files (Öhlins TTX25-type, ``fsae_ttx25``): reader and export.

The vendor files (one gzip CSV per run, columns ``Timestamp, Force (V), Force (N),
Displacement (V), Displacement (mm), Temperature (V), Temperature (C)``, 300 Hz) are read
at run time from wherever the user keeps them; the project ships none of them.
:func:`read_fsae_ttx25` converts one into the project's measured-data convention
(docs/interfaces.md §2, docs/model.md §1):

``time`` [s]
    seconds since the file's first ``Timestamp`` (ISO wall clock); strictly increasing or
    the file is rejected.
``displacement`` [m, extension positive]
    ``+9.64 mm/V × Displacement (V)`` (:data:`DISPLACEMENT_SIGN`: an *increasing*
    potentiometer reading is *extension*), relative to the **mid-stroke of the run**: the
    mean of the minimum and maximum of the Savitzky–Golay-smoothed reading over the whole
    file (smoothed so that one noisy sample cannot move the reference). It is not the
    damper's static ride position, which these files do not record.
``force`` [N, rebound (tension) positive]
    ``-198.38 N/V × Force (V)`` (:data:`FORCE_SIGN`), one slope for every file. The
    ``Force (N)`` column is ignored: its slope is +198.38 N/V in some folders and
    -198.38 N/V in others. No offset is removed: the load cell's zero is kept as recorded.
``velocity`` [m/s]
    Savitzky–Golay first derivative of the displacement, window :data:`SAVGOL_WINDOW`
    samples (83 ms at 300 Hz), cubic (:data:`SAVGOL_POLYORDER`). Its gain is within 0.5 %
    of an ideal differentiator up to 5 Hz (the 4th harmonic of the fastest run, 1.25 Hz)
    and below 1 % at 51 Hz, where the potentiometer carries a narrow-band interference
    line (about 0.04 mm r.m.s.). A per-cycle slider-crank fit was not used: the DC motor's
    speed varies within a cycle with the damper's load, which a constant-speed crank
    model cannot follow.
``temperature`` [°C]
    the file's ``Temperature (C)`` column as recorded (it carries about ±0.4 °C of the same
    51 Hz interference).

The sign convention comes from the data (``tools/fsae_survey.py`` and
``docs/measured/fsae_ttx25_data.md`` give the evidence): (a) with this convention the
force at rest and the mid-stroke average of the two strokes are negative (the gas charge
pushes the rod out, docs/model.md ``F_static = -A_rod P_gas``) and scale with the nitrogen
charge through zero at zero charge, which fixes the force sign; (b) the damper dissipates
energy, ``∮ F dx > 0`` on every cycle of every file, which then fixes the displacement sign.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import numpy as np
from scipy.signal import savgol_filter

from damper_emulator.dyno.column_map import SAVGOL_ORDER, ColumnMap, mid_stroke, savgol_velocity
from damper_emulator.dyno.measured import (
    MeasuredData,
    check_measured,
    read_csv_table,
    short_text,
    write_measured_csv,
)
from damper_emulator.errors import UserError

#: load-cell slope, the same for every file [N/V] (SOURCE.md)
FORCE_N_PER_V = 198.38
#: rebound-positive force = FORCE_SIGN × FORCE_N_PER_V × ``Force (V)``
FORCE_SIGN = -1.0
#: potentiometer slope [mm/V] (SOURCE.md)
DISPLACEMENT_MM_PER_V = 9.64
#: extension-positive displacement = DISPLACEMENT_SIGN × (reading − mid-stroke)
DISPLACEMENT_SIGN = +1.0
#: nominal sample rate [Hz]
SAMPLE_RATE_HZ = 300.0
#: Savitzky–Golay window [samples] and polynomial order of the velocity
SAVGOL_WINDOW = 25
SAVGOL_POLYORDER = SAVGOL_ORDER
#: slider-crank rig: crank radius and connecting rod [m]; stroke = 2 × crank radius
CRANK_RADIUS_M = 0.75 * 0.0254
CONNECTING_ROD_M = 6.0 * 0.0254
STROKE_M = 2.0 * CRANK_RADIUS_M
#: nominal crank frequency of each speed code [Hz] (SOURCE.md)
SPEED_CODE_HZ = {1: 0.21, 5: 1.05, 6: 1.25}
PSI_TO_PA = 6894.757293168361

#: vendor columns the reader uses (matched case-insensitively, blanks stripped)
TIME_COLUMN = "Timestamp"
FORCE_COLUMN = "Force (V)"
DISPLACEMENT_COLUMN = "Displacement (V)"
TEMPERATURE_COLUMN = "Temperature (C)"
_USED = (TIME_COLUMN, FORCE_COLUMN, DISPLACEMENT_COLUMN, TEMPERATURE_COLUMN)

#: the runs read through a column map alone, to the reader's arrays bit for bit (the
#: vendor's converted columns, its ISO stamps, the mid-stroke zero and the velocity filter);
#: in :data:`FLIPPED_FOLDER` the ``Force (N)`` column has the other sign
COLUMN_MAP = ColumnMap(columns={"time": TIME_COLUMN, "displacement": "Displacement (mm)",
                                "force": "Force (N)", "temperature": TEMPERATURE_COLUMN},
                       displacement_zero="mid-stroke", velocity_window=SAVGOL_WINDOW)
#: the folder whose ``Force (N)`` is compression-positive
FLIPPED_FOLDER = "pressure_testing"

_NAME_RE = re.compile(
    r"^t(?P<trial>\d+)_(?P<a>\d+)_(?P<b>\d+)_(?P<c>\d+)_(?P<d>\d+)_s(?P<speed>\d+)"
    r"_n(?P<cycles>\d+)_(?P<psi>\d+(?:\.\d+)?)psi(?P<heat>_with_heat_gun)?$")


@dataclass(frozen=True)
class FsaeRunInfo:
    """The fields of a vendor file name ``t<trial>_<a>_<b>_<c>_<d>_s<speed>_n<cycles>_
    <psi>psi[_with_heat_gun]``.

    ``valves`` are the four adjuster settings ``a, b, c, d`` in file-name order; the source
    calls them HSC, HSR, LSC, LSR, an order it does not confirm.
    """

    name: str
    trial: int
    valves: tuple[int, int, int, int]
    speed_code: int
    cycles: int
    gas_psi: float
    heat_gun: bool

    @property
    def valve_label(self) -> str:
        return "_".join(str(v) for v in self.valves)

    @property
    def gas_pressure_pa(self) -> float:
        """Nitrogen charge (gauge) [Pa]."""
        return self.gas_psi * PSI_TO_PA

    @property
    def nominal_frequency_hz(self) -> float | None:
        return SPEED_CODE_HZ.get(self.speed_code)


def _stem(name: str | Path) -> str:
    stem = Path(name).name
    for suffix in (".gz", ".csv"):
        if stem.lower().endswith(suffix):
            stem = stem[: -len(suffix)]
    return stem


def parse_fsae_name(name: str | Path) -> FsaeRunInfo:
    """Parse a vendor file name (directory and ``.csv``/``.csv.gz`` suffixes are ignored).

    Raises
    ------
    ValueError
        The name does not follow the pattern.
    """
    stem = _stem(name)
    m = _NAME_RE.match(stem)
    if m is None:
        raise UserError(f"{Path(name).name}: not an FSAE run name "
                         "(t<trial>_<a>_<b>_<c>_<d>_s<speed>_n<cycles>_<psi>psi"
                         "[_with_heat_gun])")
    g = m.groupdict()
    return FsaeRunInfo(name=stem, trial=int(g["trial"]),
                       valves=(int(g["a"]), int(g["b"]), int(g["c"]), int(g["d"])),
                       speed_code=int(g["speed"]), cycles=int(g["cycles"]),
                       gas_psi=float(g["psi"]), heat_gun=g["heat"] is not None)


def fsae_files(root: str | Path) -> list[Path]:
    """The vendor files (``*.csv.gz``/``*.csv`` with an FSAE run name) under ``root``,
    recursively, sorted by relative path."""
    root = Path(root)
    out = []
    for p in sorted(root.rglob("*")):
        if p.is_file() and p.name.lower().endswith((".csv", ".csv.gz")):
            try:
                parse_fsae_name(p)
            except ValueError:
                continue
            out.append(p)
    return out


def column_map(path: str | Path) -> ColumnMap:
    """The column map that reads the vendor file ``path`` as :func:`read_fsae_ttx25` does
    (:data:`COLUMN_MAP`; the force's sign flipped in :data:`FLIPPED_FOLDER`)."""
    flipped = Path(path).parent.name == FLIPPED_FOLDER
    return dataclasses.replace(COLUMN_MAP, force_sign=-1.0) if flipped else COLUMN_MAP


def read_fsae_ttx25(path: str | Path) -> MeasuredData:
    """Read one vendor file into the project's convention (see the module docstring).

    Raises
    ------
    MeasuredDataError
        One line naming the file and, where it applies, the data row (1-based; the file
        line is given too): unreadable file, missing column, bad number or timestamp,
        time not strictly increasing, fewer rows than the velocity filter needs, samples
        no dyno produces (:func:`~damper_emulator.dyno.measured.check_measured`).
    """
    path = Path(path)
    table = read_csv_table(path, _USED, parsers={TIME_COLUMN: _parse_timestamp},
                           kind="FSAE dyno file")
    cols, fail = table.values, table.fail
    stamps: list[datetime] = cols[TIME_COLUMN]
    n = len(stamps)
    if n < SAVGOL_WINDOW:
        raise fail(f"{n} data rows; need at least {SAVGOL_WINDOW} for the velocity filter")
    t0 = stamps[0]
    try:
        t = np.array([(s - t0).total_seconds() for s in stamps])
    except TypeError:  # naive and aware timestamps mixed
        i = next(i for i, s in enumerate(stamps) if (s.tzinfo is None) != (t0.tzinfo is None))
        raise fail(f"{TIME_COLUMN} mixes time zones with row 1", i + 1) from None
    bad = np.flatnonzero(~(np.diff(t) > 0))
    if bad.size:
        i = int(bad[0]) + 1
        raise fail(f"time is not strictly increasing ({stamps[i - 1].isoformat(sep=' ')} "
                   f"then {stamps[i].isoformat(sep=' ')})", i + 1)

    reading = DISPLACEMENT_MM_PER_V * np.asarray(cols[DISPLACEMENT_COLUMN]) * 1e-3  # m
    x = DISPLACEMENT_SIGN * (reading - mid_stroke(reading, SAVGOL_WINDOW))
    v = savgol_velocity(x, t, SAVGOL_WINDOW)
    force = FORCE_SIGN * FORCE_N_PER_V * np.asarray(cols[FORCE_COLUMN])
    data = MeasuredData(time=t, displacement=x, force=force, velocity=v,
                        temperature=np.asarray(cols[TEMPERATURE_COLUMN]),
                        name=path.name, path=str(path))
    check_measured(data, fail)
    return data


def _parse_timestamp(text: str, column: str, row: int, fail) -> datetime:
    """An ISO date-time from one CSV field (a :func:`read_csv_table` parser)."""
    text = text.strip()
    try:
        return datetime.fromisoformat(text)
    except ValueError:
        raise fail(f"{column} is '{short_text(text)}', not an ISO date-time", row) from None


# --------------------------------------------------------------------------------------
# cycles


def cycle_starts(data: MeasuredData, hysteresis: float = 0.25) -> np.ndarray:
    """Indices where full crank cycles start: upward crossings of mid-stroke (x = 0, in
    extension), each preceded by a visit below ``-hysteresis`` × half the stroke since the
    previous one (so noise at rest near mid-stroke cannot start a cycle)."""
    x = savgol_filter(data.displacement, SAVGOL_WINDOW, SAVGOL_POLYORDER)
    half = 0.5 * (x.max() - x.min())
    up = np.flatnonzero((x[:-1] < 0) & (x[1:] >= 0)) + 1
    below = np.flatnonzero(x < -hysteresis * half)
    starts: list[int] = []
    last = -1
    for i in up:
        # a sample below the lower threshold between the last start and this crossing
        k = np.searchsorted(below, last + 1)
        if k < below.size and below[k] < i:
            starts.append(int(i))
            last = int(i)
    return np.asarray(starts, dtype=int)


def cycle_work(data: MeasuredData, starts: np.ndarray | None = None) -> np.ndarray:
    """``∮ F dx`` of each full cycle [J] (trapezoidal rule on the recorded displacement);
    positive when the damper dissipates energy in the project's convention."""
    if starts is None:
        starts = cycle_starts(data)
    x, f = data.displacement, data.force
    dw = 0.5 * (f[1:] + f[:-1]) * np.diff(x)
    cum = np.concatenate([[0.0], np.cumsum(dw)])
    return np.diff(cum[starts]) if len(starts) > 1 else np.empty(0)


# --------------------------------------------------------------------------------------
# export


def export_fsae_csv(source: str | Path | MeasuredData, out_dir: str | Path, *,
                    compress: bool = False) -> Path:
    """Write one run as a measured-data CSV (docs/interfaces.md) under ``out_dir`` (created if
    missing), for ``damper-hil validate``/``identify``.

    ``source`` is a vendor file (read with :func:`read_fsae_ttx25`) or data it returned.
    The file is ``<run name>.csv`` (``.csv.gz`` with ``compress``) with columns
    ``time, displacement, velocity, force, temperature``. Returns its path.
    """
    data = source if isinstance(source, MeasuredData) else read_fsae_ttx25(source)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = _stem(data.name or "fsae_run")
    path = out_dir / (stem + (".csv.gz" if compress else ".csv"))
    return write_measured_csv(path, data.time, data.displacement, data.force,
                              velocity=data.velocity, temperature=data.temperature)
