"""Quarter-car ride model, Simms & Crolla eq 38 (``docs/model.md`` §5), stepped the way
a hardware-in-the-loop rig runs it.

Equations of motion in deviations from static equilibrium (wheel ``z1``, body ``z2``, road
``x0``, all up-positive; gravity and the static loads cancel)::

    M_w z1'' = K_t (x0 − z1) + C_t (x0' − z1') − K_s (z1 − z2) − C_i (z1' − z2') + f
    M_b z2'' =                                    K_s (z1 − z2) + C_i (z1' − z2') − f

    f = (F_d − F_d,static) / MR                    wheel force of the damper
    x_d = −(z1 − z2) / MR,  v_d = −(z1' − z2') / MR   damper stroke and velocity

``F_d`` is the damper force (rebound +), ``F_d,static`` its force at rest at the static
position (the gas preload, carried by the spring at static equilibrium), ``MR`` the motion
ratio (wheel / damper travel).  Suspension compression (``z1 − z2`` increasing) is damper
compression (``x_d < 0``).  With a linear damper ``F_d = F_static + c v_d`` the damper term
is ``−(c/MR²)(z1' − z2')``: eq 38 with ``C_s = c/MR²``.  ``C_t`` (tyre damping) is 0 in eq
38; ``C_i`` is an optional linear damping inside the vehicle matrices (0 when a damper
plug-in is used; used to check the sampled coupling against the exact linear car).

**Coupling (the same for every damper and for a HIL loop).**  At each sample ``t_k`` the
damper is sampled once with ``(x_d, v_d)`` of the current state and returns ``F_k``; the
force is held (zero-order hold) while the vehicle advances to ``t_k + dt``.  The rest of the
car is linear, so it is advanced *exactly* over ``dt`` by a precomputed discretisation
(matrix exponential of the augmented system) with ``f`` as a zero-order-hold input and the
road height as a first-order-hold input (linear between samples, slope
``(x0[k+1] − x0[k])/dt``).  It is stable for the stiff tyre at any ``dt``; the only
approximation is the damper's sampling (a ZOH lag of about ``dt/2``).

**Outputs at a sample** (``t_k``, right limits): ``SWS = z1 − z2``; body acceleration from
eq 38 with the state at ``t_k`` and the force ``F_k`` held over the following step
(``z2''(t_k⁺)``; the acceleration is discontinuous at the samples because the force is);
``DTL = K_t (x0 − z1) + C_t (x0' − z1')`` with the road slope of the following step (of the
preceding one at the last sample), a deviation from the static tyre load.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import expm

from damper_emulator.errors import UserError
from damper_emulator.model.jit import inlined_kernel, kernel
from damper_emulator.model.step import step as _compressible_step
from ride_sim.dampers import CompressibleSpec, DamperPlugin, StatelessSpec, stateless_force
from ride_sim.params import QuarterCarParams, validate_quarter_car

# Layout of the packed vehicle vector used by the kernels.
(Q_MW, Q_MB, Q_KT, Q_KS, Q_CI, Q_CT, Q_MR, Q_DT, Q_FSTATIC, Q_SIZE) = range(10)
# Layout of the state vector.
Z1, Z1D, Z2, Z2D = range(4)

#: The kernels' arrays: discretisation matrix, vehicle and state vectors, road, outputs.
_Vec = NDArray[np.float64]


def continuous_model(params: QuarterCarParams, internal_damping_ns_m: float = 0.0
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Continuous state-space form of the model above, ``s' = A s + B [f, x0, x0']``.

    State ``s = (z1, z1', z2, z2')``; inputs: damper wheel force ``f`` [N], road height
    [m], road rate [m/s].  Returns ``(A (4×4), B (4×3))``.
    """
    mw, mb = params.unsprung_mass_kg, params.sprung_mass_kg
    kt, ks = params.tyre_stiffness_n_m, params.spring_rate_n_m
    ci, ct = float(internal_damping_ns_m), params.tyre_damping_ns_m
    a = np.array([[0.0, 1.0, 0.0, 0.0],
                  [-(kt + ks) / mw, -(ci + ct) / mw, ks / mw, ci / mw],
                  [0.0, 0.0, 0.0, 1.0],
                  [ks / mb, ci / mb, -ks / mb, -ci / mb]])
    b = np.array([[0.0, 0.0, 0.0],
                  [1.0 / mw, kt / mw, ct / mw],
                  [0.0, 0.0, 0.0],
                  [-1.0 / mb, 0.0, 0.0]])
    return a, b


