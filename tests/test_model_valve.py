"""Valve characteristic (eqs 8–29, 40–47) against independent references.

References are written here from the paper's equations, not taken from the code: an exact
root solve of eq 19 by scipy's brentq, Taylor coefficients by numerical differentiation of
eq 19, the slope H1 by numerical differentiation of eq 27.
"""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import brentq

from damper_emulator.model import valve as V
from damper_emulator.params import valve_tables

NU = 21e-6  # docs/model.md §2.3


def _eq19(q_leak, valve):
    """Eq 19 written out: total flow of the open valve for a given leak flow."""
    k_leak, _, k_spring, dp0, _ = valve
    dp_leak = k_leak * NU ** 0.25 * q_leak ** 1.75
    return q_leak + (dp_leak - dp0) * np.sqrt(dp_leak) / k_spring


def _b0(valve):
    k_leak, _, _, dp0, _ = valve
    return (dp0 / (k_leak * NU ** 0.25)) ** (4 / 7)  # eq 23


def _exact_leak(q_tot, valve):
    b0 = _b0(valve)
    if q_tot <= b0 * (1 + 1e-12):
        return q_tot  # at the blow-off point Q_leak = Q_tot
    return brentq(lambda ql: _eq19(ql, valve) - q_tot, b0, q_tot, xtol=1e-22, rtol=1e-15)


def _exact_open_dp(q_tot, valve):
    k_leak, k_port = valve[0], valve[1]
    return NU ** 0.25 * (k_leak * _exact_leak(q_tot, valve) ** 1.75 + k_port * q_tot ** 1.75)


@pytest.fixture(params=["rebound", "compression"])
def valve(request, sport_cfg):
    return tuple(getattr(sport_cfg.damper, request.param))


def test_cardano_matches_exact_root_of_eq19(valve):
    b0 = _b0(valve)
    coeffs = V.blow_off_coefficients(valve[0], valve[2], valve[3], NU)
    q = np.linspace(b0, 2e-3, 400)[1:]
    leak_c = np.array([V.leak_flow_cardano(qq, *coeffs) for qq in q])
    leak_x = np.array([_exact_leak(qq, valve) for qq in q])
    assert np.max(np.abs(leak_c / leak_x - 1)) < 5e-3
    dp_c = np.array([V.pressure_drop_open(qq, *valve[:4], NU, V.FORM_CARDANO) for qq in q])
    dp_x = np.array([_exact_open_dp(qq, valve) for qq in q])
    assert np.max(np.abs(dp_c / dp_x - 1)) < 5e-3
    # the code's own exact form agrees with brentq to solver precision
    dp_e = np.array([V.pressure_drop_open(qq, *valve[:4], NU, V.FORM_EXACT) for qq in q])
    np.testing.assert_allclose(dp_e, dp_x, rtol=1e-9)


def test_cardano_is_exact_at_blow_off(valve):
    b0 = _b0(valve)
    coeffs = V.blow_off_coefficients(valve[0], valve[2], valve[3], NU)
    assert V.leak_flow_cardano(b0, *coeffs) == pytest.approx(b0, rel=1e-9)


def test_taylor_coefficients_equal_closed_forms_and_derivatives(valve):
    k_leak, _, k_spring, dp0, _ = valve
    b0, b1, b2, b3 = V.blow_off_coefficients(k_leak, k_spring, dp0, NU)
    assert b0 == pytest.approx(_b0(valve), rel=1e-14)
    assert _eq19(b0, valve) == pytest.approx(b0, rel=1e-12)  # blow-off flow is zero at B0
    c = dp0 ** 1.5 / k_spring
    assert b1 == pytest.approx(1 + 7 * c / (4 * b0), rel=1e-14)  # eq 41
    assert b2 == pytest.approx(35 * c / (16 * b0 ** 2), rel=1e-14)  # eq 42
    assert b3 == pytest.approx(217 * c / (512 * b0 ** 3), rel=1e-14)  # eq 43
    # and they are the Taylor coefficients of eq 19: central differences about B0
    h = 1e-2 * b0
    f = [_eq19(b0 + k * h, valve) for k in (-2, -1, 0, 1, 2)]
    d1 = (f[3] - f[1]) / (2 * h)
    d2 = (f[3] - 2 * f[2] + f[1]) / h ** 2
    d3 = (f[4] - 2 * f[3] + 2 * f[1] - f[0]) / (2 * h ** 3)
    assert d1 == pytest.approx(b1, rel=1e-3)
    assert d2 / 2 == pytest.approx(b2, rel=1e-3)
    assert d3 / 6 == pytest.approx(b3, rel=2e-2)


