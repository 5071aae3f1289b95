"""Model extensions: effects the paper's model lacks, as compiled kernels.

Each is a physically parameterised add-on to the compressible model of
:mod:`damper_emulator.model.compressible`, evaluated inside its one compiled step, off unless
its ``damper.extensions`` sub-group is given (:class:`damper_emulator.params.ExtensionParams`);
off, the step's arithmetic is the paper's model's.  Families as in the ``diagnose`` JSON:

``friction`` — LuGre friction with pre-sliding (Canudas de Wit, Olsson, Åström & Lischinsky,
    IEEE TAC 40(3), 1995) in place of eq 4's Coulomb term ``F_friction sgn(ẋ)``::

        ż = v − σ0 |v| z / g(v),   g(v) = F_c + (F_s − F_c) exp(−(v/v_s)²),   F_fr = σ0 z

    (no bristle damping σ1, no viscous σ2: the valves carry the viscous force).  For a
    velocity held over a step the bristle equation is linear in ``z``; it is integrated
    exactly (:func:`lugre_update`).
``thermal`` — viscosity–temperature law ``ν(T) = ν_ref exp(−β (T − T_ref))``.  The port and
    leak restrictions (eqs 8–9) scale with ``ν^(1/4)``; the whole valve characteristic is
    scaled by ``s = exp(−β (T − T_ref) / 4)`` (``Δp = s Δp_ref(Q)``: the blow-off part,
    eq 10, is viscosity-free, so this is exact below blow-off and an upper bound above).
    ``T`` is the measured temperature (when the data carry one) plus the rise ``ΔT`` of a
    lumped heat model ``C dΔT/dt = P − C ΔT/τ_c`` driven by the power dissipated in the
    valves and friction, ``P = (A_a Δp + F_fr) ẋ`` (:func:`heat_rise`, exact for a held
    power).
``cavitation`` — the rebound chamber's absolute pressure cannot fall below ``p_cav``: where
    the implicit solve would go below it the pressure is held at ``p_cav`` and a cavity of
    the oil volume that would have been stretched, ``V_reb α (p_cav − p)``, opens; it grows
    by ``(Q − Q_in) h`` (``Q_in`` at the sub-step's mean velocity: the trapezoid rule) and
    the pressure rises again only once it has refilled: from the time within the sub-step
    where its volume reaches zero (at the sub-step's fill rate) the implicit solve takes
    the rest of the sub-step (docs/model.md note on cavitation).
``valve_dynamics`` — the piston-valve flow lags its quasi-static value at the present Δp,
    ``τ_v dQ/dt = Q_pv(Δp) − Q`` (the blow-off disc opens and closes late), inside the
    implicit sub-step by the pressure's own multistep formula (:func:`lag_weight`; BDF2,
    second order: on a step response with τ_v = 16 ms at 10 kHz its error is 0.06 %
    r.m.s., against 2.4 % by backward Euler).
``compliance`` — a spring ``k_m`` in series between the dyno and the damper: the damper's
    stroke is ``x − F/k_m`` and its velocity ``ẋ − Ḟ/k_m``; the latter enters eq 2
    implicitly (the force is the unknown pressure's), its rate by the same multistep formula
    as the pressure's (``(F − F̂)/h_eff``).  The gas pressure at the damper's stroke enters
    the same solve linearly implicitly (its stiffness times the force's change, then eq 3
    exactly at the stroke the solved force gives): taken at the last sub-step's force, a gas
    stiffer than the spring (a nearly closed gas volume) ran away.  The start is the static
    deflection.
``end_stop`` — progressive elastomer stops, ``F += k (x − x_r)²`` past the rebound stop and
    ``− k (x_c − x)²`` past the compression stop (:func:`end_stop_force`); or stops of
    their own form, ``(k₁ δ + k δⁿ)(1 + η tanh(u/v_h)) + c δ u + c_h min(δ/δ_h, 1) u|u|``
    past either stop (``u`` the speed into it), the compression stop's scaled
    (:func:`end_stop_form_force`): an elastomer's linear and progressive stiffness and its
    hysteresis, a damping growing with the penetration, a hydraulic stop's orifice.
``air_entrainment`` — free air in the rebound chamber, isothermal, volume fraction ``ε`` at
    ``P_ATM``: the chamber's compliance becomes ``V (α + ε P_ATM / p²)``; the air term is
    integrated exactly in ``p`` (``∫ ε P_ATM / p² dp``), so the implicit residual stays
    increasing.
``position_dependent`` — a bypass groove in the pressure tube: the bypass law of
    :mod:`damper_emulator.model.adaptive` with the open area ``A_g w(x)``, ``w`` one over
    the groove and ramping to zero over 20 % of its half-length at each end
    (:func:`groove_window`).
``gas_spring`` — heat transfer between the gas and the tube: the gas temperature ratio
    ``θ = T/T_wall`` follows the adiabatic change of eq 3 and relaxes to 1 with ``τ_g``,
    ``P_com = P_gas,static (V_gas,static / V) θ`` (:func:`gas_temperature`); ``τ_g → ∞``
    is eq 3 (from a start at the static position: a start elsewhere, after a long rest,
    is at the wall temperature), ``τ_g → 0`` the isothermal gas.
"""

from __future__ import annotations

import math

from damper_emulator.model.jit import inlined_kernel, kernel

#: Atmospheric pressure [Pa]: the pressure at which the air fraction is stated.
P_ATM = 101325.0
#: The air term is evaluated at no lower pressure than this [Pa] (the oil would cavitate).
AIR_PRESSURE_FLOOR = 1000.0
#: Ramps of a bypass groove's open area, as a fraction of its half-length.
GROOVE_RAMP_FRACTION = 0.2


