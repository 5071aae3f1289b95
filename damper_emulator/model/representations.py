"""Classical damper representations (docs/model.md §4), for comparison with the hysteretic model.

- :class:`LinearDamper`: a single rate, ``F = F_static + c ẋ``.
- :class:`TableDamper`: a monotone force–velocity look-up, e.g. the '14-speed' curve: peak
  force against peak velocity of N sine tests, rebound and compression, joined through the
  static force at ``ẋ = 0``.

Both expose ``force(velocity)`` [N, rebound +] for a scalar or an array of velocities
[m/s, extension +] and carry no state (no hysteresis).  numpy / scipy only.

Builders from a model: :func:`linear_from_model` (least-squares rate of the incompressible
curve, eqs 30–32) and :func:`fourteen_speed_damper` (the N-speed test simulated on the
compressible model by the virtual dyno, :func:`damper_emulator.dyno.simulated.
fourteen_speed_table`).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, cast, overload

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import PchipInterpolator

from damper_emulator.dyno.protocols import FourteenSpeed
from damper_emulator.errors import UserError

if TYPE_CHECKING:  # pragma: no cover
    from damper_emulator.model.compressible import DamperModel
    from damper_emulator.params import ModelConfig


def _finite_number(name: str, value: Any) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise UserError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(out):
        raise UserError(f"{name} must be finite, got {value!r}")
    return out


def _velocity_array(velocity: ArrayLike) -> tuple[NDArray[np.float64], bool]:
    v: NDArray[np.float64] = np.asarray(velocity, dtype=float)
    if not np.isfinite(v).all():
        bad = v.flat[int(np.argmax(~np.isfinite(v)))] if v.ndim else v
        raise UserError(f"damper velocity must be finite, got {float(bad)!r}")
    return v, v.ndim == 0


def _curve(name: str, values: ArrayLike) -> NDArray[np.float64]:
    a: NDArray[np.float64] = np.asarray(values, dtype=float)
    if a.ndim != 1:
        raise UserError(f"{name} must be one-dimensional, got shape {a.shape}")
    bad = ~np.isfinite(a)
    if bad.any():
        i = int(np.argmax(bad))
        raise UserError(f"{name}[{i}] is {a[i]} (must be finite)")
    return a


# --------------------------------------------------------------------------------------
# linear


class LinearDamper:
    """``F = static_force_n + rate_ns_m · ẋ`` [N].

    Parameters
    ----------
    rate_ns_m : damping rate [N s/m], finite and >= 0
    static_force_n : force at rest [N] (the gas force ``−A_rod P_gas,static`` for a
        mono-tube; 0 for a pure viscous damper)
    """

    def __init__(self, rate_ns_m: float, static_force_n: float = 0.0):
        rate = _finite_number("linear damping rate [N s/m]", rate_ns_m)
        if rate < 0:
            raise UserError(f"linear damping rate must be >= 0 N s/m, got {rate_ns_m!r}")
        self.rate_ns_m = rate
        self.static_force_n = _finite_number("static force [N]", static_force_n)

    @overload
    def force(self, velocity: float) -> float: ...

    @overload
    def force(self, velocity: ArrayLike) -> float | NDArray[np.float64]: ...

    def force(self, velocity: ArrayLike) -> float | NDArray[np.float64]:
        """Force [N, rebound +] at ``velocity`` [m/s] (scalar → float, array → array)."""
        if isinstance(velocity, float | int) and not isinstance(velocity, bool):
            if not math.isfinite(velocity):
                raise UserError(f"damper velocity must be finite, got {velocity!r}")
            return self.static_force_n + self.rate_ns_m * float(velocity)
        v, scalar = _velocity_array(velocity)
        f = self.static_force_n + self.rate_ns_m * v
        return float(f) if scalar else f

    __call__ = force

    def __repr__(self) -> str:
        return (f"LinearDamper(rate_ns_m={self.rate_ns_m:.6g}, "
                f"static_force_n={self.static_force_n:.6g})")


def linear_best_fit(velocity: ArrayLike, force: ArrayLike, static_force_n: float = 0.0) -> float:
    """Least-squares damping rate [N s/m] of ``force`` against ``velocity``, the line
    constrained through ``(0, static_force_n)``:

        c = Σ ẋ (F − F_static) / Σ ẋ²

    With the default ``static_force_n = 0`` the line passes through the origin.  The
    offset is held, not fitted, so that the linear damper exerts exactly the static force
    at rest (a free intercept would absorb the rebound/compression asymmetry instead).
    """
    v = _curve("velocity", velocity)
    f = _curve("force", force)
    if v.shape != f.shape:
        raise UserError(f"velocity and force differ in length ({v.size} and {f.size})")
    f0 = _finite_number("static force [N]", static_force_n)
    den = float(np.dot(v, v))
    if den == 0.0:
        raise UserError("linear best fit needs at least one non-zero velocity")
    return float(np.dot(v, f - f0)) / den


def linear_from_model(model: DamperModel | ModelConfig, v_max: float, points: int = 201
                      ) -> LinearDamper:
    """Linear damper fitted to the incompressible force (eqs 30–32) of ``model`` (a
    :class:`~damper_emulator.model.compressible.DamperModel` or a ``ModelConfig``).

    The curve is sampled at ``points`` velocities spaced uniformly over ``[−v_max, v_max]``
    (rebound and compression weighted alike) and fitted by :func:`linear_best_fit` through
    the model's static force ``−A_rod P_gas,static``, which the result keeps.
    """
    from damper_emulator.model.incompressible import incompressible_force

    # a DamperModel's configuration, or the ModelConfig itself
    cfg = cast("ModelConfig", getattr(model, "cfg", model))
    v_max = _finite_number("v_max [m/s]", v_max)
    if v_max <= 0:
        raise UserError(f"v_max must be > 0 m/s, got {v_max!r}")
    if isinstance(points, bool) or not isinstance(points, int) or points < 2:
        raise UserError(f"points must be an integer >= 2, got {points!r}")
    v = np.linspace(-v_max, v_max, points)
    f = incompressible_force(v, cfg)
    static = float(cfg.damper.static_force_n)
    return LinearDamper(linear_best_fit(v, f, static), static)


# --------------------------------------------------------------------------------------
# table ('14-speed')


class TableDamper:
    """Monotone force–velocity look-up.

    Between the nodes: monotone cubic interpolation (``scipy.interpolate.
    PchipInterpolator``), which passes through every node and never overshoots, so a
    non-decreasing table gives a non-decreasing curve.  Beyond the end nodes: linear
    extrapolation with the interpolant's end slope (the curve stays C¹ and monotone).

    Parameters
    ----------
    velocity_m_s : strictly increasing velocities [m/s], at least 2, finite
    force_n : forces [N] at those velocities, finite and non-decreasing

    Raises
    ------
    ValueError
        Fewer than 2 nodes, lengths differ, non-finite values, velocity not strictly
        increasing or force decreasing somewhere (naming the node).
    """

    def __init__(self, velocity_m_s: ArrayLike, force_n: ArrayLike):
        v = _curve("table velocity", velocity_m_s)
        f = _curve("table force", force_n)
        if v.size != f.size:
            raise UserError(f"table velocity and force differ in length ({v.size} and "
                             f"{f.size})")
        if v.size < 2:
            raise UserError(f"a force–velocity table needs at least 2 points, got {v.size}")
        dv, df = np.diff(v), np.diff(f)
        if not (dv > 0).all():
            i = int(np.argmax(~(dv > 0))) + 1
            raise UserError(f"table velocity is not strictly increasing at point {i} "
                             f"({v[i - 1]:.6g} m/s then {v[i]:.6g} m/s)")
        if not (df >= 0).all():
            i = int(np.argmax(~(df >= 0))) + 1
            raise UserError(f"table force is not monotonic at point {i}: {f[i - 1]:.6g} N "
                             f"at {v[i - 1]:.6g} m/s but {f[i]:.6g} N at {v[i]:.6g} m/s")
        v.setflags(write=False)
        f.setflags(write=False)
        self.velocity_m_s = v
        self.force_n = f
        self._pchip = PchipInterpolator(v, f, extrapolate=False)
        slopes = self._pchip.derivative()(v[[0, -1]])
        self._slope_lo, self._slope_hi = float(slopes[0]), float(slopes[1])
        # plain-Python copies for the scalar path (a ride simulation calls it per step)
        self._knots = [float(a) for a in v]
        self._coef = [tuple(float(c) for c in col) for col in self._pchip.c.T]

    @classmethod
    def from_branches(cls, rebound_velocity_m_s: ArrayLike, rebound_force_n: ArrayLike,
                      compression_velocity_m_s: ArrayLike, compression_force_n: ArrayLike,
                      static_force_n: float) -> TableDamper:
        """Table from separate rebound (``ẋ > 0``) and compression (``ẋ < 0``) points, in
        any order, joined through ``(0, static_force_n)``."""
        vr = _curve("rebound velocity", rebound_velocity_m_s)
        fr = _curve("rebound force", rebound_force_n)
        vc = _curve("compression velocity", compression_velocity_m_s)
        fc = _curve("compression force", compression_force_n)
        f0 = _finite_number("static force [N]", static_force_n)
        if vr.size != fr.size or vc.size != fc.size:
            raise UserError("each branch needs as many forces as velocities")
        if (vr <= 0).any():
            raise UserError(f"rebound velocities must be > 0, got {vr[vr <= 0][0]:.6g} m/s")
        if (vc >= 0).any():
            raise UserError(f"compression velocities must be < 0, got "
                             f"{vc[vc >= 0][0]:.6g} m/s")
        v = np.concatenate([vc, [0.0], vr])
        f = np.concatenate([fc, [f0], fr])
        order = np.argsort(v, kind="stable")
        return cls(v[order], f[order])

    @classmethod
    def from_fourteen_speed_table(cls, table: Mapping[str, np.ndarray],
                                  static_force_n: float) -> TableDamper:
        """Table from an N-speed test table (the columns of ``14speed.csv``,
        :data:`damper_emulator.dyno.simulated.FOURTEEN_SPEED_COLUMNS`)."""
        return cls.from_branches(table["peak_velocity_rebound_m_s"],
                                 table["peak_force_rebound_n"],
                                 table["peak_velocity_compression_m_s"],
                                 table["peak_force_compression_n"], static_force_n)

    @property
    def static_force_n(self) -> float:
        """Force at ``ẋ = 0`` [N]."""
        return self.force(0.0)

    @overload
    def force(self, velocity: float) -> float: ...

    @overload
    def force(self, velocity: ArrayLike) -> float | NDArray[np.float64]: ...

    def force(self, velocity: ArrayLike) -> float | NDArray[np.float64]:
        """Force [N, rebound +] at ``velocity`` [m/s] (scalar → float, array → array)."""
        if isinstance(velocity, float | int) and not isinstance(velocity, bool):
            return self._force_scalar(float(velocity))
        v, scalar = _velocity_array(velocity)
        v_lo, v_hi = self.velocity_m_s[0], self.velocity_m_s[-1]
        inside = np.clip(v, v_lo, v_hi)
        f = np.asarray(self._pchip(inside), dtype=float)
        f = np.where(v < v_lo, self.force_n[0] + self._slope_lo * (v - v_lo), f)
        f = np.where(v > v_hi, self.force_n[-1] + self._slope_hi * (v - v_hi), f)
        return float(f) if scalar else f

    __call__ = force

    def _force_scalar(self, v: float) -> float:
        """:meth:`force` of one velocity in plain Python (about 1 µs instead of 20)."""
        knots = self._knots
        if not math.isfinite(v):
            raise UserError(f"damper velocity must be finite, got {v!r}")
        if v <= knots[0]:
            return float(self.force_n[0]) + self._slope_lo * (v - knots[0])
        if v >= knots[-1]:
            return float(self.force_n[-1]) + self._slope_hi * (v - knots[-1])
        i = bisect.bisect_right(knots, v) - 1
        c3, c2, c1, c0 = self._coef[i]
        dx = v - knots[i]
        return ((c3 * dx + c2) * dx + c1) * dx + c0

    def __repr__(self) -> str:
        return (f"TableDamper({self.velocity_m_s.size} points, "
                f"{self.velocity_m_s[0]:.4g}..{self.velocity_m_s[-1]:.4g} m/s)")


def fourteen_speed_damper(model: DamperModel, points: int = FourteenSpeed.points,
                          amplitude_m: float = FourteenSpeed.amplitude_m,
                          v_min: float = FourteenSpeed.v_min_m_s,
                          v_max: float = FourteenSpeed.v_max_m_s,
                          cycles: int = FourteenSpeed.cycles,
                          rate: float = FourteenSpeed.rate_hz) -> TableDamper:
    """The '14-speed' representation of ``model`` (a ``DamperModel``), docs/model.md §4.

    Runs the N-speed test on the compressible model with the virtual dyno
    (:func:`damper_emulator.dyno.simulated.fourteen_speed_table`: ``points`` sines of
    ``amplitude_m`` whose peak velocities are spaced geometrically from ``v_min`` to
    ``v_max``; one settle cycle dropped, ``cycles`` recorded at ``rate`` Hz), pairs the
    peak force with the peak velocity per direction and joins both branches through the
    model's static force at ``ẋ = 0``.  The paper uses 14 and 28 points.
    """
    from damper_emulator.dyno.simulated import fourteen_speed_table

    # the settings are checked by the protocol's schema (dyno.protocols.FourteenSpeed)
    table, _faults = fourteen_speed_table(model, points, amplitude_m, v_min, v_max, cycles,
                                          rate)
    return TableDamper.from_fourteen_speed_table(table, model.cfg.damper.static_force_n)
