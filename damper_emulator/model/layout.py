"""Layout of the compressible model's packed vectors, their packing, and its fault bits.

The compiled kernels (:mod:`damper_emulator.model.kernels`, :mod:`damper_emulator.model.step`,
:mod:`damper_emulator.model.batch`, :mod:`damper_emulator.model.lanes`) pass the model as
plain float arrays: the parameter vector (the ``P_*`` indices, :data:`P_SIZE` entries) that
:class:`~damper_emulator.model.compressible.DamperModel` packs, its ``damper.extensions``
written by :func:`pack_extensions`, and a stepper's state vector (the ``S_*`` indices,
:data:`S_SIZE` entries, a new one from :func:`new_state`).  The fault bits every step
returns are :class:`Fault`, and the same bits as plain ints (``FAULT_*``) for the kernels.
"""

from __future__ import annotations

import enum
import math
from typing import cast

import numpy as np

from damper_emulator.model.adaptive import bypass_coefficients
from damper_emulator.model.discovered import N_TERMS, TERM_ACCELERATION, TERM_FIELDS
from damper_emulator.params import (
    BypassGrooveParams,
    DamperParams,
    DiscoveredTermParams,
    EndStopParams,
    ExtensionParams,
    LugreFrictionParams,
    ViscosityTemperatureParams,
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


# The same bits as plain ints for the compiled kernel.
FAULT_INVALID_INPUT = int(Fault.INVALID_INPUT)
FAULT_STROKE_CLAMPED = int(Fault.STROKE_CLAMPED)
FAULT_VALVE_EXTRAPOLATED = int(Fault.VALVE_EXTRAPOLATED)
FAULT_SOLVER = int(Fault.SOLVER)
FAULT_VELOCITY_CLAMPED = int(Fault.VELOCITY_CLAMPED)

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
 P_ES_XR, P_ES_XC, P_ES_K, P_ES_FORM_K, P_ES_K1, P_ES_C, P_ES_SCALE, P_ES_N, P_ES_ETA,
 P_ES_CH, P_ES_DH,
 P_AIR_EPS,
 P_GR_AREA, P_GR_X, P_GR_HALF, P_GR_LAMINAR, P_GR_TURBULENT,
 P_GT_TAU,
 P_DT_ON, P_DT_VSIGN, P_DT_TREF, P_DT_CENTRE, P_DT_WIDTH, P_DT_TAU,
 P_DT_COEF) = range(64)
P_SIZE = P_DT_COEF + N_TERMS

# Layout of the state vector; ``S_CMD`` is the commanded valve command (0 comfort .. 1
# sport), ``S_CMD_EFF`` the effective one (after the solenoid lag); then the extensions'
# states: the measured temperature [°C] (an input; NaN: none, the reference temperature),
# the heat model's temperature rise [K], the LuGre bristle deflection [m], the cavity volume
# [m³], the lagged piston-valve flow [m³/s], the series-spring (= damper) force [N], the
# gas temperature ratio T/T_wall and the spring force one sub-step earlier [N] (for BDF2);
# the discovered term's: the velocity two samples back [m/s] and the step before the last
# [s] (the acceleration), the energy dissipated so far [J], the lagged force and the force
# without the term [N]; the lagged flow one sub-step earlier [m³/s] (for BDF2); then the
# discovered term's features at the last sample (scratch).
(S_P_REB, S_Z, S_X, S_V, S_FORCE, S_P_COM, S_P_PREV, S_H_PREV, S_CMD, S_CMD_EFF,
 S_TEMP_IN, S_HEAT_DT, S_BRISTLE, S_V_CAV, S_Q_VALVE, S_MOUNT_F, S_GAS_THETA, S_MOUNT_PREV,
 S_Z_PREV, S_V2, S_H2, S_DT_ENERGY, S_DT_LAG, S_DT_FORCE, S_Q_PREV, S_DT_ROW) = range(26)
S_SIZE = S_DT_ROW + N_TERMS


def new_state() -> np.ndarray:
    """A zero state vector with no measured temperature (NaN)."""
    state = np.zeros(S_SIZE)
    state[S_TEMP_IN] = math.nan
    return state


def pack_extensions(prm: np.ndarray, d: DamperParams) -> None:
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
        if g.plain:
            prm[P_ES_K] = g.stiffness_n_m2
        else:  # the stops' own form: on while its k is positive, the plain k off
            prm[P_ES_FORM_K], prm[P_ES_K1] = g.stiffness_n_m2, g.linear_stiffness_n_m
            prm[P_ES_C], prm[P_ES_SCALE] = g.damping_n_s_m2, g.compression_scale
            prm[P_ES_N], prm[P_ES_ETA] = g.progressive_exponent, g.hysteresis
            prm[P_ES_CH], prm[P_ES_DH] = (g.hydraulic_damping_n_s2_m2,
                                          g.hydraulic_engagement_m)
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
    if e.discovered_term is not None or e.inertia is not None:
        # an inertia is the discovered term's acceleration part: the one compiled step
        # runs both, their masses added
        t = e.discovered_term or DiscoveredTermParams()
        prm[P_DT_ON] = 1.0
        prm[P_DT_VSIGN], prm[P_DT_TREF] = t.smooth_sign_velocity_m_s, t.reference_temperature_c
        prm[P_DT_CENTRE], prm[P_DT_WIDTH] = t.profile_center_m, t.profile_width_m
        prm[P_DT_TAU] = t.lag_time_constant_s
        for k, name in enumerate(TERM_FIELDS):
            prm[P_DT_COEF + k] = getattr(t, name)
        if e.inertia is not None:
            prm[P_DT_COEF + TERM_ACCELERATION] += e.inertia.mass_kg
