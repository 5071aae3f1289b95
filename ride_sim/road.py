"""Road profiles for the quarter-car ride simulation: the sampled road and its checks.

A road is a :class:`RoadProfile`: the height ``h(s)`` of the road surface [m] sampled at
strictly increasing distances ``s`` [m] along the wheel track, evaluated between samples by
linear interpolation (:func:`resample` puts it on a uniform grid).

The road modules beside this one make and use profiles: :mod:`ride_sim.road_spectra` (the
road spectrum of Simms & Crolla eq 39 and ISO 8608), :mod:`ride_sim.road_synthesis` (road
spectra as objects and the random roads synthesised from them), :mod:`ride_sim.road_features`
(pothole, bump, step), :mod:`ride_sim.road_envelope` (tyre enveloping),
:mod:`ride_sim.road_csv` (profile files) and :mod:`ride_sim.road_speed` (speed profiles and
the road input a wheel sees).

Every invalid input raises :class:`RoadError` (a ``ValueError``) with a one-line message;
the checks that raise it, shared by the road modules, are here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from damper_emulator.errors import UserError

FloatArray = NDArray[np.float64]

#: Fewest samples of a profile or a speed profile.
MIN_PROFILE_POINTS = 2
#: Relative tolerance for "uniform spacing" and "whole number of samples".
SPACING_REL_TOL = 1e-6


class RoadError(UserError):
    """A road, a road parameter, a speed profile or a profile file is invalid (one line)."""


# --------------------------------------------------------------------------------------
# Small validators


def checked_series(label: str, x: ArrayLike, x_name: str, y: ArrayLike, y_name: str
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Two equal-length 1-D float arrays of at least ``MIN_PROFILE_POINTS`` finite samples,
    ``x`` strictly increasing; a one-line :class:`RoadError` naming ``label`` otherwise."""
    xa = float_array(x, f"{label}: {x_name}")
    ya = float_array(y, f"{label}: {y_name}")
    if xa.ndim != 1 or ya.shape != xa.shape:
        raise RoadError(f"{label}: {x_name} and {y_name} must be 1-D with the same number "
                        f"of samples, got shapes {xa.shape} and {ya.shape}")
    if xa.size < MIN_PROFILE_POINTS:
        raise RoadError(f"{label}: needs at least {MIN_PROFILE_POINTS} samples, got {xa.size}")
    for arr, what in ((xa, x_name), (ya, y_name)):
        bad = np.flatnonzero(~np.isfinite(arr))
        if bad.size:
            raise RoadError(f"{label}: {what}[{bad[0]}] = {arr[bad[0]]} is not finite")
    steps = np.flatnonzero(np.diff(xa) <= 0.0)
    if steps.size:
        i = steps[0] + 1
        raise RoadError(f"{label}: {x_name}[{i}] = {xa[i]} is not greater than "
                        f"{x_name}[{i - 1}] = {xa[i - 1]}")
    return xa, ya


