"""One closed-loop ride, sample by sample: the vehicle half of a hardware-in-the-loop run.

:class:`RideSession` holds the quarter car (:class:`~ride_sim.quarter_car.QuarterCar`) on
the run's random road and records every sample; whoever supplies the damper force (the ROS
``ride_sim`` node over ``/damper/state`` → ``/damper/force``, or a plug-in in
:func:`offline_run`) drives it with the same two calls::

    x, v = session.motion()      # damper stroke and velocity at sample k
    session.apply(force, fault)  # record sample k with the force held, advance to k + 1

so a lockstep run over ROS and :func:`offline_run` compute the same thing: the
zero-order-hold sampled coupling of :mod:`ride_sim.quarter_car`.

:func:`semi_active_run` drives a session with the adaptive damper (docs/model.md §6) and a
controller that sets its valve command from the body and damper velocities at a fixed
rate (the skyhook ride study, :func:`ride_sim.adaptive_study.adaptive_study`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from damper_emulator.errors import UserError
from ride_sim.params import QuarterCarParams, RideRunParams, RoadParams
from ride_sim.quarter_car import (
    O_SIZE,
    Z2D,
    QuarterCar,
    RideResult,
    record_sample,
    ride_result,
    road_pair,
    simulate,
)
from ride_sim.study_runs import check_random_road, metrics, random_road_input, start_state


def _run_road_params(road: RoadParams, run: RideRunParams) -> RoadParams:
    """The road of the run: ``speed_m_s × duration_s`` long, with the run's lead-in."""
    return dataclasses.replace(road, length_m=run.speed_m_s * run.duration_s,
                               lead_in_s=run.lead_in_s)


def run_road(road: RoadParams, run: RideRunParams, dt_s: float
             ) -> tuple[np.ndarray, int]:
    """Road heights of the run at the samples and the number of lead-in samples."""
    heights, n_lead, _ = random_road_input(_run_road_params(road, run), run.speed_m_s,
                                           run.seed, dt_s)
    return heights, n_lead


def check_run_road(road: RoadParams, run: RideRunParams, dt_s: float) -> None:
    """Raise :class:`~ride_sim.road.RoadError` (one line) now if the run's road cannot be
    synthesised (:func:`~ride_sim.study_runs.check_random_road`): a caller that starts
    processes for the run (``damper-hil demo``) learns it before it starts them."""
    check_random_road(_run_road_params(road, run), run.speed_m_s, dt_s)


#: Samples of the scratch session of :meth:`RideSession.warm_up` (the first and the last
#: sample of a road take different branches of the road interpolation).
WARM_UP_SAMPLES = 4


class RideSession:
    """The quarter car on the run's road, advanced one sample per :meth:`apply`.

    Parameters
    ----------
    car, road, run :
        Vehicle, road spectrum and run parameters.
    dt_s : float
        Sample period [s].
    static_force_n : float
        The damper's force at rest at the static position (carried by the spring).
    """

    def __init__(self, car: QuarterCarParams, road: RoadParams, run: RideRunParams,
                 dt_s: float, static_force_n: float):
        heights, n_lead = run_road(road, run, dt_s)
        self._setup(car, heights, n_lead, dt_s, static_force_n)

    def _setup(self, car: QuarterCarParams, heights: np.ndarray, n_lead: int, dt_s: float,
               static_force_n: float) -> None:
        self.heights, self.n_lead = heights, n_lead
        self.n = self.heights.size
        self.car = QuarterCar(car, dt_s, static_force_n)
        self.car.reset(start_state(self.heights, dt_s))
        self.dt_s = self.car.dt_s
        self._out = np.empty((O_SIZE, self.n))
        self._faults = np.zeros(self.n, dtype=np.int64)
        self.k = 0

    @classmethod
    def on_road(cls, car: QuarterCarParams, heights: np.ndarray, n_lead: int, dt_s: float,
                static_force_n: float) -> RideSession:
        """A session on given road heights (one per sample, e.g.
        :func:`ride_sim.study_runs.random_road_input`) whose first ``n_lead`` samples are the
        lead-in the metrics leave out."""
        heights = np.ascontiguousarray(heights, dtype=float)
        if heights.ndim != 1 or heights.size < 2 or not np.isfinite(heights).all():
            raise UserError("road heights must be a finite 1-D array of at least 2 samples")
        if not 0 <= n_lead < heights.size:
            raise UserError(f"lead-in of {n_lead} samples must be shorter than the road "
                             f"({heights.size} samples)")
        self = cls.__new__(cls)
        self._setup(car, heights, int(n_lead), dt_s, static_force_n)
        return self

    def warm_up(self) -> None:
        """Load or compile the kernels of :meth:`motion`, :meth:`apply` and :meth:`last` by
        running a scratch session of :data:`WARM_UP_SAMPLES` samples on this road: a
        real-time caller pays this before its clock starts, not in its first periods.
        This session is not touched."""
        scratch = RideSession.on_road(self.car.params, self.heights[:WARM_UP_SAMPLES], 0,
                                      self.dt_s, self.car.static_force_n)
        while not scratch.done:
            _x, v = scratch.motion()
            scratch.body_velocity()
            scratch.apply(self.car.static_force_n + v, 0)
            scratch.last()

    @property
    def done(self) -> bool:
        return self.k >= self.n

    def time_ns(self, k: int | None = None) -> int:
        """Simulation time of sample ``k`` (default: the current one) [ns]."""
        return int(round((self.k if k is None else k) * self.dt_s * 1e9))

    def motion(self) -> tuple[float, float]:
        """Damper ``(stroke [m], velocity [m/s])`` at the current sample."""
        return self.car.damper_motion()

    def body_velocity(self) -> float:
        """Body (sprung mass) absolute vertical velocity ``z2'`` [m/s, up +] at the current
        sample (a deviation from rest, the road's own rate included)."""
        return float(self.car._s[Z2D])

    def apply(self, force_n: float, fault: int = 0) -> None:
        """Record the current sample with ``force_n`` (full damper force, rebound +) held
        over the coming step, and advance the car to the next sample."""
        k = self.k
        if k >= self.n:
            raise IndexError("the ride is complete")
        u0, u1 = road_pair(self.heights, k)
        record_sample(self.car._q, self.car._s, k, float(force_n), int(fault), u0, u1, self._out,
                self._faults)
        if k + 1 < self.n:
            self.car.advance(force_n, u0, u1)
        self.k = k + 1

    def last(self) -> np.ndarray:
        """The latest recorded sample's outputs (a row of :mod:`ride_sim.quarter_car`'s
        loop output layout)."""
        return self._out[:, self.k - 1]

    def result(self, name: str = "") -> RideResult:
        """Time histories of the samples run so far."""
        k = self.k
        t = np.arange(k) * self.dt_s
        return ride_result(t, self.heights[:k], self._out[:, :k], self._faults[:k], name,
                       self.dt_s)

    def metrics(self) -> dict[str, float]:
        """:func:`ride_sim.study_runs.metrics` over the evaluated samples run so far."""
        if self.k <= self.n_lead + 1:
            raise UserError("the ride stopped before the evaluated part began")
        return metrics(self.result(), self.n_lead, self.k)


