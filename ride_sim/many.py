"""Many quarter cars with compressible dampers at once, on one road (issue 17: virtual
tuning runs thousands of valve designs over the same roads).

:func:`simulate_many` advances ``D`` designs together, in blocks of :data:`BLOCK`: per
block one loop over the road's samples, and inside each sample one loop over the block's
designs, on structure-of-arrays state (the
designs' parameter vectors, valve tables and stepper states are rows of 2-D arrays, their
car states the rows of a ``(D, 4)`` array).  Every design's sample is exactly what
:func:`ride_sim.quarter_car.simulate` does for one: the same compiled damper step
(:func:`damper_emulator.model.compressible.step`), the same exact vehicle update and the
same output formulas (the :mod:`ride_sim.quarter_car` kernels), so the histories agree
with the single-design path to the last bit (tested to 1e-9 relative); there is no second
copy of the physics.  The designs share the vehicle's discretisation matrix and the road,
which the single path reads once per design.

What it does not do: vectorise across designs in SIMD lanes.  The damper step solves the
pressure equation (eq 2) by a safeguarded Newton iteration whose iteration count depends
on the design and the sample; lanes would all run the slowest design's iterations and a
second, branch-free copy of the solver would be needed.  The gain over the single path
comes from the shared road and matrix and from the independent designs' work overlapping
in the processor (benchmarks/many_bench.py).

Memory: three histories (SWS, body acceleration, DTL) of ``D × n`` doubles; a caller with
many designs runs them in chunks (``tune`` runs one chunk per Dask task).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from damper_emulator.model.compressible import DamperModel
from damper_emulator.model.compressible import step as _compressible_step
from damper_emulator.model.jit import kernel
from damper_emulator.model.valve_table import TABLE_COLUMNS
from ride_sim.dampers import CompressiblePlugin
from ride_sim.params import QuarterCarParams
from ride_sim.quarter_car import (
    Q_DT,
    Q_FSTATIC,
    Q_MR,
    QuarterCar,
    _advance,
    _motion,
    _outputs,
    _road_pair,
    road_array,
)

_Vec = NDArray[np.float64]
#: Designs advanced together over the whole road, one block after another: a sample of
#: every design at once touches each design's parameters, state and valve-table rows, and
#: beyond a few dozen designs those no longer stay in the processor's nearest caches
#: (256 designs at once ran at 0.55–0.66 of the single path's rate per design, 8 at
#: 0.95–1.07; measured 2026-11-25 on the 2-core Xeon VM).
BLOCK = 8
#: rows of :func:`simulate_many`'s history array
(M_SWS, M_ACC, M_DTL, M_SIZE) = range(4)


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
        u0, u1 = _road_pair(road, k)
        for j in range(first, end):
            qj = q[j]
            sj = s[j]
            if k > 0:
                x, v = _motion(qj, sj)
                f, fault = _compressible_step(prm[j], coef_r[j, :n_r[j]], coef_c[j, :n_c[j]],
                                              dstate[j], x, v, qj[Q_DT])
                force[j] = f
                faults[j] |= fault
            sws, accel, dtl = _outputs(qj, sj, force[j], u0, u1)
            out[j, M_SWS, k] = sws
            out[j, M_ACC, k] = accel
            out[j, M_DTL, k] = dtl
            if k + 1 < n:
                _advance(d, sj, (force[j] - qj[Q_FSTATIC]) / qj[Q_MR], u0, u1)


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


def simulate_many(params: QuarterCarParams, models: Sequence[DamperModel],
                  road_height_m: ArrayLike, dt_s: float = 1e-3, *,
                  initial_state: ArrayLike | None = None) -> ManyResult:
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
    out = np.empty((len(cars), M_SIZE, road.size))
    faults = np.zeros(len(cars), dtype=np.int64)
    _loop_many(d, q, road, s, force, prm, coef_r, n_r, coef_c, n_c, dstate, out, faults)
    return ManyResult(out[:, M_SWS], out[:, M_ACC], out[:, M_DTL], faults, cars[0].dt_s)
