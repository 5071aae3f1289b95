"""The damper step in SIMD lanes (``damper_emulator.model.lanes``) against the one-design
step (``damper_emulator.model.step.step``), sample by sample: forces to 1e-9 of the
largest, the same fault bits, the same final state; over designs that differ in valves,
gas, friction, end stops, valve command (bypass open and closed) and table resolution,
through the paths a lane leaves the lanes by (invalid input, a long gap, a moving valve
command, a table too coarse for the polynomial, the velocity clamp).  And which designs
the lanes take."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from damper_emulator.diagnose.truth import EXAMPLE_EFFECTS, example_params
from damper_emulator.model import lanes, layout
from damper_emulator.model.compressible import DamperModel, DamperStepper
from damper_emulator.model.lanes import (
    L_CMD,
    L_FLAGS,
    L_FORCE,
    L_V,
    L_X,
    LANE_BUFFER,
    LANES,
    lane_compatible,
    lane_eligible,
    lane_tables,
    load_lanes,
    step_lanes,
    store_lanes,
)
from damper_emulator.model.step import step
from damper_emulator.model.valve_table import C_EXP, C_EXPM1, MAX_STEP, TABLE_COLUMNS
from damper_emulator.params import EXTENSION_TYPES, with_extensions
from ride_sim.dampers import CompressiblePlugin
from ride_sim.many import MIN_BLOCK, _lane_designs, _stack_tables, simulate_many
from ride_sim.params import load_ride_config
from ride_sim.quarter_car import simulate
from ride_sim.road_synthesis import random_road
from ride_sim.study_runs import start_state

RTOL = 1e-9
DT = 1e-3
SAMPLES = 2500
#: where the inputs take the lanes' exits: a NaN stroke for one design, a gap longer than
#: the settle time for all, a valve command that starts moving for one design
NAN_AT, GAP_AT, COMMAND_AT = 400, 900, 1300


def _designs(cfg, max_iterations=None):
    """2 × LANES designs: valves ×0.5…×2, gas, friction, end stops, a coarse table, the
    bypass open at command 0.3 on some; ``max_iterations``: every design's Newton cap."""
    rng = np.random.default_rng(7)
    if max_iterations is not None:
        cfg = dataclasses.replace(cfg, numerics=dataclasses.replace(
            cfg.numerics, newton_max_iterations=max_iterations))
    d = cfg.damper
    out = []
    for k in range(2 * LANES):
        f = 2.0 ** rng.uniform(-1.0, 1.0, 8)
        reb = dataclasses.replace(d.rebound, k_leak=d.rebound.k_leak * f[0],
                                  k_port=d.rebound.k_port * f[1],
                                  k_spring=d.rebound.k_spring * f[2],
                                  preload_pa=d.rebound.preload_pa * f[3])
        com = dataclasses.replace(d.compression, k_leak=d.compression.k_leak * f[4],
                                  k_port=d.compression.k_port * f[5],
                                  k_spring=d.compression.k_spring * f[6],
                                  preload_pa=d.compression.preload_pa * f[7])
        c = dataclasses.replace(cfg, damper=dataclasses.replace(
            d, rebound=reb, compression=com, friction_force_n=20.0 + 4.0 * k,
            gas_pressure_static_pa=d.gas_pressure_static_pa * (0.8 + 0.02 * k)))
        if k == 3:
            c = with_extensions(c, {"end_stops": EXAMPLE_EFFECTS["end_stops"]["params"]})
        if k == 5:  # a table too coarse for the polynomial: the one-design look-up
            c = dataclasses.replace(c, numerics=dataclasses.replace(
                c.numerics, valve_table_points=16))
        if k == 6:  # the velocity clamp
            c = dataclasses.replace(c, numerics=dataclasses.replace(
                c.numerics, valve_table_max_velocity_m_s=0.8))
        if k == 7:  # a small gas volume: beyond the gas law's series (the library's power)
            c = dataclasses.replace(c, damper=dataclasses.replace(
                c.damper, gas_volume_static_m3=4e-6))
        out.append(DamperStepper(DamperModel(c), valve_command=0.3 if k % 4 == 1 else 1.0))
    return out


