"""Vibration metrics of ISO 2631-1:1997 clause 6 for sampled (weighted) accelerations.

All functions take a 1-D array of finite samples (normally a frequency-weighted acceleration
from :func:`ride_sim.iso2631.weight_signal`, in m/s²) and, where time enters, the sampling rate
``fs`` [Hz].  Time integrals are evaluated by the rectangle rule on the samples, which is exact
for sums of squares and fourth powers of sampled sines over whole periods.

- :func:`rms` and :func:`peaks`: basic evaluation (§6.2.1) and the signed extremes.
- :func:`crest_factor`: peak over r.m.s. (§6.2.1: the basic method suffices up to 9).
- :func:`running_rms` and :func:`mtvv`: running r.m.s. and maximum transient vibration value
  (§6.3.1).
- :func:`vdv`: fourth-power vibration dose value (§6.3.2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import signal as sps

from damper_emulator.errors import UserError

__all__ = [
    "RUNNING_RMS",
    "RunningRmsConstants",
    "crest_factor",
    "mtvv",
    "peaks",
    "rms",
    "running_rms",
    "vdv",
]

Averaging = Literal["linear", "exponential"]


@dataclass(frozen=True)
class RunningRmsConstants:
    """Constants of the running r.m.s. of ISO 2631-1:1997 §6.3.1.

    Attributes
    ----------
    integration_time_s : float
        ``τ``, the integration time for the running average; the standard recommends 1 s for
        the maximum transient vibration value.
    """

    integration_time_s: float = 1.0


RUNNING_RMS = RunningRmsConstants()
"""The standard's running r.m.s. constants (``τ = 1 s``)."""


def _signal(x: ArrayLike) -> NDArray[np.float64]:
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim != 1:
        raise UserError(f"signal must be 1-D, got shape {arr.shape}")
    if arr.size == 0:
        raise UserError("signal must not be empty")
    if not np.all(np.isfinite(arr)):
        raise UserError("signal must be finite")
    return arr


def _rate(fs: float) -> float:
    fs = float(fs)
    if not (math.isfinite(fs) and fs > 0.0):
        raise UserError(f"sampling rate must be finite and positive, got {fs}")
    return fs


def rms(x: ArrayLike) -> float:
    """Root mean square of a signal (ISO 2631-1:1997 §6.2.1, over the whole record).

    Parameters
    ----------
    x : array_like, 1-D
        Samples, finite, not empty.

    Returns
    -------
    a_rms : float
        ``sqrt(mean(x²))``, in the unit of ``x``.
    """
    a = _signal(x)
    return float(np.sqrt(np.mean(a * a)))


def peaks(x: ArrayLike) -> tuple[float, float]:
    """Signed extremes of a signal.

    Parameters
    ----------
    x : array_like, 1-D
        Samples, finite, not empty.

    Returns
    -------
    peak_pos, peak_neg : float
        ``max(x)`` and ``min(x)``; ``peak_neg`` is negative unless ``x`` is everywhere positive.
    """
    a = _signal(x)
    return float(np.max(a)), float(np.min(a))


def crest_factor(x: ArrayLike) -> float:
    """Crest factor: the largest absolute sample over the r.m.s. (ISO 2631-1:1997 §6.2.1).

    Parameters
    ----------
    x : array_like, 1-D
        Samples, finite, not empty, not all zero.

    Returns
    -------
    cf : float
        ``max|x| / rms(x)``; the standard's basic evaluation method suffices up to 9.
    """
    a = _signal(x)
    a_rms = rms(a)
    if a_rms == 0.0:
        raise UserError("crest factor of an all-zero signal is undefined")
    return float(np.max(np.abs(a))) / a_rms


def running_rms(x: ArrayLike, fs: float, *,
                integration_time_s: float = RUNNING_RMS.integration_time_s,
                averaging: Averaging = "linear") -> NDArray[np.float64]:
    """Running r.m.s. of ISO 2631-1:1997 §6.3.1.

    Parameters
    ----------
    x : array_like, 1-D
        Weighted acceleration samples, finite, not empty.
    fs : float
        Sampling rate [Hz].
    integration_time_s : float, optional
        Integration time ``τ`` [s], 1 s by default as the standard recommends.
    averaging : {"linear", "exponential"}, optional
        ``"linear"``: ``a(t0) = [1/τ ∫_{t0-τ}^{t0} x(t)² dt]^½``, the mean of the last
        ``N = round(τ fs)`` squared samples.  ``"exponential"``:
        ``a(t0) = [1/τ ∫_{-∞}^{t0} x(t)² exp((t - t0)/τ) dt]^½``, discretised exactly for a
        piecewise-constant ``x²`` as ``m[n] = α m[n-1] + (1 - α) x[n]²``, ``α = exp(-1/(τ fs))``
        (unit gain for a constant signal).

    Returns
    -------
    a_running : ndarray
        ``a(t0)`` at every sample, the length of ``x``.  The signal is taken as zero before its
        first sample, as for an instrument started with the record: the first ``τ`` reads low
        unless the vibration starts with the record.

    Raises
    ------
    ValueError
        For a bad signal, sampling rate, integration time or averaging name.
    """
    a = _signal(x)
    fs = _rate(fs)
    tau = float(integration_time_s)
    if not (math.isfinite(tau) and tau > 0.0):
        raise UserError(f"integration time must be finite and positive, got {tau}")
    squares = a * a
    if averaging == "linear":
        n = max(1, round(tau * fs))
        cumulative = np.concatenate([np.zeros(n), np.cumsum(squares)])
        mean_square = (cumulative[n:] - cumulative[:-n]) / n
    elif averaging == "exponential":
        alpha = math.exp(-1.0 / (tau * fs))
        mean_square = sps.lfilter([1.0 - alpha], [1.0, -alpha], squares)
    else:
        raise UserError(f"averaging must be 'linear' or 'exponential', got {averaging!r}")
    level: NDArray[np.float64] = np.sqrt(np.maximum(mean_square, 0.0))
    return level


def mtvv(x: ArrayLike, fs: float, *,
         integration_time_s: float = RUNNING_RMS.integration_time_s,
         averaging: Averaging = "linear") -> float:
    """Maximum transient vibration value, ISO 2631-1:1997 §6.3.1: the largest running r.m.s.

    Parameters
    ----------
    x : array_like, 1-D
        Weighted acceleration samples, finite, not empty.
    fs : float
        Sampling rate [Hz].
    integration_time_s : float, optional
        Integration time ``τ`` [s], 1 s by default.
    averaging : {"linear", "exponential"}, optional
        Running average, see :func:`running_rms`.

    Returns
    -------
    mtvv : float
        ``max over t0 of a(t0)``, in the unit of ``x``.
    """
    return float(np.max(running_rms(x, fs, integration_time_s=integration_time_s,
                                    averaging=averaging)))


def vdv(x: ArrayLike, fs: float) -> float:
    """Fourth-power vibration dose value, ISO 2631-1:1997 §6.3.2.

    Parameters
    ----------
    x : array_like, 1-D
        Weighted acceleration samples [m/s²], finite, not empty.
    fs : float
        Sampling rate [Hz].

    Returns
    -------
    vdv : float
        ``[∫ x(t)⁴ dt]^¼ = (Σ x⁴ / fs)^¼`` over the whole record [m/s^1.75 for x in m/s²].
    """
    a = _signal(x)
    fs = _rate(fs)
    squares = a * a
    return float((np.sum(squares * squares) / fs) ** 0.25)
