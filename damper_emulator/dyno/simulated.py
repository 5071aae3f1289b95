"""The dyno protocols simulated on the model, as arrays: no files, no plots.

:mod:`damper_emulator.dyno.runner` writes them (CSV and PNG); the classical representations
(:mod:`damper_emulator.model.representations`) and the ride studies use the N-speed table
directly.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from damper_emulator.dyno import protocols
from damper_emulator.dyno.protocols import FourteenSpeed, Sine
from damper_emulator.errors import UserError
from damper_emulator.model.compressible import DamperModel, simulate
from damper_emulator.model.layout import Fault

#: What produces the forces of a protocol: ``engine(model, t, x, v)`` → an object with
#: ``force_n`` and ``faults`` arrays (default :func:`simulate`, the offline model; the
#: loopback dyno passes one that runs the samples over CAN, :mod:`can_bridge.loopback`).
#: A physical dyno's engine adds ``measured_stroke_m``, the stroke it achieved, and
#: ``measured``, which samples it measured (False where its feedback never came); the
#: measured data then record those (:func:`measured_samples`).
Engine = Callable[..., Any] | None


def measured_samples(result: Any, t: np.ndarray, x: np.ndarray, v: np.ndarray
                     ) -> tuple[np.ndarray, ...]:
    """What the measured data record of an engine's ``result``: ``(t, x, v, force,
    faults)``.  A physical dyno follows the demand only so well: its measured stroke, the
    stroke's derivative and its force, at the samples it measured (a sample the dyno's
    feedback never gave is left out, not made up).  Else the demanded ``x`` and ``v`` and
    the engine's force, at every sample."""
    force = np.asarray(result.force_n, dtype=float)
    faults = np.asarray(result.faults)
    stroke = getattr(result, "measured_stroke_m", None)
    if stroke is None:
        return t, x, v, force, faults
    keep = np.asarray(getattr(result, "measured", np.ones(t.size, dtype=bool)), dtype=bool)
    t, x = t[keep], np.asarray(stroke, dtype=float)[keep]
    return t, x, np.gradient(x, t), force[keep], faults[keep]

#: columns of ``14speed.csv``
FOURTEEN_SPEED_COLUMNS = ("frequency_hz", "peak_velocity_rebound_m_s", "peak_force_rebound_n",
                          "peak_velocity_compression_m_s", "peak_force_compression_n")


def sine_file_name(frequency_hz: float) -> str:
    """``sine_<f>hz.csv`` with ``<f>`` formatted ``%g`` (``sine_3hz.csv``, ``sine_0.5hz.csv``)."""
    return f"sine_{frequency_hz:g}hz.csv"



def add_noise(force: np.ndarray, noise_std: float, rng: np.random.Generator) -> np.ndarray:
    if noise_std > 0:
        return force + rng.normal(0.0, noise_std, force.size)
    return force


def check_travel(model: DamperModel, x: np.ndarray, what: str) -> None:
    """One-line error when a protocol's stroke leaves the damper's physical travel."""
    lo, hi = model.stroke_limits_m
    margin = model.cfg.numerics.travel_margin_m
    x_max, x_min = float(np.max(x)), float(np.min(x))
    if x_max >= hi - margin:
        raise UserError(f"{what} reaches {x_max:.4g} m of extension, beyond the damper's "
                         f"travel {hi:.4g} m (pressure_tube_length_m − x0_m)")
    if x_min <= lo + margin:
        raise UserError(f"{what} reaches {-x_min:.4g} m of compression, beyond the damper's "
                         f"travel {-lo:.4g} m (gas volume / rod area)")


def fault_names(faults: np.ndarray) -> list[str]:
    bits = Fault(int(np.bitwise_or.reduce(faults))) if faults.size else Fault.NONE
    return [f.name for f in Fault if f and f in bits]



def simulate_sine(model: DamperModel, frequency: float, amplitude: float,
                  cycles: int = Sine.cycles, rate: float = Sine.rate_hz,
                  settle_cycles: int = Sine.settle_cycles, engine: Engine = None):
    """Simulate ``x = A sin(2π f t)`` for ``settle_cycles + cycles`` periods and return the
    recorded part ``(t, x, v, F, faults)``, ``t`` starting at exactly 0.

    The lead-in lets the pressures settle from the quasi-steady initial state.
    """
    protocols.checked(Sine, "dyno", frequency_hz=frequency, amplitude_m=amplitude,
                      cycles=cycles, rate_hz=rate, settle_cycles=settle_cycles)
    t, x, v = protocols.sine(frequency, amplitude, cycles, rate, start_cycles=settle_cycles)
    check_travel(model, x, f"sine amplitude {amplitude:g} m")
    t, x, v, f, faults = measured_samples((engine or simulate)(model, t, x, v), t, x, v)
    k = int(np.searchsorted(t, 0.0))  # protocols.sine puts a sample on t = 0
    return (t[k:], x[k:], v[k:], f[k:], faults[k:])



def fourteen_speed_table(model: DamperModel, points: int = FourteenSpeed.points,
                         amplitude: float = FourteenSpeed.amplitude_m,
                         v_min: float = FourteenSpeed.v_min_m_s,
                         v_max: float = FourteenSpeed.v_max_m_s,
                         cycles: int = FourteenSpeed.cycles,
                         rate: float = FourteenSpeed.rate_hz, noise_std: float = 0.0,
                         rng: np.random.Generator | None = None, engine: Engine = None,
                         ) -> tuple[dict[str, np.ndarray], list[str]]:
    """Simulate an N-speed test (docs/model.md §4) and return its table (columns
    :data:`FOURTEEN_SPEED_COLUMNS`) and the fault names seen.

    For each frequency a sine of ``amplitude`` is simulated (one settle cycle dropped);
    the peak rebound force (max F) is paired with the peak rebound velocity (max v) and
    the peak compression force (min F) with the peak compression velocity (min v).
    """
    protocols.checked(FourteenSpeed, "dyno", points=points, amplitude_m=amplitude,
                      v_min_m_s=v_min, v_max_m_s=v_max, cycles=cycles, rate_hz=rate)
    if rng is None:
        rng = np.random.default_rng(0)
    freqs = protocols.fourteen_speed_frequencies(points, amplitude, v_min, v_max)
    rows = []
    faults = np.zeros(0, dtype=np.int64)
    for freq in freqs:
        _t, _x, v, f, flt = simulate_sine(model, float(freq), amplitude, cycles, rate, 1,
                                        engine)
        f = add_noise(f, noise_std, rng)
        rows.append((freq, v.max(), f.max(), v.min(), f.min()))
        faults = np.concatenate([faults, flt])
    arr = np.array(rows, dtype=float)
    return ({c: arr[:, i] for i, c in enumerate(FOURTEEN_SPEED_COLUMNS)},
            fault_names(faults))
