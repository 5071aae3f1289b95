"""The compressible damper's step for many designs at once, in SIMD lanes.

:func:`step_lanes` advances :data:`LANES` designs by one sample, as
:func:`damper_emulator.model.step.step` advances one, out of the same equations:
the sub-steps (:func:`~damper_emulator.model.kernels.substeps`), the BDF2 combination
(:func:`~damper_emulator.model.kernels.bdf2_combination`), the gas law (eq 3), the
residual of eq 2 (:func:`~damper_emulator.model.kernels.eq2_residual`), the valve table
(:func:`~damper_emulator.model.valve_table.valve_row_point`), the bypass
(:func:`~damper_emulator.model.adaptive.bypass_flow`), the safeguarded Newton update
(:func:`~damper_emulator.model.kernels.newton_update`) and the force (eq 4).  What
differs is only the order: each phase of the step runs for every lane before the next
phase, and the Newton solves of the lanes run in lockstep until the last lane has
converged (a converged lane's values are held by selects).  The phase that costs most, a
Newton iteration's arithmetic, has no branch and reads the lanes' values from one buffer
at fixed offsets, so the compiler runs it in SIMD lanes; the table rows are gathered in a
scalar loop before it.  The forces agree with the one-design step to rounding
(fast-math orders sums differently in the two compiled loops; tested to 1e-9 relative).

**Which designs.**  The paper's damper with any valves, gas and friction, end stops and
the adaptive bypass at a settled command (:func:`lane_eligible`).  The model extensions
(LuGre friction, viscosity–temperature, cavitation, valve lag, series compliance, end
stops of their own form, air, groove, gas heat transfer) are not in the lanes: a design
with one runs the one-design step.  So does any lane at a sample the lanes do not handle:
invalid input, a gap longer than ``numerics.settle_time_s``, or a valve command still
moving through the solenoid's lag; and an evaluation beyond the table, or past the
iteration cap, takes the one-design valve look-up for that lane.

**What makes it fast** (each measured, docs/tune.md):  numba's compiler vectorises a loop
over the lanes only when its trip count is a constant, the lanes' values sit at constant
offsets of one buffer, no division may raise (numpy's error model, each divisor provably
non-zero), no load sits under a condition, no library function is called and the logic is
written with ``&``/``|`` (``and``/``or`` become branches, then masked loads and scatters).
Long chains of dependent operations are split into short loops (a Newton iteration into
three, eq 3's power into two), so that the processor overlaps the groups of lanes.

**Buffer.**  ``lanes`` is a caller's array of :data:`LANE_BUFFER` doubles: the inputs
(stroke in ``lanes[L_X * LANES + b]``, velocity in ``L_V``), the outputs (force ``L_FORCE``,
fault bits ``L_FLAGS``) and the work values, each quantity a run of :data:`LANES`.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from damper_emulator.model.adaptive import bypass_flow
from damper_emulator.model.gas import (
    compression_chamber_pressure_kernel,
    exp_series,
    gas_volume_ratio,
    log_series,
)
from damper_emulator.model.jit import inlined_kernel, kernel, lane_kernel
from damper_emulator.model.kernels import (
    bdf2_combination,
    bdf2_step,
    bdf2_weight,
    clamp_input,
    coulomb_friction,
    damper_force,
    eq2_gain,
    eq2_residual,
    newton_update,
    substeps,
    valve_state,
)
from damper_emulator.model.layout import (
    FAULT_SOLVER,
    FAULT_VALVE_EXTRAPOLATED,
    P_A_ANNULUS,
    P_A_PISTON,
    P_A_ROD,
    P_AIR_EPS,
    P_ALPHA,
    P_BP_LAMINAR,
    P_BP_TURBULENT,
    P_CAV_ON,
    P_DT_ON,
    P_ES_FORM_K,
    P_ES_K,
    P_ES_XC,
    P_ES_XR,
    P_FRICTION,
    P_GAMMA,
    P_GAS,
    P_GR_AREA,
    P_GT_TAU,
    P_LG_S0,
    P_MAX_EXT,
    P_MAXIT,
    P_MOUNT_K,
    P_SCALE_C,
    P_SCALE_R,
    P_SETTLE,
    P_STEP_C,
    P_STEP_R,
    P_SUBSTEP,
    P_TH_BETA,
    P_TOL,
    P_V_MAX,
    P_VL_TAU,
    P_X_MAX,
    P_X_MIN,
    P_ZLIM_C,
    P_ZLIM_R,
    S_CMD,
    S_CMD_EFF,
    S_FORCE,
    S_H_PREV,
    S_P_COM,
    S_P_PREV,
    S_P_REB,
    S_Q_PREV,
    S_Q_VALVE,
    S_V,
    S_X,
    S_Z,
    S_Z_PREV,
    V_GAS,
)
from damper_emulator.model.step import bypass_area_of, step
from damper_emulator.model.valve_table import C_EXP, C_EXPM1, table_interval, valve_row_point

_Vec = NDArray[np.float64]
_Int = NDArray[np.int64]

#: Designs per call of :func:`step_lanes`.  A run of 16 per quantity: the compiler
#: vectorises the Newton arithmetic over a loop of this constant length (at 8 it unrolled
#: the loop instead of vectorising it: benchmarks/many_bench.py).
LANES = 16
#: Lanes left unconverged that finish one at a time instead of in lockstep (:func:`_finish`).
STRAGGLERS = 2

# Quantities of the lane buffer, each a run of LANES doubles: the input and output, the
# designs' constants, the state carried between sub-steps, the Newton solve's values and
# the valve-table row it gathers, whether a look-up was beyond the table in some sub-step
# of the sample (L_EXTRAP) and the gas law's exponent between its two loops (L_GAS_Y).
(L_X, L_V, L_FORCE, L_FLAGS, L_SKIP,
 L_MAX_EXT, L_AREA, L_ALPHA, L_TOL, L_ZLIM_R, L_ZLIM_C, L_STEP_R, L_STEP_C, L_SCALE_R,
 L_SCALE_C, L_N_R, L_N_C, L_BP_AREA, L_BP_A, L_BP_B, L_P_GAS, L_V_GAS, L_A_ROD, L_GAMMA,
 L_X_MIN, L_X_MAX, L_V_MAX, L_FRICTION, L_SETTLE, L_CMD, L_CMD_EFF, L_A_PISTON, L_ES_XR,
 L_ES_XC, L_ES_K, L_FR,
 L_X0, L_V0, L_P, L_P_PREV, L_H_PREV, L_Z, L_Z_PREV, L_P_COM,
 L_P_HAT, L_K, L_Q_IN, L_LO, L_HI, L_LAST, L_DONE,
 L_SIGN, L_IDX, L_T, L_SCALE, L_PRE, L_C3, L_C2, L_C1, L_C0, L_CE, L_CM, L_DP, L_DDP, L_Q,
 L_DQ, L_BEYOND, L_EXTRAP, L_GAS_Y, L_SIZE) = range(70)
#: Length of the lane buffer [doubles].
LANE_BUFFER = L_SIZE * LANES

#: Packed parameters of the model extensions the lanes leave to the one-design step (each
#: off at 0).
_EXTENSIONS = (P_LG_S0, P_TH_BETA, P_CAV_ON, P_VL_TAU, P_MOUNT_K, P_ES_FORM_K, P_AIR_EPS,
               P_GR_AREA, P_GT_TAU, P_DT_ON)


def lane_eligible(prm: np.ndarray) -> np.ndarray:
    """Which rows of packed parameter vectors (``(D, P_SIZE)``) :func:`step_lanes` can
    step: those with no model extension in use."""
    prm = np.atleast_2d(prm)
    eligible: np.ndarray = np.all(prm[:, list(_EXTENSIONS)] <= 0.0, axis=1)
    return eligible


def lane_compatible(prm: np.ndarray) -> bool:
    """Whether the designs of ``prm`` (``(D, P_SIZE)``, all :func:`lane_eligible`) can
    share lanes: the same sub-step and iteration cap (the lanes run in lockstep)."""
    prm = np.atleast_2d(prm)
    return bool(np.all(prm[:, P_SUBSTEP] == prm[0, P_SUBSTEP])
                and np.all(prm[:, P_MAXIT] == prm[0, P_MAXIT]))


@kernel
def _load_lane(prm: _Vec, n_r: _Int, n_c: _Int, dstate: _Vec, j: int, lv: _Vec, b: int
               ) -> None:
    """Design ``j``'s constants and stepper state into lane ``b``."""
    pr = prm[j]
    st = dstate[j]
    lv[L_MAX_EXT * LANES + b] = pr[P_MAX_EXT]
    lv[L_AREA * LANES + b] = pr[P_A_ANNULUS]
    lv[L_ALPHA * LANES + b] = pr[P_ALPHA]
    lv[L_TOL * LANES + b] = pr[P_TOL]
    lv[L_ZLIM_R * LANES + b] = pr[P_ZLIM_R]
    lv[L_ZLIM_C * LANES + b] = pr[P_ZLIM_C]
    lv[L_STEP_R * LANES + b] = pr[P_STEP_R]
    lv[L_STEP_C * LANES + b] = pr[P_STEP_C]
    lv[L_SCALE_R * LANES + b] = pr[P_SCALE_R]
    lv[L_SCALE_C * LANES + b] = pr[P_SCALE_C]
    lv[L_N_R * LANES + b] = n_r[j]
    lv[L_N_C * LANES + b] = n_c[j]
    lv[L_BP_AREA * LANES + b] = bypass_area_of(pr, st[S_CMD_EFF])
    lv[L_BP_A * LANES + b] = pr[P_BP_LAMINAR]
    lv[L_BP_B * LANES + b] = pr[P_BP_TURBULENT]
    lv[L_P_GAS * LANES + b] = pr[P_GAS]
    lv[L_V_GAS * LANES + b] = pr[V_GAS]
    lv[L_A_ROD * LANES + b] = pr[P_A_ROD]
    lv[L_GAMMA * LANES + b] = pr[P_GAMMA]
    lv[L_X_MIN * LANES + b] = pr[P_X_MIN]
    lv[L_X_MAX * LANES + b] = pr[P_X_MAX]
    lv[L_V_MAX * LANES + b] = pr[P_V_MAX]
    lv[L_FRICTION * LANES + b] = pr[P_FRICTION]
    lv[L_SETTLE * LANES + b] = pr[P_SETTLE]
    lv[L_CMD * LANES + b] = st[S_CMD]
    lv[L_CMD_EFF * LANES + b] = st[S_CMD_EFF]
    lv[L_A_PISTON * LANES + b] = pr[P_A_PISTON]
    lv[L_ES_XR * LANES + b] = pr[P_ES_XR]
    lv[L_ES_XC * LANES + b] = pr[P_ES_XC]
    lv[L_ES_K * LANES + b] = pr[P_ES_K]
    lv[L_X0 * LANES + b] = st[S_X]
    lv[L_V0 * LANES + b] = st[S_V]
    lv[L_P * LANES + b] = st[S_P_REB]
    lv[L_P_PREV * LANES + b] = st[S_P_PREV]
    lv[L_H_PREV * LANES + b] = st[S_H_PREV]
    lv[L_Z * LANES + b] = st[S_Z]
    lv[L_Z_PREV * LANES + b] = st[S_Z_PREV]
    lv[L_P_COM * LANES + b] = st[S_P_COM]
    lv[L_FORCE * LANES + b] = st[S_FORCE]


