"""Inverse valve look-up table ``Q(Δp)`` for the compressible model (eq 2).

The paper supplies the piston-valve flow of the compressible model "in the form of a simple
look-up table": the inverse of the incompressible characteristic ``Δp(Q)`` of
:mod:`damper_emulator.model.valve`.  Near ``Δp = 0`` the flow grows as ``Δp^(4/7)``, so the
table is built on the coordinate

    z = log(1 + (Δp / Δp_s)^(4/7)),      Δp = Δp_s (e^z − 1)^(7/4)

(``Δp_s`` the valve preload) in which ``Q`` is smooth with a finite slope at zero and which
spreads nodes evenly from the leak regime through blow-off to high flow.  Nodes are uniform
in ``z``; ``Q(z)`` is a monotone piecewise-cubic (PCHIP) interpolant through exact inverses of
``Δp(Q)``.  Beyond the last node the table extrapolates linearly in ``z`` (monotone) and says
so.  The implicit solver of the pressure equation works in ``z`` (signed: ``z > 0`` rebound
valve, ``z < 0`` compression valve).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Hashable, Iterable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from damper_emulator.errors import UserError
from damper_emulator.model.jit import batch_kernel, inlined_kernel, kernel
from damper_emulator.model.pchip import pchip_coefficients
from damper_emulator.model.valve import (
    FLOW_EXPONENT,
    form_code,
    open_constants,
    pressure_drop_array,
    pressure_drop_with,
)

# pressure_drop_of_z's square roots are the power FLOW_EXPONENT − 1 = 3/4
assert FLOW_EXPONENT == 1.75

#: Dense samples of ``Δp(Q)`` used to prove the characteristic strictly increasing.
MONOTONIC_CHECK_POINTS = 20001
#: The solver may extrapolate the table up to this multiple of its last ``z`` node.
EXTRAPOLATION_LIMIT = 2.0
#: Columns of a table's rows: the cubic's coefficients (c3, c2, c1, c0), then ``e^(z_i)``
#: and ``e^(z_i) − 1`` at the interval's first node (for :func:`valve_point`).
C_EXP, C_EXPM1, TABLE_COLUMNS = 4, 5, 6
#: The node spacing in ``z`` up to which :func:`valve_point` uses its polynomial (exact to
#: rounding below it; 1024 nodes up to z = 10, Δp/Δp_s ≈ 10⁷, space them 0.01); a coarser
#: table takes ``math.expm1``.
MAX_STEP = 0.05
# The exact inverse at the nodes: relative width of its bracket, and a bound on its steps.
_INVERSE_RTOL = 1e-15
_INVERSE_MAX_ITERATIONS = 200


class ValveTableError(UserError):
    """The valve characteristic cannot be tabulated (not invertible or not finite)."""


@kernel
def pressure_drop_of_z(z: float, scale_pa: float) -> tuple[float, float]:
    """``Δp(z) = Δp_s (e^z − 1)^(7/4)`` and ``dΔp/dz`` for ``z >= 0``."""
    u = math.expm1(z)
    # u^(3/4) as two square roots: the Newton solve of eq 2 evaluates this a few times per
    # sub-step, and a power costs about twice as much (measured, benchmarks/model_bench.py)
    u34 = math.sqrt(u * math.sqrt(u))
    return scale_pa * u * u34, scale_pa * FLOW_EXPONENT * u34 * (u + 1.0)


@kernel
def z_of_pressure_drop(dp: float, scale_pa: float) -> float:
    """Inverse of :func:`pressure_drop_of_z` for ``dp >= 0``."""
    return math.log1p((dp / scale_pa) ** (1.0 / FLOW_EXPONENT))


@kernel
def table_flow(coef: NDArray[np.float64], step: float, z: float) -> tuple[float, float, bool]:
    """Flow ``Q(z)`` [m³/s], ``dQ/dz`` and whether ``z`` lies beyond the table (``z >= 0``).

    ``coef[i, :4] = (c3, c2, c1, c0)`` of the cubic on ``[i·step, (i+1)·step]``.
    """
    n = coef.shape[0]
    i = int(z / step)
    if i >= n:
        # Linear extrapolation from the end of the last interval.
        c3, c2, c1, c0 = coef[n - 1, 0], coef[n - 1, 1], coef[n - 1, 2], coef[n - 1, 3]
        q_end = ((c3 * step + c2) * step + c1) * step + c0
        slope = (3.0 * c3 * step + 2.0 * c2) * step + c1
        return q_end + slope * (z - n * step), slope, True
    t = z - i * step
    c3, c2, c1, c0 = coef[i, 0], coef[i, 1], coef[i, 2], coef[i, 3]
    return ((c3 * t + c2) * t + c1) * t + c0, (3.0 * c3 * t + 2.0 * c2) * t + c1, False


@inlined_kernel
def table_interval(z: float, step: float, n: float) -> tuple[float, float, bool]:
    """The interval ``i`` (held as a float, exact below 2^53) of a table of ``n`` nodes
    spaced ``step`` in which ``z >= 0`` falls, the offset ``t = z − i·step`` in it, and
    whether :func:`valve_point` takes it from the row (inside the table, on a step fine
    enough for its polynomial) rather than the library's functions."""
    i = math.floor(z / step)
    return i, z - i * step, i < n and step <= MAX_STEP