def check_finite(value: float, what: str) -> float:
    """``value`` as a finite float; a one-line :class:`RoadError` naming ``what`` otherwise."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise RoadError(f"{what} must be a number, got {value!r}") from None
    if not math.isfinite(x):
        raise RoadError(f"{what} must be finite, got {x}")
    return x


def check_positive(value: float, what: str) -> float:
    """``value`` as a finite float > 0, else :class:`RoadError` naming ``what``."""
    x = check_finite(value, what)
    if x <= 0.0:
        raise RoadError(f"{what} must be > 0, got {x}")
    return x


def check_non_negative(value: float, what: str) -> float:
    """``value`` as a finite float >= 0, else :class:`RoadError` naming ``what``."""
    x = check_finite(value, what)
    if x < 0.0:
        raise RoadError(f"{what} must be >= 0, got {x}")
    return x


def float_array(values: ArrayLike, what: str) -> FloatArray:
    """``values`` as a float array (a copy), else :class:`RoadError` naming ``what``."""
    try:
        arr = np.array(values, dtype=float)
    except (TypeError, ValueError):
        raise RoadError(f"{what} must be numeric") from None
    return arr


def positive_array(values: ArrayLike, what: str) -> FloatArray:
    """``values`` as a float array of finite values > 0, else :class:`RoadError`."""
    arr = float_array(values, what)
    bad = ~np.isfinite(arr) | (arr <= 0.0)
    if np.any(bad):
        raise RoadError(f"{what} must be finite and > 0, got {arr[bad].flat[0]}")
    return arr


# --------------------------------------------------------------------------------------
# Road profile


@dataclass(frozen=True, eq=False)
class RoadProfile:
    """Road surface height along the wheel track, linearly interpolated between samples.

    Attributes
    ----------
    distance_m : ndarray
        Strictly increasing distances along the road [m] (copied, read-only).
    height_m : ndarray
        Road height at those distances [m] (copied, read-only).
    name : str
        Label for plots and reports.

    Notes
    -----
    :meth:`height_at` holds the end value up to one sample spacing beyond either end and
    raises :class:`RoadError` further out, so a simulation never silently runs off the
    road.  :meth:`slope_at` is the derivative of that interpolant: piecewise constant,
    the slope of the segment to the right at a sample, 0 beyond the ends.
    """

    distance_m: FloatArray
    height_m: FloatArray
    name: str = "road"

    def __post_init__(self) -> None:
        d, h = checked_series(f"road {self.name!r}", self.distance_m, "distance_m",
                              self.height_m, "height_m")
        d.flags.writeable = False
        h.flags.writeable = False
        object.__setattr__(self, "distance_m", d)
        object.__setattr__(self, "height_m", h)

    @property
    def start_m(self) -> float:
        """Distance of the first sample [m]."""
        return float(self.distance_m[0])

    @property
    def end_m(self) -> float:
        """Distance of the last sample [m]."""
        return float(self.distance_m[-1])

    @property
    def length_m(self) -> float:
        """Length of road covered, last minus first distance [m]."""
        return self.end_m - self.start_m

    @property
    def spacing_m(self) -> float:
        """Sample spacing of a uniformly sampled profile [m]; :class:`RoadError` if not."""
        steps = np.diff(self.distance_m)
        mean = self.length_m / steps.size
        if np.max(np.abs(steps - mean)) > SPACING_REL_TOL * mean:
            raise RoadError(f"road {self.name!r} is not uniformly sampled "
                            f"(spacing {steps.min():.6g} to {steps.max():.6g} m); "
                            f"use resample()")
        return mean

    def _on_road(self, s_m: ArrayLike) -> FloatArray:
        s = float_array(s_m, "distance s_m")
        d = self.distance_m
        lo = d[0] - (d[1] - d[0])
        hi = d[-1] + (d[-1] - d[-2])
        off = ~np.isfinite(s) | (s < lo) | (s > hi)
        if np.any(off):
            raise RoadError(f"road {self.name!r}: distance {s[off].flat[0]:.6g} m is off the "
                            f"road [{d[0]:.6g}, {d[-1]:.6g}] m by more than one sample")
        return s

    def height_at(self, s_m: ArrayLike) -> FloatArray:
        """Road height at distances ``s_m`` [m] by linear interpolation (vectorised).

        Raises
        ------
        RoadError
            If a distance is more than one sample spacing beyond either end.
        """
        s = self._on_road(s_m)
        return np.interp(s, self.distance_m, self.height_m)

    def slope_at(self, s_m: ArrayLike) -> FloatArray:
        """Road slope ``dh/ds`` [-] at ``s_m``, consistent with :meth:`height_at`.

        Piecewise constant: the slope of the segment containing ``s`` (the segment to the
        right at a sample, the last segment at the last sample), 0 where the height is held
        beyond the ends.  The road velocity is ``slope_at(s) * speed``.
        """
        s = self._on_road(s_m)
        d = self.distance_m
        segment_slope = np.diff(self.height_m) / np.diff(d)
        idx = np.clip(np.searchsorted(d, s, side="right") - 1, 0, d.size - 2)
        slope = np.where((s < d[0]) | (s > d[-1]), 0.0, segment_slope[idx])
        return slope[()] if slope.ndim == 0 else slope


def resample(profile: RoadProfile, spacing_m: float) -> RoadProfile:
    """The profile linearly interpolated onto a uniform grid from its start [m].

    The last sample is the last grid point not beyond the profile's end.
    """
    spacing = check_positive(spacing_m, "spacing_m")
    count = int(math.floor(profile.length_m / spacing * (1.0 + SPACING_REL_TOL))) + 1
    if count < MIN_PROFILE_POINTS:
        raise RoadError(f"spacing_m = {spacing} m is longer than road {profile.name!r} "
                        f"({profile.length_m:.6g} m)")
    s = profile.start_m + spacing * np.arange(count)
    s = np.minimum(s, profile.end_m)
    return RoadProfile(s, np.interp(s, profile.distance_m, profile.height_m), profile.name)
