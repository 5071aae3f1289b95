"""Compressible (hysteretic) damper model, Simms & Crolla eqs 1–4.

One compiled step serves the real-time stepper (:class:`DamperStepper`, one sample per call)
and the batch simulator (:func:`simulate`, a whole displacement history in one call).

The state is the rebound-chamber pressure ``p_reb``.  Eq 2,

    dp_reb/dt = (ẋ (A_pt − A_rod) − Q_pv(Δp)) (1 − α p_reb) / ((L_pt − X0 − x)(A_pt − A_rod) α),

is stiff near ``Δp = 0`` (docs/model.md §2.1), so each step is integrated implicitly, by
variable-step BDF2 (A-stable, second order; backward Euler on the first sub-step and after a
step ratio of :data:`BDF2_MAX_STEP_RATIO` or more), on sub-steps no longer than
``numerics.max_substep_s``, with the
stroke and velocity interpolated linearly between the previous and the current sample.  The
implicit equation is solved in the valve-table coordinate ``z`` (see
:mod:`damper_emulator.model.valve_table`), in which it is monotonic, by Newton's method
safeguarded with bisection.  ``P_com`` is algebraic (eq 3) and the force is eq 4.

**Adaptive damper** (docs/model.md §6, :mod:`damper_emulator.model.adaptive`).  The valve flow of
eq 2 is ``Q_pv(Δp) + Q_b(Δp)``: the solenoid bypass in parallel with the piston valve, open
by the *effective* valve command, which follows the commanded one
(:meth:`DamperStepper.set_valve_command`, 0 comfort .. 1 sport) through the solenoid's
first-order lag, integrated exactly at the start of each step; the bypass area is then held
over the step's sub-steps.  ``Q_b`` increases with ``Δp``, so the implicit residual stays
monotone in ``z``.  At command 1 (bypass closed), or for a damper without a
``damper.adaptive`` group, the bypass is never evaluated and the forces are bit for bit
those of the paper's model.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from damper_emulator.errors import UserError
from damper_emulator.model.adaptive import (
    bypass_area,
    bypass_coefficients,
    bypass_flow,
    solenoid_lag,
)
from damper_emulator.model.discovered import N_TERMS, TERM_FIELDS, advance, features
from damper_emulator.model.extensions import (
    AIR_PRESSURE_FLOOR,
    P_ATM,
    end_stop_force,
    gas_temperature,
    groove_window,
    heat_rise,
    lag_weight,
    lugre_steady,
    lugre_update,
    viscosity_scale,
)
from damper_emulator.model.gas import compression_chamber_pressure_kernel
from damper_emulator.model.jit import inlined_kernel, kernel
from damper_emulator.model.valve_table import EXTRAPOLATION_LIMIT, valve_point, z_of_pressure_drop
from damper_emulator.params import (
    BypassGrooveParams,
    DamperParams,
    EndStopParams,
    ExtensionParams,
    LugreFrictionParams,
    ModelConfig,
    ViscosityTemperatureParams,
    check_extensions,
    load_config,
    valve_tables,
)


class Fault(enum.IntFlag):
    """Fault bits returned with every stepper output."""

    NONE = 0
    #: stroke, velocity or time step was NaN, infinite or (dt) not positive: input ignored,
    #: the last force is held.
    INVALID_INPUT = 1
    #: stroke beyond the physical travel: clamped inside it.
    STROKE_CLAMPED = 2
    #: valve flow beyond the look-up table: extrapolated (or clamped at its limit).
    VALVE_EXTRAPOLATED = 4
    #: the implicit solve did not converge within the iteration cap.
    SOLVER = 8
    #: velocity beyond ``numerics.valve_table_max_velocity_m_s``: clamped to it.
    VELOCITY_CLAMPED = 16


#: Variable-step BDF2 is zero-stable for step ratios below 1 + √2; a larger jump in the
#: sub-step (a pause in the input) restarts with one backward-Euler step.
BDF2_MAX_STEP_RATIO = 1.0 + math.sqrt(2.0)
#: The Newton solve of eq 2 takes a step without evaluating it once more when it is at most
#: this fraction of the step before (the iteration is in its quadratic regime, not crawling
#: along a kink of the valve law) and the next step it predicts is within the tolerance.
NEWTON_CONTRACTION = 0.1
#: The gas stiffness the series spring's implicit coupling uses is a forward difference
#: over this fraction of the gas column's length (V_gas / A_rod at the stroke).
MOUNT_GAS_STEP_FRACTION = 1e-6

#: The kernels' arrays: packed parameters, valve-table coefficients, state, samples.
_Vec = NDArray[np.float64]

# The same bits as plain ints for the compiled kernel.
_INVALID_INPUT = int(Fault.INVALID_INPUT)
_STROKE_CLAMPED = int(Fault.STROKE_CLAMPED)
FAULT_VALVE_EXTRAPOLATED = int(Fault.VALVE_EXTRAPOLATED)
FAULT_SOLVER = int(Fault.SOLVER)
_VELOCITY_CLAMPED = int(Fault.VELOCITY_CLAMPED)

# Layout of the packed parameter vector (see ``DamperModel``); the bypass constants of the
# adaptive damper (all 0 without a ``damper.adaptive`` group) come next:
# ``P_BP_LAMINAR`` a = 8πρνL, ``P_BP_TURBULENT`` b = ρ/(2 C_d²), the open areas at commands
# 0 and 0.5 [m²] and the solenoid's t63 [s]; then the model extensions
# (:mod:`damper_emulator.model.extensions`), each off while its switch entry is 0:
# LuGre friction (``P_LG_S0`` σ0), viscosity–temperature (``P_TH_BETA`` β), cavitation
# (``P_CAV_ON``), valve lag (``P_VL_TAU``), series compliance (``P_MOUNT_K``), end stops
# (``P_ES_K``), air entrainment (``P_AIR_EPS``), bypass groove (``P_GR_AREA``) and gas heat
# transfer (``P_GT_TAU``); last the discovered term (``P_DT_ON``, then its coefficients
# ``P_DT_COEF + k`` in the order of :mod:`damper_emulator.model.discovered`, its smooth-sign
# velocity, reference temperature, zone centre and width and lag time constant).
(P_A_ANNULUS, P_A_PISTON, P_A_ROD, P_MAX_EXT, P_ALPHA, P_FRICTION, P_GAS, V_GAS, P_GAMMA,
 P_SCALE_R, P_STEP_R, P_SCALE_C, P_STEP_C, P_X_MIN, P_X_MAX, P_SUBSTEP, P_TOL, P_MAXIT,
 P_ZLIM_R, P_ZLIM_C, P_SETTLE, P_V_MAX, P_BP_LAMINAR, P_BP_TURBULENT, P_BP_AREA_COMFORT,
 P_BP_AREA_NORMAL, P_BP_T63,
 P_LG_FC, P_LG_FS, P_LG_VS, P_LG_S0,
 P_TH_BETA, P_TH_TREF, P_TH_CAP, P_TH_TAU,
 P_CAV_ON, P_CAV_P,
 P_VL_TAU,
 P_MOUNT_K,
 P_ES_XR, P_ES_XC, P_ES_K,
 P_AIR_EPS,
 P_GR_AREA, P_GR_X, P_GR_HALF, P_GR_LAMINAR, P_GR_TURBULENT,
 P_GT_TAU,
 P_DT_ON, P_DT_VSIGN, P_DT_TREF, P_DT_CENTRE, P_DT_WIDTH, P_DT_TAU,
 P_DT_COEF) = range(56)
P_SIZE = P_DT_COEF + N_TERMS

# Layout of the state vector; ``S_CMD`` is the commanded valve command (0 comfort .. 1
# sport), ``S_CMD_EFF`` the effective one (after the solenoid lag); then the extensions'
# states: the measured temperature [°C] (an input; NaN: none, the reference temperature),
# the heat model's temperature rise [K], the LuGre bristle deflection [m], the cavity volume
# [m³], the lagged piston-valve flow [m³/s], the series-spring (= damper) force [N], the
# gas temperature ratio T/T_wall and the spring force one sub-step earlier [N] (for BDF2);
# the discovered term's: the velocity two samples back [m/s] and the step before the last
# [s] (the acceleration), the energy dissipated so far [J], the lagged force and the force
# without the term [N]; then its features at the last sample (scratch).
(S_P_REB, S_Z, S_X, S_V, S_FORCE, S_P_COM, S_P_PREV, S_H_PREV, S_CMD, S_CMD_EFF,
 S_TEMP_IN, S_HEAT_DT, S_BRISTLE, S_V_CAV, S_Q_VALVE, S_MOUNT_F, S_GAS_THETA, S_MOUNT_PREV,
 S_Z_PREV, S_V2, S_H2, S_DT_ENERGY, S_DT_LAG, S_DT_FORCE, S_DT_ROW) = range(25)
S_SIZE = S_DT_ROW + N_TERMS


@kernel
def valve_state(z: float, prm: _Vec, coef_r: _Vec, coef_c: _Vec
                 ) -> tuple[float, float, float, float, bool]:
    """Signed Δp [Pa], dΔp/dz, signed Q_pv [m³/s], dQ/dz, beyond-table flag at ``z``."""
    if z >= 0.0:
        return valve_point(coef_r, prm[P_STEP_R], prm[P_SCALE_R], z)
    dp, ddp, q, dq, beyond = valve_point(coef_c, prm[P_STEP_C], prm[P_SCALE_C], -z)
    return -dp, ddp, -q, dq, beyond


@kernel
def _z_of(prm: _Vec, dp: float, visc: float) -> float:
    """Table coordinate at which the (viscosity-scaled, factor ``visc``) valve drop is
    ``dp`` [Pa, signed]."""
    if dp >= 0.0:
        return z_of_pressure_drop(dp / visc, prm[P_SCALE_R])
    return -z_of_pressure_drop(-dp / visc, prm[P_SCALE_C])


@kernel
def _flow_state(z: float, prm: _Vec, coef_r: _Vec, coef_c: _Vec, area: float, gr_area: float,
                visc: float, q_lag: float, lag_w: float
                ) -> tuple[float, float, float, float, bool, float]:
    """:func:`valve_state` with the extensions and parallel paths: the valve drop scaled by
    ``visc``, the valve flow lagged (old flow ``q_lag``, weight ``lag_w``), the bypass (open
    ``area`` [m²]) and the groove (open ``gr_area``) in parallel.  Returns signed Δp,
    dΔp/dz, total flow, its derivative in ``z``, beyond-table flag, the valve's own flow."""
    dp, ddp, q, dq, beyond = valve_state(z, prm, coef_r, coef_c)
    if visc != 1.0:
        dp *= visc
        ddp *= visc
    if lag_w > 0.0:
        q = lag_w * q_lag + (1.0 - lag_w) * q
        dq *= 1.0 - lag_w
    q_valve = q
    if area > 0.0:
        qb, dqb = bypass_flow(dp, area, prm[P_BP_LAMINAR], prm[P_BP_TURBULENT])
        q += qb
        dq += dqb * ddp
    if gr_area > 0.0:
        qb, dqb = bypass_flow(dp, gr_area, prm[P_GR_LAMINAR], prm[P_GR_TURBULENT])
        q += qb
        dq += dqb * ddp
    return dp, ddp, q, dq, beyond, q_valve


