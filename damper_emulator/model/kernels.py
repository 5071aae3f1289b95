"""The compiled building blocks of the compressible model's step (Simms & Crolla eq 2, eq 4).

The valve look-up in the table coordinate ``z`` (:func:`valve_state`, :func:`flow_state`
with the bypass, groove and extensions in parallel), the implicit step of eq 2 (its gain
:func:`eq2_gain` and residual :func:`eq2_residual`), variable-step BDF2
(:func:`bdf2_weight`, :func:`bdf2_combination`, :func:`bdf2_step`), the safeguarded Newton
update (:func:`newton_update`) and the implicit sub-step that solves with them
(:func:`implicit_substep`), the input clamp, the sub-step count and eq 4's force.  The
one-design step (:mod:`damper_emulator.model.step`) and the SIMD lanes
(:mod:`damper_emulator.model.lanes`) share them.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from damper_emulator.model.adaptive import bypass_flow
from damper_emulator.model.extensions import AIR_PRESSURE_FLOOR, P_ATM, end_stop_force
from damper_emulator.model.jit import inlined_kernel, kernel
from damper_emulator.model.layout import (
    FAULT_SOLVER,
    FAULT_STROKE_CLAMPED,
    FAULT_VALVE_EXTRAPOLATED,
    FAULT_VELOCITY_CLAMPED,
    P_A_ANNULUS,
    P_A_ROD,
    P_AIR_EPS,
    P_ALPHA,
    P_BP_LAMINAR,
    P_BP_TURBULENT,
    P_GR_LAMINAR,
    P_GR_TURBULENT,
    P_MAX_EXT,
    P_MAXIT,
    P_SCALE_C,
    P_SCALE_R,
    P_STEP_C,
    P_STEP_R,
    P_SUBSTEP,
    P_TOL,
    P_ZLIM_C,
    P_ZLIM_R,
)
from damper_emulator.model.valve_table import valve_point, z_of_pressure_drop

#: Variable-step BDF2 is zero-stable for step ratios below 1 + √2; a larger jump in the
#: sub-step (a pause in the input) restarts with one backward-Euler step.
BDF2_MAX_STEP_RATIO = 1.0 + math.sqrt(2.0)
#: The Newton solve of eq 2 takes a step without evaluating it once more when it is at most
#: this fraction of the step before (the iteration is in its quadratic regime, not crawling
#: along a kink of the valve law) and the next step it predicts is within the tolerance.
NEWTON_CONTRACTION = 0.1

#: The kernels' arrays: packed parameters, valve-table coefficients, state, samples.
_Vec = NDArray[np.float64]


@kernel
def valve_state(z: float, prm: _Vec, coef_r: _Vec, coef_c: _Vec
                 ) -> tuple[float, float, float, float, bool]:
    """Signed Δp [Pa], dΔp/dz, signed Q_pv [m³/s], dQ/dz, beyond-table flag at ``z``."""
    if z >= 0.0:
        return valve_point(coef_r, prm[P_STEP_R], prm[P_SCALE_R], z)
    dp, ddp, q, dq, beyond = valve_point(coef_c, prm[P_STEP_C], prm[P_SCALE_C], -z)
    return -dp, ddp, -q, dq, beyond


@kernel
def z_of(prm: _Vec, dp: float, visc: float) -> float:
    """Table coordinate at which the (viscosity-scaled, factor ``visc``) valve drop is
    ``dp`` [Pa, signed]."""
    if dp >= 0.0:
        return z_of_pressure_drop(dp / visc, prm[P_SCALE_R])
    return -z_of_pressure_drop(-dp / visc, prm[P_SCALE_C])


@kernel
def flow_state(z: float, prm: _Vec, coef_r: _Vec, coef_c: _Vec, area: float, gr_area: float,
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
    flags = ((FAULT_STROKE_CLAMPED if stroke_clamped else 0)
             | (FAULT_VELOCITY_CLAMPED if velocity_clamped else 0))
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
def implicit_substep(prm: _Vec, coef_r: _Vec, coef_c: _Vec, p_old: float, z_old: float,
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
        hi = min(hi, z_of(prm, 0.5 / alpha - p_com, visc))
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
        # flow_state written out (through a wrapper the valve look-up is no longer inlined
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
