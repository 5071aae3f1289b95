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
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np
from damper_emulator.model.jit import kernel

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

# Layout of the packed parameter vector (see ``DamperModel``).
(P_A_ANNULUS, P_A_PISTON, P_A_ROD, P_MAX_EXT, P_ALPHA, P_FRICTION, P_GAS, V_GAS, P_GAMMA,
 P_SCALE_R, P_STEP_R, P_SCALE_C, P_STEP_C, P_X_MIN, P_X_MAX, P_SUBSTEP, P_TOL, P_MAXIT,
 P_ZLIM_R, P_ZLIM_C, P_SETTLE, P_V_MAX, P_SIZE) = range(23)

# Layout of the state vector.
S_P_REB, S_Z, S_X, S_V, S_FORCE, S_P_COM, S_P_PREV, S_H_PREV, S_SIZE = range(9)


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
def _implicit_substep(prm, coef_r, coef_c, p_old, z_old, x, v, h):
    """One implicit step ``p − p_old = h f(p)`` of eq 2 to stroke ``x``, velocity ``v``:
    backward Euler as it stands, BDF2 with ``p_old``, ``h`` the BDF2 combinations.

    Solves ``R(z) = p_com + Δp(z) − p_old − k (ẋ A − Q(z)) (1 − α p(z)) = 0`` with
    ``k = h / (V_reb α)``; ``R`` increases with ``z``.  Returns ``(z, p_reb, p_com, flags)``.
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
        dp, ddp, q, dq, beyond = _valve_state(z, prm, coef_r, coef_c)
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
        dp, ddp, q, dq, beyond = _valve_state(z, prm, coef_r, coef_c)
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
def _equilibrium_z(prm, coef_r, coef_c, q_target):
    """Table coordinate at which the valve passes ``q_target`` (the rigid-oil limit)."""
    lo = -prm[P_ZLIM_C]
    hi = prm[P_ZLIM_R]
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if _valve_state(mid, prm, coef_r, coef_c)[2] < q_target:
            lo = mid
        else:
            hi = mid
        if hi - lo <= prm[P_TOL]:
            break
    return 0.5 * (lo + hi)


@kernel
def init_state(prm, coef_r, coef_c, state, x, v):
    """Put ``state`` in quasi-steady equilibrium at stroke ``x`` moving at ``v``: the valve
    passes ``v (A_pt − A_rod)`` (at rest: ``p_reb = P_com``)."""
    x = min(max(x, prm[P_X_MIN]), prm[P_X_MAX])
    z = _equilibrium_z(prm, coef_r, coef_c, v * prm[P_A_ANNULUS]) if v != 0.0 else 0.0
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

    Invalid input (non-finite, ``dt <= 0``) leaves the state untouched and returns the last
    force; a stroke beyond the travel is clamped.  The force is always finite.
    """
    if not (math.isfinite(x) and math.isfinite(v) and math.isfinite(dt) and dt > 0.0):
        return state[S_FORCE], _INVALID_INPUT
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
                                           x0 + frac * (x - x0), v0 + frac * (v - v0), h_eff)
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
def _simulate(prm, coef_r, coef_c, state, t, x, v, force, p_reb, p_com, flags):
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
        self.prm = prm

    @classmethod
    def from_file(cls, path=None) -> "DamperModel":
        return cls(load_config(path))

    @property
    def stroke_limits_m(self) -> tuple[float, float]:
        """Physical travel ``(-V_gas/A_rod, L_pt − X0)`` [m] (exclusive)."""
        d = self.cfg.damper
        return -d.max_compression_m, d.max_extension_m


class DamperStepper:
    """Real-time form of the compressible model: one sample in, one force out.

    >>> stepper = DamperStepper(DamperModel())
    >>> force, fault = stepper.step(0.001, 0.1, 1e-3)

    Parameters
    ----------
    model : DamperModel
    stroke_m, velocity_m_s : float
        Initial quasi-steady state (default: at rest at the static position).
    """

    def __init__(self, model: DamperModel, stroke_m: float = 0.0, velocity_m_s: float = 0.0):
        self.model = model
        self._prm = model.prm
        self._coef_r = model.tables[0].coef
        self._coef_c = model.tables[1].coef
        self.state = np.zeros(S_SIZE)
        self.reset(stroke_m, velocity_m_s)

    def reset(self, stroke_m: float = 0.0, velocity_m_s: float = 0.0) -> None:
        """Return to quasi-steady equilibrium at the given stroke and velocity."""
        init_state(self._prm, self._coef_r, self._coef_c, self.state, float(stroke_m),
                   float(velocity_m_s))

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


def simulate(model: DamperModel, time_s, stroke_m, velocity_m_s=None) -> SimulationResult:
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

    Returns
    -------
    SimulationResult

    Raises
    ------
    ValueError
        Non-finite samples, time not strictly increasing, stroke beyond the physical
        travel or velocity beyond the valve table (one line naming the sample).
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
    force, p_reb, p_com = np.empty(n), np.empty(n), np.empty(n)
    faults = np.zeros(n, dtype=np.int64)
    state = np.zeros(S_SIZE)
    _simulate(model.prm, model.tables[0].coef, model.tables[1].coef, state, t, x, v, force,
              p_reb, p_com, faults)
    return SimulationResult(t, x, v, force, p_reb, p_com, faults)