@kernel
def _store_lane(dstate: _Vec, j: int, lv: _Vec, b: int) -> None:
    """Lane ``b``'s state into design ``j``'s stepper state, as the one-design step
    leaves it."""
    st = dstate[j]
    st[S_CMD] = lv[L_CMD * LANES + b]
    st[S_X] = lv[L_X0 * LANES + b]
    st[S_V] = lv[L_V0 * LANES + b]
    st[S_P_REB] = lv[L_P * LANES + b]
    st[S_P_PREV] = lv[L_P_PREV * LANES + b]
    st[S_H_PREV] = lv[L_H_PREV * LANES + b]
    st[S_Z] = lv[L_Z * LANES + b]
    st[S_Z_PREV] = lv[L_Z_PREV * LANES + b]
    st[S_P_COM] = lv[L_P_COM * LANES + b]
    st[S_FORCE] = lv[L_FORCE * LANES + b]
    if lv[L_H_PREV * LANES + b] > 0.0:
        # stepped: without the valve lag the one-design solve keeps no valve flow
        st[S_Q_VALVE] = 0.0
        st[S_Q_PREV] = 0.0


@kernel
def load_lanes(prm: _Vec, n_r: _Int, n_c: _Int, dstate: _Vec, first: int, lv: _Vec
               ) -> None:
    """Designs ``first … first + LANES − 1`` into the lane buffer ``lv``, which holds
    their state from then on (:func:`step_lanes`) until :func:`store_lanes`."""
    for b in range(LANES):
        _load_lane(prm, n_r, n_c, dstate, first + b, lv, b)