def discretise(params: QuarterCarParams, dt_s: float,
               internal_damping_ns_m: float = 0.0) -> np.ndarray:
    """Exact discretisation of eq 38 over ``dt_s``: the 4×7 matrix ``D`` with

        s[k+1] = D @ (s[k], f_k, x0[k], x0[k+1])

    for the damper wheel force ``f`` held constant and the road ``x0`` linear over the step
    (state and inputs as in :func:`continuous_model`).  From the matrix exponential of the
    augmented system ``(s, f, x0, r)`` with ``f' = 0``, ``x0' = r``, ``r' = 0``.  Returns a
    writable copy of a cached matrix.
    """
    return _discretise(params, float(dt_s), float(internal_damping_ns_m)).copy()


@functools.lru_cache(maxsize=64)
def _discretise(params: QuarterCarParams, dt_s: float,
                internal_damping_ns_m: float = 0.0) -> np.ndarray:
    """:func:`discretise`, cached (the matrix is read-only)."""
    a, b = continuous_model(params, internal_damping_ns_m)
    m = np.zeros((7, 7))
    m[:4, :4] = a
    m[:4, 4] = b[:, 0]          # f, zero-order hold
    m[:4, 5] = b[:, 1]          # x0
    m[:4, 6] = b[:, 2]          # x0' = r
    m[5, 6] = 1.0               # x0 grows at r
    e = expm(m * dt_s)
    d = np.empty((4, 7))
    d[:, :5] = e[:4, :5]
    # x0 enters as (x0[k], r = (x0[k+1] − x0[k]) / dt)
    d[:, 5] = e[:4, 5] - e[:4, 6] / dt_s
    d[:, 6] = e[:4, 6] / dt_s
    d.setflags(write=False)
    return d


# --------------------------------------------------------------------------------------
# The one vehicle update, compiled; used by QuarterCar (one call per sample), by the
# batch loops and by the hybrid compensator's prediction.


@inlined_kernel
def wheel_force(damper_force: float, static_force: float, motion_ratio: float) -> float:
    """The damper force over its static value, at the wheel [N]."""
    f: float = (damper_force - static_force) / motion_ratio
    return f


@kernel
def advance_state(d: _Vec, s: _Vec, f: float, u0: float, u1: float) -> None:
    """``s ← D (s, f, u0, u1)`` in place (exact step, see :func:`discretise`)."""
    a0, a1, a2, a3 = s[0], s[1], s[2], s[3]
    for i in range(4):
        s[i] = (d[i, 0] * a0 + d[i, 1] * a1 + d[i, 2] * a2 + d[i, 3] * a3
                + d[i, 4] * f + d[i, 5] * u0 + d[i, 6] * u1)


@kernel
def state_motion(q: _Vec, s: _Vec) -> tuple[float, float]:
    """Damper stroke and velocity (extension +) of state ``s``."""
    return -(s[0] - s[2]) / q[Q_MR], -(s[1] - s[3]) / q[Q_MR]


@kernel
def state_outputs(q: _Vec, s: _Vec, damper_force: float, u0: float, u1: float
                  ) -> tuple[float, float, float]:
    """``(sws, body acceleration, dtl)`` at the sample, force held over the next step."""
    f = wheel_force(damper_force, q[Q_FSTATIC], q[Q_MR])
    sws = s[0] - s[2]
    accel = (q[Q_KS] * sws + q[Q_CI] * (s[1] - s[3]) - f) / q[Q_MB]
    dtl = q[Q_KT] * (u0 - s[0]) + q[Q_CT] * ((u1 - u0) / q[Q_DT] - s[1])
    return sws, accel, dtl