def offline_run(car: QuarterCarParams, road: RoadParams, run: RideRunParams, dt_s: float,
                damper, *, compiled: bool = True) -> tuple[RideResult, dict[str, float]]:
    """The same run with a damper plug-in in the compiled loop
    (:func:`~ride_sim.quarter_car.simulate`): the reference for a lockstep ROS run.

    ``compiled=False`` steps the plug-in per sample and the car in Python, as the
    emulator and ride nodes do: the same arithmetic as theirs, where the compiled loop
    agrees to rounding (its kernels are compiled with fast-math, and may round
    differently inlined into the loop)."""
    heights, n_lead = run_road(road, run, dt_s)
    result = simulate(car, damper, heights, dt_s, initial_state=start_state(heights, dt_s),
                      compiled=compiled)
    return result, metrics(result, n_lead, heights.size)


@dataclass(frozen=True)
class SemiActiveRun:
    """Output of :func:`semi_active_run`: the ride, its metrics and the valve command
    commanded and in effect (after the solenoid lag) at every sample."""

    result: RideResult
    metrics: dict[str, float]
    command: np.ndarray
    effective_command: np.ndarray
    update_period_samples: int


def semi_active_run(car: QuarterCarParams, heights: np.ndarray, n_lead: int, dt_s: float,
                    damper, controller: Callable[[float, float], float],
                    update_period_samples: int) -> SemiActiveRun:
    """A ride with the adaptive damper under a valve-command controller.

    Sample ``k`` (as :func:`ride_sim.quarter_car.simulate`): the damper is stepped to the
    car's stroke and velocity at ``t_k`` (its solenoid lag driven by the command held since
    ``t_(k−1)``); every ``update_period_samples`` samples (from ``k = 0``) the controller
    is called with the body velocity ``z2'`` [m/s, up +] and the damper velocity [m/s,
    extension +] at ``t_k`` and its command (0 comfort .. 1 sport) holds until the next
    update (zero-order hold); the force is held over the step.  ``damper`` is a
    :class:`~ride_sim.dampers.CompressiblePlugin` (anything with ``reset``, ``force``,
    ``set_valve_command``, ``valve_command``, ``effective_valve_command``, ``last_fault``,
    ``static_force_n``); it starts settled at its current command.
    """
    period = int(update_period_samples)
    if period < 1:
        raise UserError(f"update period must be at least one sample, got {period}")
    session = RideSession.on_road(car, heights, n_lead, dt_s, damper.static_force_n)
    n = session.n
    command = np.empty(n)
    effective = np.empty(n)
    x, v = session.motion()
    force = float(damper.reset(x, v))
    fault = 0
    for k in range(n):
        if k > 0:
            x, v = session.motion()
            force = damper.force(x, v, session.dt_s)
            fault = damper.last_fault
        effective[k] = damper.effective_valve_command   # in effect over the step to t_k
        if k % period == 0:
            damper.set_valve_command(controller(session.body_velocity(), v))
        command[k] = damper.valve_command
        session.apply(force, fault)
    result = session.result(getattr(damper, "name", "semi-active"))
    return SemiActiveRun(result, metrics(result, session.n_lead, n), command, effective,
                         period)
