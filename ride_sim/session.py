"""One closed-loop ride, sample by sample: the vehicle half of a hardware-in-the-loop run.

:class:`RideSession` holds the quarter car (:class:`~ride_sim.quarter_car.QuarterCar`) on
the run's random road and records every sample; whoever supplies the damper force (the ROS
``ride_sim`` node over ``/damper/state`` → ``/damper/force``, or a plug-in in
:func:`offline_run`) drives it with the same two calls::

    x, v = session.motion()      # damper stroke and velocity at sample k
    session.apply(force, fault)  # record sample k with the force held, advance to k + 1

so a lockstep run over ROS and :func:`offline_run` compute the same thing: the
zero-order-hold sampled coupling of :mod:`ride_sim.quarter_car`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ride_sim.params import QuarterCarParams, RideRunParams, RoadParams
from ride_sim.quarter_car import (O_SIZE, QuarterCar, RideResult, _record, _result,
                                  _road_pair, simulate)
from ride_sim.study import _start_state, metrics, random_road_input


def run_road(road: RoadParams, run: RideRunParams, dt_s: float
             ) -> tuple[np.ndarray, int]:
    """Road heights of the run at the samples and the number of lead-in samples."""
    road = dataclasses.replace(road, length_m=run.speed_m_s * run.duration_s,
                               lead_in_s=run.lead_in_s)
    heights, n_lead, _ = random_road_input(road, run.speed_m_s, run.seed, dt_s)
    return heights, n_lead


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
        self.heights, self.n_lead = run_road(road, run, dt_s)
        self.n = self.heights.size
        self.car = QuarterCar(car, dt_s, static_force_n)
        self.car.reset(_start_state(self.heights, dt_s))
        self.dt_s = self.car.dt_s
        self._out = np.empty((O_SIZE, self.n))
        self._faults = np.zeros(self.n, dtype=np.int64)
        self.k = 0

    @property
    def done(self) -> bool:
        return self.k >= self.n

    def time_ns(self, k: int | None = None) -> int:
        """Simulation time of sample ``k`` (default: the current one) [ns]."""
        return int(round((self.k if k is None else k) * self.dt_s * 1e9))

    def motion(self) -> tuple[float, float]:
        """Damper ``(stroke [m], velocity [m/s])`` at the current sample."""
        return self.car.damper_motion()

    def apply(self, force_n: float, fault: int = 0) -> None:
        """Record the current sample with ``force_n`` (full damper force, rebound +) held
        over the coming step, and advance the car to the next sample."""
        k = self.k
        if k >= self.n:
            raise IndexError("the ride is complete")
        u0, u1 = _road_pair(self.heights, k)
        _record(self.car._q, self.car._s, k, float(force_n), int(fault), u0, u1, self._out,
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
        return _result(t, self.heights[:k], self._out[:, :k], self._faults[:k], name,
                       self.dt_s)

    def metrics(self) -> dict[str, float]:
        """:func:`ride_sim.study.metrics` over the evaluated samples run so far."""
        if self.k <= self.n_lead + 1:
            raise ValueError("the ride stopped before the evaluated part began")
        return metrics(self.result(), self.n_lead, self.k)


def offline_run(car: QuarterCarParams, road: RoadParams, run: RideRunParams, dt_s: float,
                damper) -> tuple[RideResult, dict[str, float]]:
    """The same run with a damper plug-in in the compiled loop
    (:func:`~ride_sim.quarter_car.simulate`): the reference for a lockstep ROS run."""
    heights, n_lead = run_road(road, run, dt_s)
    result = simulate(car, damper, heights, dt_s, initial_state=_start_state(heights, dt_s))
    return result, metrics(result, n_lead, heights.size)