def _inputs(n_designs):
    rng = np.random.default_rng(11)
    t = np.arange(SAMPLES) * DT
    x = np.zeros((n_designs, SAMPLES))
    v = np.zeros((n_designs, SAMPLES))
    for j in range(n_designs):
        for _ in range(3):
            a, f, ph = rng.uniform(0.003, 0.02), rng.uniform(0.5, 12.0), rng.uniform(0, 6.3)
            x[j] += a * np.sin(2 * np.pi * f * t + ph)
            v[j] += a * 2 * np.pi * f * np.cos(2 * np.pi * f * t + ph)
    x[7] *= 2.2  # design 7 (the small gas volume) beyond the gas law's series both ways,
    v[7] *= 2.2  # inside the travel
    x[2, NAN_AT] = np.nan
    return x, v


@pytest.mark.slow
@pytest.mark.parametrize("max_iterations", [None, 4])
def test_the_lanes_step_as_the_one_design_step(sport_cfg, max_iterations):
    """``max_iterations`` 4 (the least allowed): some solves stop at the cap (the SOLVER
    fault)."""
    steppers = _designs(sport_cfg, max_iterations)
    n = len(steppers)
    prm = np.stack([s.model.prm for s in steppers])
    assert lane_eligible(prm).all() and lane_compatible(prm)
    coef_r, n_r = _stack_tables([s.model.tables[0].coef for s in steppers])
    coef_c, n_c = _stack_tables([s.model.tables[1].coef for s in steppers])
    sides = lane_tables(coef_r, coef_c)
    x, v = _inputs(n)
    ref_state = [s.state.copy() for s in steppers]
    dstate = np.stack([s.state.copy() for s in steppers])
    lv = np.zeros((n // LANES, LANE_BUFFER))
    for first in range(0, n, LANES):
        load_lanes(prm, n_r, n_c, dstate, first, lv[first // LANES])
    f_ref = np.zeros((n, SAMPLES))
    fl_ref = np.zeros((n, SAMPLES), dtype=np.int64)
    f_lanes = np.zeros((n, SAMPLES))
    fl_lanes = np.zeros((n, SAMPLES), dtype=np.int64)
    for k in range(1, SAMPLES):
        dt = 0.3 if k == GAP_AT else DT
        if k == COMMAND_AT:  # design 9's command starts moving (the solenoid's lag)
            ref_state[9][layout.S_CMD] = 0.0
            lv[9 // LANES, L_CMD * LANES + 9 % LANES] = 0.0
        for j, s in enumerate(steppers):
            f_ref[j, k], fl_ref[j, k] = step(s.model.prm, s.model.tables[0].coef,
                                             s.model.tables[1].coef, ref_state[j], x[j, k],
                                             v[j, k], dt)
        for first in range(0, n, LANES):
            buf = lv[first // LANES]
            buf[L_X * LANES:(L_X + 1) * LANES] = x[first:first + LANES, k]
            buf[L_V * LANES:(L_V + 1) * LANES] = v[first:first + LANES, k]
            step_lanes(prm, coef_r, n_r, coef_c, n_c, sides, dstate, first, dt, buf)
            f_lanes[first:first + LANES, k] = buf[L_FORCE * LANES:(L_FORCE + 1) * LANES]
            fl_lanes[first:first + LANES, k] = buf[L_FLAGS * LANES:(L_FLAGS + 1) * LANES]
    for first in range(0, n, LANES):
        store_lanes(dstate, first, lv[first // LANES])
    for j in range(n):  # to 1e-9 of each design's own largest force
        np.testing.assert_allclose(f_lanes[j], f_ref[j], rtol=0.0,
                                   atol=RTOL * np.abs(f_ref[j]).max(), err_msg=f"design {j}")
    np.testing.assert_array_equal(fl_lanes, fl_ref)
    np.testing.assert_allclose(dstate, np.stack(ref_state), rtol=1e-9, atol=1e-12)
    # every exit was taken: the invalid input, the velocity clamp, the solver's look-up
    # on the coarse table (no fault), and the moving command (the bypass's area changes)
    assert fl_ref[2, NAN_AT] == int(layout.Fault.INVALID_INPUT)
    assert np.any(fl_ref[6] & int(layout.Fault.VELOCITY_CLAMPED))
    assert dstate[9, layout.S_CMD_EFF] < 0.01
    assert steppers[5].model.prm[layout.P_STEP_R] > MAX_STEP
    p7 = steppers[7].model.prm
    ratio = p7[layout.V_GAS] / (p7[layout.V_GAS] + p7[layout.P_A_ROD] * np.nan_to_num(x[7]))
    assert ratio.min() < 0.6 and ratio.max() > 5.0 / 3.0  # both sides of the series' domain
    assert x[7].min() > p7[layout.P_X_MIN]
    # faults of solves the lanes ran (not the coarse table's, not the moving command's)
    in_lanes = [j for j in range(n) if j not in (5, 9)]
    assert np.any(fl_ref[in_lanes] & int(layout.Fault.VALVE_EXTRAPOLATED))
    assert bool(np.any(fl_ref[in_lanes] & int(layout.Fault.SOLVER))) is (max_iterations == 4)
    # the designs differ
    assert np.std(f_ref[:, 1:], axis=0).max() > 0.1 * np.abs(f_ref).max()


@pytest.mark.parametrize("name", list(EXTENSION_TYPES))
def test_which_designs_the_lanes_take(sport_cfg, name):
    with_one = DamperModel(with_extensions(sport_cfg, {name: example_params(name)}))
    # end stops act in the force alone (eq 4's sum), which the lanes evaluate with the
    # one-design formula; every other extension acts inside the sub-steps
    assert bool(lane_eligible(with_one.prm)[0]) is (name == "end_stops")
    assert lane_eligible(DamperModel(sport_cfg).prm)[0]


def test_designs_of_different_numerics_do_not_share_lanes(sport_cfg):
    fine = dataclasses.replace(sport_cfg, numerics=dataclasses.replace(
        sport_cfg.numerics, max_substep_s=2.5e-4))
    prm = np.stack([DamperModel(sport_cfg).prm, DamperModel(fine).prm])
    assert not lane_compatible(prm)
    assert lane_compatible(prm[:1])


@pytest.mark.slow
def test_all_in_lanes_against_the_single_design_path(sport_cfg):
    """Designs that all run in lanes (a block and a filled-up one: the branch ``tune``
    takes), each against ``ride_sim.quarter_car.simulate`` of its own."""
    rc = load_ride_config()
    road = rc.road
    heights = random_road(road.roughness, road.waviness, 40.0,
                          band_cycles_per_m=(0.025, 0.8), spacing_m=20.0 * DT,
                          seed=8).height_m
    models = [s.model for s in _designs(sport_cfg)[:LANES + MIN_BLOCK]]
    assert _lane_designs(np.stack([m.prm for m in models])).size == len(models)
    start = start_state(heights, DT)
    many = simulate_many(rc.quarter_car, models, heights, DT, initial_state=start)
    for j, m in enumerate(models):
        one = simulate(rc.quarter_car, CompressiblePlugin(m), heights, DT,
                       initial_state=start)
        for a, b in ((many.sws_m[j], one.sws_m), (many.body_accel_m_s2[j],
                                                   one.body_accel_m_s2),
                     (many.dtl_n[j], one.dtl_n)):
            np.testing.assert_allclose(a, b, rtol=0.0, atol=RTOL * np.abs(b).max())
        assert many.faults[j] == int(np.bitwise_or.reduce(one.faults))


def test_simulate_many_in_lanes_and_one_by_one(sport_cfg):
    """More designs than a block of lanes (the last block filled up), with and without
    the lanes, and one design with an extension among them (one by one either way)."""
    rc = load_ride_config()
    road = rc.road
    heights = random_road(road.roughness, road.waviness, 60.0,
                          band_cycles_per_m=(0.02, 0.8), spacing_m=20.0 * DT,
                          seed=5).height_m
    # one block, a second of 9 (filled up with copies) and one design with an extension
    # (one by one)
    models = [s.model for s in _designs(sport_cfg)[:LANES + MIN_BLOCK + 1]]
    models.append(DamperModel(with_extensions(sport_cfg, {"valve_lag": {
        "time_constant_s": 3e-3}})))
    in_lanes = _lane_designs(np.stack([m.prm for m in models]))
    np.testing.assert_array_equal(in_lanes, np.arange(LANES + MIN_BLOCK + 1))
    # a last block of fewer than MIN_BLOCK runs one by one
    prm = np.stack([m.prm for m in models[:LANES + MIN_BLOCK - 1]])
    np.testing.assert_array_equal(_lane_designs(prm), np.arange(LANES))
    a = simulate_many(rc.quarter_car, models, heights, DT)
    b = simulate_many(rc.quarter_car, models, heights, DT, lanes=False)
    for name in ("sws_m", "body_accel_m_s2", "dtl_n"):
        x, y = getattr(a, name), getattr(b, name)
        np.testing.assert_allclose(x, y, rtol=0.0, atol=RTOL * np.abs(y).max())
    np.testing.assert_array_equal(a.faults, b.faults)


def test_the_gather_clamps_each_lanes_row_into_the_table():
    """Every lane's row is loaded without a test on the lane (:func:`lanes._gather`): an
    index beyond the table, negative or NaN (a lane whose look-up is not used) reads a row
    inside it; the tables' sides side by side (:func:`lane_tables`), padded to the longer."""
    n, rows_r, rows_c = LANES, 5, 3
    coef_r = np.zeros((n, rows_r, TABLE_COLUMNS))
    coef_c = np.zeros((n, rows_c, TABLE_COLUMNS))
    for j in range(n):  # each entry says where it is: design, side, row, column
        for i in range(rows_r):
            coef_r[j, i] = 1000 * j + 10 * i + np.arange(TABLE_COLUMNS)
        for i in range(rows_c):
            coef_c[j, i] = 1000 * j + 500 + 10 * i + np.arange(TABLE_COLUMNS)
    sides = lane_tables(coef_r, coef_c)
    assert sides.shape == (n, 2, rows_r, TABLE_COLUMNS)
    assert not sides[:, 1, rows_c:].any()  # the shorter side zero-padded
    idx = [0, 2, 4, 7, -3, np.nan, np.inf, 1e300, 0, 1, 2, 3, -1, np.nan, 9, 1]
    sign = [1.0] * 8 + [-1.0] * 8
    lv = np.zeros(LANE_BUFFER)
    lv[lanes.L_IDX * LANES:(lanes.L_IDX + 1) * LANES] = idx
    lv[lanes.L_SIGN * LANES:(lanes.L_SIGN + 1) * LANES] = sign
    prm = np.zeros((n, layout.P_SIZE))
    n_r = np.full(n, rows_r, dtype=np.int64)
    n_c = np.full(n, rows_c, dtype=np.int64)
    lanes._gather(prm, coef_r, n_r, coef_c, n_c, sides, 0, lv)
    for b in range(n):
        last = rows_r - 1 if sign[b] > 0 else sides.shape[2] - 1
        i = 0 if not idx[b] > 0 else int(min(idx[b], last))
        expected = sides[b, 0 if sign[b] > 0 else 1, i]
        got = [lv[q * LANES + b] for q in (lanes.L_C3, lanes.L_C2, lanes.L_C1, lanes.L_C0,
                                            lanes.L_CE, lanes.L_CM)]
        np.testing.assert_array_equal(got, expected[[0, 1, 2, 3, C_EXP, C_EXPM1]],
                                      err_msg=f"lane {b}")


def test_the_extrapolated_bit_from_any_sub_step_of_the_sample():
    """A look-up beyond the table in the first sub-step and not the second still sets the
    lane's fault bit; a skipped lane's bits are the one-design step's."""
    lv = np.zeros(LANE_BUFFER)
    extrap = slice(lanes.L_EXTRAP * LANES, (lanes.L_EXTRAP + 1) * LANES)
    lv[extrap] = 1.0  # the sample before's
    lanes._inputs(1e-3, lv)  # a new sample: reset
    assert not lv[extrap].any()
    lv[lanes.L_SKIP * LANES:(lanes.L_SKIP + 1) * LANES] = 0.0
    lv[lanes.L_SKIP * LANES + 4] = 1.0  # took the one-design step this sample
    lv[lanes.L_FLAGS * LANES:(lanes.L_FLAGS + 1) * LANES] = 0.0
    lv[lanes.L_FLAGS * LANES + 4] = float(layout.Fault.STROKE_CLAMPED)
    lv[lanes.L_BEYOND * LANES + 3] = 1.0
    lv[lanes.L_BEYOND * LANES + 4] = 1.0
    lanes._substep_end(5e-4, lv)
    lv[lanes.L_BEYOND * LANES:(lanes.L_BEYOND + 1) * LANES] = 0.0
    lanes._substep_end(5e-4, lv)
    lanes._extrapolated(lv)
    flags = lv[lanes.L_FLAGS * LANES:(lanes.L_FLAGS + 1) * LANES].astype(np.int64)
    assert flags[3] == int(layout.Fault.VALVE_EXTRAPOLATED)
    assert flags[4] == int(layout.Fault.STROKE_CLAMPED)
    assert not np.delete(flags, [3, 4]).any()