@inlined_kernel
def eq2_gain(max_extension: float, area: float, alpha: float, x: float, h: float) -> float:
    """``k = h / (V_reb α)`` of the implicit step of eq 2 over ``h`` [s] at stroke ``x``,
    with the rebound chamber's volume ``V_reb = (L_pt − X0 − x)(A_pt − A_rod)``
    (``max_extension = L_pt − X0``, ``area = A_pt − A_rod``)."""
    gain: float = h / ((max_extension - x) * area * alpha)
    return gain


@kernel
def eq2_residual(p: float, dp_dz: float, q: float, dq_dz: float, p_old: float, k: float,
                 q_in: float, alpha: float) -> tuple[float, float]:
    """Residual of the implicit step of eq 2, ``R = p − p_old − k (q_in − Q)(1 − α p)``, and
    ``dR/dz``, at chamber pressure ``p`` and valve flow ``Q`` (with their derivatives in
    the table coordinate ``z``); ``q_in = ẋ (A_pt − A_rod)``, ``k`` from :func:`eq2_gain`."""
    r = p - p_old - k * (q_in - q) * (1.0 - alpha * p)
    dr = dp_dz + k * dq_dz * (1.0 - alpha * p) + k * (q_in - q) * alpha * dp_dz
    return r, dr


@inlined_kernel
def bdf2_weight(h: float, h_prev: float) -> float:
    """Step ratio ``w = h / h_prev`` of variable-step BDF2, or 0 (backward Euler) on the
    first sub-step and after a ratio of :data:`BDF2_MAX_STEP_RATIO` or more."""
    if h_prev > 0.0 and h / h_prev < BDF2_MAX_STEP_RATIO:
        return h / h_prev
    return 0.0


@inlined_kernel
def bdf2_combination(y: float, y_prev: float, w: float) -> float:
    """BDF2's ``ŷ = ((1 + w)² y − w² y_prev) / (1 + 2w)``: the step is ``y_new − ŷ =
    h_eff f(y_new)`` with ``h_eff = h (1 + w)/(1 + 2w)`` (:func:`bdf2_step`)."""
    combined: float = ((1.0 + w) ** 2 * y - w * w * y_prev) / (1.0 + 2.0 * w)
    return combined


@inlined_kernel
def bdf2_step(h: float, w: float) -> float:
    """``h_eff = h (1 + w) / (1 + 2w)`` of :func:`bdf2_combination`."""
    h_eff: float = h * (1.0 + w) / (1.0 + 2.0 * w)
    return h_eff


@inlined_kernel
def clamp_input(x: float, v: float, x_min: float, x_max: float, v_max: float
                ) -> tuple[float, float, int]:
    """Stroke clamped to the travel ``[x_min, x_max]`` and velocity to ``±v_max`` (the
    valve table's), with the fault bits that say so (selects only: the lanes vectorise
    it)."""
    stroke_clamped = x < x_min or x > x_max
    velocity_clamped = abs(v) > v_max
    flags = ((_STROKE_CLAMPED if stroke_clamped else 0)
             | (_VELOCITY_CLAMPED if velocity_clamped else 0))
    x = min(max(x, x_min), x_max)
    v = math.copysign(v_max, v) if velocity_clamped else v
    return x, v, flags


@inlined_kernel
def coulomb_friction(friction_n: float, v: float) -> float:
    """Eq 4's friction term ``F_friction sgn(ẋ)`` [N, rebound +]."""
    sgn = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
    force: float = friction_n * sgn
    return force


@inlined_kernel
def damper_force(a_annulus: float, a_piston: float, p_reb: float, p_com: float,
                 friction: float, x: float, stop_reb: float, stop_com: float,
                 stop_k: float) -> float:
    """Damper force [N, rebound +], eq 4: ``(A_pt − A_rod) P_reb − A_pt P_com`` plus the
    friction term, plus the end stops' force at stroke ``x`` when they are in use
    (``stop_k > 0``; :func:`~damper_emulator.model.extensions.end_stop_force`)."""
    force: float = a_annulus * p_reb - a_piston * p_com + friction
    stops = end_stop_force(x, stop_reb, stop_com, stop_k)
    return force + stops if stop_k > 0.0 else force


@kernel
def substeps(prm: _Vec, dt: float) -> tuple[int, float]:
    """Number of implicit sub-steps of a step of ``dt`` [s] (none longer than
    ``numerics.max_substep_s``) and their length."""
    n_sub = max(1, int(math.ceil(dt / prm[P_SUBSTEP] - 1e-9)))
    return n_sub, dt / n_sub


