"""Motion histories of the virtual dyno's test protocols (docs/model.md §3–4).

Each protocol returns ``(time [s], stroke [m, extension +], velocity [m/s])`` sampled at
``rate_hz``; the velocity is the exact derivative of the stroke, not a finite difference.

The settings of each protocol and their defaults (the paper's tests) are one schema per
protocol, :class:`QuasiStatic`, :class:`Chirp`, :class:`Sine` and :class:`FourteenSpeed`
(:data:`PROTOCOLS`); the functions' defaults, ``damper-hil dyno``'s options and the
diagnosis's protocol all come from them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from damper_emulator.errors import UserError
from damper_emulator.schema import ParameterError, build_group, check_value, rule

if TYPE_CHECKING:  # pragma: no cover
    from _typeshed import DataclassInstance

#: the largest count of cycles or test speeds a protocol takes
MAX_COUNT = 100_000
#: a periodic motion needs more than this many samples per period
MIN_SAMPLES_PER_PERIOD = 4.0

_P = TypeVar("_P", bound="DataclassInstance")


def _check_sampling(rate_hz: float, frequency_hz: float, what: str, where: str) -> None:
    """``what`` names the motion, with ``{f}`` for its highest frequency."""
    if not rate_hz > MIN_SAMPLES_PER_PERIOD * frequency_hz:
        raise ParameterError(f"{where}: sample rate {rate_hz:g} Hz is too low for "
                             f"{what.format(f=f'{frequency_hz:g}')} (need more than "
                             f"{MIN_SAMPLES_PER_PERIOD:g} samples per period)")


@dataclass(frozen=True)
class QuasiStatic:
    """The quasi-static test (docs/model.md §3): a constant-velocity triangle."""

    velocity_m_s: float = rule("positive", "constant stroke velocity [m/s]", 0.004)
    amplitude_m: float = rule("positive", "displacement amplitude [m]", 0.075)
    cycles: int = rule(("int_range", 1, MAX_COUNT), "recorded cycles", 2)
    rate_hz: float = rule("positive", "sample rate [Hz]", 50.0)


@dataclass(frozen=True)
class Chirp:
    """The identification chirp (docs/model.md §3): an exponential sweep whose velocity
    amplitude grows exponentially."""

    f_start_hz: float = rule("positive", "start frequency [Hz]", 0.5)
    f_end_hz: float = rule("positive", "end frequency [Hz]", 16.0)
    duration_s: float = rule("positive", "sweep duration [s]", 60.0)
    v_start_m_s: float = rule("positive", "velocity amplitude at the start [m/s]", 0.05)
    v_end_m_s: float = rule("positive", "velocity amplitude at the end [m/s]", 1.5)
    rate_hz: float = rule("positive", "sample rate [Hz]", 1000.0)

    def cross_check(self, where: str) -> None:
        """A sweep upwards, sampled at more than :data:`MIN_SAMPLES_PER_PERIOD` samples per
        period of its highest frequency."""
        if not self.f_start_hz < self.f_end_hz:
            raise ParameterError(f"{where}: the chirp's start frequency {self.f_start_hz:g} Hz "
                                 f"must be below its end frequency {self.f_end_hz:g} Hz")
        _check_sampling(self.rate_hz, self.f_end_hz, "a chirp up to {f} Hz", where)


@dataclass(frozen=True)
class Sine:
    """A sine test ``x = A sin(2π f t)``; a lead-in is simulated and not recorded."""

    frequency_hz: float = rule("positive", "frequency [Hz]", 1.0)
    amplitude_m: float = rule("positive", "displacement amplitude [m]", 0.05)
    cycles: int = rule(("int_range", 1, MAX_COUNT), "recorded cycles", 3)
    rate_hz: float = rule("positive", "sample rate [Hz]", 1000.0)
    settle_cycles: int = rule(("int_range", 0, MAX_COUNT),
                              "lead-in cycles simulated but not recorded", 1)

    def cross_check(self, where: str) -> None:
        """More than :data:`MIN_SAMPLES_PER_PERIOD` samples per period."""
        _check_sampling(self.rate_hz, self.frequency_hz, "a {f} Hz sine", where)


@dataclass(frozen=True)
class FourteenSpeed:
    """The N-speed test (docs/model.md §4): sines of one amplitude whose peak velocities
    are spaced geometrically."""

    points: int = rule(("int_range", 2, MAX_COUNT), "number of test speeds", 14)
    amplitude_m: float = rule("positive", "displacement amplitude [m]", 0.025)
    v_min_m_s: float = rule("positive", "lowest peak velocity [m/s]", 0.025)
    v_max_m_s: float = rule("positive", "highest peak velocity [m/s]", 1.5)
    cycles: int = rule(("int_range", 1, MAX_COUNT), "recorded cycles per speed", 2)
    rate_hz: float = rule("positive", "sample rate [Hz]", 1000.0)

    def cross_check(self, where: str) -> None:
        """Increasing speeds, each sine sampled finely enough."""
        if not self.v_min_m_s < self.v_max_m_s:
            raise ParameterError(f"{where}: the lowest peak velocity {self.v_min_m_s:g} m/s "
                                 f"must be below the highest {self.v_max_m_s:g} m/s")
        f_max = self.v_max_m_s / (2.0 * math.pi * self.amplitude_m)
        _check_sampling(self.rate_hz, f_max, "an N-speed test up to {f} Hz", where)


def checked(cls: type[_P], where: str, **values: Any) -> _P:
    """The protocol ``cls`` with ``values`` (the others at their defaults), every value
    checked by its rule and the protocol's own rules across values
    (:meth:`Chirp.cross_check`, ...); a broken rule raises a one-line
    :class:`~damper_emulator.schema.ParameterError` naming ``where`` and the setting."""
    plain = {k: int(v) if isinstance(v, np.integer) else v for k, v in values.items()}
    name = next(n for n, c in PROTOCOLS.items() if c is cls)
    protocol: _P = build_group(cls, plain, name, where, check_value)
    cross = getattr(protocol, "cross_check", None)
    if cross is not None:
        cross(where)
    return protocol


#: the protocols of ``damper-hil dyno --protocol`` and their schemas
PROTOCOLS: dict[str, type] = {"sine": Sine, "quasi-static": QuasiStatic, "chirp": Chirp,
                              "14-speed": FourteenSpeed}
#: the paper's validation sines (docs/model.md §3): (frequency [Hz], amplitude [m])
PAPER_SINES: tuple[tuple[float, float], ...] = ((1.0, 0.05), (3.0, 0.05), (12.0, 0.005))

#: Relative size of floating-point round-off in the analytic velocities.
ROUND_OFF = 1e-12


def _times(duration_s: float, rate_hz: float) -> np.ndarray:
    if not (duration_s > 0 and rate_hz > 0):
        raise UserError("duration and sample rate must be positive")
    return np.arange(int(round(duration_s * rate_hz)) + 1) / rate_hz


def quasi_static(velocity_m_s: float = QuasiStatic.velocity_m_s,
                 amplitude_m: float = QuasiStatic.amplitude_m,
                 cycles: int = QuasiStatic.cycles, rate_hz: float = QuasiStatic.rate_hz
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Constant-velocity triangle: 0 → +A → −A → 0 per cycle at ``velocity_m_s``.

    The paper's quasi-static test (4 mm/s); the default lasts 150 s.
    """
    if velocity_m_s <= 0 or amplitude_m <= 0 or cycles < 1:
        raise UserError("quasi-static velocity, amplitude and cycles must be positive")
    period = 4.0 * amplitude_m / velocity_m_s
    t = _times(cycles * period, rate_hz)
    # phase in [0, 4): 0→1 rising from 0 to A, 1→3 falling to −A, 3→4 rising to 0
    s = np.mod(t / period * 4.0, 4.0)
    x = amplitude_m * np.where(s < 1, s, np.where(s < 3, 2.0 - s, s - 4.0))
    v = velocity_m_s * np.where((s < 1) | (s >= 3), 1.0, -1.0)
    return t, x, v


