"""The compressible model's one compiled step (Simms & Crolla eqs 1–4) and its start.

:func:`step` advances a state vector by one sample: the solenoid lag of the valve command,
the input clamp, the implicit sub-steps of eq 2 (BDF2,
:func:`~damper_emulator.model.kernels.implicit_substep`) with the gas pressure of eq 3 and
the model extensions in use (:mod:`damper_emulator.model.extensions`: friction,
viscosity–temperature, cavitation, valve lag, series compliance, end stops, air, groove,
gas heat transfer, the discovered term), and eq 4's force.  :func:`init_state` puts a
state in quasi-steady equilibrium (the start, and the restart after a long gap).  The
real-time stepper, the batch loops (:mod:`damper_emulator.model.batch`) and the ride loops
call these kernels.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from damper_emulator.model.adaptive import bypass_area, solenoid_lag
from damper_emulator.model.discovered import N_TERMS, advance, features
from damper_emulator.model.extensions import (
    AIR_PRESSURE_FLOOR,
    end_stop_form_force,
    gas_temperature,
    groove_window,
    heat_rise,
    lag_weight,
    lugre_steady,
    lugre_update,
    viscosity_scale,
)
from damper_emulator.model.gas import compression_chamber_pressure_kernel
from damper_emulator.model.jit import kernel
from damper_emulator.model.kernels import (
    bdf2_combination,
    bdf2_step,
    bdf2_weight,
    clamp_input,
    coulomb_friction,
    damper_force,
    flow_state,
    implicit_substep,
    substeps,
    z_of,
)
from damper_emulator.model.layout import (
    FAULT_INVALID_INPUT,
    P_A_ANNULUS,
    P_A_PISTON,
    P_A_ROD,
    P_AIR_EPS,
    P_ALPHA,
    P_BP_AREA_COMFORT,
    P_BP_AREA_NORMAL,
    P_BP_T63,
    P_CAV_ON,
    P_CAV_P,
    P_DT_CENTRE,
    P_DT_COEF,
    P_DT_ON,
    P_DT_TAU,
    P_DT_TREF,
    P_DT_VSIGN,
    P_DT_WIDTH,
    P_ES_C,
    P_ES_CH,
    P_ES_DH,
    P_ES_ETA,
    P_ES_FORM_K,
    P_ES_K,
    P_ES_K1,
    P_ES_N,
    P_ES_SCALE,
    P_ES_XC,
    P_ES_XR,
    P_FRICTION,
    P_GAMMA,
    P_GAS,
    P_GR_AREA,
    P_GR_HALF,
    P_GR_X,
    P_GT_TAU,
    P_LG_FC,
    P_LG_FS,
    P_LG_S0,
    P_LG_VS,
    P_MAX_EXT,
    P_MOUNT_K,
    P_SETTLE,
    P_TH_BETA,
    P_TH_CAP,
    P_TH_TAU,
    P_TH_TREF,
    P_TOL,
    P_V_MAX,
    P_VL_TAU,
    P_X_MAX,
    P_X_MIN,
    P_ZLIM_C,
    P_ZLIM_R,
    S_BRISTLE,
    S_CMD,
    S_CMD_EFF,
    S_DT_ENERGY,
    S_DT_FORCE,
    S_DT_LAG,
    S_DT_ROW,
    S_FORCE,
    S_GAS_THETA,
    S_H2,
    S_H_PREV,
    S_HEAT_DT,
    S_MOUNT_F,
    S_MOUNT_PREV,
    S_P_COM,
    S_P_PREV,
    S_P_REB,
    S_Q_PREV,
    S_Q_VALVE,
    S_TEMP_IN,
    S_V,
    S_V2,
    S_V_CAV,
    S_X,
    S_Z,
    S_Z_PREV,
    V_GAS,
)

#: The gas stiffness the series spring's implicit coupling uses is a forward difference
#: over this fraction of the gas column's length (V_gas / A_rod at the stroke).
MOUNT_GAS_STEP_FRACTION = 1e-6

#: The kernels' arrays: packed parameters, valve-table coefficients, state.
_Vec = NDArray[np.float64]


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
def _force(prm: _Vec, p_reb: float, p_com: float, friction: float, x: float, v: float
           ) -> float:
    """Damper force [N, rebound +], eq 4 (``friction`` its last term), plus the end stops'
    force at stroke ``x`` and velocity ``v`` when they are in use (progressive, or of
    their own form)."""
    force: float = damper_force(prm[P_A_ANNULUS], prm[P_A_PISTON], p_reb, p_com, friction,
                                x, prm[P_ES_XR], prm[P_ES_XC], prm[P_ES_K])
    if prm[P_ES_FORM_K] > 0.0:
        force += end_stop_form_force(x, v, prm[P_ES_XR], prm[P_ES_XC], prm[P_ES_K1],
                                     prm[P_ES_FORM_K], prm[P_ES_N], prm[P_ES_ETA],
                                     prm[P_ES_C], prm[P_ES_CH], prm[P_ES_DH],
                                     prm[P_ES_SCALE])
    return force


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
        if flow_state(mid, prm, coef_r, coef_c, area, gr_area, visc, 0.0, 0.0)[2] < q_target:
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
    dp, _d, _q, _dq, _b, q_valve = flow_state(z, prm, coef_r, coef_c, area, gr_area, visc,
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
            z = z_of(prm, p - p_com, visc)
        force = _force(prm, p, p_com, fr, x, v)
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
    state[S_Q_PREV] = q_valve
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
        return state[S_FORCE], FAULT_INVALID_INPUT
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
    lagged = prm[P_VL_TAU] > 0.0
    q_lag = state[S_Q_VALVE]
    q_lag_prev = state[S_Q_PREV]
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
            q_hat = bdf2_combination(q_lag, q_lag_prev, w)
            if k_m > 0.0:
                mount_hat = bdf2_combination(mount_f, mount_prev, w)
            if air:
                air_hat = bdf2_combination(1.0 / max(p, AIR_PRESSURE_FLOOR),
                                           1.0 / max(p_prev, AIR_PRESSURE_FLOOR), w)
        else:
            p_hat = p
            h_eff = h
            q_hat = q_lag
            if air:
                air_hat = 1.0 / max(p, AIR_PRESSURE_FLOOR)
        # a valve lag by the same multistep formula as the pressure (its own history)
        lag_w = lag_weight(prm[P_VL_TAU], h_eff) if lagged else 0.0
        q_lag_prev = q_lag
        q_lag = q_hat
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
            z = z_of(prm, p - p_com, visc)
            q = flow_state(z, prm, coef_r, coef_c, bp_area, gr_area, visc, q_lag, lag_w)
            q_lag = q[5]
            # the piston's inflow over the sub-step by the trapezoid rule (the velocity
            # is linear across the sample: its mean over the sub-step)
            v_mid = vs - 0.5 * (v - v0) / n_sub
            q_in = v_mid * prm[P_A_ANNULUS] - mount_c * (prm[P_A_ANNULUS] * p + mount_off)
            v_cav += (q[2] - q_in) * h
            h_prev = 0.0  # restart the multistep formula from here
            if v_cav < 0.0:
                # the cavity closed within the sub-step, at its fill rate's time: from
                # there the oil's pressure equation again (backward Euler)
                h_rest = -v_cav / (q_in - q[2])
                v_cav = 0.0
                if h_rest > 0.0:
                    z, p, q_lag, f = implicit_substep(
                        prm, coef_r, coef_c, p, z, xd, vs, h_rest, bp_area, p_com, visc,
                        q_lag, lag_weight(prm[P_VL_TAU], h_rest) if lagged else 0.0,
                        gr_area, prm[P_A_ANNULUS] / (k_m * h_rest) if k_m > 0.0 else 0.0,
                        mount_f, f_const, gas_c, mount_f,
                        1.0 / max(p, AIR_PRESSURE_FLOOR) if air else 0.0)
                    flags |= f
        else:
            # the Newton solve starts from z extrapolated along the last two sub-steps (the
            # previous z alone costs about one more iteration per solve)
            z_start = z + (z - z_prev) * w
            z_prev = z
            z, p, q_lag, f = implicit_substep(prm, coef_r, coef_c, p_hat, z_start, xd, vs,
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
                z = z_of(prm, p - p_com, visc)
                h_prev = 0.0
        xd_prev = xd
        if k_m > 0.0:
            mount_prev = mount_f
            mount_f = prm[P_A_ANNULUS] * p - prm[P_A_PISTON] * p_com + fr
    state[S_P_PREV] = p_prev
    state[S_H_PREV] = h_prev
    force = _force(prm, p, p_com, fr, x, v)
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
    state[S_Q_PREV] = q_lag_prev if lagged else q_lag  # (BDF2's history of a lag only)
    state[S_MOUNT_F] = mount_f
    state[S_MOUNT_PREV] = mount_prev
    state[S_GAS_THETA] = theta
    state[S_V_CAV] = v_cav
    state[S_Z_PREV] = z_prev
    return force, flags
