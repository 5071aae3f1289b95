"""Frequency response of the linear quarter car, Simms & Crolla eq 38 (docs/model.md §5).

With a linear damper of rate ``C_s`` at the wheel, eq 38 in the frequency domain
(``s = j 2π f``, road height ``X0``) is

    (M_w s² + (C_s + C_t) s + K_s + K_t) Z1 − (C_s s + K_s) Z2 = (K_t + C_t s) X0
    −(C_s s + K_s) Z1 + (M_b s² + C_s s + K_s) Z2 = 0

(``C_t`` = tyre damping, 0 in eq 38).  The transfer functions from road height are wheel
``Z1/X0``, body ``Z2/X0``, suspension working space ``(Z1 − Z2)/X0`` [m/m], body
acceleration ``s² Z2/X0`` [(m/s²)/m] and dynamic tyre load ``(K_t + C_t s)(X0 − Z1)/X0``
[N/m].  For a stationary road of one-sided PSD ``S(f)`` [m²/Hz] (e.g. eq 39,
``S = G V^(p−1)/f^p``, from :mod:`ride_sim.road_spectra`) an output has PSD ``|H|² S``
(:func:`response_psd`) and r.m.s. ``√∫ |H|² S df`` (:func:`rms_from_psd`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from damper_emulator.errors import UserError
from ride_sim.params import QuarterCarParams


@dataclass(frozen=True)
class QuarterCarResponse:
    """Complex transfer functions from road height at the frequencies ``f_hz``."""

    f_hz: np.ndarray
    wheel: np.ndarray          # Z1/X0 [m/m]
    body: np.ndarray           # Z2/X0 [m/m]
    sws: np.ndarray            # (Z1 − Z2)/X0 [m/m]
    body_accel: np.ndarray     # s² Z2/X0 [(m/s²)/m]
    dtl: np.ndarray            # (K_t + C_t s)(X0 − Z1)/X0 [N/m]


def transfer_functions(params: QuarterCarParams, f_hz: ArrayLike,
                       damping_ns_m: float | None = None) -> QuarterCarResponse:
    """The linear quarter car's responses to road height (continuous time, eq 38).

    Parameters
    ----------
    params : QuarterCarParams
    f_hz : array_like
        Frequencies [Hz] (>= 0).
    damping_ns_m : float, optional
        Linear damping at the wheel ``C_s`` [N s/m]; default ``params.linear_damping_ns_m``
        (a damper-side rate ``c`` is ``c / MR²`` here).
    """
    f = np.asarray(f_hz, dtype=float)
    if not np.isfinite(f).all() or (f < 0).any():
        raise UserError("frequencies must be finite and >= 0 Hz")
    c = params.linear_damping_ns_m if damping_ns_m is None else float(damping_ns_m)
    s = 2j * np.pi * f
    mw, mb = params.unsprung_mass_kg, params.sprung_mass_kg
    kt, ks, ct = params.tyre_stiffness_n_m, params.spring_rate_n_m, params.tyre_damping_ns_m
    a11 = mw * s ** 2 + (c + ct) * s + ks + kt
    a12 = -(c * s + ks)
    a22 = mb * s ** 2 + c * s + ks
    tyre = kt + ct * s
    det = a11 * a22 - a12 * a12
    wheel = tyre * a22 / det
    body = -tyre * a12 / det
    return QuarterCarResponse(f, wheel, body, wheel - body, s ** 2 * body, tyre * (1 - wheel))


def response_psd(h: ArrayLike, road_psd: ArrayLike) -> np.ndarray:
    """Output PSD ``|H|² S`` of a transfer function ``h`` and road PSD ``road_psd``
    (same frequencies, same one-sided convention)."""
    h = np.asarray(h)
    s = np.asarray(road_psd, dtype=float)
    if h.shape != s.shape:
        raise UserError(f"transfer function and road PSD differ in shape ({h.shape} and "
                         f"{s.shape})")
    psd: np.ndarray = np.abs(h) ** 2 * s
    return psd


def rms_from_psd(f_hz: ArrayLike, psd: ArrayLike, band: tuple[float, float] | None = None) -> float:
    """R.m.s. ``√∫ psd df`` by the trapezoidal rule over ``band = (f_lo, f_hi)`` [Hz]
    (default: the whole grid).  Band edges between grid points are included by linear
    interpolation of the PSD; the grid must be increasing."""
    f = np.asarray(f_hz, dtype=float)
    p = np.asarray(psd, dtype=float)
    if f.ndim != 1 or p.shape != f.shape or f.size < 2:
        raise UserError("f_hz and psd must be 1-D arrays of equal length >= 2")
    if not (np.diff(f) > 0).all():
        raise UserError("f_hz must be strictly increasing")
    if band is not None:
        lo, hi = float(band[0]), float(band[1])
        if not lo < hi:
            raise UserError(f"band ({lo:g}, {hi:g}) Hz must have f_lo < f_hi")
        lo, hi = max(lo, f[0]), min(hi, f[-1])
        if not lo < hi:
            return 0.0
        inside = (f > lo) & (f < hi)
        f_b = np.concatenate([[lo], f[inside], [hi]])
        p = np.interp(f_b, f, p)
        f = f_b
    return float(np.sqrt(np.trapezoid(p, f)))