@kernel
def newton_update(z: float, r: float, dr: float, lo: float, hi: float, last_step: float,
                   tol: float) -> tuple[float, float, float, float, bool, float]:
    """One safeguarded Newton update of the implicit solve of eq 2 in ``z``.

    ``r`` and ``dr`` are the residual and its derivative at ``z``; ``[lo, hi]`` brackets the
    root (``r`` increases with ``z``), ``last_step`` is the last Newton step's length (0:
    none yet, or the last update bisected), ``tol`` the relative tolerance on ``z``.  The
    update is the Newton step ``z − r/dr``, or the bracket's midpoint where that step leaves
    the bracket or ``dr <= 0``.  The solve is done when ``r`` is 0, when the step is
    within the tolerance of ``z`` (tested before the bracket: ``z`` is always one end of it,
    and a step below ``z``'s last bit would otherwise restart bisection), or when the
    iteration is quadratic: this step is at most :data:`NEWTON_CONTRACTION` of the last and
    the next one it predicts, step³/last², is within the tolerance.

    Returns ``(z_next, lo, hi, last_step, done, dz)``; when ``done``, the root is ``z``
    (``dz == 0``) or, by the quadratic shortcut, ``z_next = z + dz``, whose values the
    caller takes to first order in ``dz`` instead of evaluating once more (2 valve
    evaluations instead of 3 in most solves; they differ from the evaluated ones by
    ``O(dz²)``, far below the tolerance).  Written with selects only, no branch on the
    data, so that a loop over designs may run it in SIMD lanes.
    """
    hi = z if r > 0.0 else hi
    lo = lo if r > 0.0 else z
    mid = 0.5 * (lo + hi)
    z_newton = z - r / dr if dr > 0.0 else mid
    z_tol = tol * (1.0 + abs(z))
    step_len = abs(z_newton - z)
    outside = z_newton <= lo or z_newton >= hi
    converged = r == 0.0 or step_len <= z_tol or (outside and abs(mid - z) <= z_tol)
    quadratic = (not converged and not outside and step_len <= NEWTON_CONTRACTION * last_step
                 and step_len * step_len * step_len <= z_tol * last_step * last_step)
    z_next = mid if outside else z_newton
    dz = z_newton - z if quadratic else 0.0
    return z_next, lo, hi, 0.0 if outside else step_len, converged or quadratic, dz


@kernel
def _implicit_substep(prm: _Vec, coef_r: _Vec, coef_c: _Vec, p_old: float, z_old: float,
                      x: float, v: float, h: float, bp_area: float, p_com: float,
                      visc: float, q_lag: float, lag_w: float, gr_area: float,
                      mount_c: float, mount_hat: float, f_const: float, gas_c: float,
                      f_ref: float, air_hat: float
                      ) -> tuple[float, float, float, int]:
    """One implicit step ``p − p_old = h f(p)`` of eq 2 to stroke ``x``, velocity ``v``:
    backward Euler as it stands, BDF2 with ``p_old``, ``h`` the BDF2 combinations.

    Solves ``R(z) = p_com + Δp(z) − p_old − k (ẋ A − Q(z)) (1 − α p(z)) = 0`` with
    ``k = h / (V_reb α)``; ``R`` increases with ``z``.  ``Q = Q_pv + Q_b``: the piston valve
    and, when ``bp_area`` [m²] > 0, the solenoid bypass in parallel (docs/model.md §6; ``Q_b``
    increases with ``Δp``, so ``R`` still increases with ``z``); with the bypass closed and
    no extension the arithmetic is the paper's model's exactly.  Extensions
    (:mod:`damper_emulator.model.extensions`), each skipped at its neutral value:
    ``visc`` ≠ 1 scales the valve drop; ``lag_w`` > 0 lags the valve flow behind ``q_lag``;
    ``gr_area`` > 0 opens the groove; ``mount_c`` = A/(k_m h) > 0 is the series spring:
    the inflow is ``ẋ A − mount_c (F − mount_hat)`` with the spring (= damper) force
    ``F = A p − A_pt P_com + F_fr`` and ``mount_hat`` its BDF2 combination, and the gas
    pressure follows the damper's own stroke ``x_d = x − F/k_m`` linearly implicitly,
    ``P_com = p_com + gas_c (F − f_ref)`` (``p_com`` at the stroke the force ``f_ref``
    gives, ``gas_c = −P_com'(x_d)/k_m``); with ``p = P_com + Δp`` that makes
    ``F = (A Δp + f_const) / (1 + A_rod gas_c)``, ``f_const = F_fr − A_rod (p_com − gas_c
    f_ref)``.  ``P_AIR_EPS`` > 0 adds the air term ``(ε P_ATM/α)(air_hat − 1/p)``
    (``air_hat`` the BDF2 combination of ``1/p``).  Each keeps ``R`` increasing.  Returns
    ``(z, p_reb, q_valve, flags)``.
    """
    area = prm[P_A_ANNULUS]
    alpha = prm[P_ALPHA]
    k = eq2_gain(prm[P_MAX_EXT], area, alpha, x, h)
    q_in = v * area
    air_c = prm[P_AIR_EPS] * P_ATM / alpha
    lo = -prm[P_ZLIM_C]
    hi = prm[P_ZLIM_R]
    if mount_c > 0.0 and 0.5 / alpha > p_com:
        # through the spring the inflow falls with p, and with eq 2's factor (1 − α p) the
        # residual turns over above p = 1/(2α) (far above any damper pressure): keep the
        # bracket below it
        hi = min(hi, _z_of(prm, 0.5 / alpha - p_com, visc))
    z = min(max(z_old, lo), hi)
    tol = prm[P_TOL]
    flags = 0
    q_valve = 0.0
    # any extension acting in this solve (one test per iteration when none does)
    ext = visc != 1.0 or lag_w > 0.0 or gr_area > 0.0 or mount_c > 0.0 or air_c > 0.0
    dq_valve = 0.0
    # the series spring: F = (A Δp + f_const) mount_s, dF/dΔp = A mount_s
    mount_s = 1.0 / (1.0 + prm[P_A_ROD] * gas_c)
    # the last Newton step's length (0: none yet, or the last step bisected)
    last_step = 0.0
    for _ in range(int(prm[P_MAXIT])):
        # _flow_state written out (through a wrapper the valve look-up is no longer inlined
        # into this loop, measured 25 % slower)
        dp, ddp, q, dq, beyond = valve_state(z, prm, coef_r, coef_c)
        if ext:
            if visc != 1.0:
                dp *= visc
                ddp *= visc
            if lag_w > 0.0:
                q = lag_w * q_lag + (1.0 - lag_w) * q
                dq *= 1.0 - lag_w
            q_valve = q
            dq_valve = dq
        if bp_area > 0.0:
            qb, dqb = bypass_flow(dp, bp_area, prm[P_BP_LAMINAR], prm[P_BP_TURBULENT])
            q += qb
            dq += dqb * ddp
        p = p_com + dp
        dpz = ddp  # dp/dz
        if ext:
            if gr_area > 0.0:
                qb, dqb = bypass_flow(dp, gr_area, prm[P_GR_LAMINAR], prm[P_GR_TURBULENT])
                q += qb
                dq += dqb * ddp
            if mount_c > 0.0:
                f_spring = (area * dp + f_const) * mount_s
                df_spring = area * ddp * mount_s
                p += gas_c * (f_spring - f_ref)
                dpz += gas_c * df_spring
                q_in = v * area - mount_c * (f_spring - mount_hat)
        r, dr = eq2_residual(p, dpz, q, dq, p_old, k, q_in, alpha)
        if ext:
            if air_c > 0.0:
                r += air_c * (air_hat - 1.0 / max(p, AIR_PRESSURE_FLOOR))
            if mount_c > 0.0:
                dr += k * mount_c * df_spring * (1.0 - alpha * p)
            if air_c > 0.0 and p > AIR_PRESSURE_FLOOR:
                dr += air_c * dpz / (p * p)
        z_new, lo, hi, last_step, done, dz = newton_update(z, r, dr, lo, hi, last_step, tol)
        if done:
            if dz != 0.0:
                # the quadratic shortcut: the step and its first-order values
                p += dpz * dz
                q_valve += dq_valve * dz
                z = z_new
            break
        z = z_new
    else:
        dp, ddp, q, dq, beyond = valve_state(z, prm, coef_r, coef_c)  # Δp only
        if visc != 1.0:
            dp *= visc
        p = p_com + dp
        if mount_c > 0.0:
            p += gas_c * ((area * dp + f_const) * mount_s - f_ref)
        flags = FAULT_SOLVER
    if beyond:
        flags |= FAULT_VALVE_EXTRAPOLATED
    return z, p, q_valve, flags