@kernel
def valve_point(coef: NDArray[np.float64], step: float, scale_pa: float, z: float
                ) -> tuple[float, float, float, float, bool]:
    """``Δp(z)``, ``dΔp/dz`` (:func:`pressure_drop_of_z`), ``Q(z)``, ``dQ/dz`` and the
    beyond-table flag (:func:`table_flow`) at ``z >= 0``, from one look-up of the interval.

    Inside the table ``e^z − 1`` is ``expm1(z_i) + e^(z_i) expm1(t)`` with the node's
    values stored in the table (:data:`C_EXP`, :data:`C_EXPM1`) and ``expm1(t)`` of the
    offset ``0 <= t < step`` by its Taylor polynomial to ``t⁶/720`` (remainder below
    ``t⁷/5040``, under 10⁻¹⁸ of ``t`` on a step below :data:`MAX_STEP`; a coarser table
    takes the library's): the same number as ``math.expm1`` to a few ulp, without its
    library call, which took a fifth of the batch simulation's time (benchmarks/model_bench.py).
    """
    i_float, t, inside = table_interval(z, step, coef.shape[0])
    if not inside:
        dp, ddp = pressure_drop_of_z(z, scale_pa)
        q, dq, beyond = table_flow(coef, step, z)
        return dp, ddp, q, dq, beyond
    i = int(i_float)
    dp, ddp, q, dq = valve_row_point(coef[i, 0], coef[i, 1], coef[i, 2], coef[i, 3],
                                     coef[i, C_EXP], coef[i, C_EXPM1], t, scale_pa)
    return dp, ddp, q, dq, False


@kernel
def valve_row_point(c3: float, c2: float, c1: float, c0: float, e_node: float,
                    expm1_node: float, t: float, scale_pa: float
                    ) -> tuple[float, float, float, float]:
    """:func:`valve_point` inside the table, from one row's values: the cubic's
    coefficients, ``e^(z_i)`` and ``e^(z_i) − 1`` at the interval's first node ``z_i``,
    and the offset ``t = z − z_i``.  Returns ``Δp``, ``dΔp/dz``, ``Q``, ``dQ/dz``.

    Arithmetic only, no branch and no library call: a loop over designs that gathers
    each design's row first can run this in SIMD lanes (:mod:`damper_emulator.model.lanes`).
    """
    e_t = t * (1.0 + t * (0.5 + t * (1.0 / 6.0 + t * (1.0 / 24.0 + t * (
        1.0 / 120.0 + t * (1.0 / 720.0))))))
    u = expm1_node + e_node * e_t
    u34 = math.sqrt(u * math.sqrt(u))
    return (scale_pa * u * u34, scale_pa * FLOW_EXPONENT * u34 * (u + 1.0),
            ((c3 * t + c2) * t + c1) * t + c0, (3.0 * c3 * t + 2.0 * c2) * t + c1)