@kernel
def store_lanes(dstate: _Vec, first: int, lv: _Vec) -> None:
    """The lanes' state back into the designs' stepper states (``dstate`` rows ``first …
    first + LANES − 1``), as the one-design step would have left them."""
    for b in range(LANES):
        _store_lane(dstate, first + b, lv, b)


@lane_kernel
def _inputs(dt: float, lv: _Vec) -> tuple[int, bool]:
    """Phase 1, vectorised: each lane's input checked, its stroke and velocity clamped and
    its friction.  A lane with invalid input, after a gap longer than the settle time, or
    with its valve command moving through the solenoid's lag is marked to take the
    one-design step (:func:`_alone`).  Returns the number of those and whether any other
    lane's bypass is open."""
    step_ok = math.isfinite(dt) and dt > 0.0
    alone = 0
    open_bypass = 0
    for b in range(LANES):
        x = lv[L_X * LANES + b]
        v = lv[L_V * LANES + b]
        settle = lv[L_SETTLE * LANES + b]
        steady = lv[L_CMD * LANES + b] == lv[L_CMD_EFF * LANES + b]
        ok = step_ok & math.isfinite(x) & math.isfinite(v) & (dt <= settle) & steady
        xc, vc, flags = clamp_input(x, v, lv[L_X_MIN * LANES + b], lv[L_X_MAX * LANES + b],
                                    lv[L_V_MAX * LANES + b])
        lv[L_SKIP * LANES + b] = 0.0 if ok else 1.0
        lv[L_X * LANES + b] = xc if ok else x
        lv[L_V * LANES + b] = vc if ok else v
        lv[L_FLAGS * LANES + b] = flags
        lv[L_EXTRAP * LANES + b] = 0.0
        lv[L_FR * LANES + b] = coulomb_friction(lv[L_FRICTION * LANES + b], vc)
        alone += 0 if ok else 1
        open_bypass += 1 if (ok & (lv[L_BP_AREA * LANES + b] > 0.0)) else 0
    return alone, open_bypass > 0