def test_linear_extension_h0_h1(valve):
    k_leak, k_port, k_spring, dp0, _ = valve
    b0, b1, _, _ = V.blow_off_coefficients(k_leak, k_spring, dp0, NU)
    h0 = b0 ** 1.75 * NU ** 0.25 * (k_leak + k_port)  # eq 47
    h1 = 1.75 * NU ** 0.25 * b0 ** 0.75 * (k_leak / b1 + k_port)  # docs/model.md §2.2 (eq 48)
    assert V.pressure_drop_open(b0, *valve[:4], NU, V.FORM_EXACT) == pytest.approx(h0, rel=1e-9)
    assert V.pressure_drop_closed(b0, k_leak, k_port, NU) == pytest.approx(h0, rel=1e-12)
    below = V.pressure_drop_open(0.5 * b0, *valve[:4], NU, V.FORM_CARDANO)
    assert below == pytest.approx(h0 - 0.5 * b0 * h1, rel=1e-12)
    # H1 is the slope of the exact eq 27 at the blow-off point (one-sided differences)
    h = 1e-6 * b0
    slope = (-3 * _exact_open_dp(b0, valve) + 4 * _exact_open_dp(b0 + h, valve)
             - _exact_open_dp(b0 + 2 * h, valve)) / (2 * h)
    assert slope == pytest.approx(h1, rel=1e-4)


def test_smoothing_eq28_limits():
    g = 1.5
    assert V.smooth_transition(1e6, 1.0, g) == pytest.approx(1.0, rel=1e-8)
    assert V.smooth_transition(1.0, 1e6, g) == pytest.approx(1.0, rel=1e-8)
    assert V.smooth_transition(2.0, 2.0, g) == pytest.approx(2.0 / 2 ** (1 / g), rel=1e-14)


@pytest.mark.parametrize("form", V.VALVE_FORMS)
def test_the_analytic_gradient_is_the_complex_step_derivative(valve, form):
    """pressure_drop_gradient (chain rule, implicit-function theorem for the leak flow)
    against the complex-step derivative of pressure_drop itself, below and above the
    blow-off flow, for the sport valves and valves scaled ×1/8 … ×8 (other cubic roots,
    blow-off at other flows), and so the Jacobian the valve fits take; the value is
    pressure_drop's own (to its last bits: the fast-math compiler contracts and reorders
    the arithmetic differently in each kernel it is inlined into)."""
    code = V.form_code(form)
    rng = np.random.default_rng(7)
    valves = [valve] + [tuple(np.array(valve) * np.r_[2.0 ** rng.uniform(-3, 3, 4), 1.0])
                        for _ in range(6)]
    for v in valves:
        b0 = _b0(v)
        q = np.concatenate((np.geomspace(1e-3 * b0, 0.999 * b0, 15),
                            np.geomspace(1.001 * b0, 2e-3, 25)))
        grad = np.array([V.pressure_drop_gradient(x, *v, NU, code) for x in q])
        np.testing.assert_allclose(grad[:, 0], V.pressure_drop_array(q, v, NU, form),
                                   rtol=1e-14)
        cs = np.empty((q.size, 5))
        for j in range(5):
            h = V.COMPLEX_STEP * v[j]
            p = [complex(x) for x in v]
            p[j] += 1j * h
            cs[:, j] = [V.pressure_drop(complex(x), *p, NU, code).imag / h for x in q]
        # each column to 1e-9 of its largest entry: the complex step of eq 22's Cardano
        # form loses digits to cancellation at large flows (3.1e-10 here, at 43 B0, where
        # a 50-digit evaluation agreed with the analytic value to 2e-13); elsewhere 1e-13
        # (the Jacobian loop's inlined copy of the gradient differed from the gradient
        # called alone by up to 7e-13 of an entry in a fresh compile: both are
        # held to the complex step, not to each other bit for bit)
        for jac in (grad[:, 1:], V.pressure_drop_jacobian(q, v, NU, form)):
            err = np.abs(jac - cs).max(axis=0) / np.abs(cs).max(axis=0)
            assert np.all(err < 1e-9), err


