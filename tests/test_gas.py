"""The gas law (eq 3) as the kernels compute it: the power's series of the SIMD lanes
against 40-digit arithmetic and NaN beyond its domain; the one-design kernel's library
power; numpy's array version."""

from __future__ import annotations

import math
from decimal import Decimal, localcontext

import numpy as np
import pytest

from damper_emulator.model.gas import (
    SERIES_MAX_S,
    compression_chamber_pressure,
    compression_chamber_pressure_kernel,
    exp_series,
    gas_volume_ratio,
    log_series,
)
from damper_emulator.model.jit import kernel

#: the bound on the relative error: two machine epsilons (the library's power: 0.5)
BOUND = 2 * np.finfo(float).eps


@kernel
def _series_only(x: float, gamma: float) -> float:
    # as the lanes compute it (damper_emulator.model.lanes._gas_exponent, _gas)
    value: float = exp_series(log_series(gas_volume_ratio(x, 1.0, 1.0), gamma))
    return value


def _exact(x: float, gamma: float) -> Decimal:
    """``r^γ`` to 40 digits of the volume ratio ``r`` as the kernel rounds it (the power's
    own error is what is tested)."""
    with localcontext() as ctx:
        ctx.prec = 40
        return Decimal(1.0 / (1.0 + x)) ** Decimal(gamma)


@pytest.mark.parametrize("gamma", [1.0, 1.3, 1.4, 5.0 / 3.0])
def test_the_series_against_40_digits(gamma):
    # gas volumes V = 1 + x from 0.6 to 1.67 of the static one (the series' domain)
    worst = worst_library = 0.0
    for x in np.linspace(-0.4, 0.66, 801):
        exact = _exact(x, gamma)
        got = _series_only(x, gamma)
        assert math.isfinite(got)  # summed, not left to the library power
        with localcontext() as ctx:
            ctx.prec = 40
            worst = max(worst, float(abs((Decimal(got) - exact) / exact)))
        library = compression_chamber_pressure_kernel(x, 1.0, 1.0, 1.0, gamma)
        assert library == pytest.approx((1.0 / (1.0 + x)) ** gamma, rel=1e-16, abs=0.0)
        with localcontext() as ctx:
            ctx.prec = 40
            worst_library = max(worst_library,
                                float(abs((Decimal(library) - exact) / exact)))
    assert worst <= BOUND
    assert worst_library <= BOUND / 4


def test_beyond_the_series_nan_for_the_library_power():
    for x in (-0.9, -0.5, 0.8, 5.0):
        ratio = 1.0 / (1.0 + x)
        assert abs((ratio - 1.0) / (ratio + 1.0)) > SERIES_MAX_S
        assert compression_chamber_pressure_kernel(x, 2.0e6, 1.0, 1.0, 1.4) == \
            pytest.approx(2.0e6 * ratio ** 1.4, rel=1e-16, abs=0.0)
        assert np.isnan(_series_only(x, 1.4))  # the lanes take the library's there
    # a large exponent leaves the series too
    assert np.isnan(_series_only(0.3, 4.0))
    assert compression_chamber_pressure_kernel(0.3, 1.0, 1.0, 1.0, 4.0) == \
        pytest.approx((1.0 / 1.3) ** 4.0, rel=1e-16, abs=0.0)


def test_numpy_arrays_and_the_kernel_agree():
    x = np.linspace(-0.05, 0.1, 301)
    args = (1.6e6, 1.2e-4, 1.33e-4, 1.4)
    array = compression_chamber_pressure(x, *args)
    compiled = np.array([compression_chamber_pressure_kernel(v, *args) for v in x])
    np.testing.assert_allclose(compiled, array, rtol=2 * BOUND, atol=0.0)