@kernel
def record_sample(q: _Vec, s: _Vec, k: int, force: float, fault: int, u0: float, u1: float,
            out: _Vec, faults: NDArray[np.int64]) -> None:
    sws, accel, dtl = state_outputs(q, s, force, u0, u1)
    x, v = state_motion(q, s)
    out[0, k] = s[0]
    out[1, k] = s[1]
    out[2, k] = s[2]
    out[3, k] = s[3]
    out[4, k] = sws
    out[5, k] = accel
    out[6, k] = dtl
    out[7, k] = x
    out[8, k] = v
    out[9, k] = force
    faults[k] = fault


# Rows of the loop output array.
(O_Z1, O_Z1D, O_Z2, O_Z2D, O_SWS, O_ACC, O_DTL, O_X, O_V, O_F, O_SIZE) = range(11)


@kernel
def road_pair(road: _Vec, k: int) -> tuple[float, float]:
    n = road.size
    if k + 1 < n:
        return road[k], road[k + 1]
    if n > 1:  # last sample: continue the preceding slope
        return road[k], 2.0 * road[k] - road[k - 1]
    return road[k], road[k]


@kernel
def _loop_compressible(d: _Vec, q: _Vec, road: _Vec, s: _Vec, force0: float, prm: _Vec,
                       coef_r: _Vec, coef_c: _Vec, dstate: _Vec, out: _Vec,
                       faults: NDArray[np.int64]) -> None:
    n = road.size
    force = force0
    fault = 0
    for k in range(n):
        if k > 0:
            x, v = state_motion(q, s)
            force, fault = _compressible_step(prm, coef_r, coef_c, dstate, x, v, q[Q_DT])
        u0, u1 = road_pair(road, k)
        record_sample(q, s, k, force, fault, u0, u1, out, faults)
        if k + 1 < n:
            advance_state(d, s, wheel_force(force, q[Q_FSTATIC], q[Q_MR]), u0, u1)


@kernel
def _loop_stateless(d: _Vec, q: _Vec, road: _Vec, s: _Vec, force0: float, kind: int, f0: float,
                    rate: float, knots: _Vec, coef: _Vec, f_lo: float, f_hi: float,
                    slope_lo: float, slope_hi: float, coulomb: float, out: _Vec,
                    faults: NDArray[np.int64]) -> None:
    n = road.size
    force = force0
    for k in range(n):
        if k > 0:
            v = state_motion(q, s)[1]
            force = stateless_force(kind, f0, rate, knots, coef, f_lo, f_hi, slope_lo,
                                    slope_hi, coulomb, v)
        u0, u1 = road_pair(road, k)
        record_sample(q, s, k, force, 0, u0, u1, out, faults)
        if k + 1 < n:
            advance_state(d, s, wheel_force(force, q[Q_FSTATIC], q[Q_MR]), u0, u1)


# --------------------------------------------------------------------------------------


class RideSample(NamedTuple):
    """Outputs at one sample (see the module docstring)."""

    sws_m: float
    body_accel_m_s2: float
    dtl_n: float


