"""A test series for the truth simulation: a rig that misbehaves and a damper that changes
from file to file.

A real test series is recorded file after file, on a rig whose load cell's zero drifts,
whose gain is off, whose force cable picks up the mains, and on a damper whose gas leaks
or whose oil warms up from one file to the next.  :class:`Series` says how, and
:func:`damper_emulator.diagnose.truth.simulate_session` applies it:

* the **series clock**: the files follow each other in protocol order, each
  :attr:`Series.gap_s` after the end of the one before (:func:`series_starts`); every
  rig artefact that depends on time runs on it;
* the **rig** (:class:`RigFaults`): ``F_rec = g F + z₀ + ż t_series + Σ A_k sin(2π f_k
  t_series + φ_k)`` on the true force, before the channel's filter and noise (a drifting
  amplifier, a miscalibrated gain, interference on the cable);
* the **damper**: per file, changes of the truth's base parameters (a gas charge that
  leaks, :func:`gas_leak`) and an oil temperature per file (:attr:`Series.
  oil_temperatures_c`, driving the truth's viscosity–temperature law), with or without
  the thermocouple's column in the files.

Nothing in the files says what the series did: a diagnosis has to find it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["RigFaults", "Series", "gas_leak", "series_starts"]


@dataclass(frozen=True)
class RigFaults:
    """What the rig adds to the recorded force, beyond its filters and noise.

    ``lines``: narrow-band interference, ``(frequency [Hz], amplitude [N])`` each (mains
    hum: 50 Hz and a weaker third harmonic); ``zero_offset_n``: the load cell's zero at the
    start of the series; ``zero_drift_n_per_s``: its drift on the series clock;
    ``gain``: the force channel's gain (1: calibrated)."""

    lines: tuple[tuple[float, float], ...] = ()
    zero_offset_n: float = 0.0
    zero_drift_n_per_s: float = 0.0
    gain: float = 1.0

    def apply(self, t_series: np.ndarray, force: np.ndarray, phases: Sequence[float]
              ) -> np.ndarray:
        """The force ``force`` [N] at the series clock's times ``t_series`` [s] as the
        rig's amplifier passes it on (``phases``: each line's phase at series time 0)."""
        out = self.gain * force + self.zero_offset_n + self.zero_drift_n_per_s * t_series
        for (f, a), phi in zip(self.lines, phases):
            out = out + a * np.sin(2.0 * math.pi * f * t_series + phi)
        return out

    @property
    def does_nothing(self) -> bool:
        return (not self.lines and self.zero_offset_n == 0.0
                and self.zero_drift_n_per_s == 0.0 and self.gain == 1.0)


@dataclass(frozen=True)
class Series:
    """How a truth session's files follow each other (module docstring)."""

    faults: RigFaults = RigFaults()
    #: per file, in protocol order (its index): changes of the truth's base parameters
    changes: Callable[[int], Mapping[str, Any]] | None = None
    #: per file, in protocol order: the oil's temperature [°C] (a viscosity–temperature
    #: truth follows it); ``None``: as the session's temperature option says
    oil_temperatures_c: tuple[float, ...] | None = None
    #: whether the files carry the oil temperatures as their temperature column
    temperature_column: bool = True
    #: time between the end of a file and the start of the next [s]
    gap_s: float = 30.0


def gas_leak(pressure_pa: float, fraction_per_file: float
             ) -> Callable[[int], dict[str, float]]:
    """A gas charge that loses ``fraction_per_file`` of ``pressure_pa`` with every file:
    file ``k`` (from 0) at ``pressure_pa (1 − k fraction_per_file)``."""
    def changes(k: int) -> dict[str, float]:
        return {"gas_pressure_static_pa": pressure_pa * (1.0 - k * fraction_per_file)}
    return changes


def series_starts(durations: Sequence[float], gap_s: float) -> list[float]:
    """Each file's start on the series clock [s]: the files in order, ``gap_s`` apart."""
    out, t = [], 0.0
    for d in durations:
        out.append(t)
        t += d + gap_s
    return out