@kernel
def _friction(prm: _Vec, state: _Vec, v: float, dt: float) -> float:
    """Friction force [N, rebound +] at velocity ``v``: eq 4's ``F_friction sgn(ẋ)``, or with
    LuGre friction ``σ0 z`` after the bristle state (``state[S_BRISTLE]``) has followed ``v``
    over ``dt`` (``dt = 0``: the steady state at ``v``)."""
    s0 = prm[P_LG_S0]
    if s0 > 0.0:
        if dt > 0.0:
            zb = lugre_update(state[S_BRISTLE], v, dt, prm[P_LG_FC], prm[P_LG_FS],
                              prm[P_LG_VS], s0)
        else:
            zb = lugre_steady(v, prm[P_LG_FC], prm[P_LG_FS], prm[P_LG_VS], s0)
        state[S_BRISTLE] = zb
        f_lugre: float = s0 * zb
        return f_lugre
    return coulomb_friction(prm[P_FRICTION], v)


@kernel
def _force(prm: _Vec, p_reb: float, p_com: float, friction: float, x: float) -> float:
    """Damper force [N, rebound +], eq 4 (``friction`` its last term), plus the end stops'
    force at stroke ``x`` when they are in use."""
    return damper_force(prm[P_A_ANNULUS], prm[P_A_PISTON], p_reb, p_com, friction, x,
                        prm[P_ES_XR], prm[P_ES_XC], prm[P_ES_K])


@kernel
def _discovered(prm: _Vec, state: _Vec, x: float, v: float, dt: float, force: float
                ) -> float:
    """The discovered term's force [N] at the sample (``x``, ``v``) ``dt`` after the last
    (``dt = 0``: a settled start, no acceleration), the model's force being ``force``
    without it; its states (acceleration history, energy, lag) advanced
    (:func:`damper_emulator.model.discovered.advance`).  Call with the sample's pressures
    in ``state`` and the last sample's velocity still in ``state[S_V]`` (a settled start:
    ``v`` already)."""
    a, energy, lag = advance(v, state[S_V], state[S_V2], dt, state[S_H2],
                             state[S_DT_ENERGY], state[S_DT_LAG], state[S_DT_FORCE], force,
                             prm[P_DT_TAU])
    state[S_DT_ENERGY], state[S_DT_LAG] = energy, lag
    state[S_V2], state[S_H2] = state[S_V], dt
    state[S_DT_FORCE] = force
    row = state[S_DT_ROW:S_DT_ROW + N_TERMS]
    features(row, x, v, a, state[S_TEMP_IN], state[S_DT_ENERGY], state[S_P_REB],
             state[S_P_COM], force, state[S_DT_LAG], prm[P_DT_VSIGN], prm[P_DT_TREF],
             prm[P_DT_CENTRE], prm[P_DT_WIDTH])
    total = 0.0
    for k in range(N_TERMS):
        total += prm[P_DT_COEF + k] * row[k]
    return total


@kernel
def _viscosity_factor(prm: _Vec, state: _Vec) -> float:
    """Valve-drop factor of the viscosity–temperature extension (1 when off)."""
    if prm[P_TH_BETA] <= 0.0:
        return 1.0
    t = state[S_TEMP_IN]
    if not math.isfinite(t):
        t = prm[P_TH_TREF]
    return viscosity_scale(prm[P_TH_BETA], prm[P_TH_TREF], t + state[S_HEAT_DT])


@kernel
def _gas_volume(prm: _Vec, x: float) -> float:
    volume: float = prm[V_GAS] + prm[P_A_ROD] * x
    return volume


@kernel
def _gas_pressure(prm: _Vec, xd: float, xd_prev: float, theta: float, h: float
                  ) -> tuple[float, float]:
    """Gas pressure [Pa] at the damper's stroke ``xd`` after a sub-step ``h`` from
    ``xd_prev``, and the gas temperature ratio then: eq 3, or with the gas exchanging heat
    (:func:`~damper_emulator.model.extensions.gas_temperature`) from ratio ``theta``."""
    if prm[P_GT_TAU] > 0.0:
        vol = _gas_volume(prm, xd)
        theta = gas_temperature(theta, _gas_volume(prm, xd_prev), vol, prm[P_GAMMA], h,
                                prm[P_GT_TAU])
        return prm[P_GAS] * prm[V_GAS] / vol * theta, theta
    return compression_chamber_pressure_kernel(xd, prm[P_GAS], prm[V_GAS], prm[P_A_ROD],
                                               prm[P_GAMMA]), theta


@kernel
def _groove_area(prm: _Vec, x: float) -> float:
    """Open area of the bypass groove at stroke ``x`` [m²] (0 without one)."""
    if prm[P_GR_AREA] <= 0.0:
        return 0.0
    area: float = prm[P_GR_AREA] * groove_window(x, prm[P_GR_X], prm[P_GR_HALF])
    return area


@kernel
def bypass_area_of(prm: _Vec, command: float) -> float:
    """Open bypass area [m²] at the effective ``command``."""
    return bypass_area(command, prm[P_BP_AREA_COMFORT], prm[P_BP_AREA_NORMAL])


@kernel
def _equilibrium_z(prm: _Vec, coef_r: _Vec, coef_c: _Vec, q_target: float, area: float,
                   gr_area: float, visc: float) -> float:
    """Table coordinate at which valve, bypass (open ``area``) and groove (``gr_area``)
    pass ``q_target`` (the rigid-oil limit)."""
    lo = -prm[P_ZLIM_C]
    hi = prm[P_ZLIM_R]
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if _flow_state(mid, prm, coef_r, coef_c, area, gr_area, visc, 0.0, 0.0)[2] < q_target:
            lo = mid
        else:
            hi = mid
        if hi - lo <= prm[P_TOL]:
            break
    z: float = 0.5 * (lo + hi)
    return z


@kernel
def init_state(prm: _Vec, coef_r: _Vec, coef_c: _Vec, state: _Vec, x: float, v: float
               ) -> None:
    """Put ``state`` in quasi-steady equilibrium at stroke ``x`` moving at ``v``: valve and
    bypass (at the effective command ``state[S_CMD_EFF]``, left as it is) pass
    ``v (A_pt − A_rod)`` (at rest: ``p_reb = P_com``).  The extensions' states settle too
    (no cavity, the gas at the wall temperature, the bristles in steady sliding); the heat
    model's temperature rise and the measured temperature are kept."""
    x = min(max(x, prm[P_X_MIN]), prm[P_X_MAX])
    area = bypass_area_of(prm, state[S_CMD_EFF])
    gr_area = _groove_area(prm, x)
    visc = _viscosity_factor(prm, state)
    if v != 0.0:
        z = _equilibrium_z(prm, coef_r, coef_c, v * prm[P_A_ANNULUS], area, gr_area, visc)
    else:
        z = 0.0
    dp, _d, _q, _dq, _b, q_valve = _flow_state(z, prm, coef_r, coef_c, area, gr_area, visc,
                                               0.0, 0.0)
    fr = _friction(prm, state, v, 0.0)
    # behind a series spring the damper sits at x − F/k: a few fixed-point rounds (the gas
    # spring is orders of magnitude softer than any mount, so each round gains as much)
    xd = x
    for _ in range(4 if prm[P_MOUNT_K] > 0.0 else 1):
        # (a gas that exchanges heat starts at the wall temperature, ratio 1)
        p_com = _gas_pressure(prm, xd, xd, 1.0, 0.0)[0]
        p = p_com + dp
        if prm[P_CAV_ON] > 0.0 and p < prm[P_CAV_P]:
            # steady flow the valve cannot pass above the cavitation pressure: the chamber
            # sits at it (the cavity opens on the first step)
            p = prm[P_CAV_P]
            z = _z_of(prm, p - p_com, visc)
        force = _force(prm, p, p_com, fr, x)
        if prm[P_MOUNT_K] > 0.0:
            xd = min(max(x - force / prm[P_MOUNT_K], prm[P_X_MIN]), prm[P_X_MAX])
    state[S_P_REB] = p
    state[S_Z] = z
    state[S_X] = x
    state[S_V] = v
    state[S_P_COM] = p_com
    state[S_FORCE] = force
    state[S_P_PREV] = p
    state[S_H_PREV] = 0.0
    state[S_V_CAV] = 0.0
    state[S_Q_VALVE] = q_valve
    state[S_MOUNT_F] = force
    state[S_MOUNT_PREV] = force
    state[S_GAS_THETA] = 1.0
    state[S_Z_PREV] = z
    if prm[P_DT_ON] > 0.0:
        state[S_FORCE] = force + _discovered(prm, state, x, v, 0.0, force)