class QuarterCar:
    """The vehicle half of the loop: exact linear update with held damper force.

    One sample of the loop (what :func:`simulate` and a HIL node do)::

        x, v = car.damper_motion()                 # send to the damper
        F = damper.force(x, v, dt)                 # full damper force, rebound +
        out = car.outputs(F, road[k], road[k + 1]) # SWS, body accel, DTL at t_k
        car.advance(F, road[k], road[k + 1])       # to t_k + dt with F held

    Parameters
    ----------
    params : QuarterCarParams
    dt_s : float
        Sample period [s].
    static_force_n : float
        The damper's force at rest at the static position (``damper.static_force_n``),
        carried by the spring at static equilibrium: :meth:`advance` and :meth:`outputs`
        take the *full* damper force and apply ``(F − static_force_n) / MR`` to the wheel.
    internal_damping_ns_m : float
        Linear damping at the wheel built into the exact update (default 0: the damping
        comes from the sampled damper).
    """

    def __init__(self, params: QuarterCarParams, dt_s: float = 1e-3,
                 static_force_n: float = 0.0, internal_damping_ns_m: float = 0.0):
        validate_quarter_car(params)
        dt_s = float(dt_s)
        if not (math.isfinite(dt_s) and dt_s > 0):
            raise UserError(f"time step must be a positive number of seconds, got {dt_s!r}")
        if not math.isfinite(static_force_n):
            raise UserError(f"static force must be finite, got {static_force_n!r}")
        if not (math.isfinite(internal_damping_ns_m) and internal_damping_ns_m >= 0):
            raise UserError(f"internal damping must be >= 0 N s/m, got "
                             f"{internal_damping_ns_m!r}")
        self.params = params
        self.dt_s = dt_s
        self.static_force_n = float(static_force_n)
        self.internal_damping_ns_m = float(internal_damping_ns_m)
        self.matrix = _discretise(params, dt_s, float(internal_damping_ns_m))  # read-only
        q = np.zeros(Q_SIZE)
        q[Q_MW] = params.unsprung_mass_kg
        q[Q_MB] = params.sprung_mass_kg
        q[Q_KT] = params.tyre_stiffness_n_m
        q[Q_KS] = params.spring_rate_n_m
        q[Q_CI] = internal_damping_ns_m
        q[Q_CT] = params.tyre_damping_ns_m
        q[Q_MR] = params.motion_ratio
        q[Q_DT] = dt_s
        q[Q_FSTATIC] = static_force_n
        self._q = q
        self._s = np.zeros(4)

    @property
    def kernel_params(self) -> np.ndarray:
        """The kernels' parameter vector (indices ``Q_*``: masses, stiffnesses, motion
        ratio, ``dt``, static force); read it, do not change it."""
        return self._q

    @property
    def state(self) -> np.ndarray:
        """``(z1, z1', z2, z2')`` deviations from static equilibrium [m, m/s] (a copy)."""
        return self._s.copy()

    def reset(self, state: ArrayLike | None = None) -> None:
        """Static equilibrium (all zero, road at 0), or the given ``(z1, z1', z2, z2')``."""
        s = np.zeros(4) if state is None else np.asarray(state, dtype=float).reshape(4)
        if not np.isfinite(s).all():
            raise UserError(f"quarter-car state must be finite, got {s!r}")
        self._s[:] = s

    def damper_motion(self) -> tuple[float, float]:
        """Damper ``(stroke [m], velocity [m/s])``, extension +, of the current state."""
        x, v = state_motion(self._q, self._s)
        return float(x), float(v)

    def outputs(self, damper_force_n: float, road_now_m: float,
                road_next_m: float) -> RideSample:
        """SWS, body acceleration and DTL at the current sample, with ``damper_force_n``
        (full force) held over the coming step and the road going from ``road_now_m`` to
        ``road_next_m``."""
        return RideSample(*map(float, state_outputs(self._q, self._s, float(damper_force_n),
                                               float(road_now_m), float(road_next_m))))

    def advance(self, damper_force_n: float, road_now_m: float, road_next_m: float) -> None:
        """Advance exactly by ``dt`` with ``damper_force_n`` (full damper force, rebound +)
        held and the road linear from ``road_now_m`` to ``road_next_m``."""
        f = wheel_force(float(damper_force_n), self.static_force_n, self.params.motion_ratio)
        advance_state(self.matrix, self._s, f, float(road_now_m), float(road_next_m))


@dataclass(frozen=True)
class RideResult:
    """Time histories of :func:`simulate`, one value per road sample (see the
    :mod:`module docstring <ride_sim.quarter_car>` for the sampling conventions)."""

    time_s: np.ndarray
    road_m: np.ndarray
    sws_m: np.ndarray                 # z1 − z2, + = suspension compressed
    body_accel_m_s2: np.ndarray       # z2''(t_k+), up +
    dtl_n: np.ndarray                 # deviation from the static tyre load, + = more load
    wheel_m: np.ndarray               # z1
    body_m: np.ndarray                # z2
    wheel_velocity_m_s: np.ndarray    # z1'
    body_velocity_m_s: np.ndarray     # z2'
    damper_stroke_m: np.ndarray       # extension +
    damper_velocity_m_s: np.ndarray   # extension +
    damper_force_n: np.ndarray        # full force, rebound +, held over the next step
    faults: np.ndarray                # damper Fault bits per sample (int64)
    damper: str = ""
    dt_s: float = 0.0

    @property
    def fault_bits(self) -> int:
        """OR of all damper Fault bits."""
        return int(np.bitwise_or.reduce(self.faults)) if self.faults.size else 0


