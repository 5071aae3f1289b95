"""The road a moving wheel sees: speed profiles and the road input.

A vehicle moving along a :class:`~ride_sim.road.RoadProfile` with a :class:`SpeedProfile`
(or at a constant speed) sees the road displacement ``h(s(t))`` and its rate
``h'(s) v(t)`` (:func:`road_input`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from ride_sim.road import (
    FloatArray,
    RoadError,
    RoadProfile,
    check_finite,
    check_non_negative,
    check_positive,
    checked_series,
    float_array,
)

#: Relative tolerance (of the duration) on the ends of a speed profile's time range.
_TIME_REL_TOL = 1e-9


@dataclass(frozen=True, eq=False)
class SpeedProfile:
    """Vehicle speed against time, linearly interpolated between points.

    Attributes
    ----------
    time_s : ndarray
        Strictly increasing times [s] (copied, read-only).
    speed_m_s : ndarray
        Forward speed at those times [m/s], >= 0 (the vehicle never reverses).

    Notes
    -----
    :meth:`distance_at` integrates the linear speed exactly (quadratic in each segment).
    Times outside ``[time_s[0], time_s[-1]]`` raise :class:`~ride_sim.road.RoadError`.
    """

    time_s: FloatArray
    speed_m_s: FloatArray
    _distance_knots_m: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        t, v = checked_series("speed profile", self.time_s, "time_s", self.speed_m_s,
                              "speed_m_s")
        negative = np.flatnonzero(v < 0.0)
        if negative.size:
            raise RoadError(f"speed profile: speed_m_s[{negative[0]}] = {v[negative[0]]} "
                            f"is negative")
        knots = np.concatenate(([0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))))
        for arr in (t, v, knots):
            arr.flags.writeable = False
        object.__setattr__(self, "time_s", t)
        object.__setattr__(self, "speed_m_s", v)
        object.__setattr__(self, "_distance_knots_m", knots)

    @classmethod
    def constant(cls, speed_m_s: float, duration_s: float) -> SpeedProfile:
        """Constant speed from ``t = 0`` to ``duration_s``."""
        speed = check_non_negative(speed_m_s, "speed_m_s")
        duration = check_positive(duration_s, "duration_s")
        return cls(np.array([0.0, duration]), np.array([speed, speed]))

    @property
    def duration_s(self) -> float:
        """Time span covered [s]."""
        return float(self.time_s[-1] - self.time_s[0])

    @property
    def total_distance_m(self) -> float:
        """Distance travelled over the whole profile [m]."""
        return float(self._distance_knots_m[-1])

    def _in_range(self, t_s: ArrayLike) -> FloatArray:
        t = float_array(t_s, "time t_s")
        tol = _TIME_REL_TOL * self.duration_s
        t0, t1 = self.time_s[0], self.time_s[-1]
        off = ~np.isfinite(t) | (t < t0 - tol) | (t > t1 + tol)
        if np.any(off):
            raise RoadError(f"time {t[off].flat[0]:.6g} s is outside the speed profile "
                            f"[{t0:.6g}, {t1:.6g}] s")
        return np.clip(t, t0, t1)

    def speed_at(self, t_s: ArrayLike) -> FloatArray:
        """Speed at times ``t_s`` [m/s] (linear interpolation, vectorised)."""
        t = self._in_range(t_s)
        return np.interp(t, self.time_s, self.speed_m_s)

    def distance_at(self, t_s: ArrayLike) -> FloatArray:
        """Distance travelled since ``time_s[0]`` at times ``t_s`` [m] (exact integral)."""
        t = self._in_range(t_s)
        knots_t, knots_v = self.time_s, self.speed_m_s
        i = np.clip(np.searchsorted(knots_t, t, side="right") - 1, 0, knots_t.size - 2)
        tau = t - knots_t[i]
        accel = (knots_v[i + 1] - knots_v[i]) / (knots_t[i + 1] - knots_t[i])
        s = self._distance_knots_m[i] + knots_v[i] * tau + 0.5 * accel * tau * tau
        return s[()] if s.ndim == 0 else s


def constant_speed(speed_m_s: float, duration_s: float) -> SpeedProfile:
    """:meth:`SpeedProfile.constant`: constant speed from ``t = 0`` to ``duration_s``."""
    return SpeedProfile.constant(speed_m_s, duration_s)


def road_input(profile: RoadProfile, speed: SpeedProfile | float, t_s: ArrayLike, *,
               start_distance_m: float | None = None) -> tuple[FloatArray, FloatArray]:
    """Road displacement and its rate seen by a wheel at times ``t_s``.

    Parameters
    ----------
    profile : RoadProfile
        The road.
    speed : SpeedProfile or float
        Speed profile (distance counted from its first time), or a constant speed [m/s]
        (distance ``speed * t``).
    t_s : array_like
        Times [s].
    start_distance_m : float, optional
        Road distance of the wheel at the start [m] (default: the profile's start).

    Returns
    -------
    height_m : ndarray
        ``h(s(t))`` [m].
    height_rate_m_s : ndarray
        ``dh/dt = h'(s(t)) v(t)`` [m/s], piecewise continuous (steps at the samples).

    Raises
    ------
    RoadError
        If a time is outside the speed profile or the wheel is off the road.
    """
    t = float_array(t_s, "time t_s")
    start = profile.start_m if start_distance_m is None else check_finite(start_distance_m,
                                                                          "start_distance_m")
    if isinstance(speed, SpeedProfile):
        travelled = speed.distance_at(t)
        v = speed.speed_at(t)
    else:
        v_const = check_non_negative(speed, "speed [m/s]")
        travelled = v_const * t
        v = np.full_like(t, v_const)
    s = start + travelled
    return profile.height_at(s), profile.slope_at(s) * v