@kernel
def step(prm: _Vec, coef_r: _Vec, coef_c: _Vec, state: _Vec, x: float, v: float, dt: float
         ) -> tuple[float, int]:
    """Advance ``state`` to the sample (stroke ``x`` [m], velocity ``v`` [m/s]) taken ``dt``
    seconds after the previous one; returns ``(force [N], fault flags)``.

    The effective valve command first follows the commanded one over ``dt`` (solenoid lag,
    docs/model.md §6); the bypass it opens is held over the step.  Invalid input (non-finite,
    ``dt <= 0``) leaves the state untouched and returns the last force; a stroke beyond
    the travel is clamped.  The force is always finite.  The model extensions in use
    (:mod:`damper_emulator.model.extensions`) act inside the same sub-steps.
    """
    if not (math.isfinite(x) and math.isfinite(v) and math.isfinite(dt) and dt > 0.0):
        return state[S_FORCE], _INVALID_INPUT
    cmd = state[S_CMD_EFF]
    if cmd != state[S_CMD]:
        cmd = solenoid_lag(cmd, state[S_CMD], dt, prm[P_BP_T63])
        state[S_CMD_EFF] = cmd
    x, v, flags = clamp_input(x, v, prm[P_X_MIN], prm[P_X_MAX], prm[P_V_MAX])
    if dt > prm[P_SETTLE]:
        # after a gap far longer than the pressure time constants the damper is in
        # quasi-steady equilibrium at the new sample (the heat model cools meanwhile)
        if prm[P_TH_BETA] > 0.0 and prm[P_TH_CAP] > 0.0:
            state[S_HEAT_DT] = heat_rise(state[S_HEAT_DT], 0.0, dt, prm[P_TH_CAP],
                                         prm[P_TH_TAU])
        init_state(prm, coef_r, coef_c, state, x, v)
        return state[S_FORCE], flags
    bp_area = bypass_area_of(prm, cmd)
    fr = _friction(prm, state, v, dt)
    visc = _viscosity_factor(prm, state)
    n_sub, h = substeps(prm, dt)
    x0 = state[S_X]
    v0 = state[S_V]
    p = state[S_P_REB]
    z = state[S_Z]
    p_com = state[S_P_COM]
    p_prev = state[S_P_PREV]
    h_prev = state[S_H_PREV]
    # extensions
    k_m = prm[P_MOUNT_K]
    mount_f = state[S_MOUNT_F]
    mount_prev = state[S_MOUNT_PREV]
    theta = state[S_GAS_THETA]
    xd_prev = x0 - mount_f / k_m if k_m > 0.0 else x0
    lag_w = lag_weight(prm[P_VL_TAU], h) if prm[P_VL_TAU] > 0.0 else 0.0
    q_lag = state[S_Q_VALVE]
    cavitation = prm[P_CAV_ON] > 0.0
    v_cav = state[S_V_CAV]
    air = prm[P_AIR_EPS] > 0.0
    z_prev = state[S_Z_PREV]
    for j in range(1, n_sub + 1):
        frac = j / n_sub
        xs = x0 + frac * (x - x0)
        vs = v0 + frac * (v - v0)
        air_hat = 0.0
        mount_hat = mount_f
        w = bdf2_weight(h, h_prev)
        if w > 0.0:
            # variable-step BDF2: p − p̂ = h_eff f(p)
            p_hat = bdf2_combination(p, p_prev, w)
            h_eff = bdf2_step(h, w)
            if k_m > 0.0:
                mount_hat = bdf2_combination(mount_f, mount_prev, w)
            if air:
                air_hat = bdf2_combination(1.0 / max(p, AIR_PRESSURE_FLOOR),
                                           1.0 / max(p_prev, AIR_PRESSURE_FLOOR), w)
        else:
            p_hat = p
            h_eff = h
            if air:
                air_hat = 1.0 / max(p, AIR_PRESSURE_FLOOR)
        p_prev = p
        mount_c = 0.0
        mount_off = 0.0
        gas_c = 0.0
        f_const = 0.0
        xd = xs
        free = False
        theta_old = theta
        if k_m > 0.0:  # the damper's own stroke behind the series spring
            xd_free = xs - mount_f / k_m
            xd = min(max(xd_free, prm[P_X_MIN]), prm[P_X_MAX])
            free = xd == xd_free
            mount_c = prm[P_A_ANNULUS] / (k_m * h_eff)
        p_com, theta = _gas_pressure(prm, xd, xd_prev, theta_old, h)
        if k_m > 0.0:
            mount_off = -prm[P_A_PISTON] * p_com + fr - mount_hat
            if free:
                # the gas follows the damper's stroke through the spring implicitly (its
                # stiffness against the spring's; explicit, a gas nearly closed ran away)
                dx = MOUNT_GAS_STEP_FRACTION * _gas_volume(prm, xd) / prm[P_A_ROD]
                gas_c = -(_gas_pressure(prm, xd + dx, xd_prev, theta_old, h)[0]
                          - p_com) / (dx * k_m)
            f_const = fr - prm[P_A_ROD] * (p_com - gas_c * mount_f)
        gr_area = _groove_area(prm, xd)
        if cavitation and v_cav > 0.0:
            # a cavity is open: the chamber sits at the cavitation pressure until it refills
            p = prm[P_CAV_P]
            z_prev = z
            z = _z_of(prm, p - p_com, visc)
            q = _flow_state(z, prm, coef_r, coef_c, bp_area, gr_area, visc, q_lag, lag_w)
            q_lag = q[5]
            q_in = vs * prm[P_A_ANNULUS] - mount_c * (prm[P_A_ANNULUS] * p + mount_off)
            v_cav += (q[2] - q_in) * h
            if v_cav < 0.0:
                v_cav = 0.0
            h_prev = 0.0  # restart the multistep formula from here
        else:
            # the Newton solve starts from z extrapolated along the last two sub-steps (the
            # previous z alone costs about one more iteration per solve)
            z_start = z + (z - z_prev) * w
            z_prev = z
            z, p, q_lag, f = _implicit_substep(prm, coef_r, coef_c, p_hat, z_start, xd, vs,
                                               h_eff, bp_area, p_com, visc, q_lag, lag_w,
                                               gr_area, mount_c, mount_hat, f_const, gas_c,
                                               mount_f, air_hat)
            flags |= f
            h_prev = h
            if free:
                # the stroke the new force gives, and the gas exactly there
                p_lin = ((p_com + gas_c * (prm[P_A_ANNULUS] * p + fr - mount_f))
                         / (1.0 + gas_c * prm[P_A_PISTON]))
                f_new = prm[P_A_ANNULUS] * p - prm[P_A_PISTON] * p_lin + fr
                xd = min(max(xs - f_new / k_m, prm[P_X_MIN]), prm[P_X_MAX])
                p_com, theta = _gas_pressure(prm, xd, xd_prev, theta_old, h)
            if cavitation and p < prm[P_CAV_P]:
                # the oil would be stretched: a cavity of that volume opens instead
                v_cav = ((prm[P_CAV_P] - p) * (prm[P_MAX_EXT] - xd) * prm[P_A_ANNULUS]
                         * prm[P_ALPHA])
                p = prm[P_CAV_P]
                z = _z_of(prm, p - p_com, visc)
                h_prev = 0.0
        xd_prev = xd
        if k_m > 0.0:
            mount_prev = mount_f
            mount_f = prm[P_A_ANNULUS] * p - prm[P_A_PISTON] * p_com + fr
    state[S_P_PREV] = p_prev
    state[S_H_PREV] = h_prev
    force = _force(prm, p, p_com, fr, x)
    if prm[P_TH_BETA] > 0.0 and prm[P_TH_CAP] > 0.0:
        power = (prm[P_A_ANNULUS] * (p - p_com) + fr) * v
        state[S_HEAT_DT] = heat_rise(state[S_HEAT_DT], power, dt, prm[P_TH_CAP],
                                     prm[P_TH_TAU])
    state[S_P_REB] = p
    state[S_P_COM] = p_com
    if prm[P_DT_ON] > 0.0:
        force += _discovered(prm, state, x, v, dt, force)
    state[S_Z] = z
    state[S_X] = x
    state[S_V] = v
    state[S_FORCE] = force
    state[S_Q_VALVE] = q_lag
    state[S_MOUNT_F] = mount_f
    state[S_MOUNT_PREV] = mount_prev
    state[S_GAS_THETA] = theta
    state[S_V_CAV] = v_cav
    state[S_Z_PREV] = z_prev
    return force, flags


