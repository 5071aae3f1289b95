"""The term discovery's gate once an effect is in (``selection.discovery_floor``): the
floor is three times the noise level of what the effects left, as the rounds go on, not
the refitted model's first floor, whose level a large smooth residual raises.

The residuals are given, not simulated (the real case is the benchmark's
``sport:valve_lag>gas_heat_transfer``: the refitted model's 370 N of a 4 ms valve lag on
the 12 Hz sine put the first floor at 29 N, and the 20 N the lag left at 1 and 3 Hz went
undiscovered); the levels are worked out here in closed form."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from damper_emulator.diagnose.outcome import (
    SEARCH_NOISE_FACTOR,
    floor_level,
    noise_level,
    pooled_rms,
)
from damper_emulator.diagnose.selection import discovery_floor

#: the truth's force noise [N], sample rate [Hz] and record length [s]
SIGMA_N, RATE_HZ, SECONDS = 4.0, 1000.0, 10.0
T = np.arange(int(SECONDS * RATE_HZ)) / RATE_HZ


def _held(residuals):
    """Held-out records as the floor reads them (their force: the residual's size)."""
    return [SimpleNamespace(data=SimpleNamespace(force=100.0 * np.ones_like(r)), start=0)
            for r in residuals]


def _sine(rms_n: float, hz: float) -> np.ndarray:
    return math.sqrt(2.0) * rms_n * np.sin(2.0 * math.pi * hz * T)


def test_a_large_smooth_residual_raises_the_first_difference_level_as_its_closed_form():
    """The level is ``1.4826 MAD(Δr)/√2``.  A sine of amplitude ``a`` at ``f`` has
    differences ``2a sin(πf/fs) cos(·)``, whose median magnitude is ``sin(π/4)`` of their
    amplitude: 370 N r.m.s. at 12 Hz reads as 29 N of noise, not 0."""
    a = math.sqrt(2.0) * 370.0
    expected = 1.4826 * 2.0 * a * math.sin(math.pi * 12.0 / RATE_HZ) * math.sin(math.pi / 4) \
        / math.sqrt(2.0)
    assert noise_level(_sine(370.0, 12.0)) == pytest.approx(expected, rel=0.01)
    assert expected > 7.0 * SIGMA_N


def test_once_an_effect_is_in_the_gate_is_three_times_the_level_of_what_is_left():
    """What a first effect left: 20 N at 1 Hz and white noise of 4 N.  Against the first
    floor (29.2 N, the refitted model's) it would be nothing to discover; against three
    times its own level (12 N: the sine's differences, 20√2·2π/1000 ≈ 0.18 N, do not
    move the median) it is structure, and the discovery runs."""
    rng = np.random.default_rng(1)
    left = [_sine(20.0, 1.0) + rng.normal(0.0, SIGMA_N, T.size)]
    first = 29.2
    assert discovery_floor(first, None) == first
    gate = discovery_floor(first, floor_level(_held(left), left)[1])
    assert gate == pytest.approx(SEARCH_NOISE_FACTOR * SIGMA_N, rel=0.05)
    assert pooled_rms(left) > gate and pooled_rms(left) < first
