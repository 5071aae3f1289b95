"""Road profiles for the quarter-car ride simulation: random roads, discrete features, files.

A road is a :class:`RoadProfile`: the height ``h(s)`` of the road surface [m] sampled at
strictly increasing distances ``s`` [m] along the wheel track, evaluated between samples by
linear interpolation.  A vehicle moving along it with a :class:`SpeedProfile` sees the road
displacement ``h(s(t))`` and its rate ``h'(s) v(t)`` (:func:`road_input`).

Random roads
------------
Simms & Crolla (SAE 2002-01-0319, eq 39) give the temporal power spectral density of the
road displacement seen at speed ``V`` [m/s]

.. math:: S(f) = G V^{p-1} f^{-p}  \\quad [m^2/Hz],

which is the one-sided spatial PSD

.. math:: S(n) = G n^{-p}  \\quad [m^2/(cycles/m)],

with the spatial frequency ``n = f / V`` in cycles/m, so that ``S(f) = S(n = f/V) / V``.
``G`` is the roughness and ``p`` the waviness (slope of the log–log spectrum).  Their minor
road is ``G = 5e-6``, ``p = 2.5`` driven at 20 m/s for 500 m (:data:`MINOR_ROAD`).
ISO 8608 writes the same form as ``Gd(n) = Gd(n0) (n/n0)^(-w)`` with ``n0 = 0.1`` cycles/m
and ``w = 2``; hence ``G = Gd(n0) n0^w`` and ``p = w`` (:func:`iso8608_class`).  The two
equations live only in :func:`spatial_psd` and :func:`temporal_psd`.

A spectrum ``n^(-p)`` cannot be synthesised over all frequencies: the synthesised band
``[n_min, n_max]`` (cycles/m) is an explicit parameter of :func:`random_road`
(default :data:`DEFAULT_BAND_CYCLES_PER_M`).  The road variance grows as ``n_min^(1-p)`` and
the road velocity and acceleration, and so the tyre load, depend strongly on ``n_max``;
short wavelengths are in reality filtered by the tyre (see :func:`envelope`).

Discrete features and tyre enveloping
-------------------------------------
:func:`pothole`, :func:`bump` and :func:`step` build a flat road with one feature, a
lead-in and a lead-out.  A tyre does not follow a sharp edge: :func:`envelope` replaces a
profile by the path of the lowest point of a rigid circle of the tyre radius rolling over
it (optionally averaged over the contact length).

Profile files
-------------
:func:`read_profile_csv` / :func:`write_profile_csv`: CSV with a header line and the
columns ``distance`` [m] and ``height`` [m] (other columns are ignored).

Every invalid input raises :class:`RoadError` (a ``ValueError``) with a one-line message.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from damper_emulator.errors import UserError

FloatArray = NDArray[np.float64]

# --------------------------------------------------------------------------------------
# Constants

#: ISO 8608 reference spatial frequency n0 [cycles/m].
ISO_8608_N0_CYCLES_PER_M = 0.1
#: ISO 8608 waviness w [-] of the classified displacement spectra.
ISO_8608_WAVINESS = 2.0
#: ISO 8608 class letters, smoothest first.
ISO_8608_CLASSES = "ABCDEFGH"
#: ISO 8608 geometric-mean Gd(n0) of class A [m³] (= m²/(cycles/m)).
ISO_8608_CLASS_A_GD_N0_M3 = 16e-6
#: Ratio of Gd(n0) between successive ISO 8608 classes [-].
ISO_8608_CLASS_RATIO = 4.0
#: Ratio between a class's upper (or geometric-mean) and geometric-mean (or lower) Gd(n0).
ISO_8608_BOUND_RATIO = 2.0
#: Spatial-frequency band over which ISO 8608 classifies roads [cycles/m] (90 m to 0.35 m).
ISO_8608_BAND_CYCLES_PER_M = (0.011, 2.83)

#: Simms & Crolla minor road: roughness G (eq 39).
MINOR_ROAD_ROUGHNESS = 5e-6
#: Simms & Crolla minor road: waviness p (eq 39) [-].
MINOR_ROAD_WAVINESS = 2.5
#: Simms & Crolla minor road: vehicle speed [m/s].
MINOR_ROAD_SPEED_M_S = 20.0
#: Simms & Crolla minor road: length of road driven [m].
MINOR_ROAD_LENGTH_M = 500.0

#: Default synthesised band [n_min, n_max] of :func:`random_road` [cycles/m]: wavelengths
#: from 100 m down to 0.1 m, i.e. 0.2 Hz to 200 Hz at 20 m/s.  A placeholder until a
#: sensitivity study picks it; pass ``band_cycles_per_m`` explicitly in studies.
DEFAULT_BAND_CYCLES_PER_M = (0.01, 10.0)
#: Default sample spacing of :func:`random_road` [m] (Nyquist 50 cycles/m, 5 x n_max).
DEFAULT_ROAD_SPACING_M = 0.01
#: Default seed of :func:`random_road` (reproducible by default).
DEFAULT_SEED = 0

#: Default sample spacing of the discrete features [m].
DEFAULT_FEATURE_SPACING_M = 0.005
#: Default flat road before a discrete feature [m] (0.5 s at 20 m/s).
DEFAULT_LEAD_IN_M = 10.0
#: Default flat road after a discrete feature, for the response to decay [m] (1.5 s at 20 m/s).
DEFAULT_LEAD_OUT_M = 30.0
#: Default pothole depth [m] (the paper's MIRA pothole geometry is not given).
DEFAULT_POTHOLE_DEPTH_M = 0.05
#: Default pothole length along the road, edge to edge at the surface [m].
DEFAULT_POTHOLE_LENGTH_M = 0.5

#: Suggested tyre (unloaded) radius for :func:`envelope` [m]: a passenger-car tyre such as
#: 205/55 R16 has 0.316 m; a Formula Student 20.5 in tyre has 0.26 m.
SUGGESTED_TYRE_RADIUS_M = 0.3
#: Suggested tyre contact-patch length for :func:`envelope` [m].
SUGGESTED_CONTACT_LENGTH_M = 0.15

#: Fewest samples of a profile or a speed profile.
MIN_PROFILE_POINTS = 2
#: Relative tolerance for "uniform spacing" and "whole number of samples".
_SPACING_REL_TOL = 1e-6
#: Relative tolerance (of the duration) on the ends of a speed profile's time range.
_TIME_REL_TOL = 1e-9
#: Column names accepted in a profile CSV (after stripping and lower-casing).
_DISTANCE_COLUMNS = ("distance", "distance_m")
_HEIGHT_COLUMNS = ("height", "height_m")
#: Header written by :func:`write_profile_csv`.
_CSV_HEADER = ("distance", "height")
#: Synthesis methods of :func:`random_road`.
AMPLITUDE_METHODS = ("deterministic", "random")
#: Shapes of :func:`bump`.
BUMP_SHAPES = ("cosine", "half_sine")
_TWO_PI = 2.0 * math.pi


class RoadError(UserError):
    """A road, a road parameter, a speed profile or a profile file is invalid (one line)."""


# --------------------------------------------------------------------------------------
# Small validators



def _checked_series(label: str, x: ArrayLike, x_name: str, y: ArrayLike, y_name: str
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Two equal-length 1-D float arrays of at least ``MIN_PROFILE_POINTS`` finite samples,
    ``x`` strictly increasing; a one-line :class:`RoadError` naming ``label`` otherwise."""
    xa = _float_array(x, f"{label}: {x_name}")
    ya = _float_array(y, f"{label}: {y_name}")
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