@kernel
def _alone(prm: _Vec, coef_r: _Vec, n_r: _Int, coef_c: _Vec, n_c: _Int, dstate: _Vec,
           first: int, dt: float, lv: _Vec) -> None:
    """Phase 1': the lanes :func:`_inputs` marked take the one-design step, their state
    through ``dstate``."""
    for b in range(LANES):
        if lv[L_SKIP * LANES + b] == 0.0:
            continue
        j = first + b
        _store_lane(dstate, j, lv, b)
        _f, flags = step(prm[j], coef_r[j, :n_r[j]], coef_c[j, :n_c[j]], dstate[j],
                         lv[L_X * LANES + b], lv[L_V * LANES + b], dt)
        _load_lane(prm, n_r, n_c, dstate, j, lv, b)
        lv[L_FLAGS * LANES + b] = flags


@inlined_kernel
def _locate(lv: _Vec, b: int, z: float) -> None:
    """Where lane ``b``'s valve look-up at ``z`` falls (as in ``valve_point``): the side
    (rebound ``z >= 0``), its interval ``i`` and the offset ``t`` in it, and whether the
    look-up must take the one-design path (beyond the table, or a table too coarse for
    the polynomial)."""
    # every value loaded before it is chosen: a load under a condition is not vectorised
    step_r = lv[L_STEP_R * LANES + b]
    step_c = lv[L_STEP_C * LANES + b]
    n_r = lv[L_N_R * LANES + b]
    n_c = lv[L_N_C * LANES + b]
    scale_r = lv[L_SCALE_R * LANES + b]
    scale_c = lv[L_SCALE_C * LANES + b]
    rebound = z >= 0.0
    i, t, inside = table_interval(z if rebound else -z, step_r if rebound else step_c,
                                  n_r if rebound else n_c)
    lv[L_SIGN * LANES + b] = 1.0 if rebound else -1.0
    lv[L_IDX * LANES + b] = i
    lv[L_T * LANES + b] = t
    lv[L_SCALE * LANES + b] = scale_r if rebound else scale_c
    lv[L_PRE * LANES + b] = 0.0 if inside else 1.0


@lane_kernel
def _gas_exponent(frac: float, lv: _Vec) -> None:
    """Phase 2a, per sub-step: the exponent ``γ ln r`` of eq 3's power at each lane's
    stroke there, by its series (NaN where the gas volume is beyond the series' domain,
    see :func:`_gas_beyond`; no gas heat transfer in the lanes), vectorised.  Divisors:
    the gas volume, positive inside the travel, and ``r + 1 > 1``."""
    for b in range(LANES):
        x0 = lv[L_X0 * LANES + b]
        xs = x0 + frac * (lv[L_X * LANES + b] - x0)
        ratio = gas_volume_ratio(xs, lv[L_V_GAS * LANES + b], lv[L_A_ROD * LANES + b])
        lv[L_GAS_Y * LANES + b] = log_series(ratio, lv[L_GAMMA * LANES + b])


@lane_kernel
def _gas(lv: _Vec) -> None:
    """Phase 2b, per sub-step: the gas pressure (eq 3) ``P_gas,static e^(γ ln r)`` from
    :func:`_gas_exponent`'s exponent, vectorised; a skipped lane keeps its pressure.  (Eq
    3's power is the series' two halves, :func:`~damper_emulator.model.gas.log_series`
    and :func:`~damper_emulator.model.gas.exp_series`, in two loops: in one, a group of
    lanes waited for the long chain of the group before it; in two the gas law takes about a
    quarter fewer cycles a design and sample: benchmarks/many_bench.py.)"""
    for b in range(LANES):
        p_com = lv[L_P_GAS * LANES + b] * exp_series(lv[L_GAS_Y * LANES + b])
        p_old = lv[L_P_COM * LANES + b]
        lv[L_P_COM * LANES + b] = p_com if lv[L_SKIP * LANES + b] == 0.0 else p_old


@kernel
def _gas_beyond(frac: float, lv: _Vec) -> None:
    """Phase 2b': a lane whose gas volume is beyond the series' domain (±40 % of the
    static volume) takes eq 3 with the library's power."""
    for b in range(LANES):
        if math.isnan(lv[L_P_COM * LANES + b]):
            x0 = lv[L_X0 * LANES + b]
            xs = x0 + frac * (lv[L_X * LANES + b] - x0)
            lv[L_P_COM * LANES + b] = compression_chamber_pressure_kernel(
                xs, lv[L_P_GAS * LANES + b], lv[L_V_GAS * LANES + b],
                lv[L_A_ROD * LANES + b], lv[L_GAMMA * LANES + b])


