"""Random roads: road spectra as objects and the Gaussian roads synthesised from them.

A :class:`RoadRoughness` is a spectrum ``S(n) = G n^(-p)`` of :mod:`ride_sim.road_spectra`:
Simms & Crolla's minor road (:data:`MINOR_ROAD`) or an ISO 8608 class
(:func:`iso8608_class`).  A spectrum ``n^(-p)`` cannot be synthesised over all frequencies:
the synthesised band ``[n_min, n_max]`` (cycles/m) is an explicit parameter of
:func:`random_road` (default :data:`DEFAULT_BAND_CYCLES_PER_M`).  The road variance grows
as ``n_min^(1-p)`` and the road velocity and acceleration, and so the tyre load, depend
strongly on ``n_max``; short wavelengths are in reality filtered by the tyre (see
:func:`ride_sim.road_envelope.envelope`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal, cast

import numpy as np
from numpy.typing import ArrayLike

from ride_sim.road import MIN_PROFILE_POINTS, FloatArray, RoadError, RoadProfile, check_positive
from ride_sim.road_spectra import (
    band_variance,
    check_band,
    check_psd_params,
    psd_integral,
    spatial_psd,
    temporal_psd,
)

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
#: Synthesis methods of :func:`random_road`.
AMPLITUDE_METHODS = ("deterministic", "random")


# --------------------------------------------------------------------------------------
# Road roughness: the minor road and the ISO 8608 classes


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
        check_psd_params(self.roughness, self.waviness)

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
    roughness, waviness = check_psd_params(roughness, waviness)
    length = check_positive(length_m, "length_m")
    spacing = check_positive(spacing_m, "spacing_m")
    n_lo, n_hi = check_band(band_cycles_per_m)
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
    power_m2 = psd_integral(roughness, waviness, lo, hi)

    rng = np.random.default_rng(seed)
    if amplitudes == "deterministic":
        phase = rng.uniform(0.0, math.tau, bins.size)
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