def _finite(value: float, what: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise RoadError(f"{what} must be a number, got {value!r}") from None
    if not math.isfinite(x):
        raise RoadError(f"{what} must be finite, got {x}")
    return x


def _positive(value: float, what: str) -> float:
    x = _finite(value, what)
    if x <= 0.0:
        raise RoadError(f"{what} must be > 0, got {x}")
    return x


def _non_negative(value: float, what: str) -> float:
    x = _finite(value, what)
    if x < 0.0:
        raise RoadError(f"{what} must be >= 0, got {x}")
    return x


def _float_array(values: ArrayLike, what: str) -> FloatArray:
    try:
        arr = np.array(values, dtype=float)
    except (TypeError, ValueError):
        raise RoadError(f"{what} must be numeric") from None
    return arr


def _positive_array(values: ArrayLike, what: str) -> FloatArray:
    arr = _float_array(values, what)
    bad = ~np.isfinite(arr) | (arr <= 0.0)
    if np.any(bad):
        raise RoadError(f"{what} must be finite and > 0, got {arr[bad].flat[0]}")
    return arr


def _whole_samples(length_m: float, spacing_m: float, what: str) -> int:
    """``length_m / spacing_m`` as an int; it must be whole (relative tolerance)."""
    ratio = length_m / spacing_m
    count = round(ratio)
    if abs(ratio - count) > _SPACING_REL_TOL * max(1.0, ratio):
        raise RoadError(f"{what} = {length_m} m is not a whole number of samples of "
                        f"spacing_m = {spacing_m} m")
    return int(count)


def _check_band(band_cycles_per_m: Sequence[float]) -> tuple[float, float]:
    try:
        lo, hi = band_cycles_per_m
    except (TypeError, ValueError):
        raise RoadError(f"band_cycles_per_m must be a pair (n_min, n_max), "
                        f"got {band_cycles_per_m!r}") from None
    lo = _positive(lo, "band n_min [cycles/m]")
    hi = _positive(hi, "band n_max [cycles/m]")
    if hi <= lo:
        raise RoadError(f"band n_max = {hi} cycles/m must be > n_min = {lo} cycles/m")
    return lo, hi


def _check_psd_params(roughness: float, waviness: float) -> tuple[float, float]:
    return _positive(roughness, "roughness G"), _positive(waviness, "waviness p")


def _psd_integral(roughness: float, waviness: float, lo: ArrayLike, hi: ArrayLike) -> FloatArray:
    """``∫_lo^hi G n^(-p) dn`` in closed form [m²] (0 where ``lo == hi``)."""
    lo = np.asarray(lo, dtype=float)
    hi = np.asarray(hi, dtype=float)
    integral: FloatArray
    if waviness == 1.0:
        integral = roughness * np.log(hi / lo)
        return integral
    exponent = 1.0 - waviness
    integral = roughness * (lo ** exponent - hi ** exponent) / (waviness - 1.0)
    return integral


# --------------------------------------------------------------------------------------
# Spectra


def spatial_psd(roughness: float, waviness: float, n: ArrayLike, *,
                band_cycles_per_m: Sequence[float] | None = None) -> FloatArray:
    """One-sided spatial PSD of the road displacement, ``S(n) = G n^(-p)``.

    Parameters
    ----------
    roughness : float
        Roughness ``G`` [m² (cycles/m)^(p-1)], the PSD at ``n = 1`` cycle/m.
    waviness : float
        Waviness ``p`` [-], the (negative) slope of the log–log spectrum.
    n : array_like
        Spatial frequencies [cycles/m], > 0.
    band_cycles_per_m : (float, float), optional
        If given, the PSD is 0 outside ``[n_min, n_max]`` (a band-limited road).

    Returns
    -------
    ndarray
        ``S(n)`` [m²/(cycles/m)], one-sided: the variance is ``∫_0^∞ S(n) dn``.
    """
    roughness, waviness = _check_psd_params(roughness, waviness)
    n = _positive_array(n, "spatial frequency n [cycles/m]")
    psd = roughness * n ** (-waviness)
    if band_cycles_per_m is not None:
        lo, hi = _check_band(band_cycles_per_m)
        psd = np.where((n >= lo) & (n <= hi), psd, 0.0)
    return psd


def temporal_psd(roughness: float, waviness: float, speed_m_s: float, f: ArrayLike, *,
                 band_cycles_per_m: Sequence[float] | None = None) -> FloatArray:
    """One-sided temporal PSD of the road displacement at speed V (Simms & Crolla eq 39).

    ``S(f) = G V^(p-1) f^(-p)``, equal to ``S(n = f/V) / V`` of :func:`spatial_psd`.

    Parameters
    ----------
    roughness, waviness : float
        ``G`` and ``p`` as in :func:`spatial_psd`.
    speed_m_s : float
        Vehicle speed ``V`` [m/s], > 0.
    f : array_like
        Temporal frequencies [Hz], > 0.
    band_cycles_per_m : (float, float), optional
        If given, the PSD is 0 where ``f / V`` is outside ``[n_min, n_max]`` [cycles/m].

    Returns
    -------
    ndarray
        ``S(f)`` [m²/Hz].
    """
    roughness, waviness = _check_psd_params(roughness, waviness)
    speed = _positive(speed_m_s, "speed_m_s")
    f = _positive_array(f, "frequency f [Hz]")
    psd: FloatArray = roughness * speed ** (waviness - 1.0) * f ** (-waviness)
    if band_cycles_per_m is not None:
        lo, hi = _check_band(band_cycles_per_m)
        n = f / speed
        psd = np.where((n >= lo) & (n <= hi), psd, 0.0)
    return psd


def band_variance(roughness: float, waviness: float,
                  band_cycles_per_m: Sequence[float]) -> float:
    """Variance of a road of PSD ``G n^(-p)`` band-limited to ``[n_min, n_max]`` [m²].

    ``G (n_min^(1-p) - n_max^(1-p)) / (p - 1)`` (``G ln(n_max/n_min)`` for ``p = 1``).
    """
    roughness, waviness = _check_psd_params(roughness, waviness)
    lo, hi = _check_band(band_cycles_per_m)
    return float(_psd_integral(roughness, waviness, lo, hi))


@dataclass(frozen=True)
class RoadRoughness:
    """A road spectrum ``S(n) = G n^(-p)`` (Simms & Crolla eq 39, ISO 8608).

    Attributes
    ----------
    roughness : float
        ``G`` [m² (cycles/m)^(p-1)]: the one-sided spatial PSD in m²/(cycles/m) at
        ``n = 1`` cycle/m.  Its unit depends on ``p``, so it carries none in its name.
    waviness : float
        ``p`` [-].
    name : str
        Label used to name the generated profiles.
    """

    roughness: float
    waviness: float
    name: str = "road"

    def __post_init__(self) -> None:
        _check_psd_params(self.roughness, self.waviness)

    @property
    def gd_n0_m3(self) -> float:
        """ISO 8608 ``Gd(n0) = G n0^(-p)`` at ``n0 = 0.1`` cycles/m [m³ = m²/(cycles/m)]."""
        gd: float = self.roughness * ISO_8608_N0_CYCLES_PER_M ** (-self.waviness)
        return gd

    def spatial_psd(self, n: ArrayLike, *,
                    band_cycles_per_m: Sequence[float] | None = None) -> FloatArray:
        """:func:`spatial_psd` of this road."""
        return spatial_psd(self.roughness, self.waviness, n, band_cycles_per_m=band_cycles_per_m)

    def temporal_psd(self, speed_m_s: float, f: ArrayLike, *,
                     band_cycles_per_m: Sequence[float] | None = None) -> FloatArray:
        """:func:`temporal_psd` of this road at ``speed_m_s``."""
        return temporal_psd(self.roughness, self.waviness, speed_m_s, f,
                            band_cycles_per_m=band_cycles_per_m)

    def variance_m2(self, band_cycles_per_m: Sequence[float] = DEFAULT_BAND_CYCLES_PER_M
                    ) -> float:
        """:func:`band_variance` of this road over the band [m²]."""
        return band_variance(self.roughness, self.waviness, band_cycles_per_m)

    def random_road(self, length_m: float, **kwargs: Any) -> RoadProfile:
        """:func:`random_road` of this spectrum (keyword arguments are passed on)."""
        kwargs.setdefault("name", f"{self.name} seed {kwargs.get('seed', DEFAULT_SEED)}")
        return random_road(self.roughness, self.waviness, length_m, **kwargs)


#: Simms & Crolla minor road (eq 39): G = 5e-6, p = 2.5 (driven at 20 m/s for 500 m).
MINOR_ROAD = RoadRoughness(MINOR_ROAD_ROUGHNESS, MINOR_ROAD_WAVINESS,
                           "minor road (Simms & Crolla 2002)")


def iso8608_class(letter: str,
                  bound: Literal["mean", "lower", "upper"] = "mean") -> RoadRoughness:
    """ISO 8608 road class as a :class:`RoadRoughness`.

    Parameters
    ----------
    letter : str
        Class ``"A"`` (smoothest) to ``"H"``.
    bound : {"mean", "lower", "upper"}
        Which ``Gd(n0)`` of the class: its geometric mean (16e-6 m³ for A, x4 per class)
        or its lower or upper limit (mean / 2, mean x 2).  Class A has no lower limit and
        class H no upper limit.

    Returns
    -------
    RoadRoughness
        ``G = Gd(n0) n0^w`` and ``p = w = 2`` with ``n0 = 0.1`` cycles/m.
    """
    key = str(letter).strip().upper()
    if len(key) != 1 or key not in ISO_8608_CLASSES:
        raise RoadError(f"ISO 8608 class must be one of {', '.join(ISO_8608_CLASSES)}, "
                        f"got {letter!r}")
    index = ISO_8608_CLASSES.index(key)
    gd_mean = ISO_8608_CLASS_A_GD_N0_M3 * ISO_8608_CLASS_RATIO ** index
    if bound == "mean":
        gd = gd_mean
    elif bound == "lower":
        if index == 0:
            raise RoadError("ISO 8608 class A has no lower limit")
        gd = gd_mean / ISO_8608_BOUND_RATIO
    elif bound == "upper":
        if index == len(ISO_8608_CLASSES) - 1:
            raise RoadError("ISO 8608 class H has no upper limit")
        gd = gd_mean * ISO_8608_BOUND_RATIO
    else:
        raise RoadError(f"bound must be 'mean', 'lower' or 'upper', got {bound!r}")
    roughness = gd * ISO_8608_N0_CYCLES_PER_M ** ISO_8608_WAVINESS
    return RoadRoughness(roughness, ISO_8608_WAVINESS, f"ISO 8608 class {key} ({bound})")


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
        d, h = _checked_series(f"road {self.name!r}", self.distance_m, "distance_m",
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
        if np.max(np.abs(steps - mean)) > _SPACING_REL_TOL * mean:
            raise RoadError(f"road {self.name!r} is not uniformly sampled "
                            f"(spacing {steps.min():.6g} to {steps.max():.6g} m); "
                            f"use resample()")
        return mean

    def _on_road(self, s_m: ArrayLike) -> FloatArray:
        s = _float_array(s_m, "distance s_m")
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
    spacing = _positive(spacing_m, "spacing_m")
    count = int(math.floor(profile.length_m / spacing * (1.0 + _SPACING_REL_TOL))) + 1
    if count < MIN_PROFILE_POINTS:
        raise RoadError(f"spacing_m = {spacing} m is longer than road {profile.name!r} "
                        f"({profile.length_m:.6g} m)")
    s = profile.start_m + spacing * np.arange(count)
    s = np.minimum(s, profile.end_m)
    return RoadProfile(s, np.interp(s, profile.distance_m, profile.height_m), profile.name)


# --------------------------------------------------------------------------------------
# Random roads


def random_road(roughness: float, waviness: float, length_m: float, *,
                band_cycles_per_m: Sequence[float] = DEFAULT_BAND_CYCLES_PER_M,
                spacing_m: float = DEFAULT_ROAD_SPACING_M,
                seed: int | np.random.SeedSequence | None = DEFAULT_SEED,
                amplitudes: Literal["deterministic", "random"] = "deterministic",
                name: str | None = None) -> RoadProfile:
    """Gaussian random road of one-sided spatial PSD ``G n^(-p)`` inside a band, 0 outside.

    Parameters
    ----------
    roughness, waviness : float
        ``G`` and ``p`` of :func:`spatial_psd` (e.g. ``MINOR_ROAD.roughness``, or use
        :meth:`RoadRoughness.random_road`).
    length_m : float
        Road length [m], rounded to a whole number of samples.
    band_cycles_per_m : (float, float)
        Synthesised band ``[n_min, n_max]`` [cycles/m].  It sets the road variance and,
        through ``n_max``, the road velocity and the tyre load: choose it deliberately.
        ``n_min`` must be at least one cycle per road period (``1 / (length + spacing)``)
        and ``n_max`` below the Nyquist frequency ``1 / (2 spacing)``.
    spacing_m : float
        Sample spacing [m].
    seed : int, SeedSequence or None
        Seed of ``numpy.random.default_rng``; the same seed gives the same road.
        ``None`` draws fresh entropy (not reproducible).
    amplitudes : {"deterministic", "random"}
        Synthesis, see Notes.
    name : str, optional
        Profile name (default describes G, p, band and seed).

    Returns
    -------
    RoadProfile
        ``N = round(length/spacing) + 1`` samples from 0 to ``(N-1) spacing``, zero mean.

    Notes
    -----
    Sum of sinusoids by inverse FFT.  The ``N`` samples are exactly one period
    ``P = N spacing`` of ``h(s) = Σ_k A_k cos(2π k s / P + φ_k)`` over the FFT bins
    ``k = 1 … floor((N-1)/2)`` (no mean, no Nyquist term).  Bin ``k`` stands for the
    frequency interval ``[(k - 1/2), (k + 1/2)] / P``; its power ``A_k^2 / 2`` is the exact
    integral of ``G n^(-p)`` over that interval intersected with the band, so bins wholly
    outside the band are exactly 0 and the variance of the samples equals the closed form
    :func:`band_variance` (Parseval).

    ``"deterministic"`` (default): ``A_k = sqrt(2 P_k)`` with phases ``φ_k`` uniform on
    ``[0, 2π)``.  Every seed has exactly the target periodogram and variance; seeds differ
    only in phase, so there is no seed-to-seed scatter of RMS height or spectrum (but
    peaks and exceedances still vary).  The height is only approximately Gaussian: for
    steep spectra a few long-wavelength bins carry much of the variance.

    ``"random"``: complex Gaussian coefficients (Rayleigh amplitudes, uniform phases,
    ``E[A_k^2] = 2 P_k``), a sample of a stationary Gaussian process.  The periodogram of
    one road scatters about the target (χ² with 2 degrees of freedom per bin) and the
    variance varies between seeds, as for a measured road; average several seeds.
    """
    roughness, waviness = _check_psd_params(roughness, waviness)
    length = _positive(length_m, "length_m")
    spacing = _positive(spacing_m, "spacing_m")
    n_lo, n_hi = _check_band(band_cycles_per_m)
    if amplitudes not in AMPLITUDE_METHODS:
        raise RoadError(f"amplitudes must be one of {AMPLITUDE_METHODS}, got {amplitudes!r}")
    n_samples = int(round(length / spacing)) + 1
    if n_samples < MIN_PROFILE_POINTS + 1:
        raise RoadError(f"length_m = {length} m is too short for spacing_m = {spacing} m")
    period_m = n_samples * spacing
    dn = 1.0 / period_m
    bins = np.arange(1, (n_samples - 1) // 2 + 1)
    top_cycles_per_m = (bins[-1] + 0.5) * dn
    if n_hi > top_cycles_per_m:
        raise RoadError(f"band n_max = {n_hi} cycles/m is above the Nyquist frequency "
                        f"{top_cycles_per_m:.6g} cycles/m of spacing_m = {spacing} m")
    if n_lo < dn:
        raise RoadError(f"band n_min = {n_lo} cycles/m is a wavelength {1.0 / n_lo:.6g} m "
                        f"longer than the road period {period_m:.6g} m")
    centres = bins * dn
    lo = np.clip(centres - 0.5 * dn, n_lo, n_hi)
    hi = np.clip(centres + 0.5 * dn, n_lo, n_hi)
    power_m2 = _psd_integral(roughness, waviness, lo, hi)

    rng = np.random.default_rng(seed)
    if amplitudes == "deterministic":
        phase = rng.uniform(0.0, _TWO_PI, bins.size)
        coefficients = np.sqrt(2.0 * power_m2) * np.exp(1j * phase)
    else:
        gauss = rng.standard_normal((2, bins.size))
        coefficients = np.sqrt(power_m2) * (gauss[0] + 1j * gauss[1])
    spectrum = np.zeros(n_samples // 2 + 1, dtype=complex)
    spectrum[bins] = coefficients * (n_samples / 2.0)   # irfft divides by N, halves pairs
    height = np.fft.irfft(spectrum, n=n_samples)
    # (float64: numpy's stubs type a float times an int array as floating[Any])
    distance = cast(FloatArray, spacing * np.arange(n_samples))
    if name is None:
        name = (f"random road G={roughness:g} p={waviness:g} band {n_lo:g}-{n_hi:g} "
                f"cycles/m seed {seed}")
    return RoadProfile(distance, height, name)


# --------------------------------------------------------------------------------------
# Discrete features


def _flat_grid(feature_samples: int, lead_in_m: float, lead_out_m: float,
               spacing_m: float) -> tuple[FloatArray, NDArray[np.int64]]:
    """Distances of a flat road and the feature-local sample index ``j`` (0 at its start)."""
    lead_in = _non_negative(lead_in_m, "lead_in_m")
    lead_out = _non_negative(lead_out_m, "lead_out_m")
    n_in = int(math.ceil(lead_in / spacing_m * (1.0 - _SPACING_REL_TOL)))
    n_out = int(math.ceil(lead_out / spacing_m * (1.0 - _SPACING_REL_TOL)))
    index = np.arange(n_in + feature_samples + n_out + 1)
    # (float64 and int64 at run time; numpy's stubs say floating[Any] and the platform int)
    return cast(FloatArray, spacing_m * index), cast("NDArray[np.int64]", index - n_in)


def _feature_grid(length_m: float, lead_in_m: float, lead_out_m: float, spacing_m: float
                  ) -> tuple[FloatArray, NDArray[np.int64], int]:
    """Grid of a feature ``length_m`` long (a whole number, at least MIN_PROFILE_POINTS, of
    samples) in a flat road: ``(distance, sample index from the feature start, samples in
    the feature)``."""
    spacing = _positive(spacing_m, "spacing_m")
    n_feature = _whole_samples(_positive(length_m, "length_m"), spacing, "length_m")
    if n_feature < MIN_PROFILE_POINTS:
        raise RoadError(f"length_m = {length_m} m must be at least {MIN_PROFILE_POINTS} "
                        f"samples of spacing_m = {spacing} m")
    distance, j = _flat_grid(n_feature, lead_in_m, lead_out_m, spacing)
    return distance, j, n_feature


def pothole(depth_m: float = DEFAULT_POTHOLE_DEPTH_M,
            length_m: float = DEFAULT_POTHOLE_LENGTH_M, *,
            lead_in_m: float = DEFAULT_LEAD_IN_M, lead_out_m: float = DEFAULT_LEAD_OUT_M,
            spacing_m: float = DEFAULT_FEATURE_SPACING_M) -> RoadProfile:
    """Rectangular pothole with sharp edges in a flat road.

    Parameters
    ----------
    depth_m : float
        Depth below the road surface [m], > 0 (default 50 mm).
    length_m : float
        Length along the road from edge to edge at the surface [m] (default 0.5 m), a
        whole number (>= 2) of samples.
    lead_in_m, lead_out_m : float
        Flat road before and after [m], rounded up to whole samples.
    spacing_m : float
        Sample spacing [m].

    Returns
    -------
    RoadProfile
        Height 0, except ``-depth_m`` at every sample strictly between the edges at
        ``lead_in`` and ``lead_in + length_m``: each wall is as steep as the sampling allows
        (one spacing wide) and the opening at the surface is exactly ``length_m``.
        Apply :func:`envelope` for what a tyre sees.

    Notes
    -----
    The MIRA pothole of Simms & Crolla is not described in the paper; the defaults are a
    plausible urban pothole, to be tuned by a later study.
    """
    depth = _positive(depth_m, "depth_m")
    distance, j, n_feature = _feature_grid(length_m, lead_in_m, lead_out_m, spacing_m)
    height = np.where((j > 0) & (j < n_feature), -depth, 0.0)
    return RoadProfile(distance, height, f"pothole {depth:g} m deep, {length_m:g} m long")


def bump(height_m: float, length_m: float, *,
         shape: Literal["cosine", "half_sine"] = "cosine",
         lead_in_m: float = DEFAULT_LEAD_IN_M, lead_out_m: float = DEFAULT_LEAD_OUT_M,
         spacing_m: float = DEFAULT_FEATURE_SPACING_M) -> RoadProfile:
    """Smooth bump (or dip, if ``height_m < 0``) in a flat road.

    Parameters
    ----------
    height_m : float
        Peak height [m], non-zero; negative for a dip.
    length_m : float
        Base length along the road [m], a whole number (>= 2) of samples.
    shape : {"cosine", "half_sine"}
        ``"cosine"``: ``h = H (1 - cos(2π x / L)) / 2``, continuous slope;
        ``"half_sine"``: ``h = H sin(π x / L)``, slope steps at the ends;
        ``x`` from 0 to ``L`` along the bump.
    lead_in_m, lead_out_m, spacing_m : float
        As in :func:`pothole`.
    """
    peak = _finite(height_m, "height_m")
    if peak == 0.0:
        raise RoadError("height_m must be non-zero")
    if shape not in BUMP_SHAPES:
        raise RoadError(f"shape must be one of {BUMP_SHAPES}, got {shape!r}")
    distance, j, n_feature = _feature_grid(length_m, lead_in_m, lead_out_m, spacing_m)
    fraction = np.clip(j / n_feature, 0.0, 1.0)
    if shape == "cosine":
        profile = 0.5 * (1.0 - np.cos(_TWO_PI * fraction))
    else:
        profile = np.sin(math.pi * fraction)
    height = np.where((j > 0) & (j < n_feature), peak * profile, 0.0)
    return RoadProfile(distance, height, f"{shape} bump {peak:g} m high, {length_m:g} m long")


def step(height_m: float, *, ramp_length_m: float = 0.0,
         lead_in_m: float = DEFAULT_LEAD_IN_M, lead_out_m: float = DEFAULT_LEAD_OUT_M,
         spacing_m: float = DEFAULT_FEATURE_SPACING_M) -> RoadProfile:
    """Step up (or down, if ``height_m < 0``) in a flat road.

    Parameters
    ----------
    height_m : float
        Step height [m], non-zero.
    ramp_length_m : float
        Length of the linear ramp [m], a whole number of samples; 0 (default) gives the
        sharpest step the sampling allows, a ramp of one spacing.
    lead_in_m, lead_out_m, spacing_m : float
        As in :func:`pothole`; the ramp starts at ``lead_in``.
    """
    rise = _finite(height_m, "height_m")
    if rise == 0.0:
        raise RoadError("height_m must be non-zero")
    spacing = _positive(spacing_m, "spacing_m")
    ramp = _non_negative(ramp_length_m, "ramp_length_m")
    n_ramp = max(1, _whole_samples(ramp, spacing, "ramp_length_m"))
    distance, j = _flat_grid(n_ramp, lead_in_m, lead_out_m, spacing)
    height = rise * np.clip(j / n_ramp, 0.0, 1.0)
    return RoadProfile(distance, height, f"step {rise:g} m")


# --------------------------------------------------------------------------------------
# Tyre enveloping


def envelope(profile: RoadProfile, tyre_radius_m: float,
             contact_length_m: float | None = None) -> RoadProfile:
    """Tyre enveloping: the road as seen by a rigid circle of the tyre radius rolling on it.

    Parameters
    ----------
    profile : RoadProfile
        Uniformly sampled road (see :func:`resample`).
    tyre_radius_m : float
        Tyre radius ``R`` [m], > 0 (:data:`SUGGESTED_TYRE_RADIUS_M` for a passenger car).
    contact_length_m : float, optional
        If given, the enveloped profile is then averaged by a centred moving average over
        this length (rounded to an odd number of samples, ends held), a simple model of
        the contact patch (:data:`SUGGESTED_CONTACT_LENGTH_M`).

    Returns
    -------
    RoadProfile
        Same distances, height ``h_e(s) = max_{|u| <= R} [h(s+u) + sqrt(R² - u²)] - R``:
        the height of the lowest point of the circle whose centre is above ``s`` and which
        touches the road without penetrating it (a morphological dilation of the profile
        by a semicircle).

    Notes
    -----
    The maximum is taken over the samples within ``R`` (at the ends, over those that
    exist), one pass of ``np.maximum`` per sample offset: ``O(N R / spacing)``.  Without
    averaging ``h_e >= h`` everywhere; the circle bridges a gap of width ``L < 2R`` with a
    dip of ``R - sqrt(R² - (L/2)²)`` and climbs a step early along the arc.  The
    averaging smooths the edges the circle leaves but may lower peaks below ``h``.
    """
    radius = _positive(tyre_radius_m, "tyre_radius_m")
    spacing = profile.spacing_m
    h = np.asarray(profile.height_m)
    out = h.copy()
    offsets = min(int(math.floor(radius / spacing * (1.0 + _SPACING_REL_TOL))), h.size - 1)
    for k in range(1, offsets + 1):
        u = min(k * spacing, radius)
        drop = u * u / (radius + math.sqrt(radius * radius - u * u))   # R - sqrt(R² - u²)
        np.maximum(out[:-k], h[k:] - drop, out=out[:-k])                # sample ahead
        np.maximum(out[k:], h[:-k] - drop, out=out[k:])                 # sample behind
    name = f"{profile.name} enveloped R={radius:g} m"
    if contact_length_m is not None:
        contact = _positive(contact_length_m, "contact_length_m")
        window = 2 * int(round(contact / (2.0 * spacing))) + 1
        if window > 1:
            # imported here: scipy.ndimage is slow to import, and every command-line start
            # imports this module (the ride's parameter schema) without needing it
            from scipy.ndimage import uniform_filter1d

            out = uniform_filter1d(out, size=window, mode="nearest")
        name += f" contact {contact:g} m"
    return RoadProfile(profile.distance_m, out, name)


# --------------------------------------------------------------------------------------
# Profile files


def _column(header: list[str], names: tuple[str, ...], path: Path, line: int) -> int:
    for name in names:
        if name in header:
            return header.index(name)
    raise RoadError(f"{path}: line {line}: missing column '{names[0]}' in header "
                    f"{','.join(header)}")


def _cell(row: list[str], col: int, what: str, path: Path, line: int) -> float:
    if col >= len(row) or not row[col].strip():
        raise RoadError(f"{path}: line {line}: missing value for column '{what}'")
    text = row[col].strip()
    try:
        value = float(text)
    except ValueError:
        raise RoadError(f"{path}: line {line}: {what} {text!r} is not a number") from None
    if not math.isfinite(value):
        raise RoadError(f"{path}: line {line}: {what} {text!r} is not finite")
    return value


def read_profile_csv(path: str | Path, *, name: str | None = None) -> RoadProfile:
    """Read a road profile from CSV.

    Parameters
    ----------
    path : str or Path
        CSV file: a header line with the columns ``distance`` [m] and ``height`` [m]
        (``distance_m`` / ``height_m`` also accepted, case-insensitive; other columns are
        ignored), then one row per sample with strictly increasing distance.  Blank lines
        and lines starting with ``#`` are skipped.
    name : str, optional
        Profile name (default: the file stem).

    Raises
    ------
    RoadError
        One line naming the file, the line and the problem (unreadable file, missing
        column or value, non-numeric or non-finite value, non-increasing distance, fewer
        than two rows).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise RoadError(f"{path}: cannot read road profile: {exc.strerror}") from None
    except UnicodeDecodeError:
        raise RoadError(f"{path}: not a UTF-8 text file") from None
    reader = csv.reader(io.StringIO(text))
    d_col = h_col = -1
    header_seen = False
    distance: list[float] = []
    height: list[float] = []
    prev_line = 0
    try:
        for row in reader:
            line = reader.line_num
            if not any(cell.strip() for cell in row) or row[0].lstrip().startswith("#"):
                continue
            if not header_seen:
                header = [cell.strip().lower() for cell in row]
                d_col = _column(header, _DISTANCE_COLUMNS, path, line)
                h_col = _column(header, _HEIGHT_COLUMNS, path, line)
                header_seen = True
                continue
            s = _cell(row, d_col, "distance", path, line)
            z = _cell(row, h_col, "height", path, line)
            if distance and s <= distance[-1]:
                raise RoadError(f"{path}: line {line}: distance {s:g} m is not greater than "
                                f"{distance[-1]:g} m on line {prev_line}")
            distance.append(s)
            height.append(z)
            prev_line = line
    except csv.Error as exc:
        raise RoadError(f"{path}: line {reader.line_num}: malformed CSV: {exc}") from None
    if not header_seen:
        raise RoadError(f"{path}: empty file, expected a header with columns "
                        f"'distance' and 'height'")
    if len(distance) < MIN_PROFILE_POINTS:
        raise RoadError(f"{path}: needs at least {MIN_PROFILE_POINTS} data rows, "
                        f"found {len(distance)}")
    return RoadProfile(np.array(distance), np.array(height),
                       path.stem if name is None else name)


def write_profile_csv(profile: RoadProfile, path: str | Path) -> None:
    """Write a profile as CSV (``distance,height`` header, [m]) readable by
    :func:`read_profile_csv`; values are written with full precision (exact round trip)."""
    path = Path(path)
    try:
        with path.open("w", newline="", encoding="utf-8") as fh:
            writer = csv.writer(fh)
            writer.writerow(_CSV_HEADER)
            for s, z in zip(profile.distance_m.tolist(), profile.height_m.tolist()):
                writer.writerow((repr(s), repr(z)))
    except OSError as exc:
        raise RoadError(f"{path}: cannot write road profile: {exc.strerror}") from None


# --------------------------------------------------------------------------------------
# Speed


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
    Times outside ``[time_s[0], time_s[-1]]`` raise :class:`RoadError`.
    """

    time_s: FloatArray
    speed_m_s: FloatArray
    _distance_knots_m: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        t, v = _checked_series("speed profile", self.time_s, "time_s", self.speed_m_s,
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
        speed = _non_negative(speed_m_s, "speed_m_s")
        duration = _positive(duration_s, "duration_s")
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
        t = _float_array(t_s, "time t_s")
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
    t = _float_array(t_s, "time t_s")
    start = profile.start_m if start_distance_m is None else _finite(start_distance_m,
                                                                     "start_distance_m")
    if isinstance(speed, SpeedProfile):
        travelled = speed.distance_at(t)
        v = speed.speed_at(t)
    else:
        v_const = _non_negative(speed, "speed [m/s]")
        travelled = v_const * t
        v = np.full_like(t, v_const)
    s = start + travelled
    return profile.height_at(s), profile.slope_at(s) * v