@lane_kernel
def _substep_begin(frac: float, h: float, lv: _Vec) -> None:
    """Phase 2c, per sub-step: the stroke and velocity there, the BDF2 combination and
    the Newton solve's start (as in ``model.step.step``), vectorised.  Divisors: ``h_prev``
    tested, ``1 + 2w >= 1``, and the chamber volume, positive inside the clamped travel;
    a skipped lane's values are not used."""
    for b in range(LANES):
        x0 = lv[L_X0 * LANES + b]
        v0 = lv[L_V0 * LANES + b]
        xs = x0 + frac * (lv[L_X * LANES + b] - x0)
        vs = v0 + frac * (lv[L_V * LANES + b] - v0)
        # a skipped lane's state (here and below) is kept: it took the one-design step
        live = lv[L_SKIP * LANES + b] == 0.0
        p = lv[L_P * LANES + b]
        p_prev = lv[L_P_PREV * LANES + b]
        w = bdf2_weight(h, lv[L_H_PREV * LANES + b])
        restart = w == 0.0
        p_hat = p if restart else bdf2_combination(p, p_prev, w)
        h_eff = h if restart else bdf2_step(h, w)
        lv[L_P_PREV * LANES + b] = p if live else p_prev
        lv[L_P_HAT * LANES + b] = p_hat
        z = lv[L_Z * LANES + b]
        z_prev = lv[L_Z_PREV * LANES + b]
        z_start = z + (z - z_prev) * w
        lv[L_Z_PREV * LANES + b] = z if live else z_prev
        area = lv[L_AREA * LANES + b]
        lv[L_K * LANES + b] = eq2_gain(lv[L_MAX_EXT * LANES + b], area,
                                       lv[L_ALPHA * LANES + b], xs, h_eff)
        lv[L_Q_IN * LANES + b] = vs * area
        lo = -lv[L_ZLIM_C * LANES + b]
        hi = lv[L_ZLIM_R * LANES + b]
        lv[L_LO * LANES + b] = lo
        lv[L_HI * LANES + b] = hi
        z_first = min(max(z_start, lo), hi)
        lv[L_Z * LANES + b] = z_first if live else z
        lv[L_LAST * LANES + b] = 0.0
        lv[L_DONE * LANES + b] = 0.0
        _locate(lv, b, z_first)


def lane_tables(coef_r: np.ndarray, coef_c: np.ndarray) -> np.ndarray:
    """The designs' rebound and compression valve tables (``(D, L_r, TABLE_COLUMNS)`` and
    ``(D, L_c, TABLE_COLUMNS)``, zero-padded) side by side, ``(D, 2, max(L_r, L_c),
    TABLE_COLUMNS)``, as
    :func:`step_lanes` gathers their rows: a lane's row is then an offset computed from
    its side, not a choice between two arrays (a quarter of the gather:
    benchmarks/many_bench.py)."""
    length = max(coef_r.shape[1], coef_c.shape[1])
    sides = np.zeros((coef_r.shape[0], 2, length, coef_r.shape[2]))
    sides[:, 0, :coef_r.shape[1]] = coef_r
    sides[:, 1, :coef_c.shape[1]] = coef_c
    return sides


@inlined_kernel
def _row(sides: _Vec, j: int, lv: _Vec, b: int) -> None:
    """Lane ``b``'s valve-table row, where :func:`_locate` put it (design ``j``; the index
    clamped into the padded table, so that a lane whose look-up is beyond it, or not
    used, still reads a row)."""
    idx = lv[L_IDX * LANES + b]
    # clamped as a float (a NaN index, a lane not in the solve's, to row 0)
    i = int(min(idx if idx > 0.0 else 0.0, sides.shape[2] - 1.0))
    row = sides[j, 0 if lv[L_SIGN * LANES + b] > 0.0 else 1, i]
    lv[L_C3 * LANES + b] = row[0]
    lv[L_C2 * LANES + b] = row[1]
    lv[L_C1 * LANES + b] = row[2]
    lv[L_C0 * LANES + b] = row[3]
    lv[L_CE * LANES + b] = row[C_EXP]
    lv[L_CM * LANES + b] = row[C_EXPM1]


@inlined_kernel
def _pre_lane(prm: _Vec, coef_r: _Vec, n_r: _Int, coef_c: _Vec, n_c: _Int, j: int,
              lv: _Vec, b: int) -> None:
    """Lane ``b``'s valve point by the one-design look-up (design ``j``), where
    :func:`_locate` said so: beyond the table, or a table too coarse for the polynomial."""
    dp, ddp, q, dq, beyond = valve_state(lv[L_Z * LANES + b], prm[j],
                                          coef_r[j, :n_r[j]], coef_c[j, :n_c[j]])
    lv[L_DP * LANES + b] = dp
    lv[L_DDP * LANES + b] = ddp
    lv[L_Q * LANES + b] = q
    lv[L_DQ * LANES + b] = dq
    lv[L_BEYOND * LANES + b] = 1.0 if beyond else 0.0


