"""Classical damper representations (docs/model.md §4): linear rate and '14-speed' table."""

import math

import numpy as np
import pytest

from damper_emulator.model.incompressible import incompressible_force
from damper_emulator.model.representations import (
    LinearDamper,
    TableDamper,
    fourteen_speed_damper,
    linear_best_fit,
    linear_from_model,
)

#: a digressive table with a steep low-speed part, like a real damper's
V = np.array([-1.5, -0.6, -0.1, -0.02, 0.0, 0.02, 0.1, 0.6, 1.5])
F = np.array([-3400.0, -1850.0, -1100.0, -700.0, -398.0, -40.0, 1500.0, 3300.0, 5000.0])


# --------------------------------------------------------------------------------------
# TableDamper


def test_table_reproduces_its_points_exactly():
    td = TableDamper(V, F)
    assert np.array_equal(td.force(V), F)
    assert td.force(0.1) == F[6] and isinstance(td.force(0.1), float)
    assert td.static_force_n == -398.0


def test_table_is_monotonic_between_points():
    td = TableDamper(V, F)
    vg = np.linspace(-3.0, 3.0, 20001)
    f = td.force(vg)
    assert np.all(np.diff(f) >= 0.0)
    inside = (vg >= V[0]) & (vg <= V[-1])
    assert f[inside].min() >= F[0] and f[inside].max() <= F[-1]  # no overshoot


def test_table_scalar_and_array_evaluation_agree():
    td = TableDamper(V, F)
    v = np.concatenate([np.linspace(-3.0, 3.0, 601), V])
    scalar = np.array([td.force(float(x)) for x in v])
    assert np.allclose(scalar, td.force(v), rtol=1e-12, atol=1e-9)
    lin = LinearDamper(1500.0, -398.0)
    assert np.allclose([lin.force(float(x)) for x in v], lin.force(v), rtol=1e-15)


def test_table_extrapolates_linearly_and_continuously():
    td = TableDamper(V, F)
    for end, out in ((V[-1], 1.0), (V[0], -1.0)):
        v = end + out * np.array([0.5, 1.0, 1.5])
        f = td.force(v)
        assert f[2] - f[1] == pytest.approx(f[1] - f[0], rel=1e-12)  # a straight line
        eps = 1e-7
        assert td.force(end + out * eps) == pytest.approx(td.force(end), abs=1e-3)
        slope_out = (td.force(end + out * 1e-4) - td.force(end)) / (out * 1e-4)
        slope_in = (td.force(end) - td.force(end - out * 1e-4)) / (out * 1e-4)
        assert slope_out == pytest.approx(slope_in, rel=1e-3)  # C¹ at the end node
        assert slope_out > 0


def test_table_from_branches_joins_through_static_force():
    vr, fr = V[5:], F[5:]
    vc, fc = V[:4], F[:4]
    td = TableDamper.from_branches(vr[::-1], fr[::-1], vc, fc, static_force_n=-398.0)
    assert np.array_equal(td.velocity_m_s, V) and np.array_equal(td.force_n, F)


@pytest.mark.parametrize(("v", "f", "match"), [
    ([0.0, 1.0, 0.5], [0.0, 1.0, 2.0], "not strictly increasing at point 2"),
    ([0.0, 1.0, 2.0], [0.0, 2.0, 1.0], "not monotonic at point 2"),
    ([0.0, math.nan], [0.0, 1.0], r"velocity\[1\] is nan"),
    ([0.0, 1.0], [0.0, math.inf], r"force\[1\] is inf"),
    ([0.0], [0.0], "at least 2 points"),
    ([0.0, 1.0], [0.0, 1.0, 2.0], "differ in length"),
])
def test_table_rejects_bad_tables(v, f, match):
    with pytest.raises(ValueError, match=match):
        TableDamper(v, f)


def test_table_rejects_bad_branches_and_velocities():
    with pytest.raises(ValueError, match="rebound velocities must be > 0"):
        TableDamper.from_branches([-0.1], [1.0], [-0.2], [-1.0], 0.0)
    with pytest.raises(ValueError, match="compression velocities must be < 0"):
        TableDamper.from_branches([0.1], [1.0], [0.2], [-1.0], 0.0)
    with pytest.raises(ValueError, match="not monotonic"):  # compression above static
        TableDamper.from_branches([0.1], [1.0], [-0.1], [5.0], 0.0)
    with pytest.raises(ValueError, match="must be finite"):
        TableDamper(V, F).force([0.0, math.nan])


