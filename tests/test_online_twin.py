"""The twin's online correction: its recursive least squares against the batch solution,
its bounds, and the map's identity."""

import dataclasses

import numpy as np
import pytest

from ride_sim.hybrid.online import IDENTITY, TERMS, OnlineTwin, mapped_force
from ride_sim.hybrid.params import LearnParams

DT = 1e-3
STATIC = -450.0
SLOPE = 20e3


def motion(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A random ride-like stroke, its velocity and a twin force that is not linear in it
    (a digressive damper about a static force, with a gas spring)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    x = sum(a * np.sin(2 * np.pi * f * t + p) for a, f, p in
            zip(rng.uniform(2e-3, 1e-2, 6), rng.uniform(0.5, 12.0, 6),
                rng.uniform(0, 2 * np.pi, 6)))
    v = np.gradient(x, DT)
    force = STATIC + 8e3 * x + np.where(v < 0, 2500.0, 3500.0) * np.tanh(v / 0.12)
    return x, v, force


def regressors(force, x, v):
    d = force - STATIC
    return np.c_[np.ones(x.size), np.where(v < 0, d, 0.0), np.where(v >= 0, d, 0.0), v, x,
                 np.sign(v)]


def test_the_identity_map_is_the_twin_itself():
    theta = np.array(IDENTITY)
    for force, x, v in ((-450.0, 0.0, 0.0), (812.5, 0.01, 0.3), (-2000.0, -0.02, -0.7)):
        assert mapped_force(theta, STATIC, force, x, v) == force


def test_without_forgetting_the_estimate_is_the_regularised_batch_solution():
    """With no forgetting, recursive least squares from ``θ₀`` with covariance ``P₀`` is
    the closed form ``(XᵀX + P₀⁻¹)⁻¹ (Xᵀy + P₀⁻¹ θ₀)`` over every sample (solved here by
    numpy, independently), and with samples enough it is the map that made the data."""
    x, v, force = motion(6000)
    truth = np.array([35.0, 0.88, 1.12, 150.0, 900.0, -40.0])
    measured = np.array([mapped_force(truth, STATIC, f, a, b) for f, a, b in zip(force, x, v)])
    measured += np.random.default_rng(1).normal(0.0, 5.0, measured.size)
    learn = LearnParams(online_window_s=1e9, online_gain_bound=0.9)
    twin = OnlineTwin(learn, STATIC, SLOPE, DT)
    p0 = twin._p.copy()
    for f, a, b, m in zip(force, x, v, measured):
        twin.update(f, a, b, m)
    X = regressors(force, x, v)
    info = np.linalg.inv(p0)
    closed = np.linalg.solve(X.T @ X + info, X.T @ (measured - STATIC) + info @ IDENTITY)
    np.testing.assert_allclose(twin.theta, closed, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(twin.theta, truth, rtol=0.05, atol=2.0)
    assert twin.updates == x.size


def test_forgetting_follows_a_change_of_the_specimen():
    """The valves' force falls by a fifth halfway: a window later the map has it."""
    x, v, force = motion(12000, seed=2)
    twin = OnlineTwin(LearnParams(online_window_s=1.0), STATIC, SLOPE, DT)
    before = np.array(IDENTITY)
    after = np.array([0.0, 0.8, 0.8, 0.0, 0.0, 0.0])
    for i, (f, a, b) in enumerate(zip(force, x, v)):
        truth = before if i < 6000 else after
        twin.update(f, a, b, mapped_force(truth, STATIC, f, a, b))
        if i == 5999:
            np.testing.assert_allclose(twin.theta[1:3], 1.0, atol=1e-3)
    np.testing.assert_allclose(twin.theta[1:3], 0.8, atol=0.01)
    assert abs(twin.theta[0]) < 5.0


def test_the_valve_gains_stay_within_their_bound_and_the_estimate_stays_finite():
    """A specimen three times the twin: the gains never leave 1 ± bound, and the map
    still predicts it better than the twin; a long stretch at rest (only the static force
    is excited) leaves the covariance no larger than it started (no wind-up) and the
    estimate finite, predicting the force at rest."""
    x, v, force = motion(4000, seed=3)
    twin = OnlineTwin(LearnParams(online_gain_bound=0.5), STATIC, SLOPE, DT)
    gains, errors = [], []
    for f, a, b in zip(force, x, v):
        measured = STATIC + 3.0 * (f - STATIC)
        errors.append((twin.force(f, a, b) - measured, f - measured))
        twin.update(f, a, b, measured)
        gains.append(twin.theta[1:3].copy())
    assert np.min(gains) >= 0.5 and np.max(gains) <= 1.5
    late = np.array(errors[-1000:])
    assert np.sqrt(np.mean(late[:, 0] ** 2)) < 0.9 * np.sqrt(np.mean(late[:, 1] ** 2))
    for _ in range(20000):
        twin.update(STATIC, 0.0, 0.0, STATIC)
    assert np.all(np.isfinite(twin.theta)) and np.all(np.isfinite(twin._p))
    assert np.mean(np.diag(twin._p) / twin._p_start) <= 1.0 + 1e-9
    assert twin.force(STATIC, 0.0, 0.0) == pytest.approx(STATIC, abs=0.1)


def test_disabled_it_learns_nothing_and_the_slope_follows_the_gains():
    x, v, force = motion(2000, seed=4)
    twin = OnlineTwin(dataclasses.replace(LearnParams(), online=False), STATIC, SLOPE, DT)
    for f, a, b in zip(force, x, v):
        twin.update(f, a, b, f + 100.0)
    assert twin.updates == 0 and tuple(twin.theta) == IDENTITY
    assert twin.slope() == SLOPE
    twin.theta[:] = (0.0, 1.2, 0.9, 500.0, 0.0, 0.0)
    assert twin.slope() == pytest.approx(1.2 * SLOPE + 500.0)
    assert set(twin.terms()) == {name for name, _ in TERMS}
