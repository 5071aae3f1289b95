"""Damper plug-ins for the quarter car (docs/model.md §5, eq 38).

A plug-in is sampled once per vehicle step with the damper's stroke and velocity and returns
its force, which the vehicle holds over the following step (see
:mod:`ride_sim.quarter_car`).  Conventions are the damper's own (docs/model.md §1): stroke and
velocity positive in extension (rebound), force positive in rebound.

Protocol (:class:`DamperPlugin`)::

    name: str
    static_force_n: float              # force at rest at the static position
    last_fault: int                    # Fault bits of the latest sample (0 when stateless)
    faults: int                        # OR of all Fault bits since the latest reset
    reset(stroke_m, velocity_m_s) -> float   # (re)start at this sample; returns its force
    force(stroke_m, velocity_m_s, dt_s) -> float   # the next sample, dt_s after the last

Adapters over the project's existing representations (nothing is re-implemented):

- :class:`LinearPlugin` — :class:`~damper_emulator.model.representations.LinearDamper`;
- :class:`TablePlugin` — :class:`~damper_emulator.model.representations.TableDamper`
  (e.g. the 14-speed curve of :func:`~damper_emulator.model.representations.
  fourteen_speed_damper`);
- :class:`IncompressiblePlugin` — the incompressible curve, eqs 30–32
  (:func:`~damper_emulator.model.incompressible.incompressible_force`) tabulated once;
- :class:`CompressiblePlugin` — the hysteretic model, eqs 1–4, stepped by
  :class:`~damper_emulator.model.compressible.DamperStepper` with the real ``dt``; for the
  adaptive damper (docs/model.md §6) at a valve command (0 comfort .. 1 sport) that
  :meth:`CompressiblePlugin.set_valve_command` may change between samples (the compiled
  loop keeps the command the plug-in holds when it starts).

Each built-in plug-in also describes itself to the compiled ride loop
(:attr:`kernel_spec`), so :func:`ride_sim.quarter_car.simulate` runs it without a Python
call per step; a plug-in without ``kernel_spec`` runs through the same vehicle update in a
Python loop.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol, cast, runtime_checkable

import numpy as np
from scipy.interpolate import PchipInterpolator

from damper_emulator.dyno.protocols import FourteenSpeed
from damper_emulator.errors import UserError
from damper_emulator.model.compressible import DamperModel, DamperStepper
from damper_emulator.model.incompressible import incompressible_force
from damper_emulator.model.jit import kernel
from damper_emulator.model.layout import Fault
from damper_emulator.model.representations import LinearDamper, TableDamper, fourteen_speed_damper
from damper_emulator.params import ModelConfig

if TYPE_CHECKING:  # pragma: no cover
    from numpy.typing import NDArray

    from ride_sim.params import QuarterCarParams


@runtime_checkable
class DamperPlugin(Protocol):
    """What the quarter car needs of a damper (see the module docstring)."""

    name: str
    last_fault: int
    faults: int

    @property
    def static_force_n(self) -> float: ...

    def reset(self, stroke_m: float = 0.0, velocity_m_s: float = 0.0) -> float: ...

    def force(self, stroke_m: float, velocity_m_s: float, dt_s: float) -> float: ...


# --------------------------------------------------------------------------------------
# Stateless curves: a description the compiled loop evaluates.

#: ``StatelessSpec.kind`` values.
LINEAR, TABLE = 0, 1


@dataclass(frozen=True)
class StatelessSpec:
    """A stateless force–velocity curve in compiled form.

    ``kind == LINEAR``: ``F = f0 + rate · v``.  ``kind == TABLE``: the monotone piecewise
    cubic of a :class:`TableDamper` (``knots``, ``coef`` rows ``(c3, c2, c1, c0)`` in powers
    of ``v − knot``), continued linearly beyond its ends with slopes ``slope_lo`` /
    ``slope_hi`` from ``f_lo`` / ``f_hi``, plus ``coulomb · sgn v``.
    """

    kind: int
    f0: float = 0.0
    rate: float = 0.0
    knots: np.ndarray = field(default_factory=lambda: np.zeros(2))
    coef: np.ndarray = field(default_factory=lambda: np.zeros((1, 4)))
    f_lo: float = 0.0
    f_hi: float = 0.0
    slope_lo: float = 0.0
    slope_hi: float = 0.0
    coulomb: float = 0.0


@dataclass(frozen=True)
class CompressibleSpec:
    """The compressible model's compiled arrays (``DamperModel.prm``, valve-table
    coefficients) and the stepper state the loop advances in place."""

    prm: np.ndarray
    coef_r: np.ndarray
    coef_c: np.ndarray
    state: np.ndarray


def table_spec(table: TableDamper, coulomb_n: float = 0.0) -> StatelessSpec:
    """The compiled form of ``table`` (same PCHIP, built from its public nodes)."""
    v, f = table.velocity_m_s, table.force_n
    pchip = PchipInterpolator(v, f, extrapolate=False)
    slopes = pchip.derivative()(v[[0, -1]])
    return StatelessSpec(TABLE, knots=np.ascontiguousarray(v, dtype=float),
                         coef=np.ascontiguousarray(pchip.c.T, dtype=float),
                         f_lo=float(f[0]), f_hi=float(f[-1]), slope_lo=float(slopes[0]),
                         slope_hi=float(slopes[1]), coulomb=float(coulomb_n))


@kernel
def stateless_force(kind: int, f0: float, rate: float, knots: NDArray[np.float64],
                    coef: NDArray[np.float64], f_lo: float, f_hi: float, slope_lo: float,
                    slope_hi: float, coulomb: float, v: float) -> float:
    """Force [N] of a :class:`StatelessSpec` at velocity ``v`` [m/s] (compiled)."""
    if kind == 0:
        return f0 + rate * v
    n = knots.size
    if v <= knots[0]:
        f: float = f_lo + slope_lo * (v - knots[0])
    elif v >= knots[n - 1]:
        f = f_hi + slope_hi * (v - knots[n - 1])
    else:
        lo = 0
        hi = n - 1
        while hi - lo > 1:  # knots[lo] <= v < knots[hi]
            mid = (lo + hi) // 2
            if knots[mid] <= v:
                lo = mid
            else:
                hi = mid
        dx = v - knots[lo]
        f = ((coef[lo, 0] * dx + coef[lo, 1]) * dx + coef[lo, 2]) * dx + coef[lo, 3]
    if v > 0.0:
        f += coulomb
    elif v < 0.0:
        f -= coulomb
    return f


class _Stateless:
    """Shared behaviour of the stateless plug-ins: force depends on velocity only."""

    name = "stateless"
    last_fault = 0
    faults = 0

    def _curve(self, velocity_m_s: float) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    def reset(self, stroke_m: float = 0.0, velocity_m_s: float = 0.0) -> float:
        """No state to reset; returns the force at ``velocity_m_s``."""
        return self._curve(float(velocity_m_s))

    def force(self, stroke_m: float, velocity_m_s: float, dt_s: float) -> float:
        """Force [N, rebound +] at ``velocity_m_s``; stroke and ``dt_s`` are ignored."""
        return self._curve(float(velocity_m_s))

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"


class LinearPlugin(_Stateless):
    """A :class:`LinearDamper`, ``F = F_static + c ẋ`` (damper-side rate ``c``)."""

    def __init__(self, damper: LinearDamper, name: str = "linear"):
        self.damper = damper
        self.name = name
        self.kernel_spec = StatelessSpec(LINEAR, f0=damper.static_force_n,
                                         rate=damper.rate_ns_m)

    @property
    def static_force_n(self) -> float:
        return self.damper.static_force_n

    def _curve(self, v: float) -> float:
        return self.damper.force(v)


class TablePlugin(_Stateless):
    """A :class:`TableDamper` force–velocity look-up (e.g. the 14-speed curve)."""

    def __init__(self, table: TableDamper, name: str = "table"):
        self.table = table
        self.name = name
        self.kernel_spec = table_spec(table)

    @property
    def static_force_n(self) -> float:
        return self.table.static_force_n

    def _curve(self, v: float) -> float:
        return self.table.force(v)


#: Nodes per direction of the incompressible look-up: with 400 the table is within 0.02 N
#: of eqs 30–32 over ±10 m/s for the sport damper (0.4 µs a call against 8 µs direct).
INCOMPRESSIBLE_TABLE_POINTS = 400
#: Smallest non-zero node speed of that table [m/s].
INCOMPRESSIBLE_TABLE_V_MIN = 1e-6


class IncompressiblePlugin(_Stateless):
    """The incompressible (rigid-oil) force of eqs 30–32, ``F = F_static + Δp(ẋ)
    (A_pt − A_rod) + F_friction sgn ẋ``.

    Built once: the continuous part ``F − F_friction sgn ẋ`` is sampled by
    :func:`incompressible_force` at 0 and ±``points`` speeds spaced geometrically from
    ``v_min`` to the valve table's ``numerics.valve_table_max_velocity_m_s`` and held in a
    :class:`TableDamper` (monotone PCHIP, linear beyond the ends); the Coulomb friction is
    added exactly, so the force jumps by ``2 F_friction`` through ``ẋ = 0`` as eq 30 does.
    """

    def __init__(self, cfg: ModelConfig | DamperModel | None = None,
                 points: int = INCOMPRESSIBLE_TABLE_POINTS,
                 v_min: float = INCOMPRESSIBLE_TABLE_V_MIN, name: str = "incompressible"):
        if cfg is None:
            from damper_emulator.params import load_config
            cfg = load_config()
        cfg = cast(ModelConfig, getattr(cfg, "cfg", cfg))  # a DamperModel's, or cfg itself
        self.cfg = cfg
        self.name = name
        v_max = cfg.numerics.valve_table_max_velocity_m_s
        pos = np.geomspace(v_min, v_max, points)
        v = np.concatenate([-pos[::-1], [0.0], pos])
        friction = cfg.damper.friction_force_n
        smooth = incompressible_force(v, cfg) - friction * np.sign(v)
        self.table = TableDamper(v, smooth)
        self.friction_n = float(friction)
        self.kernel_spec = table_spec(self.table, self.friction_n)

    @property
    def static_force_n(self) -> float:
        """The curve at ``ẋ = 0``: ``F_static = −A_rod P_gas,static`` (eq 30)."""
        return self._curve(0.0)

    def _curve(self, v: float) -> float:
        f = self.table.force(v)
        if v > 0.0:
            return f + self.friction_n
        if v < 0.0:
            return f - self.friction_n
        return f


class CompressiblePlugin:
    """The hysteretic model (eqs 1–4) stepped in the loop by :class:`DamperStepper`.

    Every sample advances the pressure state by the real ``dt_s``.  The Fault bits of the
    latest sample are in :attr:`last_fault`, their OR since the latest reset in
    :attr:`faults` (clamped stroke or velocity, extrapolated valve table, solver).
    ``valve_command`` (0 comfort .. 1 sport, default) sets the adaptive damper's bypass
    (docs/model.md §6); :meth:`reset` settles the solenoid at the commanded value.
    """

    def __init__(self, model: DamperModel | None = None, name: str = "compressible",
                 valve_command: float = 1.0):
        self.model = model if model is not None else DamperModel()
        self.name = name
        self.stepper = DamperStepper(self.model, valve_command=valve_command)
        # the kernel's own force at rest at the static position: eq 30's −A_rod P_gas,static
        # up to rounding, taken from the kernel so that rest is an exact equilibrium
        self._static_force_n = self.stepper.force_n
        self.kernel_spec = CompressibleSpec(self.model.prm, self.model.tables[0].coef,
                                            self.model.tables[1].coef, self.stepper.state)
        self.last_fault = 0
        self.faults = 0

    @property
    def static_force_n(self) -> float:
        """The force at rest at the static position, ``−A_rod P_gas,static`` (eq 30), as
        the compiled model evaluates it (equal to ``cfg.damper.static_force_n`` to
        rounding; taken from the kernel so that rest is an exact equilibrium)."""
        return self._static_force_n

    def reset(self, stroke_m: float = 0.0, velocity_m_s: float = 0.0) -> float:
        """Quasi-steady equilibrium at this sample; clears the fault record."""
        self.stepper.reset(stroke_m, velocity_m_s)
        self.last_fault = 0
        self.faults = 0
        return self.stepper.force_n

    def force(self, stroke_m: float, velocity_m_s: float, dt_s: float) -> float:
        force, fault = self.stepper.step(stroke_m, velocity_m_s, dt_s)
        self.last_fault = int(fault)
        self.faults |= self.last_fault
        return float(force)

    def set_valve_command(self, command: float) -> None:
        """Command the bypass (0 comfort .. 1 sport); the solenoid lag acts from the next
        :meth:`force` on.  ``ValueError`` outside [0, 1]."""
        self.stepper.set_valve_command(command)

    @property
    def valve_command(self) -> float:
        """The commanded valve command."""
        return self.stepper.valve_command

    @property
    def effective_valve_command(self) -> float:
        """The valve command the bypass is at (after the solenoid lag)."""
        return self.stepper.effective_valve_command

    @property
    def fault_flags(self) -> Fault:
        """:attr:`faults` as :class:`~damper_emulator.model.layout.Fault`."""
        return Fault(self.faults)

    def __repr__(self) -> str:
        return f"CompressiblePlugin({self.name!r})"


def make_damper(kind: str, model: DamperModel | None = None, *,
                car: QuarterCarParams | None = None,
                rate_ns_m: float | None = None, points: int = FourteenSpeed.points,
                valve_command: float = 1.0) -> DamperPlugin:
    """A damper plug-in by kind.

    Parameters
    ----------
    kind : {"linear", "14speed", "incompressible", "compressible", "nonlinear"}
        ``nonlinear`` is the paper's name for ``compressible`` (the hysteretic model).
    model : DamperModel, optional
        The damper (default ``config/sport.yaml``).  The linear damper takes its static
        force from it, so every kind carries the same gas preload.
    car : QuarterCarParams, optional
        For ``linear`` without ``rate_ns_m``: the rate ``C_s · MR²`` (default
        ``config/quarter_car.yaml``).
    rate_ns_m : float, optional
        Damper-side linear rate [N s/m] for ``linear``.
    points : int
        N of the N-speed test for ``14speed`` (the paper uses 14 and 28).
    valve_command : float
        For ``compressible``/``nonlinear``: the adaptive damper's valve command, 0 comfort
        .. 0.5 normal .. 1 sport (default; docs/model.md §6).
    """
    kinds = ("linear", "14speed", "incompressible", "compressible", "nonlinear")
    if kind not in kinds:
        raise UserError(f"damper kind {kind!r} must be one of {', '.join(kinds)}")
    if model is None:
        model = DamperModel()
    if kind == "linear":
        if rate_ns_m is None:
            if car is None:
                from ride_sim.params import load_quarter_car
                car = load_quarter_car()
            rate_ns_m = car.damper_linear_rate_ns_m
        return LinearPlugin(LinearDamper(rate_ns_m, model.cfg.damper.static_force_n))
    if kind == "14speed":
        return TablePlugin(fourteen_speed_damper(model, points=points),
                           name=f"{points}-speed")
    if kind == "incompressible":
        return IncompressiblePlugin(model.cfg)
    return CompressiblePlugin(model, name=kind, valve_command=valve_command)