@batch_kernel
def _flows_at(dp_nodes: NDArray[np.float64], q_hi: float, valve: tuple[float, ...], nu: float,
              form: int, out: NDArray[np.float64]) -> None:
    """Exact inverse of ``Δp(Q)`` at each node (``dp_nodes`` increasing), by the Illinois
    variant of regula falsi on the forward characteristic, bracketed between the previous
    node's flow and ``q_hi``, to a relative width of :data:`_INVERSE_RTOL`.

    (Plain bisection to 2⁻⁶⁴ took 64 characteristic evaluations per node, 13 ms a table;
    this takes about ten, and a table costs about a fifth: it is rebuilt at every change
    of a valve constant while ``diagnose`` fits them.)"""
    k_leak, k_port, k_spring, preload, g = valve
    const = open_constants(k_leak, k_port, k_spring, preload, nu)
    q_prev = 0.0
    for i in range(dp_nodes.size):
        target = dp_nodes[i]
        lo, hi = q_prev, q_hi
        f_lo = pressure_drop_with(lo, k_leak, k_port, k_spring, preload, g, nu, form,
                                  const) - target
        f_hi = pressure_drop_with(hi, k_leak, k_port, k_spring, preload, g, nu, form,
                                  const) - target
        if f_lo >= 0.0:
            out[i] = lo
            continue
        if f_hi <= 0.0:
            out[i] = hi
            q_prev = hi
            continue
        side = 0
        for _ in range(_INVERSE_MAX_ITERATIONS):
            if hi - lo <= _INVERSE_RTOL * hi:
                break
            q = (lo * f_hi - hi * f_lo) / (f_hi - f_lo)
            if not lo < q < hi:
                q = 0.5 * (lo + hi)
            f = pressure_drop_with(q, k_leak, k_port, k_spring, preload, g, nu, form,
                                   const) - target
            if f == 0.0:
                lo = hi = q
                break
            if f < 0.0:
                lo, f_lo = q, f
                if side == -1:
                    f_hi *= 0.5
                side = -1
            else:
                hi, f_hi = q, f
                if side == 1:
                    f_lo *= 0.5
                side = 1
        out[i] = 0.5 * (lo + hi)
        q_prev = lo


@batch_kernel
def _table_flow_array(coef: NDArray[np.float64], step: float, z: NDArray[np.float64],
                      out: NDArray[np.float64]) -> None:
    for i in range(z.size):
        out[i] = table_flow(coef, step, z[i])[0]


@dataclass(frozen=True)
class ValveTable:
    """Inverse characteristic of one valve direction.

    Attributes
    ----------
    scale_pa : float
        ``Δp_s`` of the ``z`` coordinate (the valve preload) [Pa].
    step : float
        Node spacing in ``z``.
    coef : ndarray, shape (n - 1, TABLE_COLUMNS)
        Cubic coefficients per interval, highest power first, then ``e^z`` and
        ``e^z − 1`` at the interval's first node.
    max_flow_m3_s, max_pressure_drop_pa : float
        The last node.
    """

    scale_pa: float
    step: float
    coef: NDArray[np.float64]
    max_flow_m3_s: float
    max_pressure_drop_pa: float

    @property
    def z_max(self) -> float:
        return float(self.step * self.coef.shape[0])

    def flow(self, dp_pa: np.ndarray) -> np.ndarray:
        """``Q(Δp)`` [m³/s] for pressure drop magnitudes ``Δp >= 0`` [Pa]."""
        dp = np.asarray(dp_pa, dtype=float)
        z = np.log1p((dp / self.scale_pa) ** (1.0 / FLOW_EXPONENT)).ravel()
        out = np.empty(z.size)
        _table_flow_array(self.coef, self.step, z, out)
        return out.reshape(dp.shape)


