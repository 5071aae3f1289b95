"""The host's side of a damper in the loop: the quarter car drives the dyno.

:class:`HybridHost` is the :class:`~ride_sim.hybrid.rig_host.RigHost` whose run proper is
the ride (phase ``ride``): each cycle the quarter car
(:class:`~ride_sim.session.RideSession`) takes the measured force for the current sample
and advances; the compensator (:mod:`ride_sim.hybrid.compensator`) turns the car's next
states into the demand; the tracker follows the rig's delay and gain; the twin (the
damper's model on the measured motion) gives the force the model expects.  The road ramps
in over ``ramp_s``, the evaluated ``duration_s`` follows, then the road ramps out
(:func:`hybrid_road`).  The same road with the twin in place of the dyno is the
all-numerical reference (:func:`reference_run`), which the instability detector and the
report compare against.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from damper_emulator.model.compressible import DamperModel, DamperStepper
from damper_emulator.realtime.worker import Executor
from ride_sim.dampers import CompressiblePlugin
from ride_sim.hybrid.compensator import Compensator, steepest_slope
from ride_sim.hybrid.online import OnlineTwin
from ride_sim.hybrid.params import CompensatorParams, HybridRunParams, LearnParams, SafetyParams
from ride_sim.hybrid.rig_host import HOST_CYCLE_S, RECORD_COLUMNS, Command, RigHost, export_measured

__all__ = ["RECORD_COLUMNS", "RIDE_KEYS", "Command", "HybridHost", "HybridRoad",
           "export_measured", "hybrid_road", "reference_run"]
from ride_sim.hybrid.transfer import NOMINAL_ESTIMATE
from ride_sim.params import QuarterCarParams, RoadParams
from ride_sim.quarter_car import RideResult, simulate
from ride_sim.road_synthesis import iso8608_class
from ride_sim.session import RideSession
from ride_sim.study_runs import metrics, random_road_input, start_state

#: The ride metrics ``hybrid.json`` reports (``ride`` and ``reference``).
RIDE_KEYS = ("sws_rms", "accel_w_rms", "dtl_rms")


@dataclass(frozen=True)
class HybridRoad:
    """The ride's road: one height per cycle; ``[n_lead, n_lead + n_eval)`` is evaluated."""

    heights: np.ndarray
    n_lead: int
    n_eval: int

    @property
    def evaluated(self) -> slice:
        return slice(self.n_lead, self.n_lead + self.n_eval)


def hybrid_road(run: HybridRunParams, dt_s: float) -> HybridRoad:
    """The ISO 8608 random road of the run (eq 39 with the class's mean roughness),
    ramped in over ``ramp_s`` (raised cosine, taken from the periodic road's end), ramped
    out over ``ramp_s`` after the evaluated part and followed by ``ramp_s`` of flat road
    (the car settles).  Its longest wavelength is the shorter of 100 m and the evaluated
    length."""
    roughness = iso8608_class(run.road_class)
    length = run.speed_m_s * run.duration_s
    defaults = RoadParams()
    band = (max(defaults.band_cycles_per_m[0], 1.0 / length), defaults.band_cycles_per_m[1])
    road = dataclasses.replace(defaults, roughness=roughness.roughness,
                               waviness=roughness.waviness, length_m=length,
                               lead_in_s=run.ramp_s)
    heights, n_lead, n_eval = random_road_input(road, run.speed_m_s, run.seed, dt_s, band)
    n_ramp = n_lead
    ramp = 0.5 - 0.5 * np.cos(np.pi * np.arange(n_ramp) / max(n_ramp, 1))
    # the periodic road goes on after the evaluated part (one period) with its start
    out = np.take(heights[n_lead: n_lead + n_eval], np.arange(n_ramp), mode="wrap") \
        * ramp[::-1]
    heights = heights.copy()
    heights[:n_lead] *= ramp
    full = np.concatenate([heights, out, np.zeros(n_ramp)])
    return HybridRoad(full, n_lead, n_eval)


def reference_run(car: QuarterCarParams, model: DamperModel, road: HybridRoad, dt_s: float
                  ) -> tuple[RideResult, dict[str, float]]:
    """The all-numerical reference: the same road with the twin model in the loop."""
    damper = CompressiblePlugin(model, name="reference")
    result = simulate(car, damper, road.heights, dt_s,
                      initial_state=start_state(road.heights, dt_s))
    sl = road.evaluated
    return result, metrics(result, sl.start, sl.stop)


