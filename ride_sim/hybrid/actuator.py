"""The transfer system of a dyno: a transport delay and a second-order servo.

From the stroke demand ``u`` to the stroke the actuator achieves ``x``::

    x(s) = G(s) u(s),   G(s) = g ω² e^(−s τ) / (s² + 2 ζ ω s + ω²),   ω = 2π f_servo

(:class:`~ride_sim.hybrid.params.ActuatorParams`).  :class:`Servo` steps it in time with
the demand held between updates (zero-order hold), integrated exactly over each step by
the matrix exponential of the servo's state-space form; :class:`DelayLine` gives the
demand in effect ``τ`` after it arrived.  :func:`frequency_response` is ``G(j 2π f)``:
the compensator and the loop's stability margin use it.
"""

from __future__ import annotations

import functools
import math
from collections import deque

import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg import expm

from ride_sim.hybrid.params import ActuatorParams


def omega(params: ActuatorParams) -> float:
    """The servo's natural angular frequency ω = 2π f_servo [rad/s]."""
    return 2.0 * math.pi * params.bandwidth_hz


def frequency_response(params: ActuatorParams, f_hz: ArrayLike) -> np.ndarray:
    """``G(j 2π f)``, the complex response of achieved to demanded stroke at ``f_hz``."""
    w = omega(params)
    s = 2j * np.pi * np.asarray(f_hz, dtype=float)
    return params.gain * w * w * np.exp(-s * params.delay_s) / (s * s + 2 * params.damping
                                                                 * w * s + w * w)


def servo_lag_s(params: ActuatorParams) -> float:
    """The servo's low-frequency time lag ``2ζ/ω`` [s] (its phase lag divided by the
    angular frequency as ω → 0); the whole transfer system lags ``τ + 2ζ/ω``."""
    return 2.0 * params.damping / omega(params)


@functools.lru_cache(maxsize=32)
def _step_matrix(bandwidth_hz: float, damping: float, dt_s: float) -> np.ndarray:
    """3×3 exact step of ``(x, ẋ)`` with the demand held: ``[x, ẋ, u] → [x, ẋ]``."""
    w = 2.0 * math.pi * bandwidth_hz
    m = np.zeros((3, 3))
    m[0, 1] = 1.0
    m[1, 0] = -w * w
    m[1, 1] = -2.0 * damping * w
    m[1, 2] = w * w
    e: np.ndarray = expm(m * dt_s)[:2, :]
    e.setflags(write=False)
    return e


class Servo:
    """The servo's state ``(x, ẋ)`` [m, m/s], stepped with the demand held.

    Parameters
    ----------
    params : ActuatorParams
        Its natural frequency, damping and gain (the delay is :class:`DelayLine`'s).
    stroke_m : float
        The start, at rest.
    """

    def __init__(self, params: ActuatorParams, stroke_m: float = 0.0) -> None:
        self.params = params
        self.stroke_m = float(stroke_m)
        self.velocity_m_s = 0.0

    def step(self, demand_m: float, dt_s: float) -> tuple[float, float]:
        """Advance by ``dt_s`` with ``demand_m`` held; returns the new ``(x, ẋ)``."""
        e = _step_matrix(self.params.bandwidth_hz, self.params.damping, float(dt_s))
        u = self.params.gain * float(demand_m)
        x, v = self.stroke_m, self.velocity_m_s
        self.stroke_m = float(e[0, 0] * x + e[0, 1] * v + e[0, 2] * u)
        self.velocity_m_s = float(e[1, 0] * x + e[1, 1] * v + e[1, 2] * u)
        return self.stroke_m, self.velocity_m_s

    def hold(self, stroke_m: float) -> None:
        """At rest at ``stroke_m``."""
        self.stroke_m = float(stroke_m)
        self.velocity_m_s = 0.0


class DelayLine:
    """Demands by arrival time; :meth:`at` gives the one in effect a delay later.

    A demand carries its rate (``VelocityDemand``): the demand in effect moves on at that
    rate from when it became due until the next one is due (a first-order hold), for at
    most ``horizon_s``; a rate of 0 holds it.

    Parameters
    ----------
    delay_s : float
        The transport delay τ [s]; settable (:attr:`delay_s`) while running.
    initial : float
        The demand in effect before any arrived.
    horizon_s : float
        The longest a demand moves on at its rate [s] (default 0: each demand is held).
    """

    def __init__(self, delay_s: float, initial: float = 0.0, horizon_s: float = 0.0) -> None:
        self.delay_s = float(delay_s)
        self.horizon_s = float(horizon_s)
        self._times: deque[float] = deque()
        self._values: deque[tuple[float, float]] = deque()
        self._current = (float(initial), 0.0)
        self._due = -math.inf

    def push(self, t_s: float, demand: float, rate: float = 0.0) -> None:
        """A demand [m] and its rate [m/s] that arrived at ``t_s`` (times must not
        decrease)."""
        self._times.append(float(t_s))
        self._values.append((float(demand), float(rate)))

    def at(self, t_s: float) -> float:
        """The demand in effect at ``t_s``: the latest that arrived by ``t_s − τ``, moved
        on at its rate since it became due."""
        due = t_s - self.delay_s
        times = self._times
        while times and times[0] <= due:
            self._due = times.popleft() + self.delay_s
            self._current = self._values.popleft()
        value, rate = self._current
        if rate == 0.0:
            return value
        return value + rate * min(t_s - self._due, self.horizon_s)
