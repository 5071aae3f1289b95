"""Quasi-static fit of the gas spring and friction (Simms & Crolla eqs 36–37).

At a constant low velocity the valves pass little flow, and

    F = −A_rod P_gas,static (V_gas,static / (V_gas,static + A_rod x))^γ + sgn(ẋ) F_friction

(eq 37) is fitted for ``P_gas,static``, ``V_gas,static`` and ``F_friction``.  The paper
neglects the viscous force; at 4 mm/s the sport damper's valves still carry about 12 N,
which eq 37 alone would book as friction.  When a valve model is known (from the chirp fit)
its force at the measured velocities is passed in as ``valve_force_n`` and included.
"""

from __future__ import annotations

from typing import TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from damper_emulator.errors import UserError
from damper_emulator.identify.fitting import FitResult, fit
from damper_emulator.model.gas import compression_chamber_pressure

NAMES = ("gas_pressure_static_pa", "gas_volume_static_m3", "friction_force_n")
#: Bounds: the gas parameters within this factor of their start values.
GAS_BOUND_FACTOR = 20.0
#: The gas volume's lower bound keeps this multiple of the rod volume the data stroke in
#: compression (eq 3 needs V_gas + A_rod x > 0 at every sample).
GAS_TRAVEL_MARGIN = 1.05


#: a stroke: one value, or an array of them (the force has its type)
_X = TypeVar("_X", float, NDArray[np.float64])


class IdentificationError(UserError):
    """The data cannot support the fit (one-line message)."""


def gas_force(x_m: _X, p_gas_pa: float, v_gas_m3: float, rod_area_m2: float, gamma: float
              ) -> _X:
    """Gas-spring force ``−A_rod P_com(x)`` [N] (eqs 3, 37)."""
    return -rod_area_m2 * compression_chamber_pressure(x_m, p_gas_pa, v_gas_m3, rod_area_m2,
                                                       gamma)


def start_values(x: np.ndarray, v: np.ndarray, force: np.ndarray, rod_area_m2: float,
                 gamma: float) -> np.ndarray:
    """Start values from the data: ``F ≈ c0 + c1 x + c2 sgn ẋ`` by linear least squares;
    ``P = −c0/A_rod``, ``V = γ A_rod² P / c1`` (the slope of eq 37 at x = 0),
    ``F_friction = c2``."""
    basis = np.column_stack((np.ones_like(x), x, np.sign(v)))
    c0, c1, c2 = np.linalg.lstsq(basis, force, rcond=None)[0]
    if not c0 < 0:
        raise IdentificationError(
            f"the quasi-static force has no gas preload (mean force {c0:.3g} N must be "
            "negative: the gas pushes the rod out); check the force sign convention")
    p = -c0 / rod_area_m2
    if not c1 > 0:
        raise IdentificationError(
            f"the quasi-static force does not rise with extension (slope {c1:.3g} N/m); "
            "the gas spring cannot be identified (check the displacement sign)")
    return np.array([p, gamma * rod_area_m2 ** 2 * p / c1, max(c2, 0.0)])


def fit_quasi_static(x: np.ndarray, v: np.ndarray, force: np.ndarray, rod_area_m2: float,
                     gamma: float, valve_force_n: ArrayLike | None = None) -> FitResult:
    """Fit eq 37 (plus a known valve force) to quasi-static data.

    Parameters
    ----------
    x, v, force : ndarray
        Displacement [m], velocity [m/s], force [N, rebound +].  Samples at rest
        (``v == 0``) are left out.
    rod_area_m2, gamma : float
        Fixed geometry and polytropic exponent.
    valve_force_n : ndarray, optional
        Viscous (valve) force at the samples, from a known valve model.

    Returns
    -------
    FitResult
        ``gas_pressure_static_pa``, ``gas_volume_static_m3``, ``friction_force_n``.
    """
    moving = v != 0
    if moving.sum() < 10:
        raise IdentificationError("the quasi-static data has fewer than 10 moving samples")
    x, v, force = x[moving], v[moving], force[moving]
    extra = np.zeros_like(force) if valve_force_n is None else np.asarray(valve_force_n)[moving]
    target = force - extra
    if not ((v > 0).any() and (v < 0).any()):
        raise IdentificationError("the quasi-static data must move in both directions")
    start = start_values(x, v, target, rod_area_m2, gamma)
    sgn = np.sign(v)

    def residual(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p, vol, fr = theta
        fg = gas_force(x, p, vol, rod_area_m2, gamma)
        r = fg + fr * sgn - target
        d_p = fg / p
        d_v = fg * gamma * rod_area_m2 * x / (vol * (vol + rod_area_m2 * x))
        return r, np.column_stack((d_p, d_v, sgn))

    f_max = float(np.max(np.abs(target)))
    lower = np.array([start[0] / GAS_BOUND_FACTOR, start[1] / GAS_BOUND_FACTOR, 0.0])
    upper = np.array([start[0] * GAS_BOUND_FACTOR, start[1] * GAS_BOUND_FACTOR, f_max])
    # the gas volume must stay positive over the whole stroke of the data (eq 3): a slope
    # steepened by viscous force (a test that is not slow enough) can put the linear start
    # value below that
    v_travel = GAS_TRAVEL_MARGIN * max(-rod_area_m2 * float(np.min(x)), 0.0)
    if lower[1] < v_travel:
        lower[1] = v_travel
        start[1] = max(start[1], 2.0 * v_travel)
        upper[1] = max(upper[1], start[1] * GAS_BOUND_FACTOR)
    return fit(residual, NAMES, start, (True, True, False), lower, upper, target)
