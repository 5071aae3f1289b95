"""Road spectra: the power spectral density of Simms & Crolla eq 39 and its integral.

Simms & Crolla (SAE 2002-01-0319, eq 39) give the temporal power spectral density of the
road displacement seen at speed ``V`` [m/s]

.. math:: S(f) = G V^{p-1} f^{-p}  \\quad [m^2/Hz],

which is the one-sided spatial PSD

.. math:: S(n) = G n^{-p}  \\quad [m^2/(cycles/m)],

with the spatial frequency ``n = f / V`` in cycles/m, so that ``S(f) = S(n = f/V) / V``.
``G`` is the roughness and ``p`` the waviness (slope of the log–log spectrum).  Their minor
road is ``G = 5e-6``, ``p = 2.5`` driven at 20 m/s for 500 m
(:data:`ride_sim.road_synthesis.MINOR_ROAD`).  ISO 8608 writes the same form as
``Gd(n) = Gd(n0) (n/n0)^(-w)`` with ``n0 = 0.1`` cycles/m and ``w = 2``; hence
``G = Gd(n0) n0^w`` and ``p = w`` (:func:`ride_sim.road_synthesis.iso8608_class`).  The two
equations live only in :func:`spatial_psd` and :func:`temporal_psd`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from ride_sim.road import FloatArray, RoadError, check_positive, positive_array


def check_band(band_cycles_per_m: Sequence[float]) -> tuple[float, float]:
    """The band ``(n_min, n_max)`` [cycles/m] with ``0 < n_min < n_max``, else
    :class:`~ride_sim.road.RoadError`."""
    try:
        lo, hi = band_cycles_per_m
    except (TypeError, ValueError):
        raise RoadError(f"band_cycles_per_m must be a pair (n_min, n_max), "
                        f"got {band_cycles_per_m!r}") from None
    lo = check_positive(lo, "band n_min [cycles/m]")
    hi = check_positive(hi, "band n_max [cycles/m]")
    if hi <= lo:
        raise RoadError(f"band n_max = {hi} cycles/m must be > n_min = {lo} cycles/m")
    return lo, hi


def check_psd_params(roughness: float, waviness: float) -> tuple[float, float]:
    """``(G, p)``, both finite and > 0, else :class:`~ride_sim.road.RoadError`."""
    return check_positive(roughness, "roughness G"), check_positive(waviness, "waviness p")


def psd_integral(roughness: float, waviness: float, lo: ArrayLike, hi: ArrayLike) -> FloatArray:
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
    roughness, waviness = check_psd_params(roughness, waviness)
    n = positive_array(n, "spatial frequency n [cycles/m]")
    psd = roughness * n ** (-waviness)
    if band_cycles_per_m is not None:
        lo, hi = check_band(band_cycles_per_m)
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
    roughness, waviness = check_psd_params(roughness, waviness)
    speed = check_positive(speed_m_s, "speed_m_s")
    f = positive_array(f, "frequency f [Hz]")
    psd: FloatArray = roughness * speed ** (waviness - 1.0) * f ** (-waviness)
    if band_cycles_per_m is not None:
        lo, hi = check_band(band_cycles_per_m)
        n = f / speed
        psd = np.where((n >= lo) & (n <= hi), psd, 0.0)
    return psd


def band_variance(roughness: float, waviness: float,
                  band_cycles_per_m: Sequence[float]) -> float:
    """Variance of a road of PSD ``G n^(-p)`` band-limited to ``[n_min, n_max]`` [m²].

    ``G (n_min^(1-p) - n_max^(1-p)) / (p - 1)`` (``G ln(n_max/n_min)`` for ``p = 1``).
    """
    roughness, waviness = check_psd_params(roughness, waviness)
    lo, hi = check_band(band_cycles_per_m)
    return float(psd_integral(roughness, waviness, lo, hi))
