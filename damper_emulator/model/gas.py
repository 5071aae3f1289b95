"""Gas spring of the mono-tube damper (Simms & Crolla eq 3)."""

from __future__ import annotations

import math
from typing import TypeVar

import numpy as np
from numba.extending import register_jitable
from numpy.typing import NDArray

from damper_emulator.model.jit import inlined_kernel, kernel

#: a stroke: one value, or an array of them (the result has its type)
_X = TypeVar("_X", float, NDArray[np.float64])

#: The power ``r^γ`` of eq 3 as the SIMD lanes compute it (:func:`log_series`, then
#: :func:`exp_series`) sums series where
#: ``|s| = |r − 1| / (r + 1)`` is at most this (``0.6 <= r <= 5/3``: a gas volume within
#: ±40 % of its static one) and ``|γ ln r|`` at most :data:`SERIES_MAX_EXPONENT`; elsewhere
#: it is NaN and the lanes take the library's power.
SERIES_MAX_S = 0.25
SERIES_MAX_EXPONENT = 1.0
#: Terms of ``atanh(s) = Σ s^(2k+1)/(2k+1)``: the first left out is below
#: ``0.25^29/29 < 1e-19`` of ``s``.
ATANH_TERMS = 14
#: Terms of ``e^y = Σ y^k/k!`` after the 1: the remainder is below ``e/20! < 1e-18`` for
#: ``|y| <= 1``.
EXP_TERMS = 19
# Horner's coefficients, unrolled into the compiled code as constants (with a division by
# the loop's counter a power took 30 divisions, 1.7x the library power's time; indexed in
# a loop, the tuple stopped the lanes' vectorisation)
_ATANH_COEFFICIENTS = 1.0 / (2.0 * np.arange(ATANH_TERMS - 1, -1, -1) + 1.0)
_EXP_STEPS = 1.0 / np.arange(EXP_TERMS, 0, -1.0)


@inlined_kernel
def log_series(ratio: float, gamma: float) -> float:
    """``γ ln r`` as the series ``2γ atanh(s)``, ``s = (r − 1)/(r + 1)``, by Horner's rule;
    NaN where ``|s|`` exceeds :data:`SERIES_MAX_S` or is NaN (compiled code only).

    With :func:`exp_series` it is eq 3's power ``r^γ`` as the SIMD lanes compute it
    (:mod:`damper_emulator.model.lanes`, the two halves in two loops): within two machine
    epsilons of the exact power (the library's: half of one; tested against 40-digit
    arithmetic), with no library call, so that a loop over designs runs it in SIMD lanes
    (the library's power was a quarter of that loop's time: benchmarks/many_bench.py).  The
    one-design step keeps the library's power (:func:`compression_chamber_pressure`): in
    its one chain of dependent operations the series' 33 multiply-adds took longer (3-5 %
    of a ride simulation).
    """
    s = (ratio - 1.0) / (ratio + 1.0)
    s2 = s * s
    acc = 0.0
    for k in range(ATANH_TERMS):
        acc = acc * s2 + _ATANH_COEFFICIENTS[k]
    y: float = 2.0 * gamma * s * acc
    return y if abs(s) <= SERIES_MAX_S else math.nan


@inlined_kernel
def exp_series(y: float) -> float:
    """``e^y`` as its series by Horner's rule (:func:`log_series`); NaN where ``|y|``
    exceeds :data:`SERIES_MAX_EXPONENT` or is NaN (compiled code only)."""
    e = 1.0
    for k in range(EXP_TERMS):
        e = 1.0 + y * e * _EXP_STEPS[k]
    return e if abs(y) <= SERIES_MAX_EXPONENT else math.nan


@register_jitable(inline="always")
def gas_volume_ratio(x_m: _X, v_gas_static_m3: float, rod_area_m2: float) -> _X:
    """``V_gas,static / (V_gas,static + A_rod x)``, the base of eq 3's power at stroke
    ``x`` (scalars or arrays; compiled code calls it too)."""
    ratio: _X = v_gas_static_m3 / (v_gas_static_m3 + rod_area_m2 * x_m)
    return ratio


def compression_chamber_pressure(x_m: _X, p_gas_static_pa: float, v_gas_static_m3: float,
                                 rod_area_m2: float, gamma: float) -> _X:
    """Compression-chamber (gas) pressure ``P_com`` [Pa], eq 3.

    ``P_com = P_gas,static (V_gas,static / (V_gas,static + A_rod x))^γ``: extension (``x > 0``)
    withdraws the rod and enlarges the gas volume.  Works on scalars and numpy arrays (the
    kernels call :data:`compression_chamber_pressure_kernel`, this source compiled, with
    the library's power; the SIMD lanes take the power as a series, :func:`log_series`).
    """
    p_com: _X = p_gas_static_pa * gas_volume_ratio(x_m, v_gas_static_m3, rod_area_m2) ** gamma
    return p_com


#: :func:`compression_chamber_pressure` compiled for the kernels, on scalars (the kernels
#: run without numba's runtime and cannot allocate the array an array argument returns)
compression_chamber_pressure_kernel = kernel(compression_chamber_pressure)

# up to a monatomic gas (γ = 5/3) every ratio within SERIES_MAX_S is summed
assert 2.0 * math.atanh(SERIES_MAX_S) * 5.0 / 3.0 < SERIES_MAX_EXPONENT