def chirp(f_start_hz: float = Chirp.f_start_hz, f_end_hz: float = Chirp.f_end_hz,
          duration_s: float = Chirp.duration_s, v_start_m_s: float = Chirp.v_start_m_s,
          v_end_m_s: float = Chirp.v_end_m_s, rate_hz: float = Chirp.rate_hz
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exponential sine sweep whose velocity amplitude grows exponentially.

    Frequency ``f(t) = f0 (f1/f0)^(t/T)``, phase ``φ = 2π f0 T (e^(t ln(f1/f0)/T) − 1) /
    ln(f1/f0)``, displacement amplitude ``A(t) = v_a(t) / (2π f(t))`` with ``v_a`` growing
    from ``v_start`` to ``v_end``; ``x = A sin φ``.
    """
    if not (0 < f_start_hz < f_end_hz):
        raise UserError("chirp needs 0 < f_start < f_end")
    if not (v_start_m_s > 0 and v_end_m_s > 0):
        raise UserError("chirp velocity amplitudes must be positive")
    t = _times(duration_s, rate_hz)
    k = math.log(f_end_hz / f_start_hz) / duration_s
    phase = 2.0 * math.pi * f_start_hz * np.expm1(k * t) / k
    omega = 2.0 * math.pi * f_start_hz * np.exp(k * t)
    a0 = v_start_m_s / (2.0 * math.pi * f_start_hz)
    beta = math.log((v_end_m_s / v_start_m_s) * (f_start_hz / f_end_hz)) / duration_s
    amp = a0 * np.exp(beta * t)
    x = amp * np.sin(phase)
    v = amp * (beta * np.sin(phase) + omega * np.cos(phase))
    return t, x, v


def sine(frequency_hz: float, amplitude_m: float, cycles: float = Sine.cycles,
         rate_hz: float = Sine.rate_hz, start_cycles: float = 0.0
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``x = A sin(2π f t)`` for ``cycles`` periods from ``t = 0``, optionally preceded by a
    lead-in of ``start_cycles`` periods (negative times, to discard).  The lead-in is rounded
    up to whole samples so that one sample falls exactly on ``t = 0``."""
    if frequency_hz <= 0 or amplitude_m <= 0 or cycles <= 0 or rate_hz <= 0:
        raise UserError("sine frequency, amplitude, cycles and sample rate must be positive")
    if start_cycles < 0:
        raise UserError("sine lead-in cycles must not be negative")
    lead = int(math.ceil(start_cycles * rate_hz / frequency_hz - 1e-9))
    t = np.arange(-lead, int(round(cycles * rate_hz / frequency_hz)) + 1) / rate_hz
    w = 2.0 * math.pi * frequency_hz
    v = amplitude_m * w * np.cos(w * t)
    # at the turning points cos() leaves round-off (±1e-16) whose sign would pick the
    # friction direction at random: those samples are at rest
    v[np.abs(v) < ROUND_OFF * amplitude_m * w] = 0.0
    return t, amplitude_m * np.sin(w * t), v


def fourteen_speed_frequencies(points: int = FourteenSpeed.points,
                               amplitude_m: float = FourteenSpeed.amplitude_m,
                               v_min_m_s: float = FourteenSpeed.v_min_m_s,
                               v_max_m_s: float = FourteenSpeed.v_max_m_s) -> np.ndarray:
    """Frequencies [Hz] of an N-speed test: peak velocities spaced geometrically from
    ``v_min`` to ``v_max`` at the fixed displacement amplitude."""
    if points < 2 or not (0 < v_min_m_s < v_max_m_s) or amplitude_m <= 0:
        raise UserError("N-speed test needs points >= 2, 0 < v_min < v_max, amplitude > 0")
    return np.geomspace(v_min_m_s, v_max_m_s, points) / (2.0 * math.pi * amplitude_m)
