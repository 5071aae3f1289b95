"""The many-design kernel (``ride_sim.many``) against the single-design path
(``ride_sim.quarter_car.simulate`` with the compressible plug-in): every design's
histories agree to 1e-9 relative, for designs that differ in valves, gas, friction and
extensions, on a rough road at the ride's sample rate; plus one closed-form limit of the
shared vehicle update."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from damper_emulator.errors import UserError
from damper_emulator.model.compressible import DamperModel
from damper_emulator.params import with_extensions
from ride_sim.dampers import CompressiblePlugin
from ride_sim.many import simulate_many
from ride_sim.params import load_ride_config
from ride_sim.quarter_car import simulate
from ride_sim.road_synthesis import random_road
from ride_sim.study_runs import pothole_input, start_state

#: the agreement the batch path must keep with the single path (relative)
RTOL = 1e-9


def _designs(cfg):
    d = cfg.damper
    soft = dataclasses.replace(d.rebound, preload_pa=0.6 * d.rebound.preload_pa,
                               k_spring=0.7 * d.rebound.k_spring)
    firm = dataclasses.replace(d.compression, k_port=2.0 * d.compression.k_port,
                               preload_pa=1.5 * d.compression.preload_pa)
    return [
        cfg,
        dataclasses.replace(cfg, damper=dataclasses.replace(d, rebound=soft)),
        dataclasses.replace(cfg, damper=dataclasses.replace(d, compression=firm,
                                                            friction_force_n=60.0)),
        dataclasses.replace(cfg, damper=dataclasses.replace(d, gas_pressure_static_pa=1.8e6)),
        with_extensions(cfg, {"valve_lag": {"time_constant_s": 3e-3}}),
    ]


@pytest.fixture(scope="module")
def ride():
    rc = load_ride_config()
    dt = rc.simulation.step_s
    road = rc.road
    heights = random_road(road.roughness, road.waviness, 100.0,
                          band_cycles_per_m=road.band_cycles_per_m, spacing_m=20.0 * dt,
                          seed=3).height_m
    return rc.quarter_car, heights, dt, rc.road


def test_every_design_agrees_with_the_single_design_path(sport_cfg, ride):
    car, heights, dt, _ = ride
    models = [DamperModel(c) for c in _designs(sport_cfg)]
    start = start_state(heights, dt)  # moving with the road, as the studies start
    many = simulate_many(car, models, heights, dt, initial_state=start)
    assert many.sws_m.shape == (len(models), heights.size)
    for j, m in enumerate(models):
        one = simulate(car, CompressiblePlugin(m), heights, dt, initial_state=start)
        for a, b in ((many.sws_m[j], one.sws_m), (many.body_accel_m_s2[j],
                                                   one.body_accel_m_s2),
                     (many.dtl_n[j], one.dtl_n)):
            scale = np.max(np.abs(b))
            assert scale > 0
            np.testing.assert_allclose(a, b, rtol=0.0, atol=RTOL * scale)
        assert many.faults[j] == int(np.bitwise_or.reduce(one.faults))
    # the designs differ: the batch does not copy one design into every row
    assert np.std(many.body_accel_m_s2, axis=0).max() > 0.05 * np.abs(
        many.body_accel_m_s2).max()


def test_the_order_of_the_designs_does_not_matter(sport_cfg, ride):
    car, heights, dt, _ = ride
    models = [DamperModel(c) for c in _designs(sport_cfg)]
    a = simulate_many(car, models, heights[:3000], dt)
    b = simulate_many(car, models[::-1], heights[:3000], dt)
    np.testing.assert_array_equal(a.dtl_n, b.dtl_n[::-1])


@pytest.mark.slow
def test_a_pothole_and_at_rest(sport_cfg, ride):
    car, _, dt, road = ride
    model = DamperModel(sport_cfg)
    # on a flat road every design stays at static equilibrium: exactly zero outputs
    flat = simulate_many(car, [model, model], np.zeros(500), dt)
    assert np.all(flat.sws_m == 0.0) and np.all(flat.dtl_n == 0.0)
    hole = pothole_input(road, road.pothole_speed_m_s, dt)[2]
    many = simulate_many(car, [model], hole, dt)
    one = simulate(car, CompressiblePlugin(model), hole, dt)
    np.testing.assert_allclose(many.sws_m[0], one.sws_m, rtol=0, atol=RTOL * np.abs(
        one.sws_m).max())


def test_bad_road_is_a_user_error(sport_cfg, ride):
    car, _, dt, _ = ride
    with pytest.raises(UserError, match="sample 2"):
        simulate_many(car, [DamperModel(sport_cfg)], [0.0, 0.0, np.nan], dt)