@kernel
def simulate_commanded_samples(prm: _Vec, coef_r: _Vec, coef_c: _Vec, state: _Vec, t: _Vec, x: _Vec,
                        v: _Vec, command: _Vec, temperature: _Vec, force: _Vec, p_reb: _Vec,
                        p_com: _Vec, command_eff: _Vec, flags: NDArray[np.int64]) -> None:
    """The batch loop: ``command[i]`` is the valve command from sample ``i`` on (it drives
    the solenoid lag over the step to sample ``i + 1``); the start is settled at
    ``command[0]``.  ``temperature[i]`` [°C] (NaN: none) is the measured temperature the
    step to sample ``i`` sees (the viscosity–temperature extension)."""
    for i in range(t.size):
        state[S_TEMP_IN] = temperature[i]
        if i == 0:
            state[S_CMD] = command[0]
            state[S_CMD_EFF] = command[0]
            init_state(prm, coef_r, coef_c, state, x[0], v[0])
            force[0] = state[S_FORCE]
            flags[0] = 0
        else:
            force[i], flags[i] = step(prm, coef_r, coef_c, state, x[i], v[i], t[i] - t[i - 1])
        p_reb[i] = state[S_P_REB]
        p_com[i] = state[S_P_COM]
        command_eff[i] = state[S_CMD_EFF]
        state[S_CMD] = command[i]


@kernel
def simulate_samples(prm: _Vec, coef_r: _Vec, coef_c: _Vec, state: _Vec, t: _Vec, x: _Vec, v: _Vec,
              force: _Vec, p_reb: _Vec, p_com: _Vec, flags: NDArray[np.int64]) -> None:
    """The batch loop at valve command 1 ('sport', bypass closed) throughout, whatever
    ``state`` holds (the replay passes a zero state)."""
    state[S_CMD] = 1.0
    state[S_CMD_EFF] = 1.0
    state[S_TEMP_IN] = math.nan
    for i in range(t.size):
        if i == 0:
            init_state(prm, coef_r, coef_c, state, x[0], v[0])
            force[0] = state[S_FORCE]
            flags[0] = 0
        else:
            force[i], flags[i] = step(prm, coef_r, coef_c, state, x[i], v[i], t[i] - t[i - 1])
        p_reb[i] = state[S_P_REB]
        p_com[i] = state[S_P_COM]


def _pack_extensions(prm: np.ndarray, d: DamperParams) -> None:
    """Write the ``damper.extensions`` in use into the packed parameter vector (the others
    keep their neutral 0)."""
    e = cast(ExtensionParams, d.extensions)  # the callers pass a damper with extensions
    g: LugreFrictionParams | ViscosityTemperatureParams | EndStopParams | BypassGrooveParams
    if e.lugre_friction is not None:
        g = e.lugre_friction
        prm[P_LG_FC], prm[P_LG_FS] = g.coulomb_n, g.static_n
        prm[P_LG_VS], prm[P_LG_S0] = g.stribeck_velocity_m_s, g.bristle_stiffness_n_m
    if e.viscosity_temperature is not None:
        g = e.viscosity_temperature
        prm[P_TH_BETA] = g.temperature_coefficient_per_k
        prm[P_TH_TREF] = g.reference_temperature_c
        prm[P_TH_CAP] = g.heat_capacity_j_per_k
        prm[P_TH_TAU] = g.cooling_time_constant_s
    if e.cavitation is not None:
        prm[P_CAV_ON] = 1.0
        prm[P_CAV_P] = e.cavitation.cavitation_pressure_pa
    if e.valve_lag is not None:
        prm[P_VL_TAU] = e.valve_lag.time_constant_s
    if e.series_compliance is not None:
        prm[P_MOUNT_K] = e.series_compliance.stiffness_n_m
    if e.end_stops is not None:
        g = e.end_stops
        prm[P_ES_XR], prm[P_ES_XC] = g.rebound_position_m, g.compression_position_m
        prm[P_ES_K] = g.stiffness_n_m2
    if e.air_entrainment is not None:
        prm[P_AIR_EPS] = e.air_entrainment.air_volume_fraction
    if e.bypass_groove is not None:
        g = e.bypass_groove
        prm[P_GR_AREA], prm[P_GR_X], prm[P_GR_HALF] = g.area_m2, g.center_m, g.half_length_m
        prm[P_GR_LAMINAR], prm[P_GR_TURBULENT] = bypass_coefficients(
            g.oil_density_kg_m3, d.oil_kinematic_viscosity_m2_s, g.land_length_m,
            g.discharge_coefficient)
    if e.gas_heat_transfer is not None:
        prm[P_GT_TAU] = e.gas_heat_transfer.thermal_time_constant_s
    if e.discovered_term is not None:
        t = e.discovered_term
        prm[P_DT_ON] = 1.0
        prm[P_DT_VSIGN], prm[P_DT_TREF] = t.smooth_sign_velocity_m_s, t.reference_temperature_c
        prm[P_DT_CENTRE], prm[P_DT_WIDTH] = t.profile_center_m, t.profile_width_m
        prm[P_DT_TAU] = t.lag_time_constant_s
        for k, name in enumerate(TERM_FIELDS):
            prm[P_DT_COEF + k] = getattr(t, name)


def new_state() -> np.ndarray:
    """A zero state vector with no measured temperature (NaN)."""
    state = np.zeros(S_SIZE)
    state[S_TEMP_IN] = math.nan
    return state


