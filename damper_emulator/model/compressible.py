"""Compressible (hysteretic) damper model, Simms & Crolla eqs 1–4.

One compiled step serves the real-time stepper (:class:`DamperStepper`, one sample per call)
and the batch simulator (:func:`simulate`, a whole displacement history in one call).

The state is the rebound-chamber pressure ``p_reb``.  Eq 2,

    dp_reb/dt = (ẋ (A_pt − A_rod) − Q_pv(Δp)) (1 − α p_reb) / ((L_pt − X0 − x)(A_pt − A_rod) α),

is stiff near ``Δp = 0`` (MODEL.md note), so each step is integrated by backward Euler —
unconditionally stable — on sub-steps no longer than ``numerics.max_substep_s``, with the
stroke and velocity interpolated linearly between the previous and the current sample.  The
implicit equation is solved in the valve-table coordinate ``z`` (see
:mod:`damper_emulator.model.valve_table`), in which it is monotonic, by Newton's method
safeguarded with bisection.  ``P_com`` is algebraic (eq 3) and the force is eq 4.

**Adaptive damper** (MODEL.md §6, :mod:`damper_emulator.model.adaptive`).  The valve flow of
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

import enum
import math
from dataclasses import dataclass

import numpy as np
from damper_emulator.model.jit import kernel

from damper_emulator.model.adaptive import (bypass_area, bypass_coefficients, bypass_flow,
                                            solenoid_lag)
from damper_emulator.model.gas import compression_chamber_pressure
from damper_emulator.model.valve_table import (EXTRAPOLATION_LIMIT, build_valve_tables,
                                               pressure_drop_of_z, table_flow)
from damper_emulator.params import ModelConfig, load_config


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

# The same bits as plain ints for the compiled kernel.
_INVALID_INPUT = int(Fault.INVALID_INPUT)
_STROKE_CLAMPED = int(Fault.STROKE_CLAMPED)
_VALVE_EXTRAPOLATED = int(Fault.VALVE_EXTRAPOLATED)
_SOLVER = int(Fault.SOLVER)
_VELOCITY_CLAMPED = int(Fault.VELOCITY_CLAMPED)

# Layout of the packed parameter vector (see ``DamperModel``); the bypass constants of the
# adaptive damper (all 0 without a ``damper.adaptive`` group) come last:
# ``P_BP_LAMINAR`` a = 8πρνL, ``P_BP_TURBULENT`` b = ρ/(2 C_d²), the open areas at commands
# 0 and 0.5 [m²] and the solenoid's t63 [s].
(P_A_ANNULUS, P_A_PISTON, P_A_ROD, P_MAX_EXT, P_ALPHA, P_FRICTION, P_GAS, V_GAS, P_GAMMA,
 P_SCALE_R, P_STEP_R, P_SCALE_C, P_STEP_C, P_X_MIN, P_X_MAX, P_SUBSTEP, P_TOL, P_MAXIT,
 P_ZLIM_R, P_ZLIM_C, P_SETTLE, P_V_MAX, P_BP_LAMINAR, P_BP_TURBULENT, P_BP_AREA_COMFORT,
 P_BP_AREA_NORMAL, P_BP_T63, P_SIZE) = range(28)

# Layout of the state vector; ``S_CMD`` is the commanded valve command (0 comfort .. 1
# sport), ``S_CMD_EFF`` the effective one (after the solenoid lag).
(S_P_REB, S_Z, S_X, S_V, S_FORCE, S_P_COM, S_P_PREV, S_H_PREV, S_CMD, S_CMD_EFF,
 S_SIZE) = range(11)


@kernel
def _valve_state(z, prm, coef_r, coef_c):
    """Signed Δp [Pa], dΔp/dz, signed Q_pv [m³/s], dQ/dz, beyond-table flag at ``z``."""
    if z >= 0.0:
        dp, ddp = pressure_drop_of_z(z, prm[P_SCALE_R])
        q, dq, beyond = table_flow(coef_r, prm[P_STEP_R], z)
        return dp, ddp, q, dq, beyond
    dp, ddp = pressure_drop_of_z(-z, prm[P_SCALE_C])
    q, dq, beyond = table_flow(coef_c, prm[P_STEP_C], -z)
    return -dp, ddp, -q, dq, beyond


@kernel
def _flow_state(z, prm, coef_r, coef_c, area):
    """:func:`_valve_state` with the bypass (open ``area`` [m²]) in parallel: signed Δp,
    dΔp/dz, ``Q_pv + Q_b``, its derivative in ``z``, beyond-table flag."""
    dp, ddp, q, dq, beyond = _valve_state(z, prm, coef_r, coef_c)
    if area > 0.0:
        qb, dqb = bypass_flow(dp, area, prm[P_BP_LAMINAR], prm[P_BP_TURBULENT])
        q += qb
        dq += dqb * ddp
    return dp, ddp, q, dq, beyond


@kernel
def _implicit_substep(prm, coef_r, coef_c, p_old, z_old, x, v, h, bp_area):
    """One implicit step ``p − p_old = h f(p)`` of eq 2 to stroke ``x``, velocity ``v``:
    backward Euler as it stands, BDF2 with ``p_old``, ``h`` the BDF2 combinations.

    Solves ``R(z) = p_com + Δp(z) − p_old − k (ẋ A − Q(z)) (1 − α p(z)) = 0`` with
    ``k = h / (V_reb α)``; ``R`` increases with ``z``.  ``Q = Q_pv + Q_b``: the piston valve
    and, when ``bp_area`` [m²] > 0, the solenoid bypass in parallel (MODEL.md §6; ``Q_b``
    increases with ``Δp``, so ``R`` still increases with ``z``); with the bypass closed the
    arithmetic is the paper's model's exactly.  Returns ``(z, p_reb, p_com, flags)``.
    """
    area = prm[P_A_ANNULUS]
    alpha = prm[P_ALPHA]
    p_com = compression_chamber_pressure(x, prm[P_GAS], prm[V_GAS], prm[P_A_ROD], prm[P_GAMMA])
    k = h / ((prm[P_MAX_EXT] - x) * area * alpha)
    q_in = v * area
    lo = -prm[P_ZLIM_C]
    hi = prm[P_ZLIM_R]
    z = min(max(z_old, lo), hi)
    tol = prm[P_TOL]
    flags = 0
    for _ in range(int(prm[P_MAXIT])):
        # _flow_state written out (through a wrapper the valve look-up is no longer inlined
        # into this loop, measured 25 % slower)
        dp, ddp, q, dq, beyond = _valve_state(z, prm, coef_r, coef_c)
        if bp_area > 0.0:
            qb, dqb = bypass_flow(dp, bp_area, prm[P_BP_LAMINAR], prm[P_BP_TURBULENT])
            q += qb
            dq += dqb * ddp
        p = p_com + dp
        r = p - p_old - k * (q_in - q) * (1.0 - alpha * p)
        if r == 0.0:
            break
        dr = ddp + k * dq * (1.0 - alpha * p) + k * (q_in - q) * alpha * ddp
        if r > 0.0:
            hi = z
        else:
            lo = z
        z_new = z - r / dr if dr > 0.0 else 0.5 * (lo + hi)
        if z_new <= lo or z_new >= hi:
            z_new = 0.5 * (lo + hi)
        if abs(z_new - z) <= tol * (1.0 + abs(z)):
            break  # z (evaluated above) is within the tolerance of the root
        z = z_new
    else:
        dp, ddp, q, dq, beyond = _valve_state(z, prm, coef_r, coef_c)  # Δp only
        flags = _SOLVER
    if beyond:
        flags |= _VALVE_EXTRAPOLATED
    return z, p_com + dp, p_com, flags


@kernel
def _force(prm, p_reb, p_com, v):
    """Damper force [N, rebound +], eq 4."""
    sgn = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
    return prm[P_A_ANNULUS] * p_reb - prm[P_A_PISTON] * p_com + prm[P_FRICTION] * sgn


@kernel
def _bypass_area_of(prm, command):
    """Open bypass area [m²] at the effective ``command``."""
    return bypass_area(command, prm[P_BP_AREA_COMFORT], prm[P_BP_AREA_NORMAL])


@kernel
def _equilibrium_z(prm, coef_r, coef_c, q_target, area):
    """Table coordinate at which valve and bypass (open ``area``) pass ``q_target`` (the
    rigid-oil limit)."""
    lo = -prm[P_ZLIM_C]
    hi = prm[P_ZLIM_R]
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if _flow_state(mid, prm, coef_r, coef_c, area)[2] < q_target:
            lo = mid
        else:
            hi = mid
        if hi - lo <= prm[P_TOL]:
            break
    return 0.5 * (lo + hi)


@kernel
def init_state(prm, coef_r, coef_c, state, x, v):
    """Put ``state`` in quasi-steady equilibrium at stroke ``x`` moving at ``v``: valve and
    bypass (at the effective command ``state[S_CMD_EFF]``, left as it is) pass
    ``v (A_pt − A_rod)`` (at rest: ``p_reb = P_com``)."""
    x = min(max(x, prm[P_X_MIN]), prm[P_X_MAX])
    area = _bypass_area_of(prm, state[S_CMD_EFF])
    z = _equilibrium_z(prm, coef_r, coef_c, v * prm[P_A_ANNULUS], area) if v != 0.0 else 0.0
    p_com = compression_chamber_pressure(x, prm[P_GAS], prm[V_GAS], prm[P_A_ROD], prm[P_GAMMA])
    p = p_com + _valve_state(z, prm, coef_r, coef_c)[0]
    state[S_P_REB] = p
    state[S_Z] = z
    state[S_X] = x
    state[S_V] = v
    state[S_P_COM] = p_com
    state[S_FORCE] = _force(prm, p, p_com, v)
    state[S_P_PREV] = p
    state[S_H_PREV] = 0.0


@kernel
def step(prm, coef_r, coef_c, state, x, v, dt):
    """Advance ``state`` to the sample (stroke ``x`` [m], velocity ``v`` [m/s]) taken ``dt``
    seconds after the previous one; returns ``(force [N], fault flags)``.

    The effective valve command first follows the commanded one over ``dt`` (solenoid lag,
    MODEL.md §6); the bypass it opens is held over the step.  Invalid input (non-finite,
    ``dt <= 0``) leaves the state untouched and returns the last force; a stroke beyond
    the travel is clamped.  The force is always finite.
    """
    if not (math.isfinite(x) and math.isfinite(v) and math.isfinite(dt) and dt > 0.0):
        return state[S_FORCE], _INVALID_INPUT
    cmd = state[S_CMD_EFF]
    if cmd != state[S_CMD]:
        cmd = solenoid_lag(cmd, state[S_CMD], dt, prm[P_BP_T63])
        state[S_CMD_EFF] = cmd
    flags = 0
    if x < prm[P_X_MIN]:
        x = prm[P_X_MIN]
        flags |= _STROKE_CLAMPED
    elif x > prm[P_X_MAX]:
        x = prm[P_X_MAX]
        flags |= _STROKE_CLAMPED
    if abs(v) > prm[P_V_MAX]:
        v = math.copysign(prm[P_V_MAX], v)
        flags |= _VELOCITY_CLAMPED
    if dt > prm[P_SETTLE]:
        # after a gap far longer than the pressure time constants the damper is in
        # quasi-steady equilibrium at the new sample
        init_state(prm, coef_r, coef_c, state, x, v)
        return state[S_FORCE], flags
    bp_area = _bypass_area_of(prm, cmd)
    n_sub = max(1, int(math.ceil(dt / prm[P_SUBSTEP] - 1e-9)))
    h = dt / n_sub
    x0 = state[S_X]
    v0 = state[S_V]
    p = state[S_P_REB]
    z = state[S_Z]
    p_com = state[S_P_COM]
    p_prev = state[S_P_PREV]
    h_prev = state[S_H_PREV]
    for j in range(1, n_sub + 1):
        frac = j / n_sub
        if h_prev > 0.0 and h / h_prev < BDF2_MAX_STEP_RATIO:
            # variable-step BDF2: p − p̂ = h_eff f(p)
            w = h / h_prev
            p_hat = ((1.0 + w) ** 2 * p - w * w * p_prev) / (1.0 + 2.0 * w)
            h_eff = h * (1.0 + w) / (1.0 + 2.0 * w)
        else:
            p_hat = p
            h_eff = h
        p_prev = p
        z, p, p_com, f = _implicit_substep(prm, coef_r, coef_c, p_hat, z,
                                           x0 + frac * (x - x0), v0 + frac * (v - v0),
                                           h_eff, bp_area)
        h_prev = h
        flags |= f
    state[S_P_PREV] = p_prev
    state[S_H_PREV] = h_prev
    force = _force(prm, p, p_com, v)
    state[S_P_REB] = p
    state[S_Z] = z
    state[S_X] = x
    state[S_V] = v
    state[S_P_COM] = p_com
    state[S_FORCE] = force
    return force, flags


@kernel
def _simulate_commanded(prm, coef_r, coef_c, state, t, x, v, command, force, p_reb, p_com,
                        command_eff, flags):
    """The batch loop: ``command[i]`` is the valve command from sample ``i`` on (it drives
    the solenoid lag over the step to sample ``i + 1``); the start is settled at
    ``command[0]``."""
    for i in range(t.size):
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
def _simulate(prm, coef_r, coef_c, state, t, x, v, force, p_reb, p_com, flags):
    """The batch loop at valve command 1 ('sport', bypass closed) throughout, whatever
    ``state`` holds (the replay passes a zero state)."""
    state[S_CMD] = 1.0
    state[S_CMD_EFF] = 1.0
    for i in range(t.size):
        if i == 0:
            init_state(prm, coef_r, coef_c, state, x[0], v[0])
            force[0] = state[S_FORCE]
            flags[0] = 0
        else:
            force[i], flags[i] = step(prm, coef_r, coef_c, state, x[i], v[i], t[i] - t[i - 1])
        p_reb[i] = state[S_P_REB]
        p_com[i] = state[S_P_COM]


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
        rebound, compression = build_valve_tables(self.cfg)
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
        self.prm = prm

    @classmethod
    def from_file(cls, path=None) -> "DamperModel":
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


def check_valve_command(value) -> float:
    """``value`` as a float if it is a valve command in [0, 1]; else ``ValueError``."""
    try:
        c = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"valve command must be a number in [0, 1], got {value!r}") from None
    if not (math.isfinite(c) and 0.0 <= c <= 1.0):
        raise ValueError(f"valve command {value!r} outside [0, 1] (0 comfort .. 1 sport)")
    return c


def quasi_steady_force(model: DamperModel, velocity_m_s: float, valve_command: float = 1.0,
                       stroke_m: float = 0.0) -> float:
    """Quasi-steady (rigid-oil limit, eqs 2–4 at ``ṗ_reb = 0``) force [N, rebound +] at
    constant ``velocity_m_s`` through ``stroke_m``, with the bypass of a settled
    ``valve_command``: valve and bypass pass ``ẋ (A_pt − A_rod)`` (friction included).
    The equilibrium the stepper starts from."""
    state = np.zeros(S_SIZE)
    state[S_CMD] = state[S_CMD_EFF] = check_valve_command(valve_command)
    init_state(model.prm, model.tables[0].coef, model.tables[1].coef, state, float(stroke_m),
               float(velocity_m_s))
    return float(state[S_FORCE])


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
        self.state = np.zeros(S_SIZE)
        self.state[S_CMD] = check_valve_command(valve_command)
        self.reset(stroke_m, velocity_m_s)

    def reset(self, stroke_m: float = 0.0, velocity_m_s: float = 0.0) -> None:
        """Return to quasi-steady equilibrium at the given stroke and velocity, the solenoid
        settled at the commanded valve command."""
        self.state[S_CMD_EFF] = self.state[S_CMD]
        init_state(self._prm, self._coef_r, self._coef_c, self.state, float(stroke_m),
                   float(velocity_m_s))

    def set_valve_command(self, command: float) -> None:
        """Command the valve: 0 comfort (softest) .. 0.5 normal .. 1 sport (bypass closed).

        The effective command follows it through the solenoid lag from the next
        :meth:`step` on (MODEL.md §6).  Raises ``ValueError`` unless ``0 <= command <= 1``.
        Without a ``damper.adaptive`` group the command is kept but changes nothing.
        """
        self.state[S_CMD] = check_valve_command(command)

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
        raise ValueError(f"{name} sample {i} is {arr[i]} (must be finite)")


def _check_samples(t: np.ndarray, x: np.ndarray, model: DamperModel) -> None:
    _check_finite("time", t)
    _check_finite("stroke", x)
    if t.size > 1:
        dt = np.diff(t)
        if not (dt > 0).all():
            i = int(np.argmax(~(dt > 0))) + 1
            raise ValueError(f"time is not strictly increasing at sample {i} "
                             f"({t[i - 1]!r} then {t[i]!r})")
    lo, hi = model.stroke_limits_m
    out = (x <= lo) | (x >= hi)
    if out.any():
        i = int(np.argmax(out))
        raise ValueError(f"stroke sample {i} = {x[i]:.6g} m is beyond the physical travel "
                         f"({lo:.4g} m .. {hi:.4g} m: gas volume / L_pt − X0)")


def simulate(model: DamperModel, time_s, stroke_m, velocity_m_s=None,
             valve_command=1.0) -> SimulationResult:
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
        raise ValueError(f"time and stroke must be 1-D arrays of equal, non-zero length "
                         f"(got shapes {t.shape} and {x.shape})")
    _check_samples(t, x, model)
    if velocity_m_s is None:
        v = np.gradient(x, t) if t.size > 1 else np.zeros_like(x)
    else:
        v = np.ascontiguousarray(velocity_m_s, dtype=float)
        if v.shape != t.shape:
            raise ValueError(f"velocity has shape {v.shape}, time {t.shape}")
        _check_finite("velocity", v)
    v_max = model.cfg.numerics.valve_table_max_velocity_m_s
    fast = np.abs(v) > v_max
    if fast.any():
        i = int(np.argmax(fast))
        raise ValueError(f"velocity sample {i} = {v[i]:.6g} m/s exceeds "
                         f"numerics.valve_table_max_velocity_m_s = {v_max:g} m/s")
    n = t.size
    cmd = np.asarray(valve_command, dtype=float)
    if cmd.ndim == 0:
        check_valve_command(float(cmd))
        cmd = np.full(n, float(cmd))
    elif cmd.shape != t.shape:
        raise ValueError(f"valve command has shape {cmd.shape}, time {t.shape}")
    else:
        bad = ~((cmd >= 0.0) & (cmd <= 1.0))
        if bad.any():
            i = int(np.argmax(bad))
            raise ValueError(f"valve command sample {i} = {cmd[i]!r} outside [0, 1]")
        cmd = np.ascontiguousarray(cmd)
    force, p_reb, p_com, c_eff = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    faults = np.zeros(n, dtype=np.int64)
    state = np.zeros(S_SIZE)
    _simulate_commanded(model.prm, model.tables[0].coef, model.tables[1].coef, state, t, x, v,
                        cmd, force, p_reb, p_com, c_eff, faults)
    return SimulationResult(t, x, v, force, p_reb, p_com, faults, c_eff)