@pytest.mark.parametrize("form", V.VALVE_FORMS)
def test_smoothed_curve_continuous_and_strictly_increasing(valve, form):
    b0 = _b0(valve)
    near_b0 = b0 * (1 + np.linspace(-1e-6, 1e-6, 11))
    q = np.sort(np.concatenate((np.linspace(0, 2e-3, 20001), near_b0)))
    dp = V.pressure_drop_array(q, valve, NU, form)
    assert dp[0] == 0.0
    assert np.all(np.diff(dp) > 0)
    # continuity across the blow-off point: the jump over ±1e-9 B0 is that of a smooth curve
    step = V.pressure_drop_array(np.array([b0 * (1 - 1e-9), b0 * (1 + 1e-9)]), valve, NU, form)
    assert abs(step[1] - step[0]) < 1e-6 * step[0]


def test_inverse_table_round_trip(sport_cfg):
    rng = np.random.default_rng(1)
    d = sport_cfg.damper
    for side, table in zip(("rebound", "compression"), valve_tables(sport_cfg)):
        dp = np.exp(rng.uniform(np.log(1.0), np.log(table.max_pressure_drop_pa), 5000))
        q = table.flow(dp)
        back = V.pressure_drop_array(q, getattr(d, side), d.oil_kinematic_viscosity_m2_s)
        assert np.max(np.abs(back / dp - 1)) < 1e-3, side
        assert np.all(np.diff(table.flow(np.sort(dp))) > 0)


@pytest.mark.parametrize("points", [1024, 16])
def test_valve_point_is_the_exact_pressure_drop_and_the_table_flow(sport_cfg, points):
    """The step's one look-up (``valve_point``: Δp from the node's stored e^z and a Taylor
    polynomial of the offset, Q from the cubic) against ``Δp_s (e^z − 1)^(7/4)`` with
    numpy's expm1 and against ``table_flow``: at every node, mid-interval, next to each
    node and beyond the table, on the default table and on a 16-node one (whose steps are
    too coarse for the polynomial: the library's expm1)."""
    from damper_emulator.model.valve_table import table_flow, valve_point

    cfg = dataclasses.replace(sport_cfg, numerics=dataclasses.replace(
        sport_cfg.numerics, valve_table_points=points))
    for table in valve_tables(cfg):
        n = table.coef.shape[0]
        nodes = table.step * np.arange(n + 1)
        z = np.concatenate([nodes, nodes[:-1] + 0.5 * table.step,
                            nodes[1:] * (1 - 1e-12), [1.5 * table.z_max, 1e-9]])
        for zi in z:
            dp, ddp, q, dq, beyond = valve_point(table.coef, table.step, table.scale_pa, zi)
            u = np.expm1(zi)
            assert dp == pytest.approx(table.scale_pa * u ** 1.75, rel=1e-13, abs=1e-300)
            assert ddp == pytest.approx(table.scale_pa * 1.75 * u ** 0.75 * (u + 1.0),
                                        rel=1e-13, abs=1e-300)
            assert (q, dq, beyond) == table_flow(table.coef, table.step, zi)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.floats(1e-6, 10.0), st.floats(-1e3, 1e3)), min_size=2,
                max_size=40),
       st.floats(-5.0, 5.0), st.integers(0, 3))
def test_pchip_coefficients_are_scipys_bit_for_bit(steps, x0, flats):
    """The valve tables' own PCHIP (no scipy import at a model's build) gives
    ``PchipInterpolator(x, y).c.T`` exactly: on uneven nodes, with sign changes, flat
    stretches (repeated values) and monotone runs."""
    from scipy.interpolate import PchipInterpolator

    from damper_emulator.model.pchip import pchip_coefficients

    x = x0 + np.cumsum([0.0, *(h for h, _ in steps)])
    y = np.cumsum([0.0, *(dy for _, dy in steps)])
    y[1:1 + flats] = y[0]                                   # a flat start
    got = pchip_coefficients(x, y)
    expected = PchipInterpolator(x, y).c.T
    assert got.shape == expected.shape
    assert np.array_equal(got, expected), np.max(np.abs(got - expected))



@pytest.mark.parametrize("velocity", [5e-324, 1e-320])
def test_a_table_velocity_too_small_to_tabulate_is_one_line(sport_cfg, velocity):
    """A positive but subnormal largest velocity passes the parameter's rule; the table's
    monotonicity check then had geometric flows from zero (numpy's ValueError, a
    traceback: found by the parameter fuzzing)."""
    from damper_emulator.model.valve_table import ValveTableError

    cfg = dataclasses.replace(sport_cfg, numerics=dataclasses.replace(
        sport_cfg.numerics, valve_table_max_velocity_m_s=velocity))
    with pytest.raises(ValveTableError, match="too small to tabulate") as err:
        valve_tables(cfg)
    assert "\n" not in str(err.value)