@inlined_kernel
def _gather_lane(prm: _Vec, coef_r: _Vec, n_r: _Int, coef_c: _Vec, n_c: _Int,
                 sides: _Vec, first: int, lv: _Vec, b: int) -> None:
    """Lane ``b``'s valve-table row, or the one-design look-up's values."""
    if lv[L_PRE * LANES + b] != 0.0:
        _pre_lane(prm, coef_r, n_r, coef_c, n_c, first + b, lv, b)
    else:
        lv[L_BEYOND * LANES + b] = 0.0
        _row(sides, first + b, lv, b)


@inlined_kernel
def _gather(prm: _Vec, coef_r: _Vec, n_r: _Int, coef_c: _Vec, n_c: _Int, sides: _Vec,
            first: int, lv: _Vec) -> None:
    """Phase 3a, per Newton iteration: every lane's valve-table row, loaded without a test
    on the lane's state (a converged lane's row is not used); then, one at a time, the
    one-design look-up for the unconverged lanes :func:`_locate` marked.  (A test per
    lane on its state and on the row it held was a branch the processor mispredicted:
    loading every row is faster: benchmarks/many_bench.py.)"""
    for b in range(LANES):
        live = (lv[L_SKIP * LANES + b] == 0.0) & (lv[L_DONE * LANES + b] == 0.0)
        beyond_old = lv[L_BEYOND * LANES + b]
        lv[L_BEYOND * LANES + b] = 0.0 if live else beyond_old
        _row(sides, first + b, lv, b)
    for b in range(LANES):
        if ((lv[L_PRE * LANES + b] != 0.0) & (lv[L_SKIP * LANES + b] == 0.0)
                & (lv[L_DONE * LANES + b] == 0.0)):
            _pre_lane(prm, coef_r, n_r, coef_c, n_c, first + b, lv, b)


@inlined_kernel
def _valve_lane(lv: _Vec, b: int) -> None:
    """Lane ``b``'s valve point (its row's polynomial, or the one-design look-up's values
    where :func:`_locate` said so) into ``L_DP``, ``L_DDP``, ``L_Q``, ``L_DQ``."""
    dpa, ddpa, qa, dqa = valve_row_point(
        lv[L_C3 * LANES + b], lv[L_C2 * LANES + b], lv[L_C1 * LANES + b],
        lv[L_C0 * LANES + b], lv[L_CE * LANES + b], lv[L_CM * LANES + b],
        lv[L_T * LANES + b], lv[L_SCALE * LANES + b])
    # every value loaded before it is chosen (a load under a condition is not vectorised)
    pre = lv[L_PRE * LANES + b] != 0.0
    sign = lv[L_SIGN * LANES + b]
    dp_pre = lv[L_DP * LANES + b]
    ddp_pre = lv[L_DDP * LANES + b]
    q_pre = lv[L_Q * LANES + b]
    dq_pre = lv[L_DQ * LANES + b]
    lv[L_DP * LANES + b] = dp_pre if pre else sign * dpa
    lv[L_DDP * LANES + b] = ddp_pre if pre else ddpa
    lv[L_Q * LANES + b] = q_pre if pre else sign * qa
    lv[L_DQ * LANES + b] = dq_pre if pre else dqa


@inlined_kernel
def _update_lane(lv: _Vec, b: int, bypass: bool) -> int:
    """Lane ``b``'s residual of eq 2 at its valve point and the safeguarded Newton update;
    1 while it is unconverged."""
    dp = lv[L_DP * LANES + b]
    ddp = lv[L_DDP * LANES + b]
    q = lv[L_Q * LANES + b]
    dq = lv[L_DQ * LANES + b]
    if bypass:
        qb, dqb = bypass_flow(dp, lv[L_BP_AREA * LANES + b], lv[L_BP_A * LANES + b],
                              lv[L_BP_B * LANES + b])
        q += qb
        dq += dqb * ddp
    p = lv[L_P_COM * LANES + b] + dp
    r, dr = eq2_residual(p, ddp, q, dq, lv[L_P_HAT * LANES + b], lv[L_K * LANES + b],
                         lv[L_Q_IN * LANES + b], lv[L_ALPHA * LANES + b])
    z = lv[L_Z * LANES + b]
    z_new, lo, hi, last, done, dz = newton_update(
        z, r, dr, lv[L_LO * LANES + b], lv[L_HI * LANES + b], lv[L_LAST * LANES + b],
        lv[L_TOL * LANES + b])
    skip = lv[L_SKIP * LANES + b]
    was_done = lv[L_DONE * LANES + b]
    p_old = lv[L_P * LANES + b]
    lo_old = lv[L_LO * LANES + b]
    hi_old = lv[L_HI * LANES + b]
    last_old = lv[L_LAST * LANES + b]
    live = (skip == 0.0) & (was_done == 0.0)
    shortcut = done & (dz != 0.0)
    z_out = z_new if (shortcut | (not done)) else z
    p_out = p + ddp * dz if shortcut else p
    lv[L_Z * LANES + b] = z_out if live else z
    lv[L_P * LANES + b] = p_out if live else p_old
    lv[L_LO * LANES + b] = lo if live else lo_old
    lv[L_HI * LANES + b] = hi if live else hi_old
    lv[L_LAST * LANES + b] = last if live else last_old
    finished = done | (not live)
    lv[L_DONE * LANES + b] = 1.0 if finished else 0.0
    return 0 if finished else 1