def ride_result(t: np.ndarray, road: np.ndarray, out: np.ndarray, faults: np.ndarray, name: str,
            dt: float) -> RideResult:
    return RideResult(t, road, out[O_SWS], out[O_ACC], out[O_DTL], out[O_Z1], out[O_Z2],
                      out[O_Z1D], out[O_Z2D], out[O_X], out[O_V], out[O_F], faults, name, dt)


def road_array(road_height_m: ArrayLike) -> np.ndarray:
    """The road heights as a contiguous 1-D float array.

    Raises
    ------
    UserError
        Not a non-empty 1-D array, or a sample that is not finite (naming it).
    """
    road = np.ascontiguousarray(road_height_m, dtype=float)
    if road.ndim != 1 or road.size == 0:
        raise UserError(f"road height must be a non-empty 1-D array, got shape {road.shape}")
    bad = ~np.isfinite(road)
    if bad.any():
        i = int(np.argmax(bad))
        raise UserError(f"road height sample {i} is {road[i]} (must be finite)")
    return road


def simulate(params: QuarterCarParams, damper: DamperPlugin, road_height_m: ArrayLike,
             dt_s: float = 1e-3, *, initial_state: ArrayLike | None = None,
             compiled: bool = True) -> RideResult:
    """Ride simulation over a road height history sampled every ``dt_s``.

    The car starts at static equilibrium (or ``initial_state`` ``(z1, z1', z2, z2')``) with
    the damper reset at the matching stroke and velocity (its static force carried by the
    spring); sample ``k`` is at ``t = k dt``.  See the module docstring for the coupling
    and output conventions.

    Parameters
    ----------
    params : QuarterCarParams
    damper : DamperPlugin
        Reset here; afterwards it holds the state of the last sample (and, for
        :class:`~ride_sim.dampers.CompressiblePlugin`, the accumulated Fault bits).
    road_height_m : array_like, shape (n,)
        Road height under the tyre [m, up +] at the samples, linear in between.
    dt_s : float
        Sample period [s].
    compiled : bool
        Run the built-in plug-ins in the compiled loop (default).  ``False`` (or a plug-in
        without ``kernel_spec``) runs the same update through :class:`QuarterCar` and the
        plug-in's ``force`` in Python.
    """
    road = road_array(road_height_m)
    car = QuarterCar(params, dt_s, damper.static_force_n)
    car.reset(initial_state)
    n = road.size
    t = np.arange(n) * car.dt_s
    x0, v0 = car.damper_motion()
    force0 = float(damper.reset(x0, v0))
    out = np.empty((O_SIZE, n))
    faults = np.zeros(n, dtype=np.int64)
    spec = getattr(damper, "kernel_spec", None) if compiled else None
    s = car._s
    if isinstance(spec, CompressibleSpec):
        _loop_compressible(car.matrix, car._q, road, s, force0, spec.prm, spec.coef_r,
                           spec.coef_c, spec.state, out, faults)
        bits = int(np.bitwise_or.reduce(faults))
        damper.last_fault = int(faults[-1])
        damper.faults |= bits
    elif isinstance(spec, StatelessSpec):
        _loop_stateless(car.matrix, car._q, road, s, force0, spec.kind, spec.f0, spec.rate,
                        spec.knots, spec.coef, spec.f_lo, spec.f_hi, spec.slope_lo,
                        spec.slope_hi, spec.coulomb, out, faults)
    else:
        force = force0
        fault = 0
        for k in range(n):
            if k > 0:
                x, v = car.damper_motion()
                force = float(damper.force(x, v, car.dt_s))
                if not math.isfinite(force):
                    raise UserError(f"damper {damper.name!r} returned a non-finite force "
                                     f"{force!r} at sample {k}")
                fault = int(getattr(damper, "last_fault", 0))
            u0, u1 = road_pair(road, k)
            record_sample(car._q, s, k, force, fault, u0, u1, out, faults)
            if k + 1 < n:
                car.advance(force, u0, u1)
    return ride_result(t, road, out, faults, getattr(damper, "name", type(damper).__name__),
                   car.dt_s)
