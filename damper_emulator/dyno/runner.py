"""Virtual dyno: run the test protocols on the compressible model and write the results.

The simulations themselves are :mod:`damper_emulator.dyno.simulated`'s (re-exported here).
Each ``run_*`` function simulates one protocol (docs/model.md §3–4) on a :class:`DamperModel`,
optionally adds Gaussian force noise (a seeded :class:`numpy.random.Generator`, like a load
cell's), writes the measured data (a CSV, docs/interfaces.md, an MDF4 file or both) and
its PNG plot into ``out_dir`` and returns a small JSON-ready summary: ``files`` (names
written, relative to ``out_dir``), peak forces [N], peak velocities [m/s] and, for sines,
the dissipated energy per cycle [J].

``progress``, when given, is called with the path of every file as soon as it is written.
``engine``, when given, replaces the offline model as the source of the forces (:data:`Engine`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from damper_emulator.dyno import protocols
from damper_emulator.dyno.formats import DEFAULT_FORMAT, write_measured
from damper_emulator.dyno.measured import MeasuredData, check_measured, failure
from damper_emulator.dyno.protocols import Chirp, FourteenSpeed, QuasiStatic, Sine
from damper_emulator.dyno.simulated import (
    FOURTEEN_SPEED_COLUMNS,
    Engine,
    add_noise,
    check_travel,
    fault_names,
    fourteen_speed_table,
    measured_samples,
    simulate_sine,
    sine_file_name,
)
from damper_emulator.errors import UserError
from damper_emulator.model.compressible import DamperModel, simulate

Progress = Callable[[Path], None] | None



# --------------------------------------------------------------------------------------
# helpers


def _rng(noise_std: float, seed: int | None) -> np.random.Generator:
    if not (math.isfinite(noise_std) and noise_std >= 0):
        raise UserError(f"force noise standard deviation must be >= 0 N, got {noise_std!r}")
    return np.random.default_rng(seed)


def _energy(x: np.ndarray, f: np.ndarray) -> float:
    """``∫ F dx`` [J] by the trapezoid rule: work done on the damper by the dyno."""
    return float(np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(x)))


def _write(out_dir: Path, name: str, progress: Progress, fmt: str, comment: str,
           t, x, v, f) -> list[Path]:
    """Write the measured data in the format ``fmt`` (:mod:`~damper_emulator.dyno.formats`:
    ``NAME.csv``, ``NAME.mf4`` or both), then check them as every reader does
    (:func:`~damper_emulator.dyno.measured.check_measured`): a dyno over CAN whose samples
    no dyno produces is refused naming the row, and its recording is kept for a look."""
    paths = write_measured(out_dir / name, fmt, t, x, f, velocity=v,
                           comment=f"damper-hil dyno: {comment}")
    for path in paths:
        if progress:
            progress(path)
    data = MeasuredData(time=np.asarray(t, dtype=float), displacement=np.asarray(x, float),
                        force=np.asarray(f, dtype=float), velocity=np.asarray(v, float),
                        name=paths[0].name, path=str(paths[0]))
    check_measured(data, failure(paths[0]))
    return paths


def _plot(plot: bool, path: Path, progress: Progress, name: str, *args: Any,
          **kw: Any) -> list[str]:
    """Draw ``path`` with :mod:`~damper_emulator.dyno.plots`' function ``name`` when
    ``plot``: the names of the files written (plotting is imported only then)."""
    if not plot:
        return []
    from damper_emulator.dyno import plots

    getattr(plots, name)(path, *args, **kw)
    if progress:
        progress(path)
    return [path.name]


def _out(out_dir: str | Path) -> Path:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return out


def _force_summary(v: np.ndarray, f: np.ndarray) -> dict[str, float]:
    return {"peak_force_rebound_n": float(f.max()),
            "peak_force_compression_n": float(f.min()),
            "peak_velocity_rebound_m_s": float(v.max()),
            "peak_velocity_compression_m_s": float(v.min())}


# --------------------------------------------------------------------------------------
# protocols


def run_sine(model: DamperModel, out_dir: str | Path, frequency: float, amplitude: float,
             cycles: int = Sine.cycles, rate: float = Sine.rate_hz,
             settle_cycles: int = Sine.settle_cycles,
             noise_std: float = 0.0, seed: int | None = 0, progress: Progress = None,
             engine: Engine = None, plot: bool = True,
             fmt: str = DEFAULT_FORMAT) -> dict[str, Any]:
    """Sine test ``x = A sin(2π f t)``: writes ``sine_<f>hz.csv`` (``.mf4``, or both, by
    ``fmt``: :mod:`~damper_emulator.dyno.formats`) and ``sine_<f>hz.png`` (the plot unless
    ``plot`` is false).

    ``settle_cycles`` lead-in periods are simulated but not recorded; the file's time
    starts at 0.  Summary: peak forces and velocities, dissipated energy per cycle
    ``∮ F dx / cycles`` [J].
    """
    rng = _rng(noise_std, seed)
    out = _out(out_dir)
    t, x, v, f, faults = simulate_sine(model, frequency, amplitude, cycles, rate,
                                       settle_cycles, engine)
    f = add_noise(f, noise_std, rng)
    name = sine_file_name(frequency)
    title = (f"Sine {frequency:g} Hz, amplitude {amplitude * 1e3:g} mm "
             f"({model.cfg.damper.name} damper, compressible model)")
    paths = _write(out, name, progress, fmt, title, t, x, v, f)
    png = _plot(plot, paths[0].with_suffix(".png"), progress, "plot_loops", (t, x, v, f),
                title, cfg=model.cfg)
    return {"protocol": "sine", "files": [*(p.name for p in paths), *png],
            "frequency_hz": float(frequency), "amplitude_m": float(amplitude),
            "cycles": cycles, "settle_cycles": settle_cycles, "rate_hz": float(rate),
            "samples": int(t.size), "duration_s": float(t[-1]),
            **_force_summary(v, f),
            "energy_per_cycle_j": _energy(x, f) / cycles,
            "faults": fault_names(faults)}


def run_quasi_static(model: DamperModel, out_dir: str | Path,
                     velocity: float = QuasiStatic.velocity_m_s,
                     amplitude: float = QuasiStatic.amplitude_m,
                     cycles: int = QuasiStatic.cycles, rate: float = QuasiStatic.rate_hz,
                     noise_std: float = 0.0, seed: int | None = 0, progress: Progress = None,
                     engine: Engine = None, plot: bool = True,
             fmt: str = DEFAULT_FORMAT) -> dict[str, Any]:
    """Quasi-static test (constant-velocity triangle, docs/model.md §3): writes
    ``quasi_static.csv`` (``.mf4``, or both, by ``fmt``) and ``quasi_static.png`` (the plot
    unless ``plot`` is false).

    Summary adds ``friction_estimate_n``: half the difference between the mean forces
    while extending and while compressing (the gas force cancels over the symmetric
    stroke), i.e. friction plus the small viscous force at ``velocity``.
    """
    rng = _rng(noise_std, seed)
    protocols.checked(QuasiStatic, "dyno", velocity_m_s=velocity, amplitude_m=amplitude,
                      cycles=cycles, rate_hz=rate)
    out = _out(out_dir)
    t, x, v = protocols.quasi_static(velocity, amplitude, cycles, rate)
    check_travel(model, x, f"quasi-static amplitude {amplitude:g} m")
    t, x, v, f, faults = measured_samples((engine or simulate)(model, t, x, v), t, x, v)
    f = add_noise(f, noise_std, rng)
    title = (f"Quasi-static test, {velocity * 1e3:g} mm/s, ±{amplitude * 1e3:g} mm "
             f"({model.cfg.damper.name} damper)")
    paths = _write(out, "quasi_static.csv", progress, fmt, title, t, x, v, f)
    png = _plot(plot, paths[0].with_suffix(".png"), progress, "plot_loops", (t, x, v, f),
                title, cfg=model.cfg, time_series=True, velocity_points=True)
    ext, com = v > 0, v < 0
    friction = 0.5 * (float(f[ext].mean()) - float(f[com].mean()))
    return {"protocol": "quasi-static", "files": [*(p.name for p in paths), *png],
            "velocity_m_s": float(velocity), "amplitude_m": float(amplitude),
            "cycles": cycles, "rate_hz": float(rate), "samples": int(t.size),
            "duration_s": float(t[-1] - t[0]), **_force_summary(v, f),
            "friction_estimate_n": friction, "faults": fault_names(faults)}


def run_chirp(model: DamperModel, out_dir: str | Path, f_start: float = Chirp.f_start_hz,
              f_end: float = Chirp.f_end_hz, duration: float = Chirp.duration_s,
              v_start: float = Chirp.v_start_m_s, v_end: float = Chirp.v_end_m_s,
              rate: float = Chirp.rate_hz, noise_std: float = 0.0,
              seed: int | None = 0, progress: Progress = None,
              engine: Engine = None, plot: bool = True,
             fmt: str = DEFAULT_FORMAT) -> dict[str, Any]:
    """Exponential sine chirp with growing velocity amplitude (docs/model.md §3): writes
    ``chirp.csv`` (``.mf4``, or both, by ``fmt``) and ``chirp.png`` (the plot unless
    ``plot`` is false)."""
    rng = _rng(noise_std, seed)
    protocols.checked(Chirp, "dyno", f_start_hz=f_start, f_end_hz=f_end, duration_s=duration,
                      v_start_m_s=v_start, v_end_m_s=v_end, rate_hz=rate)
    out = _out(out_dir)
    t, x, v = protocols.chirp(f_start, f_end, duration, v_start, v_end, rate)
    check_travel(model, x, "chirp displacement")
    t, x, v, f, faults = measured_samples((engine or simulate)(model, t, x, v), t, x, v)
    f = add_noise(f, noise_std, rng)
    title = (f"Chirp {f_start:g}–{f_end:g} Hz in {duration:g} s, velocity amplitude "
             f"{v_start:g}–{v_end:g} m/s ({model.cfg.damper.name} damper)")
    paths = _write(out, "chirp.csv", progress, fmt, title, t, x, v, f)
    png = _plot(plot, paths[0].with_suffix(".png"), progress, "plot_loops", (t, x, v, f),
                title, cfg=model.cfg, time_series=True)
    return {"protocol": "chirp", "files": [*(p.name for p in paths), *png],
            "f_start_hz": float(f_start), "f_end_hz": float(f_end),
            "duration_s": float(duration), "v_start_m_s": float(v_start),
            "v_end_m_s": float(v_end), "rate_hz": float(rate), "samples": int(t.size),
            **_force_summary(v, f), "peak_displacement_m": float(np.abs(x).max()),
            "dissipated_energy_j": _energy(x, f), "faults": fault_names(faults)}


def run_fourteen_speed(model: DamperModel, out_dir: str | Path,
                       points: int = FourteenSpeed.points,
                       amplitude: float = FourteenSpeed.amplitude_m,
                       v_min: float = FourteenSpeed.v_min_m_s,
                       v_max: float = FourteenSpeed.v_max_m_s,
                       cycles: int = FourteenSpeed.cycles, rate: float = FourteenSpeed.rate_hz,
                       noise_std: float = 0.0,
                       seed: int | None = 0, progress: Progress = None,
                       engine: Engine = None, plot: bool = True) -> dict[str, Any]:
    """N-speed test ('14-speed', docs/model.md §4): writes ``14speed.csv`` (columns
    :data:`FOURTEEN_SPEED_COLUMNS`) and ``14speed.png`` (the plot unless ``plot`` is false)."""
    rng = _rng(noise_std, seed)
    out = _out(out_dir)
    table, faults = fourteen_speed_table(model, points, amplitude, v_min, v_max, cycles, rate,
                                         noise_std, rng, engine)
    csv_path = out / "14speed.csv"
    np.savetxt(csv_path, np.column_stack([table[c] for c in FOURTEEN_SPEED_COLUMNS]),
               fmt="%.9g", delimiter=",", header=",".join(FOURTEEN_SPEED_COLUMNS),
               comments="")
    if progress:
        progress(csv_path)
    png = _plot(plot, csv_path.with_suffix(".png"), progress, "plot_fourteen_speed", table,
                model.cfg, title=f"{points}-speed test, amplitude {amplitude * 1e3:g} mm "
                f"({model.cfg.damper.name} damper): peak force vs peak velocity")
    return {"protocol": "14-speed", "files": [csv_path.name, *png],
            "points": points, "amplitude_m": float(amplitude), "v_min_m_s": float(v_min),
            "v_max_m_s": float(v_max), "cycles": cycles, "rate_hz": float(rate),
            "table": {c: [float(a) for a in table[c]] for c in FOURTEEN_SPEED_COLUMNS},
            "faults": faults}


def read_fourteen_speed_csv(path: str | Path) -> dict[str, np.ndarray]:
    """Read a ``14speed.csv`` table written by :func:`run_fourteen_speed`."""
    data = np.genfromtxt(path, delimiter=",", names=True, dtype=float)
    missing = [c for c in FOURTEEN_SPEED_COLUMNS if c not in (data.dtype.names or ())]
    if missing:
        raise UserError(f"{path}: missing column '{missing[0]}' of an N-speed table")
    return {c: np.atleast_1d(data[c]) for c in FOURTEEN_SPEED_COLUMNS}