@inlined_kernel
def _newton_lane(lv: _Vec, b: int, bypass: bool) -> int:
    """Lane ``b`` of :func:`_newton_lanes`; 1 while it is unconverged."""
    _valve_lane(lv, b)
    active = _update_lane(lv, b, bypass)
    # the next iteration's look-up (a finished lane's is not used)
    _locate(lv, b, lv[L_Z * LANES + b])
    return active


@lane_kernel
def _newton_lanes(lv: _Vec, bypass: bool) -> int:
    """Phase 3b, per Newton iteration: every lane's valve point, eq 2's residual and the
    safeguarded update, by selects (no branch on a lane's data: the compiler vectorises
    these loops); a converged or skipped lane keeps its state.  Three loops, each over
    every lane, not one: a lane's iteration is one chain of dependent operations (two
    square roots and two divisions among them) about as long as the processor's
    out-of-order window, so that in one loop a group of lanes waited for the group before
    it; in three short loops the groups overlap.  ``bypass``: some lane's bypass is open
    (else its flow, a square root and two divisions a lane, is not evaluated, as the
    one-design solve skips it; the update in two loops, so that each is vectorised without
    a test per lane).  Divisors: the Newton step's is tested, the bypass's are tested, the
    table step is positive.  Returns the lanes still unconverged."""
    for b in range(LANES):
        _valve_lane(lv, b)
    active = 0
    if bypass:
        for b in range(LANES):
            active += _update_lane(lv, b, True)
    else:
        for b in range(LANES):
            active += _update_lane(lv, b, False)
    for b in range(LANES):
        _locate(lv, b, lv[L_Z * LANES + b])
    return active


@kernel
def _finish(prm: _Vec, coef_r: _Vec, n_r: _Int, coef_c: _Vec, n_c: _Int, sides: _Vec,
            first: int, lv: _Vec, bypass: bool, iterations: int) -> int:
    """Phase 3c: the last few unconverged lanes, one at a time (the same look-up and
    update, up to ``iterations`` more): a lockstep iteration costs every lane's work,
    and about one lane in thirteen needs a third iteration (which, in lockstep, took
    most blocks into one: benchmarks/many_bench.py).  Returns the number of lanes left
    unconverged."""
    left = 0
    for b in range(LANES):
        for _ in range(iterations):
            if lv[L_SKIP * LANES + b] != 0.0 or lv[L_DONE * LANES + b] != 0.0:
                break
            _gather_lane(prm, coef_r, n_r, coef_c, n_c, sides, first, lv, b)
            _newton_lane(lv, b, bypass)
        left += 1 if (lv[L_SKIP * LANES + b] == 0.0 and lv[L_DONE * LANES + b] == 0.0) else 0
    return left


@kernel
def _solve(prm: _Vec, coef_r: _Vec, n_r: _Int, coef_c: _Vec, n_c: _Int, sides: _Vec,
           first: int, lv: _Vec, bypass: bool, maxit: int) -> int:
    """Phase 3: the lanes' Newton solves of eq 2 (lockstep, then the stragglers), at most
    ``maxit`` iterations each.  Returns the number of lanes left unconverged."""
    active = 0
    for iteration in range(maxit):
        _gather(prm, coef_r, n_r, coef_c, n_c, sides, first, lv)
        active = _newton_lanes(lv, bypass)
        if active == 0:
            return 0
        if active <= STRAGGLERS:
            return _finish(prm, coef_r, n_r, coef_c, n_c, sides, first, lv, bypass,
                           maxit - iteration - 1)
    return active


@kernel
def _unconverged(prm: _Vec, coef_r: _Vec, n_r: _Int, coef_c: _Vec, n_c: _Int, first: int,
                 lv: _Vec) -> None:
    """Phase 4', per sub-step, when some lane reached the iteration cap: it takes the
    valve's pressure at its last ``z`` and says so (as the one-design solve does)."""
    for b in range(LANES):
        if lv[L_SKIP * LANES + b] != 0.0 or lv[L_DONE * LANES + b] != 0.0:
            continue
        j = first + b
        dp, _d, _q, _dq, beyond = valve_state(lv[L_Z * LANES + b], prm[j],
                                               coef_r[j, :n_r[j]], coef_c[j, :n_c[j]])
        lv[L_P * LANES + b] = lv[L_P_COM * LANES + b] + dp
        lv[L_BEYOND * LANES + b] = 1.0 if beyond else 0.0
        lv[L_FLAGS * LANES + b] = int(lv[L_FLAGS * LANES + b]) | FAULT_SOLVER


