"""The joint fit's Jacobian (``damper_emulator.diagnose.joint._Jacobian``): forward
differences, Broyden's secant update in between, and a bounded fit that still reaches the
exact optimum of a problem whose solution is known in closed form."""

import numpy as np
from scipy.optimize import least_squares

from damper_emulator.diagnose import joint
from damper_emulator.diagnose.joint import DIFF_STEP, JACOBIAN_REFRESH, _Jacobian

T = np.linspace(0.0, 2.0, 400)
#: a sum of 4 decaying exponentials: 8 parameters in [0, 1] (amplitude, rate)
TRUE = np.array([0.8, 0.2, 0.6, 0.4, 0.3, 0.7, 0.5, 0.9])


def model(s):
    a, k = s[0::2], s[1::2]
    return (a[:, None] * np.exp(-(1.0 + 4.0 * k[:, None]) * T)).sum(axis=0)


def residual(s):
    return model(s) - model(TRUE)


def exact_jacobian(s):
    """d model / d s, by hand."""
    a, k = s[0::2], s[1::2]
    e = np.exp(-(1.0 + 4.0 * k[:, None]) * T)
    j = np.empty((T.size, s.size))
    j[:, 0::2] = e.T
    j[:, 1::2] = (-4.0 * T * a[:, None] * e).T
    return j


def assert_forward_difference(j, s):
    """Within a forward difference's truncation error (step DIFF_STEP) of the exact one."""
    np.testing.assert_allclose(j, exact_jacobian(s), atol=10 * DIFF_STEP)


def counted():
    calls = [0]

    def f(s):
        calls[0] += 1
        return residual(s)
    return f, calls


def test_fresh_jacobian_is_a_forward_difference_inside_the_bounds():
    points = []

    def f(s):
        points.append(s.copy())
        return residual(s)
    jac = _Jacobian(f)
    s = np.array([0.5, 0.5, 1.0, 0.2, 0.3, 0.999999, 0.1, 0.0])
    assert_forward_difference(jac.jac(s), s)
    assert len(points) == 1 + s.size
    assert np.all(np.array(points) >= 0.0) and np.all(np.array(points) <= 1.0)


def test_update_meets_the_secant_condition_and_costs_no_simulation():
    f, calls = counted()
    jac = _Jacobian(f)
    s0 = np.full(8, 0.5)
    jac.fun(s0)
    j0 = jac.jac(s0)
    s1 = s0 + np.linspace(-0.05, 0.05, 8)
    f1 = jac.fun(s1)
    before = calls[0]
    j1 = jac.jac(s1)
    assert calls[0] == before                           # Broyden: no new evaluation
    np.testing.assert_allclose(j1 @ (s1 - s0), f1 - residual(s0), rtol=1e-10, atol=1e-13)
    # a direction orthogonal to the step keeps the old slope (least change)
    d = np.zeros(8)
    d[0], d[1] = 1.0, -1.0
    d -= d @ (s1 - s0) / ((s1 - s0) @ (s1 - s0)) * (s1 - s0)
    np.testing.assert_allclose(j1 @ d, j0 @ d, rtol=1e-9, atol=1e-12)


def test_a_fresh_jacobian_every_refresh_calls_and_on_request():
    f, calls = counted()
    jac = _Jacobian(f)
    s = np.full(8, 0.5)
    fresh = []
    for k in range(2 * JACOBIAN_REFRESH):
        s = s + 0.01 * (k + 1) * np.linspace(-1.0, 1.0, 8) / 8
        jac.fun(s)
        before = calls[0]
        jac.jac(s)
        fresh.append(calls[0] - before == s.size)
    assert fresh == ([True] + [False] * (JACOBIAN_REFRESH - 1)) * 2
    before = calls[0]
    assert_forward_difference(jac.jac(s, fresh=True), s)
    assert calls[0] - before == s.size


def test_refused_point_takes_a_fresh_jacobian():
    calls = [0]

    def f(s):
        calls[0] += 1
        return np.full(T.size, joint.FAILED_COST) if s[0] > 0.9 else residual(s)
    jac = _Jacobian(f)
    s0 = np.full(8, 0.5)
    jac.fun(s0)
    jac.jac(s0)
    s1 = s0.copy()
    s1[0] = 0.95
    jac.fun(s1)
    before = calls[0]
    jac.jac(s1)
    assert calls[0] - before == s1.size


def test_bounded_fit_with_updates_reaches_the_exact_optimum():
    """Noise-free data: the optimum is the truth (residual zero), and the fit with
    Broyden's updates finds it with far fewer evaluations than one Jacobian per step."""
    f, calls = counted()
    jac = _Jacobian(f)
    s0 = np.array([0.6, 0.1, 0.5, 0.5, 0.4, 0.6, 0.6, 0.8])
    sol = least_squares(jac.fun, s0, jac=jac.jac, bounds=(0.0, 1.0), method="trf",
                        x_scale="jac", max_nfev=200, ftol=1e-15, xtol=1e-15, gtol=1e-15)
    assert np.sqrt(np.mean(sol.fun ** 2)) < 1e-6 * np.sqrt(np.mean(model(TRUE) ** 2))
    np.testing.assert_allclose(model(sol.x), model(TRUE), atol=1e-6)
    assert calls[0] < (sol.nfev + 1) * (s0.size + 1)
