"""Compressible (hysteretic) damper model, Simms & Crolla eqs 1–4.

:class:`DamperModel` compiles a validated configuration for the kernels (packed parameter
vector and valve tables).  One compiled step (:func:`damper_emulator.model.step.step`)
serves the real-time stepper (:class:`DamperStepper`, one sample per call, with its
warm-up) and the batch simulator (:func:`simulate`, a whole displacement history in one
call, :mod:`damper_emulator.model.batch`).  The vectors' layout and the fault bits are in
:mod:`damper_emulator.model.layout`, the step's building blocks (valve look-up, eq 2's
residual, BDF2, the Newton solve) in :mod:`damper_emulator.model.kernels`.

The state is the rebound-chamber pressure ``p_reb``.  Eq 2,

    dp_reb/dt = (ẋ (A_pt − A_rod) − Q_pv(Δp)) (1 − α p_reb) / ((L_pt − X0 − x)(A_pt − A_rod) α),

is stiff near ``Δp = 0`` (docs/model.md §2.1), so each step is integrated implicitly, by
variable-step BDF2 (A-stable, second order; backward Euler on the first sub-step and after a
step ratio of :data:`~damper_emulator.model.kernels.BDF2_MAX_STEP_RATIO` or more), on
sub-steps no longer than ``numerics.max_substep_s``, with the stroke and velocity
interpolated linearly between the previous and the current sample.  The implicit equation
is solved in the valve-table coordinate ``z`` (see :mod:`damper_emulator.model.valve_table`),
in which it is monotonic, by Newton's method safeguarded with bisection.  ``P_com`` is
algebraic (eq 3) and the force is eq 4.

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
import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from damper_emulator.errors import UserError
from damper_emulator.model.adaptive import bypass_coefficients
from damper_emulator.model.batch import SimulationResult, simulate_commanded_samples
from damper_emulator.model.layout import (
    P_A_ANNULUS,
    P_A_PISTON,
    P_A_ROD,
    P_ALPHA,
    P_BP_AREA_COMFORT,
    P_BP_AREA_NORMAL,
    P_BP_LAMINAR,
    P_BP_T63,
    P_BP_TURBULENT,
    P_FRICTION,
    P_GAMMA,
    P_GAS,
    P_LG_FC,
    P_MAX_EXT,
    P_MAXIT,
    P_SCALE_C,
    P_SCALE_R,
    P_SETTLE,
    P_SIZE,
    P_STEP_C,
    P_STEP_R,
    P_SUBSTEP,
    P_TOL,
    P_V_MAX,
    P_X_MAX,
    P_X_MIN,
    P_ZLIM_C,
    P_ZLIM_R,
    S_CMD,
    S_CMD_EFF,
    S_DT_ENERGY,
    S_FORCE,
    S_HEAT_DT,
    S_P_COM,
    S_P_REB,
    S_TEMP_IN,
    V_GAS,
    new_state,
    pack_extensions,
)
from damper_emulator.model.step import init_state, step
from damper_emulator.model.valve_table import EXTRAPOLATION_LIMIT
from damper_emulator.params import (
    ExtensionParams,
    ModelConfig,
    check_extensions,
    load_config,
    valve_tables,
)


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
            pack_extensions(prm, d)
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
            pack_extensions(prm, cfg.damper)
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
        """Advance by ``dt_s`` to the new sample; returns ``(force [N], Fault bits)``
        (:class:`~damper_emulator.model.layout.Fault`).

        Never raises for bad numbers: invalid input holds the last force and sets
        ``Fault.INVALID_INPUT``; a stroke beyond the travel or a velocity beyond the
        valve table is clamped (``Fault.STROKE_CLAMPED``, ``Fault.VELOCITY_CLAMPED``).
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