# --------------------------------------------------------------------------------------
# linear


def test_linear_best_fit_recovers_the_rate():
    v = np.linspace(-1.2, 0.9, 37)
    assert linear_best_fit(v, 2500.0 * v) == pytest.approx(2500.0, rel=1e-12)
    assert linear_best_fit(v, -398.0 + 1800.0 * v, static_force_n=-398.0) == pytest.approx(
        1800.0, rel=1e-12)


def test_linear_damper_force_and_checks():
    d = LinearDamper(2000.0, -398.0)
    assert d.force(0.5) == pytest.approx(602.0)
    assert np.allclose(d.force(np.array([-1.0, 0.0])), [-2398.0, -398.0])
    with pytest.raises(ValueError, match=">= 0"):
        LinearDamper(-1.0)
    with pytest.raises(ValueError, match="finite"):
        LinearDamper(math.nan)
    with pytest.raises(ValueError, match="non-zero velocity"):
        linear_best_fit([0.0, 0.0], [1.0, 2.0])


def test_linear_from_model_is_the_least_squares_line(sport_cfg, sport_model):
    lin = linear_from_model(sport_model, 1.5)
    assert lin.static_force_n == pytest.approx(sport_cfg.damper.static_force_n, rel=1e-12)
    v = np.linspace(-1.5, 1.5, 201)
    f = incompressible_force(v, sport_cfg) - lin.static_force_n
    (rate,), *_ = np.linalg.lstsq(v[:, None], f, rcond=None)  # independent solver
    assert lin.rate_ns_m == pytest.approx(rate, rel=1e-9)
    assert 1000.0 < lin.rate_ns_m < 6000.0  # the sport damper's secant slopes span this


# --------------------------------------------------------------------------------------
# '14-speed' from the model


@pytest.fixture(scope="module")
def tables(sport_model):
    return {n: fourteen_speed_damper(sport_model, points=n) for n in (14, 28)}


#: Tolerance of the N-speed table against the incompressible curve at its nodes, relative
#: to the dynamic force |F_inc − F_static|.  The peak force of a 25 mm sine is not the
#: quasi-steady force at the peak velocity: the pressures lag (hysteresis, growing with
#: frequency) and the gas-spring force at the instant of the peak differs from the static
#: one.  Measured on the sport damper: at most 0.41 % (at the slowest point, 0.025 m/s,
#: where the gas-spring term weighs most), 0.04–0.2 % elsewhere.
NODE_TOLERANCE = 0.01


@pytest.mark.parametrize("points", [14, 28])
def test_fourteen_speed_table_matches_incompressible_curve_at_nodes(tables, sport_cfg,
                                                                    points):
    td = tables[points]
    v = td.velocity_m_s
    assert v.size == 2 * points + 1
    assert v[0] == pytest.approx(-1.5, rel=1e-3) and v[-1] == pytest.approx(1.5, rel=1e-3)
    static = sport_cfg.damper.static_force_n
    assert td.static_force_n == pytest.approx(static, rel=1e-12)
    nodes = v != 0.0
    f_inc = incompressible_force(v[nodes], sport_cfg)
    rel = np.abs(td.force_n[nodes] - f_inc) / np.abs(f_inc - static)
    assert rel.max() < NODE_TOLERANCE, rel.max()


def test_more_points_interpolate_better(tables, sport_cfg):
    """Between its nodes the 14-point table follows the curve less closely than the
    28-point one (the paper's reason for 28 points)."""
    v = tables[28].velocity_m_s[1::2]  # the 28-point nodes that are not 14-point nodes
    v = v[v != 0.0]
    f_inc = incompressible_force(v, sport_cfg)
    err14 = np.abs(tables[14].force(v) - f_inc).max()
    err28 = np.abs(tables[28].force(v) - f_inc).max()
    assert err28 < err14
