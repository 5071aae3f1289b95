"""Validation of the compressible model against measured data (docs/model.md §3, eqs 34–35).

:func:`validate_file` simulates the compressible (hysteretic) model over a measured
displacement history and compares the simulated force with the measured one:

    rms_N        = √(mean((F_sim − F_meas)²))          (eq 34, C_RMS)
    relative_rms = rms_N / √(mean(F_meas²))            (eq 35)

Every sample of the file counts, the first cycle included: the simulation starts in
quasi-steady equilibrium at the first sample (:func:`~damper_emulator.model.compressible.
simulate`), so nothing is discarded.  Where the real damper was not in quasi-steady state
at that instant (e.g. a file cut out of a running sine), the simulated pressures need a few
of the model's pressure time constants (a few ms) to catch up; for the paper's sines
recorded by the virtual dyno this start-up transient is the whole of the difference, and it
contributes an r.m.s. of 0.04–0.8 N (relative 2e-5–5e-4) over three cycles.

Velocity: the file's ``velocity`` column when present, otherwise a Savitzky–Golay
derivative of the displacement (:func:`estimate_velocity`).

:mod:`damper_emulator.validation_report` draws the report figures.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from damper_emulator.acquisition.chain import model_record
from damper_emulator.acquisition.rig import RigParams
from damper_emulator.dyno.measured import MeasuredData
from damper_emulator.errors import UserError
from damper_emulator.model.compressible import DamperModel, simulate
from damper_emulator.model.layout import Fault

#: polynomial order of the Savitzky–Golay derivative
SAVGOL_POLYORDER = 3
#: the Savitzky–Golay window spans this fraction of the dominant period of the velocity
SAVGOL_PERIOD_FRACTION = 1.0 / 20.0
#: sample intervals whose spread (max − min) exceeds this fraction of the median count as
#: non-uniform sampling: the displacement is resampled on a uniform grid for the filter
UNIFORM_DT_TOLERANCE = 1e-3

#: keys of :func:`validate_file`'s result holding arrays (not JSON)
SERIES_KEY = "series"


# --------------------------------------------------------------------------------------
# velocity from displacement


def dominant_frequency(time_s, displacement_m) -> float:
    """Frequency [Hz] of the largest peak of the *velocity* spectrum ``|f X(f)|`` of the
    displacement (mean and linear trend removed), or ``nan`` when there is none.

    Weighting the displacement spectrum by ``f`` picks the component that dominates the
    velocity, i.e. the fastest motion that matters for the derivative (for a chirp whose
    velocity amplitude grows: the end of the sweep).  Non-uniform samples are treated as
    uniform at the median interval (good enough to choose a filter window).
    """
    t = np.asarray(time_s, dtype=float)
    x = np.asarray(displacement_m, dtype=float)
    n = t.size
    if n < 4:
        return math.nan
    dt = float(np.median(np.diff(t)))
    k = np.arange(n)
    x = x - np.polyval(np.polyfit(k, x, 1), k)
    spec = np.abs(np.fft.rfft(x)) * np.fft.rfftfreq(n, dt)
    spec[0] = 0.0
    i = int(np.argmax(spec))
    if spec[i] <= 0.0:
        return math.nan
    return float(np.fft.rfftfreq(n, dt)[i])


def savgol_window(rate_hz: float, frequency_hz: float, n: int) -> int:
    """Odd Savitzky–Golay window [samples]: :data:`SAVGOL_PERIOD_FRACTION` of the period
    ``1/frequency_hz`` at ``rate_hz``, at least ``SAVGOL_POLYORDER + 2`` (5) and at most
    ``n`` samples.  Without a dominant frequency (``nan``) the smallest window is used."""
    lo = SAVGOL_POLYORDER + 2
    if math.isfinite(frequency_hz) and frequency_hz > 0:
        w = int(round(SAVGOL_PERIOD_FRACTION * rate_hz / frequency_hz))
    else:
        w = lo
    w = max(w, lo)
    if w % 2 == 0:
        w += 1
    return min(w, n if n % 2 else n - 1)


def estimate_velocity(time_s, displacement_m) -> tuple[np.ndarray, dict[str, Any]]:
    """Smoothed derivative of the displacement [m/s] and a description of how it was made.

    Savitzky–Golay (``scipy.signal.savgol_filter``, cubic, ``deriv=1``, ``mode='interp'``
    so the ends are fitted, not padded).  The window spans 1/20 of the period of the
    velocity's dominant frequency (:func:`dominant_frequency`): a cubic fitted over 18° of
    a sine differentiates it with a bias below 1e-4 while averaging measurement noise over
    as many samples as the motion allows (3 Hz at 1 kHz: 17 samples; 12 Hz or more at
    1 kHz: the minimum, 5).  Sampling that is not uniform (interval spread above
    :data:`UNIFORM_DT_TOLERANCE` of the median) is resampled linearly on a uniform grid of
    the median interval, differentiated there and interpolated back.  Fewer than 5 samples:
    ``numpy.gradient``.

    The description holds ``velocity_source`` (``"savgol"`` or ``"gradient"``),
    ``savgol_window`` [samples], ``savgol_polyorder``, ``dominant_frequency_hz`` and
    ``resampled`` (bool).
    """
    from scipy.signal import savgol_filter

    t = np.asarray(time_s, dtype=float)
    x = np.asarray(displacement_m, dtype=float)
    n = t.size
    if n < SAVGOL_POLYORDER + 2:
        v = np.gradient(x, t) if n > 1 else np.zeros_like(x)
        return v, {"velocity_source": "gradient"}
    dts = np.diff(t)
    dt = float(np.median(dts))
    resampled = bool((dts.max() - dts.min()) > UNIFORM_DT_TOLERANCE * dt)
    if resampled:
        m = int(round((t[-1] - t[0]) / dt)) + 1
        tu = t[0] + dt * np.arange(m)
        tu[-1] = min(tu[-1], t[-1])
        xu = np.interp(tu, t, x)
    else:
        tu, xu = t, x
    f_dom = dominant_frequency(tu, xu)
    window = savgol_window(1.0 / dt, f_dom, tu.size)
    vu = savgol_filter(xu, window, SAVGOL_POLYORDER, deriv=1, delta=dt, mode="interp")
    v = np.interp(t, tu, vu) if resampled else vu
    return v, {"velocity_source": "savgol", "savgol_window": int(window),
               "savgol_polyorder": SAVGOL_POLYORDER,
               "dominant_frequency_hz": f_dom if math.isfinite(f_dom) else None,
               "resampled": resampled}


# --------------------------------------------------------------------------------------
# validation


def rms(a: np.ndarray) -> float:
    """Root mean square of ``a`` (0 for an empty array)."""
    return float(np.sqrt(np.mean(np.square(a)))) if a.size else 0.0


def simulate_record(model: DamperModel, data: MeasuredData, rig: RigParams | None = None):
    """``(velocity, how, result)``: ``model`` run over the measured record's time and
    displacement with its velocity column or, when absent, :func:`estimate_velocity`
    (``how`` says which), from quasi-steady equilibrium at the first sample; the record's
    temperature column, when it has one, is the measured temperature of the
    viscosity–temperature extension.  The force as :func:`recorded_force` (``rig``: an
    estimated chain, where the record carries none).

    Raises
    ------
    ValueError
        One line naming the file: the history cannot be simulated.
    """
    v, how = record_velocity(data)
    return v, how, simulate_measured(model, data, v, rig)


def record_velocity(data: MeasuredData) -> tuple[np.ndarray, dict[str, Any]]:
    """``(velocity, how)``: the record's velocity column or, when absent,
    :func:`estimate_velocity` (``how`` says which)."""
    if data.velocity is not None:
        return np.asarray(data.velocity, dtype=float), {"velocity_source": "file"}
    return estimate_velocity(data.time, data.displacement)


def recorded_force(data: MeasuredData, force: np.ndarray,
                   rig: RigParams | None = None) -> np.ndarray:
    """``force``, a force of the damper at the record's sample times before any chain, as
    the record holds it: through the record's own measurement chain (``data.acquisition``)
    or, where it carries none, the estimated chain ``rig``
    (:func:`damper_emulator.acquisition.model_record`)."""
    chain = data.acquisition if data.acquisition is not None else rig
    if chain is None or chain.does_nothing:
        return force
    out: np.ndarray = model_record(data.time, force, chain)
    return out


def simulate_measured(model: DamperModel, data: MeasuredData, velocity: np.ndarray,
                      rig: RigParams | None = None):
    """``model`` over the record's time and displacement at ``velocity`` (and its
    temperature column, if any), from quasi-steady equilibrium at the first sample; its
    force as the record holds it (:func:`recorded_force`: the record's measurement chain,
    or ``rig`` where it carries none).

    Raises
    ------
    ValueError
        One line naming the file: the history cannot be simulated.
    """
    try:
        result = simulate(model, data.time, data.displacement, velocity,
                          temperature_c=data.temperature)
    except ValueError as exc:
        where = data.path or data.name or "<data>"
        raise UserError(f"{where}: cannot simulate this history: {exc}") from None
    return dataclasses.replace(result, force_n=recorded_force(data, result.force_n, rig))


def validate_file(model: DamperModel, data: MeasuredData) -> dict[str, Any]:
    """Simulate ``model`` over the displacement history of ``data`` and compare forces.

    Returns a dict:

    - ``name``, ``samples``, ``duration_s``
    - ``rms_N``: r.m.s. of ``F_sim − F_meas`` over all samples [N] (eq 34)
    - ``relative_rms``: ``rms_N`` / r.m.s. of ``F_meas`` (eq 35; ``None`` if the measured
      force is identically zero)
    - ``rms_measured_N``, ``max_abs_error_N``, ``mean_error_N`` (``F_sim − F_meas``)
    - ``peak_force_{measured,simulated}_{rebound,compression}_n``: max / min force [N]
    - ``velocity_source`` (``"file"``, ``"savgol"`` or ``"gradient"``) and, when estimated,
      the filter settings of :func:`estimate_velocity`
    - ``faults``: names of the stepper's fault bits raised during the simulation
    - ``series``: arrays ``time``, ``displacement``, ``velocity``, ``force_measured``,
      ``force_simulated`` (for plotting; drop it for JSON, see :func:`json_summary`)

    The whole file counts, the first cycle included; the simulation starts in
    quasi-steady equilibrium at the first sample (module docstring).

    Raises
    ------
    ValueError
        One line naming the file: the history cannot be simulated (stroke beyond the
        damper's travel, velocity beyond the valve table, ...).
    """
    t, x, f_meas = data.time, data.displacement, data.force
    v, how, res = simulate_record(model, data)
    f_sim = res.force_n
    err = f_sim - f_meas
    rms_n = rms(err)
    rms_meas = rms(f_meas)
    bits = Fault(int(np.bitwise_or.reduce(res.faults))) if res.faults.size else Fault.NONE
    return {
        "name": data.name,
        "samples": int(t.size),
        "duration_s": float(t[-1] - t[0]),
        "rms_N": rms_n,
        "relative_rms": rms_n / rms_meas if rms_meas > 0 else None,
        "rms_measured_N": rms_meas,
        "max_abs_error_N": float(np.abs(err).max()),
        "mean_error_N": float(np.mean(err)),
        "peak_force_measured_rebound_n": float(f_meas.max()),
        "peak_force_measured_compression_n": float(f_meas.min()),
        "peak_force_simulated_rebound_n": float(f_sim.max()),
        "peak_force_simulated_compression_n": float(f_sim.min()),
        **how,
        "faults": [f.name for f in Fault if f and f in bits],
        SERIES_KEY: {"time": t, "displacement": x, "velocity": v,
                     "force_measured": f_meas, "force_simulated": f_sim},
    }


def json_summary(result: Mapping[str, Any]) -> dict[str, Any]:
    """The JSON-ready part of a :func:`validate_file` result (everything but the arrays
    and the redundant ``name``)."""
    return {k: val for k, val in result.items() if k not in (SERIES_KEY, "name")}


def report_stem(name: str) -> str:
    """File name without ``.csv`` / ``.csv.gz`` (``sine_3hz.csv`` → ``sine_3hz``)."""
    for suffix in (".csv.gz", ".gz", ".csv"):
        if name.lower().endswith(suffix):
            return name[: -len(suffix)]
    return Path(name).stem