class HybridHost(RigHost):
    """The host's loop of a damper in the loop (see the module docstring).

    Parameters
    ----------
    run : HybridRunParams
    car : QuarterCarParams
    twin : DamperModel
        The damper's model: the twin, the compensator's prediction and the reference.
    compensator : CompensatorParams
    safety : SafetyParams
    dt_s : float
        The rig's cycle [s] (the host runs once per feedback).
    executor : Executor, optional
        Runs the identification's fit off the loop (default: at once, in the cycle).
    learn : LearnParams, optional
        The twin's online correction during the ride (``online``…; default: on).
    """

    RUN_PHASE = "ride"

    def __init__(self, run: HybridRunParams, car: QuarterCarParams, twin: DamperModel,
                 compensator: CompensatorParams, safety: SafetyParams, dt_s: float = HOST_CYCLE_S,
                 executor: Executor | None = None, learn: LearnParams | None = None
                 ) -> None:
        road = hybrid_road(run, dt_s)
        super().__init__(run, compensator, safety, dt_s, road.heights.size, executor)
        self.car = car
        self.twin_model = twin
        self.road = road
        self.reference, self.reference_metrics = reference_run(car, twin, self.road, dt_s)
        self.session: RideSession | None = None
        self.comp: Compensator | None = None
        self.twin = DamperStepper(twin)
        #: the twin's steepest slope (the force path's ``c``: :func:`steepest_slope`)
        self.twin_slope_ns_m = steepest_slope(twin)
        #: the twin's online correction (its map's force is ``force_model``)
        self.online = OnlineTwin(learn if learn is not None else LearnParams(),
                                 self.twin.force_n, self.twin_slope_ns_m, dt_s)
        #: the twin's force before the online correction, at each sample of the ride [N]
        self.twin_raw = np.full(road.heights.size, np.nan)
        self._prev_measured = (math.nan, math.nan)

    def warm_up(self) -> None:
        """Load or compile what the loop runs (the damper's and the car's kernels, the
        compensator's prediction, the identification's fit) before its clock starts: a
        compile inside the loop would stall it past the watchdog."""
        super().warm_up()
        stepper = DamperStepper(self.twin_model)
        stepper.warm_up()
        static = stepper.force_n
        RideSession.on_road(self.car, self.road.heights, 0, self.dt_s, static).warm_up()
        comp = Compensator(self.compensator_params, self.car, self.dt_s, static,
                           self.twin_model, self.road.heights, self.online)
        self.online.warm_up()
        comp.reset(0.0, 0.0)
        comp.observe(0.0, 0.0, static)
        comp.demand(np.zeros(4), 0, NOMINAL_ESTIMATE, NOMINAL_ESTIMATE.delay_s, 1.0)

    def _after_fit(self, t_s: float) -> tuple[float, float]:
        self.session = RideSession.on_road(self.car, self.road.heights, self.road.n_lead,
                                           self.dt_s, self.static_force_n)
        self.comp = Compensator(self.compensator_params, self.car, self.dt_s,
                                self.static_force_n, self.twin_model, self.road.heights,
                                self.online)
        x, v = self.session.motion()
        self.comp.reset(x, v)
        self.twin.reset(self._measured, 0.0)
        self._enter(self.RUN_PHASE, t_s)
        self.k = 0
        return self._ride_demand()

    def _ride_demand(self) -> tuple[float, float]:
        session, comp, tracker, est = self.session, self.comp, self.tracker, self.transfer
        assert session is not None and comp is not None and tracker is not None \
            and est is not None
        return comp.demand(session.car.state, session.k, est, tracker.delay_s, tracker.gain)

    def _run_cycle(self, t_s: float, t_ns: int) -> tuple[float, float]:
        session, comp = self.session, self.comp
        assert session is not None and comp is not None
        k = session.k
        if k >= session.n:
            self._enter("return", t_s)
            return self._return(t_s, None, t_ns)
        x_m, force = self._measured, self._force
        x_t, v_t = session.motion()
        comp.observe(x_t, v_t, force)
        session.apply(force)
        self.safety.tracking(t_s, x_m - x_t, float(self.reference.damper_stroke_m[k]))
        self._record_sample(k, x_t, t_ns)
        # the twin one sample behind, at the central difference of the measured stroke
        x1, x2 = self._prev_measured
        if k >= 1 and math.isfinite(x2):
            v1 = (x_m - x2) / (2.0 * self.dt_s)
            raw, _ = self.twin.step(x1, v1, self.dt_s)
            # a force from a held sample's motion is no prediction (half the velocity, a
            # spike of the damping force): NaN, and the residual leaves it out
            fresh = self.fresh
            predicted = fresh[k] and fresh[k - 1] and (k < 2 or fresh[k - 2])
            online = self.online
            # the twin's prediction, then the sample it predicted teaches it
            self.record[4, k - 1] = online.force(raw, x1, v1) if predicted else math.nan
            self.twin_raw[k - 1] = raw if predicted else math.nan
            measured = self.record[3, k - 1]
            if predicted and math.isfinite(measured):
                online.update(raw, x1, v1, measured)
        self._prev_measured = (x_m, x1)
        self.k = k + 1
        if not self.safety.enable:
            return self._demand, 0.0
        return self._ride_demand()

    # -- the outcome -------------------------------------------------------------------
    def ride_result(self) -> RideResult:
        """The car's histories over the samples ridden."""
        assert self.session is not None
        return self.session.result("hybrid")

    def ride_metrics(self) -> dict[str, float] | None:
        """The ride's metrics over the evaluated part, None when the ride stopped before
        its end."""
        if self.session is None or self.session.k < self.road.evaluated.stop:
            return None
        sl = self.road.evaluated
        return metrics(self.ride_result(), sl.start, sl.stop)