@lane_kernel
def _substep_end(h: float, lv: _Vec) -> None:
    """Phase 4, per sub-step, vectorised: whether the lane's valve look-up was beyond its
    table (its fault bit is set once a sample, :func:`_extrapolated`: the bit operation
    on a lane's flags held as a double is not vectorised); the sub-step becomes the one
    before (a skipped lane keeps its own)."""
    for b in range(LANES):
        live = lv[L_SKIP * LANES + b] == 0.0
        extrap_old = lv[L_EXTRAP * LANES + b]
        beyond = lv[L_BEYOND * LANES + b]
        h_old = lv[L_H_PREV * LANES + b]
        lv[L_EXTRAP * LANES + b] = max(extrap_old, beyond) if live else extrap_old
        lv[L_H_PREV * LANES + b] = h if live else h_old


@kernel
def _extrapolated(lv: _Vec) -> None:
    """Phase 5', once a sample: the valve-extrapolated fault bit of each lane whose
    look-up was beyond its table in some sub-step (:func:`_substep_end`)."""
    for b in range(LANES):
        if lv[L_EXTRAP * LANES + b] != 0.0:
            lv[L_FLAGS * LANES + b] = int(lv[L_FLAGS * LANES + b]) | FAULT_VALVE_EXTRAPOLATED


@lane_kernel
def _end(lv: _Vec) -> None:
    """Phase 5, vectorised: the force (eq 4 and the end stops); the sample becomes the one
    before."""
    for b in range(LANES):
        live = lv[L_SKIP * LANES + b] == 0.0
        x = lv[L_X * LANES + b]
        force = damper_force(lv[L_AREA * LANES + b], lv[L_A_PISTON * LANES + b],
                             lv[L_P * LANES + b], lv[L_P_COM * LANES + b],
                             lv[L_FR * LANES + b], x, lv[L_ES_XR * LANES + b],
                             lv[L_ES_XC * LANES + b], lv[L_ES_K * LANES + b])
        force_old = lv[L_FORCE * LANES + b]
        x_old = lv[L_X0 * LANES + b]
        v_old = lv[L_V0 * LANES + b]
        lv[L_FORCE * LANES + b] = force if live else force_old
        lv[L_X0 * LANES + b] = x if live else x_old
        lv[L_V0 * LANES + b] = lv[L_V * LANES + b] if live else v_old


@kernel
def step_lanes(prm: _Vec, coef_r: _Vec, n_r: _Int, coef_c: _Vec, n_c: _Int, sides: _Vec,
               dstate: _Vec, first: int, dt: float, lv: _Vec) -> None:
    """Advance designs ``first … first + LANES − 1``, loaded into ``lv`` by
    :func:`load_lanes`, to their next sample, ``dt`` [s] after the last, as
    :func:`damper_emulator.model.step.step` advances one.

    Parameters
    ----------
    prm : ndarray, shape (D, P_SIZE)
        The designs' packed parameters (every one :func:`lane_eligible`, all
        :func:`lane_compatible`).
    coef_r, coef_c : ndarray, shape (D, L, TABLE_COLUMNS)
        The designs' rebound and compression valve tables, zero-padded to one length.
    n_r, n_c : ndarray of int64, shape (D,)
        The tables' own lengths.
    sides : ndarray, shape (D, 2, L, TABLE_COLUMNS)
        The same tables side by side, :func:`lane_tables` (the lanes gather their rows
        from it; the one-design look-ups take ``coef_r`` and ``coef_c``).
    dstate : ndarray, shape (D, S_SIZE)
        The designs' stepper states: only the lanes that take the one-design step this
        sample go through them (the others' state is in ``lv``, :func:`load_lanes`).
    first : int
        The first design of this call.
    dt : float
        Time since the last sample [s].
    lv : ndarray, shape (LANE_BUFFER,)
        Lane buffer (module docstring): strokes and velocities in, forces and fault bits
        out.
    """
    alone, bypass = _inputs(dt, lv)
    if alone:
        _alone(prm, coef_r, n_r, coef_c, n_c, dstate, first, dt, lv)
        if alone == LANES:
            # (a gap or a bad dt for all: no sub-step to run, and dt may be NaN)
            return
    n_sub, h = substeps(prm[first], dt)
    maxit = int(prm[first, P_MAXIT])
    for sub in range(1, n_sub + 1):
        frac = sub / n_sub
        _gas_exponent(frac, lv)
        _gas(lv)
        _gas_beyond(frac, lv)
        _substep_begin(frac, h, lv)
        if _solve(prm, coef_r, n_r, coef_c, n_c, sides, first, lv, bypass, maxit):
            _unconverged(prm, coef_r, n_r, coef_c, n_c, first, lv)
        _substep_end(h, lv)
    _end(lv)
    _extrapolated(lv)