@kernel
def lugre_capacity(v: float, f_c: float, f_s: float, v_s: float) -> float:
    """``g(v) = F_c + (F_s − F_c) exp(−(v/v_s)²)`` [N] (Stribeck curve), at least 1e-9 N."""
    r = v / v_s
    return max(f_c + (f_s - f_c) * math.exp(-r * r), 1e-9)


@kernel
def lugre_update(z: float, v: float, dt: float, f_c: float, f_s: float, v_s: float,
                 sigma0: float) -> float:
    """Bristle deflection [m] after ``dt`` [s] at the held velocity ``v`` [m/s]:
    ``z_ss + (z − z_ss) exp(−σ0 |v| dt / g(v))`` with ``z_ss = g(v) sgn(v) / σ0``
    (exact for the LuGre bristle equation at constant ``v``); unchanged at rest."""
    if v == 0.0:
        return z
    g = lugre_capacity(v, f_c, f_s, v_s)
    z_ss = math.copysign(g / sigma0, v)
    return z_ss + (z - z_ss) * math.exp(-sigma0 * abs(v) * dt / g)


@kernel
def lugre_steady(v: float, f_c: float, f_s: float, v_s: float, sigma0: float) -> float:
    """Bristle deflection in steady sliding at ``v`` (0 at rest)."""
    if v == 0.0:
        return 0.0
    return math.copysign(lugre_capacity(v, f_c, f_s, v_s) / sigma0, v)


@kernel
def viscosity_scale(beta: float, t_ref: float, t_c: float) -> float:
    """Valve pressure-drop factor ``(ν(T)/ν_ref)^(1/4) = exp(−β (T − T_ref)/4)``."""
    return math.exp(-0.25 * beta * (t_c - t_ref))


@kernel
def heat_rise(rise: float, power: float, dt: float, capacity: float, tau: float) -> float:
    """Temperature rise [K] of the lumped heat model after ``dt`` at the held ``power``
    [W]: ``ΔT_∞ + (ΔT − ΔT_∞) exp(−dt/τ)``, ``ΔT_∞ = P τ / C``."""
    target = power * tau / capacity
    return target + (rise - target) * math.exp(-dt / tau)


@inlined_kernel
def end_stop_force(x: float, x_reb: float, x_com: float, k: float) -> float:
    """Force of the progressive end stops [N, rebound +] at stroke ``x``."""
    if x > x_reb:
        d = x - x_reb
        return k * d * d
    if x < x_com:
        d = x_com - x
        return -k * d * d
    return 0.0


#: the speed over which an end stop's elastomer hysteresis turns round [m/s] (it hardly
#: depends on the speed beyond)
STOP_HYSTERESIS_SPEED = 0.005


@inlined_kernel
def end_stop_form_force(x: float, v: float, x_reb: float, x_com: float, k1: float,
                        k: float, n: float, eta: float, c: float, c_h: float, d_h: float,
                        scale: float) -> float:
    """Force of end stops of their own form [N, rebound +] at stroke ``x`` and velocity
    ``v``: past a stop (penetration ``δ``, ``u`` the speed into it, ``ẋ`` past the rebound
    stop and ``−ẋ`` past the compression stop) ``(k₁ δ + k δⁿ)(1 + η tanh(u/v_h)) + c δ u
    + c_h min(δ/δ_h, 1) u|u|`` pushing back towards the middle of the stroke, the
    compression stop's times ``scale``: an elastomer's spring and hysteresis, a damping
    that resists the motion, and a hydraulic stop's orifice (its pressure drop quadratic
    in the flow, engaging over the cup's entry ``δ_h``)."""
    if x > x_reb:
        d = x - x_reb
        spring = k1 * d + k * math.pow(d, n)
        return (spring * (1.0 + eta * math.tanh(v / STOP_HYSTERESIS_SPEED)) + c * d * v
                + c_h * min(d / d_h, 1.0) * v * abs(v))
    if x < x_com:
        d = x_com - x
        spring = k1 * d + k * math.pow(d, n)
        return -scale * (spring * (1.0 + eta * math.tanh(-v / STOP_HYSTERESIS_SPEED))
                         - c * d * v - c_h * min(d / d_h, 1.0) * v * abs(v))
    return 0.0


@kernel
def groove_window(x: float, center: float, half_length: float) -> float:
    """Open fraction (0..1) of a bypass groove at stroke ``x``: 1 within the groove, linear
    ramps of ``GROOVE_RAMP_FRACTION × half_length`` centred on its ends."""
    ramp = GROOVE_RAMP_FRACTION * half_length
    w = (half_length - abs(x - center)) / ramp + 0.5
    return min(max(w, 0.0), 1.0)


@kernel
def gas_temperature(theta: float, v_old: float, v_new: float, gamma: float, h: float,
                    tau: float) -> float:
    """Gas temperature ratio ``T/T_wall`` after the volume goes from ``v_old`` to ``v_new``
    [m³] in ``h`` [s]: the adiabatic change ``θ (V_old/V_new)^(γ−1)``, then relaxation
    towards 1 with the factor ``exp(−h/τ)``."""
    theta_ad: float = theta * (v_old / v_new) ** (gamma - 1.0)
    return 1.0 + (theta_ad - 1.0) * math.exp(-h / tau)


@kernel
def lag_weight(tau: float, h: float) -> float:
    """Weight of the old value in an implicit step of ``τ dq/dt = q_ss − q`` over ``h``:
    ``q_new = w q̂ + (1 − w) q_ss``, ``w = τ/(τ + h)``: backward Euler with ``q̂`` the old
    value, BDF2 with ``q̂`` the combination of the last two and ``h`` the effective step
    (:func:`~damper_emulator.model.kernels.bdf2_combination`, ``bdf2_step``)."""
    return tau / (tau + h)
