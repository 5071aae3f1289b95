"""Model-based compensation of the transfer system: what to demand now so that the rig's
measured stroke follows the car's damper stroke.

The rig answers a demand after a pure delay ``d`` and through its servo
(:mod:`ride_sim.hybrid.transfer`).  To make the measured stroke equal the car's stroke at
every cycle, the demand sent at ``t_k`` is the servo's inverse applied to the car's stroke
``d`` ahead (plus half a cycle: the demand is held over the rig's cycle)::

    u_k = ( x̂ + (2ζ/ω) v̂ + â/ω² ) / g,    (x̂, v̂, â) = damper stroke, velocity and
                                             acceleration predicted at t_k + d + T/2

**The prediction is the car's own model, not an extrapolation.**  The quarter car is advanced
exactly (:class:`~ride_sim.quarter_car.QuarterCar`) over the horizon on the known road, with
the damper force of the twin model (the damper's model, stepped on the car's motion from the
state it has on the car's stroke) plus a band-limited correction by the measured force::

    F̂(t + h) = F_model(t + h) + LP_fc[ F_measured(t) − F_model(t) ]

Extrapolating the stroke from its own derivatives (the naive compensator) amplifies what
lies beyond the servo's bandwidth and lets the measured force reach the demand directly:
with a steep damper this closes a loop on the rig that limit-cycles.  Here the measured
force reaches the demand only through the car's inertia over the horizon and through the
correction's low-pass ``fc`` (``force_correction_hz``): :func:`force_path_gain` is the gain
of that loop, and the small-gain margin the report shows.

``mode: none`` demands the car's stroke as it is (uncompensated), for comparison.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from damper_emulator.model.compressible import DamperModel, DamperStepper
from damper_emulator.model.jit import kernel
from damper_emulator.model.step import step as damper_step
from ride_sim.hybrid.actuator import frequency_response
from ride_sim.hybrid.online import OnlineTwin, mapped_force
from ride_sim.hybrid.params import CompensatorParams
from ride_sim.hybrid.transfer import TransferEstimate
from ride_sim.params import QuarterCarParams
from ride_sim.quarter_car import (
    Q_DT,
    Q_FSTATIC,
    Q_MR,
    QuarterCar,
    advance_state,
    continuous_model,
    state_motion,
    wheel_force,
)

#: Fractional prediction steps are rounded to this many per cycle (their exact
#: discretisations are cached).
FRACTION_STEPS = 20

_Vec = NDArray[np.float64]


@kernel
def road_at(heights: _Vec, k: float) -> float:
    """The road at the fractional sample ``k`` (linear between samples; the last height
    beyond the end) [m]."""
    n = heights.size
    if k >= n - 1:
        last: float = heights[n - 1]
        return last
    i = int(k)
    h: float = heights[i] + (k - i) * (heights[i + 1] - heights[i])
    return h


@kernel
def predict(d: _Vec, d_fraction: _Vec, q: _Vec, a: _Vec, b: _Vec, s: _Vec, heights: _Vec,
            k: int, whole: int, fraction: float, prm: _Vec, coef_r: _Vec, coef_c: _Vec,
            twin: _Vec, theta: _Vec, static_n: float, correction: float
            ) -> tuple[float, float, float]:
    """The damper's stroke, velocity and acceleration ``whole + fraction`` cycles after the
    car's state ``s`` at sample ``k``: the car advanced exactly (``d``, and ``d_fraction``
    over the last ``fraction`` of a cycle) on the road ``heights``, with the twin's force
    (damper state ``twin``, stepped on the car's motion, through the online correction
    ``theta`` about ``static_n``: :func:`~ride_sim.hybrid.online.mapped_force`) plus
    ``correction``; the acceleration from the continuous model
    ``ṡ = A s + B (f_wheel, u, u̇)``.  ``s`` and ``twin`` are scratch: both end at the
    horizon."""
    dt = q[Q_DT]
    for j in range(whole):
        x, v = state_motion(q, s)
        force = mapped_force(theta, static_n, damper_step(prm, coef_r, coef_c, twin, x, v,
                                                          dt)[0], x, v) + correction
        advance_state(d, s, wheel_force(force, q[Q_FSTATIC], q[Q_MR]),
                      road_at(heights, k + j), road_at(heights, k + j + 1))
    x, v = state_motion(q, s)
    force = mapped_force(theta, static_n, damper_step(prm, coef_r, coef_c, twin, x, v,
                                                      dt)[0], x, v) + correction
    f_wheel = wheel_force(force, q[Q_FSTATIC], q[Q_MR])
    road0 = road_at(heights, k + whole)
    if fraction > 0.0:
        road1 = road_at(heights, k + whole + fraction)
        advance_state(d_fraction, s, f_wheel, road0, road1)
        x, v = state_motion(q, s)
        road0 = road1
    rate = (road_at(heights, k + whole + fraction + 1.0) - road0) / dt
    wheel_accel = _state_rate(a, b, s, 1, f_wheel, road0, rate)
    body_accel = _state_rate(a, b, s, 3, f_wheel, road0, rate)
    return x, v, -(wheel_accel - body_accel) / q[Q_MR]


@kernel
def _state_rate(a: _Vec, b: _Vec, s: _Vec, i: int, f_wheel: float, u: float, du: float
                ) -> float:
    """Row ``i`` of ``ṡ = A s + B (f_wheel, u, u̇)``."""
    rate: float = (a[i, 0] * s[0] + a[i, 1] * s[1] + a[i, 2] * s[2] + a[i, 3] * s[3]
                   + b[i, 0] * f_wheel + b[i, 1] * u + b[i, 2] * du)
    return rate


def effective_mass_kg(car: QuarterCarParams) -> float:
    """The mass the damper force accelerates at the damper's own stroke,
    ``MR² / (1/M_w + 1/M_b)`` [kg]: a force ``F`` changes the damper's stroke acceleration
    by ``−F / m``."""
    return car.motion_ratio ** 2 / (1.0 / car.unsprung_mass_kg + 1.0 / car.sprung_mass_kg)


class Compensator:
    """The demand of each cycle (see the module docstring).

    Parameters
    ----------
    params : CompensatorParams
    car : QuarterCarParams
    dt_s : float
        The host's cycle [s].
    static_force_n : float
        The force at rest at the static position (the host's tare).
    model : DamperModel
        The twin: the prediction's damper.
    heights : ndarray
        The road of the ride, one height per cycle (known ahead).
    online : OnlineTwin
        The twin's online correction: the prediction's damper force passes through its
        map, as it learns.
    """

    def __init__(self, params: CompensatorParams, car: QuarterCarParams, dt_s: float,
                 static_force_n: float, model: DamperModel, heights: np.ndarray,
                 online: OnlineTwin) -> None:
        self.params = params
        self.car = car
        self.dt_s = float(dt_s)
        self.static_force_n = float(static_force_n)
        self._heights = np.ascontiguousarray(heights, dtype=float)
        self._car = QuarterCar(car, dt_s, static_force_n)
        # the car over each fraction of a cycle the horizon can end in, made here: made
        # in the loop when the followed delay first reached it, its matrix exponential
        # took tens of milliseconds on a loaded 2-core machine and stopped rides on the
        # host's watchdog (the discretisations are cached: a second compensator for the
        # same car and cycle, the ride's after the warm-up's, computes none)
        self._fraction_cars = [self._car] + [
            QuarterCar(car, steps * dt_s / FRACTION_STEPS, static_force_n)
            for steps in range(1, FRACTION_STEPS)]
        a, b = continuous_model(car)
        self._a, self._b = np.ascontiguousarray(a), np.ascontiguousarray(b)
        self._mr = car.motion_ratio
        self.on_target = DamperStepper(model)
        self._s = np.zeros(4)
        self._twin = self.on_target.state.copy()
        self._model_force = self.on_target.force_n
        # the map's coefficients, read in place: they follow the online correction
        self._theta = online.theta
        self._static_n = online.static_n
        self._correction = 0.0
        self._alpha = 1.0 - math.exp(-2.0 * math.pi * params.force_correction_hz * dt_s)

    def reset(self, stroke_m: float, velocity_m_s: float) -> None:
        """The twin at quasi-steady equilibrium at the car's damper motion."""
        self.on_target.reset(stroke_m, velocity_m_s)
        self._model_force = self.on_target.force_n
        self._correction = 0.0

    def observe(self, stroke_m: float, velocity_m_s: float, force_measured_n: float) -> None:
        """Step the twin on the car's damper motion at this sample and update the
        measured-force correction with the force measured now."""
        raw, _ = self.on_target.step(stroke_m, velocity_m_s, self.dt_s)
        self._model_force = float(mapped_force(self._theta, self._static_n, raw, stroke_m,
                                               velocity_m_s))
        self._correction += self._alpha * (force_measured_n - self._model_force
                                           - self._correction)

    def demand(self, state: np.ndarray, k: int, estimate: TransferEstimate,
               delay_s: float, gain: float) -> tuple[float, float]:
        """The stroke demand [m] and its rate [m/s] for the car in ``state`` at
        sample ``k`` (the next sample's state, after the force of sample ``k − 1``), with
        the rig's delay ``delay_s`` and gain ``gain`` as followed now."""
        mr = self._mr
        if self.params.mode == "none":
            return (-(state[0] - state[2]) / mr, -(state[1] - state[3]) / mr)
        horizon = max(0.0, delay_s + 0.5 * self.dt_s - self.dt_s)
        whole = int(horizon / self.dt_s)
        fraction = int(round((horizon - whole * self.dt_s) / self.dt_s * FRACTION_STEPS))
        if fraction == FRACTION_STEPS:
            whole, fraction = whole + 1, 0
        car = self._car
        d_fraction = self._fraction_cars[fraction].matrix
        self._s[:] = state
        self._twin[:] = self.on_target.state
        model = self.on_target.model
        x, v, a = predict(car.matrix, d_fraction, car.kernel_params, self._a, self._b,
                          self._s, self._heights, k, whole, fraction / FRACTION_STEPS,
                          model.prm, model.tables[0].coef, model.tables[1].coef,
                          self._twin, self._theta, self._static_n, self._correction)
        w = 2.0 * math.pi * estimate.bandwidth_hz
        u = (x + 2.0 * estimate.damping / w * v + a / (w * w)) / gain
        # the demand's rate, for the rig to move on between commands (the jerk's term
        # left out)
        return u, (v + 2.0 * estimate.damping / w * a) / gain


def force_path_gain(params: CompensatorParams, estimate: TransferEstimate,
                    car: QuarterCarParams, damping_slope_ns_m: float, dt_s: float,
                    f_hz: np.ndarray | None = None) -> tuple[float, float]:
    """Peak gain of the loop the measured force closes through the compensator and the
    rig, and its frequency: ``(|L|max, f)``.

    A force measured now reaches the demand through the correction's low-pass and the car
    over the horizon ``h``: at most ``(h²/2 + (2ζ/ω) h + 1/ω²) / (m g)`` metres per newton
    (:func:`effective_mass_kg` ``m``); the rig turns the demand into stroke (``G(jω)``, the
    identified transfer) and the damper into force (``c jω``, ``c`` its steepest slope)::

        L(jω) = c jω G(jω) LP(jω) (h²/2 + (2ζ/ω_s) h + 1/ω_s²) / (m g)

    ``|L| < 1`` at every frequency: the loop cannot sustain an oscillation (small-gain
    theorem).  Uncompensated (``mode: none``) the demand does not see the force at all
    (0); that loop's stability is the car's with the rig's lag in it.
    """
    if params.mode == "none":
        return 0.0, math.nan
    f = np.geomspace(0.1, 0.5 / dt_s, 400) if f_hz is None else np.asarray(f_hz, float)
    horizon = estimate.delay_s + 0.5 * dt_s
    w_s = 2.0 * math.pi * estimate.bandwidth_hz
    reach = (horizon ** 2 / 2.0 + 2.0 * estimate.damping / w_s * horizon + 1.0 / w_s ** 2) \
        / (effective_mass_kg(car) * estimate.gain)
    lp = 1.0 / (1.0 + 1j * f / params.force_correction_hz)
    loop = damping_slope_ns_m * 2j * np.pi * f * frequency_response(estimate.actuator(), f) \
        * lp * reach
    i = int(np.argmax(np.abs(loop)))
    return float(np.abs(loop[i])), float(f[i])


#: Velocities over which :func:`steepest_slope` looks for the damper's steepest slope [m/s].
SLOPE_VELOCITIES_M_S = (0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5)


def steepest_slope(model: DamperModel) -> float:
    """The damper's steepest force–velocity slope ``dF/dv`` [N s/m] over
    :data:`SLOPE_VELOCITIES_M_S` both ways, from its quasi-steady force at rest at the static
    position (secants between neighbouring velocities, from 0): the ``c`` of
    :func:`force_path_gain`."""
    def force(v: float) -> float:
        return DamperStepper(model, 0.0, v).force_n

    steepest = 0.0
    for sign in (1.0, -1.0):
        previous_v, previous_f = 0.0, force(0.0)
        for v in SLOPE_VELOCITIES_M_S:
            f = force(sign * v)
            steepest = max(steepest, abs(f - previous_f) / v if previous_v == 0.0
                           else abs(f - previous_f) / (v - previous_v))
            previous_v, previous_f = v, f
    return steepest
