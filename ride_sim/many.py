"""Many quarter cars with compressible dampers at once, on one road (virtual
tuning runs thousands of valve designs over the same roads).

:func:`simulate_many` advances ``D`` designs together on structure-of-arrays state (the
designs' parameter vectors, valve tables and stepper states are rows of 2-D arrays, their
car states the rows of a ``(D, 4)`` array), sharing the road and the vehicle's
discretisation matrix.  Two loops, chosen per design:

* **In SIMD lanes** (:func:`_loop_lanes`), the designs without a model extension
  (:func:`damper_emulator.model.lanes.lane_eligible`): blocks of
  :data:`~damper_emulator.model.lanes.LANES` designs over the whole road, the damper step
  of a block's designs in one call of :func:`damper_emulator.model.lanes.step_lanes`
  (its Newton solves in lockstep, their arithmetic vectorised), then each design's
  vehicle update.
* **One by one** (:func:`_loop_many`), the others: blocks of :data:`BLOCK` designs over
  the whole road, each design's sample the compiled one-design step
  (:func:`damper_emulator.model.step.step`).

Both use the same equations as :func:`ride_sim.quarter_car.simulate` (the damper step's
formulas, the exact vehicle update and the output formulas of :mod:`ride_sim.quarter_car`);
there is no second copy of the physics.  The one-by-one loop agrees with the single-design
path to the last bit, the lanes to rounding (tested to 1e-9 relative;
benchmarks/many_bench.py measures both).

Memory: three histories (SWS, body acceleration, DTL) of ``D × n`` doubles; a caller with
many designs runs them in chunks (``tune`` runs one chunk per Dask task).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from damper_emulator.model.compressible import DamperModel
from damper_emulator.model.jit import inlined_kernel, kernel
from damper_emulator.model.lanes import (
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
from damper_emulator.model.step import step as _compressible_step
from damper_emulator.model.valve_table import TABLE_COLUMNS
from ride_sim.dampers import CompressiblePlugin
from ride_sim.params import QuarterCarParams
from ride_sim.quarter_car import (
    Q_DT,
    Q_FSTATIC,
    Q_MR,
    QuarterCar,
    advance_state,
    road_array,
    road_pair,
    state_motion,
    state_outputs,
    wheel_force,
)

_Vec = NDArray[np.float64]
#: Designs advanced together over the whole road, one block after another: a sample of
#: every design at once touches each design's parameters, state and valve-table rows, and
#: beyond a few dozen designs those no longer stay in the processor's nearest caches
#: (256 designs at once ran at about 0.6 of the single path's rate per design, 8 at about
#: 1: benchmarks/many_bench.py).
BLOCK = 8
#: rows of :func:`simulate_many`'s history array
(M_SWS, M_ACC, M_DTL, M_SIZE) = range(4)


@inlined_kernel
def _car_sample(d: _Vec, q: _Vec, s: _Vec, force: float, out: _Vec, j: int, k: int,
                u0: float, u1: float) -> None:
    """Car ``j``'s outputs at sample ``k`` with its damper's ``force`` held, and its state
    one sample on (not after the road's last sample)."""
    qj = q[j]
    sj = s[j]
    sws, accel, dtl = state_outputs(qj, sj, force, u0, u1)
    out[j, M_SWS, k] = sws
    out[j, M_ACC, k] = accel
    out[j, M_DTL, k] = dtl
    if k + 1 < out.shape[2]:
        advance_state(d, sj, wheel_force(force, qj[Q_FSTATIC], qj[Q_MR]), u0, u1)


@kernel
def _loop_many(d: _Vec, q: _Vec, road: _Vec, s: _Vec, force: _Vec, prm: _Vec, coef_r: _Vec,
               n_r: NDArray[np.int64], coef_c: _Vec, n_c: NDArray[np.int64], dstate: _Vec,
               out: _Vec, faults: NDArray[np.int64]) -> None:
    """The compiled loop: blocks of :data:`BLOCK` designs outer, samples, the block's
    designs inner (module docstring)."""
    designs = s.shape[0]
    for first in range(0, designs, BLOCK):
        _loop_block(d, q, road, s, force, prm, coef_r, n_r, coef_c, n_c, dstate, out, faults,
                    first, min(first + BLOCK, designs))


@kernel
def _loop_block(d: _Vec, q: _Vec, road: _Vec, s: _Vec, force: _Vec, prm: _Vec, coef_r: _Vec,
                n_r: NDArray[np.int64], coef_c: _Vec, n_c: NDArray[np.int64], dstate: _Vec,
                out: _Vec, faults: NDArray[np.int64], first: int, end: int) -> None:
    """Designs ``first … end − 1`` over the whole road."""
    n = road.size
    for k in range(n):
        u0, u1 = road_pair(road, k)
        for j in range(first, end):
            qj = q[j]
            sj = s[j]
            if k > 0:
                x, v = state_motion(qj, sj)
                f, fault = _compressible_step(prm[j], coef_r[j, :n_r[j]], coef_c[j, :n_c[j]],
                                              dstate[j], x, v, qj[Q_DT])
                force[j] = f
                faults[j] |= fault
            _car_sample(d, q, s, force[j], out, j, k, u0, u1)


@kernel
def _loop_lanes(d: _Vec, q: _Vec, road: _Vec, s: _Vec, force: _Vec, prm: _Vec, coef_r: _Vec,
                n_r: NDArray[np.int64], coef_c: _Vec, n_c: NDArray[np.int64], sides: _Vec,
                dstate: _Vec, out: _Vec, faults: NDArray[np.int64], lv: _Vec) -> None:
    """:func:`_loop_many` for designs the damper step runs in SIMD lanes
    (:func:`damper_emulator.model.lanes.step_lanes`; ``D`` a multiple of
    :data:`~damper_emulator.model.lanes.LANES`): per block of lanes, per sample, the
    cars' damper motions, the dampers' step, then each car's outputs and exact update,
    one car at a time with the one-design loop's kernels.

    (The cars in lanes too were 5 % faster, but the vectorised update rounds the last bit
    differently, and Coulomb friction's sign at a relative velocity of exactly zero, as at
    a start moving with the road, follows that bit: a 2 F_friction step in the force, 1e-4
    of the ride's histories.)"""
    n = road.size
    for first in range(0, s.shape[0], LANES):
        load_lanes(prm, n_r, n_c, dstate, first, lv)
        for k in range(n):
            u0, u1 = road_pair(road, k)
            if k > 0:
                for b in range(LANES):
                    x, v = state_motion(q[first + b], s[first + b])
                    lv[L_X * LANES + b] = x
                    lv[L_V * LANES + b] = v
                step_lanes(prm, coef_r, n_r, coef_c, n_c, sides, dstate, first, q[first, Q_DT],
                           lv)
                for b in range(LANES):
                    force[first + b] = lv[L_FORCE * LANES + b]
                    faults[first + b] |= int(lv[L_FLAGS * LANES + b])
            for j in range(first, first + LANES):
                _car_sample(d, q, s, force[j], out, j, k, u0, u1)
        store_lanes(dstate, first, lv)


@dataclass(frozen=True)
class ManyResult:
    """Histories of :func:`simulate_many`, one row per design, one column per road sample
    (the conventions of :class:`ride_sim.quarter_car.RideResult`)."""

    sws_m: np.ndarray             # (D, n) z1 − z2, + = suspension compressed
    body_accel_m_s2: np.ndarray   # (D, n) z2''(t_k+), up +
    dtl_n: np.ndarray             # (D, n) deviation from the static tyre load
    faults: np.ndarray            # (D,) OR of each design's damper Fault bits
    dt_s: float


def _stack_tables(tables: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Valve tables of different lengths as one zero-padded ``(D, L, TABLE_COLUMNS)``
    array and the lengths (the kernel slices each design's own)."""
    n = np.array([t.shape[0] for t in tables], dtype=np.int64)
    out = np.zeros((len(tables), int(n.max()), TABLE_COLUMNS))
    for j, t in enumerate(tables):
        out[j, :t.shape[0]] = t
    return out, n


#: Fewest designs in a block of lanes: a block of fewer is mostly copies (each lane costs
#: the same) and its designs run one by one instead; with 16 lanes a design there costs
#: about 0.36 of one by one (benchmarks/many_bench.py; a block of 6 would break even).
MIN_BLOCK = LANES // 2


def _lane_designs(prm: np.ndarray) -> np.ndarray:
    """Indices of the designs :func:`simulate_many` steps in lanes: the eligible ones
    (:func:`damper_emulator.model.lanes.lane_eligible`; all of one sub-step and iteration
    cap, else none), without a last block of fewer than :data:`MIN_BLOCK`."""
    eligible = np.flatnonzero(lane_eligible(prm))
    if eligible.size == 0 or not lane_compatible(prm[eligible]):
        return np.zeros(0, np.int64)
    tail = eligible.size % LANES
    keep = eligible.size if tail == 0 or tail >= MIN_BLOCK else eligible.size - tail
    chosen: np.ndarray = eligible[:keep]
    return chosen


def simulate_many(params: QuarterCarParams, models: Sequence[DamperModel],
                  road_height_m: ArrayLike, dt_s: float = 1e-3, *,
                  initial_state: ArrayLike | None = None, lanes: bool = True) -> ManyResult:
    """Ride simulation of every damper of ``models`` on the car ``params`` over one road.

    Each design starts as :func:`ride_sim.quarter_car.simulate` starts one: the car at
    static equilibrium (or at ``initial_state`` ``(z1, z1', z2, z2')``, the same for every
    design), the damper in quasi-steady equilibrium there, its static force carried by the
    spring.

    Parameters
    ----------
    params : QuarterCarParams
    models : sequence of DamperModel
        The designs (any valves, gas, extensions; a damper with ``damper.adaptive`` at its
        default command).
    road_height_m : array_like, shape (n,)
        Road height under the tyre [m, up +] at the samples, linear in between.
    dt_s : float
        Sample period [s].
    lanes : bool
        Step the designs the damper's SIMD lanes can take (no model extension;
        :mod:`damper_emulator.model.lanes`) in them (default), the others one by one;
        ``False``: every design one by one (the results agree to rounding).
    """
    road = road_array(road_height_m)
    if not models:
        raise ValueError("simulate_many needs at least one damper model")
    plugins = [CompressiblePlugin(m) for m in models]
    cars = [QuarterCar(params, dt_s, p.static_force_n) for p in plugins]
    for c in cars:
        c.reset(initial_state)
    d = cars[0].matrix
    q = np.ascontiguousarray(np.stack([c._q for c in cars]))
    s = np.ascontiguousarray(np.stack([c.state for c in cars]))
    force = np.array([p.reset(*c.damper_motion()) for p, c in zip(plugins, cars)])
    prm = np.ascontiguousarray(np.stack([p.kernel_spec.prm for p in plugins]))
    coef_r, n_r = _stack_tables([p.kernel_spec.coef_r for p in plugins])
    coef_c, n_c = _stack_tables([p.kernel_spec.coef_c for p in plugins])
    dstate = np.ascontiguousarray(np.stack([p.kernel_spec.state for p in plugins]))
    in_lanes = _lane_designs(prm) if lanes else np.zeros(0, np.int64)
    alone = np.setdiff1d(np.arange(len(cars)), in_lanes)
    # whole blocks of lanes, the last one filled up with copies of the last design (their
    # results dropped)
    rows = np.full(-(-in_lanes.size // LANES) * LANES, in_lanes[-1] if in_lanes.size else 0)
    rows[:in_lanes.size] = in_lanes
    if in_lanes.size:
        lane_out = np.empty((rows.size, M_SIZE, road.size))
        lane_faults = np.zeros(rows.size, dtype=np.int64)
        cr, cc = coef_r[rows], coef_c[rows]
        _loop_lanes(d, q[rows], road, s[rows], force[rows], prm[rows], cr, n_r[rows], cc,
                    n_c[rows], lane_tables(cr, cc), dstate[rows], lane_out, lane_faults,
                    np.zeros(LANE_BUFFER))
    if alone.size == 0:  # all in lanes: their rows are the output's, no copy
        out, faults = lane_out[:len(cars)], lane_faults[:len(cars)]
    else:
        out = np.empty((len(cars), M_SIZE, road.size))
        faults = np.zeros(len(cars), dtype=np.int64)
        if alone.size == len(cars):
            _loop_many(d, q, road, s, force, prm, coef_r, n_r, coef_c, n_c, dstate, out,
                       faults)
        else:
            o, f = out[alone], faults[alone]
            _loop_many(d, q[alone], road, s[alone], force[alone], prm[alone],
                       coef_r[alone], n_r[alone], coef_c[alone], n_c[alone], dstate[alone],
                       o, f)
            out[alone], faults[alone] = o, f
            out[in_lanes] = lane_out[:in_lanes.size]
            faults[in_lanes] = lane_faults[:in_lanes.size]
    return ManyResult(out[:, M_SWS], out[:, M_ACC], out[:, M_DTL], faults, cars[0].dt_s)