class DamperModel:
    """A validated configuration compiled for the kernel: parameter vector + valve tables.

    Parameters
    ----------
    cfg : ModelConfig, optional
        Default: ``config/sport.yaml``.
    """

    def __init__(self, cfg: ModelConfig | None = None):
        self.cfg = cfg if cfg is not None else load_config()
        d, n = self.cfg.damper, self.cfg.numerics
        rebound, compression = valve_tables(self.cfg)
        self.tables = (rebound, compression)
        prm = np.zeros(P_SIZE)
        prm[P_A_ANNULUS] = d.annulus_area_m2
        prm[P_A_PISTON] = d.piston_area_m2
        prm[P_A_ROD] = d.rod_area_m2
        prm[P_MAX_EXT] = d.max_extension_m
        prm[P_ALPHA] = d.oil_compressibility_per_pa
        prm[P_FRICTION] = d.friction_force_n
        prm[P_GAS] = d.gas_pressure_static_pa
        prm[V_GAS] = d.gas_volume_static_m3
        prm[P_GAMMA] = d.gas_gamma
        prm[P_SCALE_R], prm[P_STEP_R] = rebound.scale_pa, rebound.step
        prm[P_SCALE_C], prm[P_STEP_C] = compression.scale_pa, compression.step
        prm[P_X_MIN] = -d.max_compression_m + n.travel_margin_m
        prm[P_X_MAX] = d.max_extension_m - n.travel_margin_m
        prm[P_SUBSTEP] = n.max_substep_s
        prm[P_TOL] = n.newton_tolerance
        prm[P_MAXIT] = n.newton_max_iterations
        prm[P_SETTLE] = n.settle_gap_s
        prm[P_V_MAX] = n.valve_table_max_velocity_m_s
        prm[P_ZLIM_R] = EXTRAPOLATION_LIMIT * rebound.z_max
        prm[P_ZLIM_C] = EXTRAPOLATION_LIMIT * compression.z_max
        ad = d.adaptive
        if ad is not None:  # else no bypass: areas (and a, b, t63) stay 0
            prm[P_BP_LAMINAR], prm[P_BP_TURBULENT] = bypass_coefficients(
                ad.oil_density_kg_m3, d.oil_kinematic_viscosity_m2_s, ad.bypass_length_m,
                ad.bypass_discharge_coefficient)
            prm[P_BP_AREA_COMFORT] = ad.comfort_area_m2
            prm[P_BP_AREA_NORMAL] = ad.normal_area_m2
            prm[P_BP_T63] = ad.solenoid_t63_s
        if d.extensions is not None:
            _pack_extensions(prm, d)
        self.prm = prm

    def with_extensions(self, extensions: ExtensionParams | None) -> DamperModel:
        """This model with its ``damper.extensions`` replaced by ``extensions``
        (:class:`~damper_emulator.params.ExtensionParams` or ``None``), checked; the valve
        tables are shared (extensions do not change them), so this is cheap."""
        cfg = dataclasses.replace(self.cfg, damper=dataclasses.replace(
            self.cfg.damper, extensions=extensions))
        check_extensions(extensions, cfg.source)
        new = object.__new__(DamperModel)
        new.cfg = cfg
        new.tables = self.tables
        prm = self.prm.copy()
        prm[P_LG_FC:] = 0.0
        if extensions is not None:
            _pack_extensions(prm, cfg.damper)
        new.prm = prm
        return new

    def with_max_substep(self, max_substep_s: float) -> DamperModel:
        """This model integrated on sub-steps of at most ``max_substep_s`` [s] (the
        ``numerics.max_substep_s`` of a copy; tables shared, cheap)."""
        if max_substep_s == self.prm[P_SUBSTEP]:
            return self
        new = object.__new__(DamperModel)
        new.cfg = dataclasses.replace(self.cfg, numerics=dataclasses.replace(
            self.cfg.numerics, max_substep_s=float(max_substep_s)))
        new.tables = self.tables
        new.prm = self.prm.copy()
        new.prm[P_SUBSTEP] = float(max_substep_s)
        return new

    @classmethod
    def from_file(cls, path: str | Path | None = None) -> DamperModel:
        return cls(load_config(path))

    @property
    def stroke_limits_m(self) -> tuple[float, float]:
        """Physical travel ``(-V_gas/A_rod, L_pt − X0)`` [m] (exclusive)."""
        d = self.cfg.damper
        return -d.max_compression_m, d.max_extension_m

    @property
    def adaptive(self) -> bool:
        """Whether the damper has a bypass (a ``damper.adaptive`` group with an open area),
        i.e. whether the valve command changes anything."""
        return bool(self.prm[P_BP_AREA_COMFORT] > 0.0 or self.prm[P_BP_AREA_NORMAL] > 0.0)


def check_valve_command(value: Any) -> float:
    """``value`` as a float if it is a valve command in [0, 1]; else ``ValueError``."""
    try:
        c = float(value)
    except (TypeError, ValueError):
        raise UserError(f"valve command must be a number in [0, 1], got {value!r}") from None
    if not (math.isfinite(c) and 0.0 <= c <= 1.0):
        raise UserError(f"valve command {value!r} outside [0, 1] (0 comfort .. 1 sport)")
    return c


def quasi_steady_force(model: DamperModel, velocity_m_s: float, valve_command: float = 1.0,
                       stroke_m: float = 0.0) -> float:
    """Quasi-steady (rigid-oil limit, eqs 2–4 at ``ṗ_reb = 0``) force [N, rebound +] at
    constant ``velocity_m_s`` through ``stroke_m``, with the bypass of a settled
    ``valve_command``: valve and bypass pass ``ẋ (A_pt − A_rod)`` (friction included).
    The equilibrium the stepper starts from."""
    state = new_state()
    state[S_CMD] = state[S_CMD_EFF] = check_valve_command(valve_command)
    init_state(model.prm, model.tables[0].coef, model.tables[1].coef, state, float(stroke_m),
               float(velocity_m_s))
    return float(state[S_FORCE])


#: :meth:`DamperStepper.warm_up`'s script: steps per cycle of its motion, its stroke and
#: velocity amplitudes (well inside the travel, past the valves' blow-off) and a measured
#: temperature (any finite value reaches the viscosity–temperature branch).
WARM_UP_STEPS = 8
WARM_UP_STROKE_M = 0.01
WARM_UP_VELOCITY_M_S = 0.5
WARM_UP_TEMPERATURE_C = 40.0


class DamperStepper:
    """Real-time form of the compressible model: one sample in, one force out.

    >>> stepper = DamperStepper(DamperModel())
    >>> force, fault = stepper.step(0.001, 0.1, 1e-3)
    >>> stepper.set_valve_command(0.0)      # comfort; the solenoid lag acts from the next step

    Parameters
    ----------
    model : DamperModel
    stroke_m, velocity_m_s : float
        Initial quasi-steady state (default: at rest at the static position).
    valve_command : float
        Initial valve command, 0 comfort .. 0.5 normal .. 1 sport (default), settled.
    """

    def __init__(self, model: DamperModel, stroke_m: float = 0.0, velocity_m_s: float = 0.0,
                 valve_command: float = 1.0):
        self.model = model
        self._prm = model.prm
        self._coef_r = model.tables[0].coef
        self._coef_c = model.tables[1].coef
        self.state = new_state()
        self.state[S_CMD] = check_valve_command(valve_command)
        self.reset(stroke_m, velocity_m_s)

    def reset(self, stroke_m: float = 0.0, velocity_m_s: float = 0.0) -> None:
        """Return to quasi-steady equilibrium at the given stroke and velocity, the solenoid
        settled at the commanded valve command (a discovered term's energy from 0)."""
        self.state[S_CMD_EFF] = self.state[S_CMD]
        self.state[S_DT_ENERGY] = 0.0
        init_state(self._prm, self._coef_r, self._coef_c, self.state, float(stroke_m),
                   float(velocity_m_s))

    def set_valve_command(self, command: float) -> None:
        """Command the valve: 0 comfort (softest) .. 0.5 normal .. 1 sport (bypass closed).

        The effective command follows it through the solenoid lag from the next
        :meth:`step` on (docs/model.md §6).  Raises ``ValueError`` unless ``0 <= command <= 1``.
        Without a ``damper.adaptive`` group the command is kept but changes nothing.
        """
        self.state[S_CMD] = check_valve_command(command)

    def set_temperature(self, temperature_c: float | None) -> None:
        """The measured oil temperature [°C] the viscosity–temperature extension uses from
        the next :meth:`step` on (``None``: none, the extension's reference temperature).
        Without that extension it changes nothing."""
        t = math.nan if temperature_c is None else float(temperature_c)
        if temperature_c is not None and not math.isfinite(t):
            raise UserError(f"temperature must be finite, got {temperature_c!r}")
        self.state[S_TEMP_IN] = t

    @property
    def temperature_rise_k(self) -> float:
        """The oil's temperature rise of the viscosity–temperature extension's heat model
        [K] (0 without it, or without a heat capacity)."""
        return float(self.state[S_HEAT_DT])

    @property
    def valve_command(self) -> float:
        """The commanded valve command (0 comfort .. 1 sport)."""
        return float(self.state[S_CMD])

    @property
    def effective_valve_command(self) -> float:
        """The valve command the bypass is at now (after the solenoid lag)."""
        return float(self.state[S_CMD_EFF])

    def step(self, stroke_m: float, velocity_m_s: float, dt_s: float) -> tuple[float, int]:
        """Advance by ``dt_s`` to the new sample; returns ``(force [N], Fault bits)``.

        Never raises for bad numbers: invalid input holds the last force and sets
        :attr:`Fault.INVALID_INPUT`; a stroke beyond the travel or a velocity beyond the
        valve table is clamped (:attr:`Fault.STROKE_CLAMPED`, :attr:`Fault.VELOCITY_CLAMPED`).
        """
        return step(self._prm, self._coef_r, self._coef_c, self.state, stroke_m, velocity_m_s,
                    dt_s)

    def copy(self) -> DamperStepper:
        """An independent stepper of the same model in the same state (a scratch copy: a
        predictor steps it ahead without touching this one)."""
        twin = object.__new__(DamperStepper)
        twin.model, twin._prm = self.model, self._prm
        twin._coef_r, twin._coef_c = self._coef_r, self._coef_c
        twin.state = self.state.copy()
        return twin

    def warm_up(self) -> None:
        """Load or compile every kernel :meth:`step`, :meth:`reset` and the valve command
        can reach, and run each branch once: the real-time caller's start-up cost, paid
        before it says it is ready rather than in its first loop period (a compile there
        stalls it for seconds).

        A scratch copy of the state goes through a scripted sequence (a settled start,
        strokes both ways, a valve-command sweep through comfort and normal (the bypass and
        the solenoid lag), a measured temperature, a pause longer than
        ``numerics.settle_gap_s`` (the restart from equilibrium), and every fault: NaN
        input, ``dt <= 0``, a stroke beyond the travel, a velocity beyond the table).  This
        stepper's own state is not touched.
        """
        scratch = self.copy()
        lo, hi = self.model.stroke_limits_m
        dt = self.model.cfg.numerics.max_substep_s
        v_fast = 2.0 * self.model.cfg.numerics.valve_table_max_velocity_m_s
        scratch.reset(0.0, 0.0)
        for command in (0.0, 0.5, 1.0):
            scratch.set_valve_command(command)
            for k in range(WARM_UP_STEPS):
                phase = 2.0 * math.pi * k / WARM_UP_STEPS
                scratch.step(WARM_UP_STROKE_M * math.sin(phase),
                             WARM_UP_VELOCITY_M_S * math.cos(phase), dt)
        scratch.set_temperature(WARM_UP_TEMPERATURE_C)
        scratch.step(0.0, 0.1, dt)
        scratch.set_temperature(None)
        scratch.step(0.0, 0.1, 2.0 * self.model.cfg.numerics.settle_gap_s)  # restart
        for x, v, h in ((math.nan, 0.0, dt), (0.0, 0.0, 0.0), (2.0 * hi, 0.0, dt),
                        (2.0 * lo, 0.0, dt), (0.0, v_fast, dt), (0.0, -v_fast, dt)):
            scratch.step(x, v, h)

    @property
    def force_n(self) -> float:
        return float(self.state[S_FORCE])

    @property
    def rebound_pressure_pa(self) -> float:
        return float(self.state[S_P_REB])

    @property
    def compression_pressure_pa(self) -> float:
        return float(self.state[S_P_COM])