def build_valve_table(valve: Iterable[float], annulus_area_m2: float, nu_m2_s: float, form: str,
                      points: int, max_velocity_m_s: float, label: str) -> ValveTable:
    """Tabulate the inverse of one valve's ``Δp(Q)`` after checking it is invertible.

    Raises
    ------
    ValveTableError
        If ``Δp(Q)`` is not finite and strictly increasing from 0 to the flow at
        ``max_velocity_m_s``.
    """
    q_max = max_velocity_m_s * annulus_area_m2
    if not (np.isfinite(q_max) and q_max * 1e-9 > 0.0):
        # (a positive but subnormal velocity passes the parameter's rule: the check's
        # geometric flows would start at zero)
        raise ValveTableError(
            f"{label}: the table's largest flow {q_max:.3g} m³/s (velocity "
            f"{max_velocity_m_s:.3g} m/s) is too small to tabulate")
    q = np.concatenate(([0.0], np.geomspace(q_max * 1e-9, q_max, MONOTONIC_CHECK_POINTS)))
    dp = pressure_drop_array(q, valve, nu_m2_s, form)
    bad = ~np.isfinite(dp)
    if bad.any():
        qb = q[np.argmax(bad)]
        raise ValveTableError(
            f"{label}: Δp(Q) is not finite at Q = {qb:.3g} m³/s "
            f"(velocity {qb / annulus_area_m2:.3g} m/s)")
    rising = np.diff(dp) > 0
    if not rising.all():
        qb = q[np.argmin(rising)]
        raise ValveTableError(
            f"{label}: Δp(Q) is not strictly increasing near Q = {qb:.3g} m³/s "
            f"(velocity {qb / annulus_area_m2:.3g} m/s), so it cannot be inverted "
            "(docs/model.md §2.1)")
    valve = tuple(float(v) for v in valve)
    scale = valve[3]
    z_max = math.log1p((dp[-1] / scale) ** (1.0 / FLOW_EXPONENT))
    z = np.linspace(0.0, z_max, points)
    dp_nodes = scale * np.expm1(z) ** FLOW_EXPONENT
    dp_nodes[-1] = min(dp_nodes[-1], dp[-1])
    q_nodes = np.empty(points)
    _flows_at(dp_nodes, q_max, valve, nu_m2_s, form_code(form),
              q_nodes)
    q_nodes[0] = 0.0
    step = float(z[1] - z[0])
    coef = np.empty((points - 1, TABLE_COLUMNS))
    coef[:, :4] = pchip_coefficients(z, q_nodes)
    coef[:, C_EXP] = np.exp(z[:-1])
    coef[:, C_EXPM1] = np.expm1(z[:-1])
    return ValveTable(scale, step, coef, float(q_nodes[-1]), float(dp[-1]))


class Valve(Hashable, Iterable[float], Protocol):
    """A valve's parameters in the order of the valve laws (:mod:`~damper_emulator.model.valve`),
    hashable (the tables are cached per valve): e.g. the frozen parameter group."""


def build_valve_tables(rebound: Valve, compression: Valve,
                       annulus_area_m2: float, nu_m2_s: float, form: str, points: int,
                       max_velocity_m_s: float) -> tuple[ValveTable, ValveTable]:
    """The (rebound, compression) tables of a damper's two valves (each hashable, e.g. a
    frozen parameter group; cached per valve: a change of the gas or of one valve
    rebuilds only what it changes).  :func:`damper_emulator.params.valve_tables` gives
    them for a configuration."""
    return (_build_table(rebound, annulus_area_m2, nu_m2_s, form, points, max_velocity_m_s,
                         "damper.rebound valve"),
            _build_table(compression, annulus_area_m2, nu_m2_s, form, points,
                         max_velocity_m_s, "damper.compression valve"))


_build_table = functools.lru_cache(maxsize=64)(build_valve_table)
