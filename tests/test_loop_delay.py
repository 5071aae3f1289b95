"""The ride's loop-delay bound and summary (ride_sim.loop_delay)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ride_sim.loop_delay import MAX_PHASE_LAG, delay_bound_s, summarise, warning, wheel_hop_rad_s
from ride_sim.params import load_ride_config


def test_the_bound_is_45_degrees_of_the_wheel_hop():
    car = load_ride_config().quarter_car
    # the wheel's own mode with the body held: the 1-DOF natural frequency
    omega = math.sqrt((car.spring_rate_n_m + car.tyre_stiffness_n_m) / car.unsprung_mass_kg)
    assert wheel_hop_rad_s(car) == pytest.approx(omega, rel=1e-12)
    tau = delay_bound_s(car)
    # a damper force c x'(t - tau) on x = sin(w t): its part in phase with x' (the only
    # part that dissipates) over whole periods is c cos(w tau) -- cos 45 deg at the bound
    t = np.linspace(0.0, 20 * 2 * math.pi / omega, 200_001)
    v = omega * np.cos(omega * t)
    v_late = omega * np.cos(omega * (t - tau))
    dissipative = np.trapezoid(v * v_late, t) / np.trapezoid(v * v, t)
    assert dissipative == pytest.approx(math.cos(math.pi / 4), abs=1e-3)
    assert pytest.approx(math.pi / 4) == MAX_PHASE_LAG
    # the project's car: a wheel hop near 11-12 Hz, a bound near 10-11 ms
    assert 8e-3 < tau < 13e-3


def test_the_summary_counts_the_samples_over_the_bound():
    delays = np.array([-1, -1, 1, 1, 2, 1, 15, 1, 3, 1], np.int64)
    d = summarise(delays, 1e-3, 10e-3)
    assert d["samples"] == 8  # the static force's samples are not counted
    assert d["max_ms"] == pytest.approx(15.0)
    assert d["p50_ms"] == pytest.approx(1.0)
    assert d["over_bound"] == 1 and d["within_bound"] is False
    ok = summarise(delays[delays < 10], 1e-3, 10e-3)
    assert ok["over_bound"] == 0 and ok["within_bound"] is True
    assert warning(ok) is None
    line = warning(d)
    assert line and "exceeded its bound (10.0 ms" in line and "1 of 8 samples (max 15 ms)" in line
    none = summarise(np.array([-1, -1], np.int64), 1e-3, 10e-3)
    assert none["samples"] == 0 and math.isnan(none["max_ms"]) and none["within_bound"] is False