@dataclass(frozen=True)
class SimulationResult:
    """Output of :func:`simulate`, one value per input sample."""

    time_s: np.ndarray
    stroke_m: np.ndarray
    velocity_m_s: np.ndarray
    force_n: np.ndarray
    rebound_pressure_pa: np.ndarray
    compression_pressure_pa: np.ndarray
    faults: np.ndarray
    #: effective valve command (after the solenoid lag) at each sample
    valve_command_eff: np.ndarray | None = None


def _check_finite(name: str, arr: np.ndarray) -> None:
    bad = ~np.isfinite(arr)
    if bad.any():
        i = int(np.argmax(bad))
        raise UserError(f"{name} sample {i} is {arr[i]} (must be finite)")


def _check_samples(t: np.ndarray, x: np.ndarray, model: DamperModel) -> None:
    _check_finite("time", t)
    _check_finite("stroke", x)
    if t.size > 1:
        dt = np.diff(t)
        if not (dt > 0).all():
            i = int(np.argmax(~(dt > 0))) + 1
            raise UserError(f"time is not strictly increasing at sample {i} "
                             f"({t[i - 1]!r} then {t[i]!r})")
    lo, hi = model.stroke_limits_m
    out = (x <= lo) | (x >= hi)
    if out.any():
        i = int(np.argmax(out))
        raise UserError(f"stroke sample {i} = {x[i]:.6g} m is beyond the physical travel "
                         f"({lo:.4g} m .. {hi:.4g} m: gas volume / L_pt − X0)")


def simulate(model: DamperModel, time_s: ArrayLike, stroke_m: ArrayLike,
             velocity_m_s: ArrayLike | None = None, valve_command: ArrayLike = 1.0,
             temperature_c: ArrayLike | None = None) -> SimulationResult:
    """Simulate the compressible model over a whole displacement history.

    Uses the same compiled step as :class:`DamperStepper`, starting in quasi-steady
    equilibrium at the first sample.

    Parameters
    ----------
    model : DamperModel
    time_s, stroke_m : array_like, shape (n,)
        Sample times (strictly increasing) [s] and strokes [m, extension +].
    velocity_m_s : array_like, shape (n,), optional
        Stroke velocity [m/s]; by default the numerical derivative of ``stroke_m``.
    valve_command : float or array_like, shape (n,)
        Valve command, 0 comfort .. 1 sport (default): one value, or one per sample, the
        command from that sample on (held until the next; the solenoid lag acts on it; the
        start is settled at the first).  Command 1 gives the paper's model bit for bit.
    temperature_c : array_like, shape (n,), optional
        Measured oil temperature [°C] per sample, for the viscosity–temperature extension
        (ignored without it).

    Returns
    -------
    SimulationResult

    Raises
    ------
    ValueError
        Non-finite samples, time not strictly increasing, stroke beyond the physical
        travel, velocity beyond the valve table or a valve command outside [0, 1] (one
        line naming the sample).
    """
    t = np.ascontiguousarray(time_s, dtype=float)
    x = np.ascontiguousarray(stroke_m, dtype=float)
    if t.ndim != 1 or x.shape != t.shape or t.size == 0:
        raise UserError(f"time and stroke must be 1-D arrays of equal, non-zero length "
                         f"(got shapes {t.shape} and {x.shape})")
    _check_samples(t, x, model)
    if velocity_m_s is None:
        v = np.gradient(x, t) if t.size > 1 else np.zeros_like(x)
    else:
        v = np.ascontiguousarray(velocity_m_s, dtype=float)
        if v.shape != t.shape:
            raise UserError(f"velocity has shape {v.shape}, time {t.shape}")
        _check_finite("velocity", v)
    v_max = model.cfg.numerics.valve_table_max_velocity_m_s
    fast = np.abs(v) > v_max
    if fast.any():
        i = int(np.argmax(fast))
        raise UserError(f"velocity sample {i} = {v[i]:.6g} m/s exceeds "
                         f"numerics.valve_table_max_velocity_m_s = {v_max:g} m/s")
    n = t.size
    cmd = np.asarray(valve_command, dtype=float)
    if cmd.ndim == 0:
        check_valve_command(float(cmd))
        cmd = np.full(n, float(cmd))
    elif cmd.shape != t.shape:
        raise UserError(f"valve command has shape {cmd.shape}, time {t.shape}")
    else:
        bad = ~((cmd >= 0.0) & (cmd <= 1.0))
        if bad.any():
            i = int(np.argmax(bad))
            raise UserError(f"valve command sample {i} = {cmd[i]!r} outside [0, 1]")
        cmd = np.ascontiguousarray(cmd)
    if temperature_c is None:
        temp = np.full(n, math.nan)
    else:
        temp = np.ascontiguousarray(temperature_c, dtype=float)
        if temp.shape != t.shape:
            raise UserError(f"temperature has shape {temp.shape}, time {t.shape}")
        _check_finite("temperature", temp)
    force, p_reb, p_com, c_eff = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    faults = np.zeros(n, dtype=np.int64)
    simulate_commanded_samples(model.prm, model.tables[0].coef, model.tables[1].coef, new_state(),
                        t, x, v, cmd, temp, force, p_reb, p_com, c_eff, faults)
    return SimulationResult(t, x, v, force, p_reb, p_com, faults, c_eff)
